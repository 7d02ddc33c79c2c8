"""The Foxglove layout for pneumad's channels (:mod:`daemon.recordings.channels`), live or
recorded: ``python -m daemon.recordings.layout [RIG] > docs/foxglove-layout.json`` (the
committed file is the built-in rig's; tests/test_foxglove.py checks it names only what the
daemon advertises, and that it is this module's output).

One tab per joint (angle against set-point, tracking error, each command interface with its
limits, the chamber pressure commands), a tab for the tip path (y against x, measured and
set-point), and a tab for the loop and the controller. Every tab has a state strip (the loop's
mode, the safe state, the reference's phase: where the approach ends and the path begins)
and the daemon's log (trips, switches, references starting and ending). Built with
foxglove-sdk's own layout types, so the file is what Foxglove's "Import layout" reads.
"""
from __future__ import annotations

import json
import sys

from foxglove import layouts as fl

from daemon.recordings.channels import COMMANDS, CONTROLLER, LOG, LOOP, PRESSURES, TIP, TRACKING


def _plot(title: str, series: list[tuple[str, str, str]], ylabel: str, **config) -> fl.PlotPanel:
    """A plot panel; ``series``: (message path, label, line style)."""
    return fl.PlotPanel(title=title, config=fl.PlotConfig(
        paths=[fl.PlotSeries(value=path, label=label, line_style=style, enabled=True) for path, label, style in series],
        y_axis_label=ylabel, show_legend=True, legend_display="top", **config))


def _with_events(content) -> fl.SplitContainer:
    """A tab's plots above the state strip and the daemon's log."""
    strip = fl.StateTransitionsPanel(title="mode, output, reference phase", config=fl.StateTransitionsConfig(paths=[
        fl.StateTransitionsSeries(value=f"{TRACKING}.mode", label="mode"),
        fl.StateTransitionsSeries(value=f"{COMMANDS}.output", label="output"),
        fl.StateTransitionsSeries(value=f"{TRACKING}.phase", label="reference: approach | path | hold")]))
    log = fl.LogPanel(title="events", config=fl.LogConfig(topic_to_render=LOG))
    return fl.SplitContainer(direction="column", items=[
        fl.SplitItem(proportion=4, content=content), fl.SplitItem(proportion=1, content=strip),
        fl.SplitItem(proportion=1, content=log)])


def _joint_tab(joint: str, commands: list[str]) -> fl.TabItem:
    tracking = f"{TRACKING}.joints.{joint}"
    command_series = []
    for c in commands:
        at = f"{COMMANDS}.joints.{joint}.{c}"
        command_series += [(at, c, "solid"), (f"{at}_min", f"{c} lower limit", "dashed"),
                           (f"{at}_max", f"{c} upper limit", "dashed")]
    panels = [
        _plot(f"{joint}: angle and set-point", [(f"{tracking}.angle_deg", "angle", "solid"),
                                                (f"{tracking}.setpoint_deg", "set-point", "dashed")], "angle [deg]"),
        _plot(f"{joint}: tracking error", [(f"{tracking}.error_deg", "set-point - angle", "solid")], "error [deg]"),
        _plot(f"{joint}: commands in force (none in the safe state) and their limits", command_series,
              "V_MV [V] / pressure [Pa] / brake [N m]"),
        _plot(f"{joint}: chamber pressure commands (after the rig's limits)", [(f"{PRESSURES}.joints.{joint}.p_head_kpa", "head (a)", "solid"),
                                                       (f"{PRESSURES}.joints.{joint}.p_rod_kpa", "rod (b)", "dotted")],
              "pressure [kPa]"),
    ]
    grid = fl.SplitContainer(direction="column", items=[fl.SplitItem(content=p) for p in panels])
    return fl.TabItem(title=joint, content=_with_events(grid))


def build(describe: dict) -> fl.Layout:
    joints = [j["name"] for j in describe["joints"]]
    interfaces = describe.get("command_interfaces") or [{"joint": j, "name": "v_mv"} for j in joints]
    tabs = [_joint_tab(j, [c["name"] for c in interfaces if c["joint"] == j]) for j in joints]
    if len(joints) >= 2:
        tip = fl.PlotPanel(title="tip path (forward kinematics of the first two joints)", config=fl.PlotConfig(
            paths=[fl.PlotSeries(value=f"{TIP}.y_mm", x_value_path=f"{TIP}.x_mm", label="tip", enabled=True),
                   fl.PlotSeries(value=f"{TIP}.setpoint_y_mm", x_value_path=f"{TIP}.setpoint_x_mm", label="set-point",
                                 line_style="dashed", enabled=True)],
            x_axis_val="custom", x_axis_path=fl.PlotXAxisPath(value=f"{TIP}.x_mm", enabled=True), time_range="all",
            x_axis_label="x [mm]", y_axis_label="y [mm]", show_legend=True))
        tabs.append(fl.TabItem(title="tip path", content=_with_events(tip)))
    loop = fl.SplitContainer(direction="column", items=[
        fl.SplitItem(content=_plot("loop timing (per stats window)", [
            (f"{LOOP}.latency_us.p99", "wake-up latency p99", "solid"),
            (f"{LOOP}.compute_us.p99", "cycle's work p99 (read to commands)", "solid"), (f"{LOOP}.latency_us.max", "wake-up max", "dotted")],
            "time [us]")),
        fl.SplitItem(content=_plot("overruns (per stats window)", [(f"{LOOP}.overruns", "overruns", "solid")],
                                   "cycles")),
        fl.SplitItem(content=fl.RawMessagesPanel(title="controller internals (units from the controller)",
                                                 config=fl.RawMessagesConfig(topic_path=CONTROLLER))),
    ])
    tabs.append(fl.TabItem(title="loop and controller", content=_with_events(loop)))
    return fl.Layout(content=fl.TabContainer(tabs=tabs))


def main(argv=None) -> int:
    from hal import config  # the rig file's joints and command interfaces, as describe gives them
    from hal.actuation import RigActuation

    args = list(sys.argv[1:] if argv is None else argv)
    rig = config.load(args[0]) if args else config.load()
    describe = {"joints": [{"name": j.name} for j in rig.joints],
                "command_interfaces": [c.describe() for c in RigActuation(rig).commands]}
    print(json.dumps(json.loads(build(describe).to_json()), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
