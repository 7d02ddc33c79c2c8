"""The Foxglove layout for pneumad's channels (:mod:`daemon.recordings.channels`), live or
recorded: ``python -m daemon.recordings.layout [RIG] > docs/foxglove-layout.json`` (the
committed file is the built-in rig's; tests/test_foxglove.py checks it names only what the
daemon advertises, and that it is this module's output).

Made from the cycle record's layout (the describe's ``cycle_layout``): one tab per joint
(position against set-point and the tracking error in the unit a person reads the joint in,
deg or mm; each command interface with its limits; the chamber pressures commanded, and those
measured where a transmitter is wired), a tab for the rig's other sensors where it has any, a
tab for the tip path (y against x, measured and set-point) on a rig with link lengths, and a
tab for the loop and the controller. Every tab has a state strip (the loop's
mode, the safe state, the reference's phase: where the approach ends and the path begins)
and the daemon's log (trips, switches, references starting and ending). Built with
foxglove-sdk's own layout types, so the file is what Foxglove's "Import layout" reads.
"""
from __future__ import annotations

import json
import sys

from foxglove import layouts as fl

from daemon.recordings.channels import (
    COMMANDED_PRESSURES,
    COMMANDS,
    CONTROLLER,
    LOG,
    LOOP,
    MEASURED_PRESSURES,
    SENSORS,
    TIP,
    TRACKING,
    ChannelFields,
)
from daemon.recordings.legacy import layout_of


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


def _joint_tab(fields: ChannelFields, joint: str) -> fl.TabItem:
    tracking = f"{TRACKING}.joints.{joint}"
    keys = {name[len(joint) + 1:]: key for name, key, _ in fields.tracking[joint]}  # quantity -> its key
    unit = fields.layout[f"{joint}.position"].display[0]
    command_series = []
    for _, c in fields.commands[joint]:
        at = f"{COMMANDS}.joints.{joint}.{c}"
        command_series += [(at, c, "solid"), (f"{at}_min", f"{c} lower limit", "dashed"),
                           (f"{at}_max", f"{c} upper limit", "dashed")]
    styles = ("solid", "dotted")
    panels = [
        _plot(f"{joint}: position and set-point", [(f"{tracking}.{keys['position']}", "position", "solid"),
                                                   (f"{tracking}.{keys['setpoint']}", "set-point", "dashed")],
              f"position [{unit}]"),
        _plot(f"{joint}: tracking error", [(f"{tracking}.{keys['error']}", "set-point - position", "solid")],
              f"error [{unit}]"),
        _plot(f"{joint}: commands in force (none in the safe state) and their limits", command_series,
              "V_MV [V] / pressure [Pa] / brake [N m] / valve [V]"),
    ]
    if fields.commanded[joint]:
        panels.append(_plot(f"{joint}: chamber pressures commanded (after the rig's limits)",
                            [(f"{COMMANDED_PRESSURES}.joints.{joint}.{key}", key[:-4], style)
                             for (_, key), style in zip(fields.commanded[joint], styles)], "pressure [kPa]"))
    if fields.measured[joint]:
        panels.append(_plot(f"{joint}: chamber pressures measured",
                            [(f"{MEASURED_PRESSURES}.joints.{joint}.{key}", key[:-4], style)
                             for (_, key), style in zip(fields.measured[joint], styles)], "pressure [kPa]"))
    grid = fl.SplitContainer(direction="column", items=[fl.SplitItem(content=p) for p in panels])
    return fl.TabItem(title=joint, content=_with_events(grid))


def build(describe: dict) -> fl.Layout:
    fields = ChannelFields(layout_of(describe))
    joints = fields.joints
    tabs = [_joint_tab(fields, j) for j in joints]
    named = [(n, f"{SENSORS}.{n}") for n in fields.sensors] + [
        (name, f"{SENSORS}.joints.{j}.{q}") for j, pairs in fields.inputs.items() for name, q in pairs]
    if named:
        layout = fields.layout
        panels = [_plot(f"{n} [{layout[n].unit}]", [(path, n, "solid")], f"{n} [{layout[n].unit}]")
                  for n, path in named]
        tabs.append(fl.TabItem(title="sensors", content=_with_events(
            fl.SplitContainer(direction="column", items=[fl.SplitItem(content=p) for p in panels]))))
    arm = describe.get("arm", {}).get("link_lengths_mm", [])
    if len(joints) >= 2 and len(arm) >= 2:
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
    from daemon.wire.cycle_layout import CycleLayout  # the rig's cycle record, as describe gives it
    from hal import config
    from hal.actuation import RigActuation
    from hal.declare import declare
    from hal.transport import rig_channels

    args = list(sys.argv[1:] if argv is None else argv)
    rig = config.load(args[0]) if args else config.load()
    layout = CycleLayout.of(declare(rig, [ch.name for ch in rig_channels(rig)[1]]))
    describe = {"joints": [{"name": j.name} for j in rig.joints], "cycle_layout": layout.describe(),
                "command_interfaces": [c.describe() for c in RigActuation(rig).commands],
                "arm": {"link_lengths_mm": list(rig.arm.link_lengths_mm)}}
    print(json.dumps(json.loads(build(describe).to_json()), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
