"""Every reader of the cycle record follows its layout, with no code of its own per rig: a field
a rig adds (a sensor kind installed from outside the tree) reaches ``watch``, the plots, the
Bluesky signals and ``recordings.load`` as the layout names it; and the worked rigs (the
example rig file, the built-in linear axis, the 2-joint arm and the muscle joint) show in
``watch`` and the plots in their display units (a linear joint in mm, a rotary one in deg),
every axis labelled with its unit, commanded and measured pressures named apart."""
from __future__ import annotations

import math
import os
import re
from pathlib import Path

import matplotlib.pyplot as plt
import pytest
from rich.console import Console

from daemon.client import plots
from daemon.client.client import Client
from daemon.client.watch import View, line
from daemon.recordings import mcap_log, reading
from daemon.testing.daemons import STOP_WAIT_S
from daemon.testing.loop import make_loop, ok, run_seconds
from hal import config
from tests import device_plugin
from tests.daemons import real_daemon, wait_for_own_daemon

ROOT = Path(__file__).resolve().parents[1]
RIGS = {"one-joint": (ROOT / "examples" / "rigs" / "one_joint.toml").read_text(),
        "sim-axis": config.load("sim-axis").source, "sim": config.load("sim").source,
        "sim-muscle": config.load("sim-muscle").source}


@pytest.fixture(autouse=True)
def close_figures():
    yield
    plt.close("all")


def tolerant(text: str) -> str:
    """A rig file whose stall limit a busy test machine does not trip (tests/daemons.py says why)."""
    changed = re.sub(r"stall_after_s = [0-9.]+", "stall_after_s = 5.0", text)
    assert changed != text
    return changed


def rendered(view: View) -> str:
    console = Console(record=True, width=160)
    console.print(view.render())
    return console.export_text()


def recorded(tmp_path: Path, rig_text: str, seconds: float = 0.6) -> tuple[Path, dict, dict]:
    """An in-process loop on ``rig_text``, enabled, its telemetry recorded as the daemon's
    recorder writes it: (the MCAP file, describe, the last state message)."""
    loop, captured, srv = make_loop(rig_text, server=True, controller=config.parse(rig_text).rig.controller or "pid")
    try:
        from daemon.testing.loop import dealer
        sock = dealer(srv)
        describe = ok(loop, sock, "describe")
        lease = ok(loop, sock, "lease.acquire", {"ttl_s": 60.0})["lease"]
        ok(loop, sock, "enable", lease=lease)
        run_seconds(loop, seconds)
        controller = ok(loop, sock, "controller.get")
    finally:
        srv.close()
    path = tmp_path / "run.mcap"
    with open(path, "wb") as f:
        recording = mcap_log.McapRecording(f, describe, controller)
        for topic, message in captured.messages:
            if topic in ("state", "event"):
                recording.write(topic, message)
        recording.finish()
    return path, describe, captured.of("state")[-1]


@pytest.mark.parametrize("name", list(RIGS))
def test_each_worked_rig_shows_in_watch_and_the_plots_in_its_display_units(name, tmp_path):
    path, describe, last = recorded(tmp_path, RIGS[name])
    run = reading.open_run(path)
    layout = run.layout
    assert layout.id == describe["cycle_layout_id"]
    joints = layout.owners()
    # watch: each joint's position in its display unit, with no code for this rig
    view = View(describe)
    view.take("state", last)
    text = rendered(view)
    assert run.samples[-1]["cycle"] == last["cycle"][-1]  # the recording holds what watch saw last
    for j in joints:
        unit = layout[f"{j}.position"].display[0]
        assert unit == ("mm" if layout[f"{j}.position"].unit == "m" else "deg")
        shown = last[f"{j}.position"][-1] * layout[f"{j}.position"].display[1]
        assert f"{shown:.2f} {unit}" in text, (j, text)
        assert f"{j}.position" in line(layout, last) or f"{shown:.2f} {unit}" in line(layout, last)
    # the plots: every axis says its unit; positions in deg or mm; commanded and measured apart
    made = plots.figures([("run", run)])
    for figure, fig in made.items():
        if fig is None or figure.startswith("internals"):
            continue
        for ax in fig.axes:
            assert re.search(r"\[[^\]]+\]$", ax.get_ylabel()), (figure, ax.get_ylabel())
            assert ax.get_xlabel() in ("", "time [s]", "x [mm]"), (figure, ax.get_xlabel())
    for ax, j in zip(made["joints"].axes, joints):
        assert ax.get_ylabel() == f"position [{layout[f'{j}.position'].display[0]}]"
        drawn = next(line for line in ax.get_lines() if line.get_label() == "run position")
        finite = [v for v in drawn.get_ydata() if v == v]
        assert finite[-1] == pytest.approx(math.degrees(run.samples[-1][f"{j}.position"])
                                           if layout[f"{j}.position"].unit == "rad"
                                           else 1000.0 * run.samples[-1][f"{j}.position"])
    if any(f.group == "commanded" for f in layout.fields) and made["pressures"] is not None:
        labels = {line.get_label() for ax in made["pressures"].axes for line in ax.get_lines()}
        commanded = {lb for lb in labels if " commanded " in lb}
        measured = {lb for lb in labels if " measured " in lb}
        assert commanded and not commanded & measured
        if any(f.group == "measured" and f.quantity.startswith("p_") for f in layout.fields):
            assert measured, labels


def test_a_field_a_rig_adds_reaches_every_reader(tmp_path, monkeypatch):
    """A thermocouple of a kind installed from outside the tree (tests/device_plugin.py) on the
    linear axis: the layout gains ``oil_temperature`` [K], and watch, the Bluesky device, a
    recording's columns and the plots show it, by that name, in that unit."""
    site = device_plugin.install(tmp_path)
    monkeypatch.syspath_prepend(str(site))  # installed where the readers run too (the Bluesky device reads the rig file)
    rig_path = tmp_path / "axis-with-oil.toml"
    rig_path.write_text(tolerant(device_plugin.rig_text(config.load("sim-axis").source)))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")]))}
    daemon, eps = real_daemon(tmp_path, "--config", str(rig_path), env=env)
    try:
        with Client(**eps, timeout=5.0) as client:
            wait_for_own_daemon(client, daemon)
            layout = client.layout()
            oil = layout["oil_temperature"]
            assert (oil.unit, oil.owner, oil.group) == ("K", "", "measured")
            # watch: the live view and the piped line
            view = View(client.describe())
            with client.latest() as feed:
                sample = feed.row()
                sub = client.subscribe((b"state",))
                topic, message = sub.receive(5.0)
                sub.close()
            view.take(topic, message)
            assert view.foreign == 0 and "rig: supply_pressure" in rendered(view)
            assert re.search(r"oil_temperature 3\d\d\.\d\d K", rendered(view)), rendered(view)
            assert line(layout, message).split()[0] == message["mode"][-1]
            assert sample["oil_temperature"] == pytest.approx(338.15, abs=1.0)  # the simulator: its range's middle
            _bluesky_reads_the_field(eps, tmp_path)
            # a recording of the feed: a column by the field's name
            path = tmp_path / "oil.mcap"
            mcap_log.record(client, str(path), 0.5)
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
    columns = reading.load(path)
    assert "oil_temperature" in columns and columns.layout["oil_temperature"].unit == "K"
    assert abs(float(columns["oil_temperature"][-1]) - 338.15) < 1.0
    rig_figure = plots.figures([("oil", reading.open_run(path))])["rig"]
    assert "oil_temperature [K]" in [ax.get_ylabel() for ax in rig_figure.axes]


def _bluesky_reads_the_field(eps: dict, tmp_path: Path) -> None:
    from tests import extras
    if extras.missing("bluesky"):
        pytest.skip(extras.reason("bluesky"))
    import bluesky.plan_stubs as bps
    from bluesky import RunEngine
    from bluesky.run_engine import call_in_bluesky_event_loop

    from daemon.client.bluesky.device import PneumadRig
    rig = PneumadRig.connect_to("axis", hdf5_directory=str(tmp_path), **eps)
    try:
        seen = {}

        def read():
            seen["oil"] = yield from bps.rd(rig.oil_temperature)
            seen["position"] = yield from bps.rd(rig.joints[0].position)
        engine = RunEngine({})
        engine(read())
        seen["described"] = call_in_bluesky_event_loop(rig.describe())
    finally:
        rig.close()
    assert seen["oil"] == pytest.approx(338.15, abs=1.0)
    assert rig.oil_temperature.source == f"pneumad://{rig.link.rig_name}/rig/oil_temperature"
    assert 0.0 < seen["position"] < 1000.0  # [mm] on the axis's stroke
    units = {key: d.get("units") for key, d in seen["described"].items()}
    assert units[rig.joints[0].position.name] == "mm" and units[rig.oil_temperature.name] == "K", units


def test_a_state_message_of_another_layout_is_not_read_through_this_one():
    """A daemon restarted with another rig file: its messages name another layout, which watch
    counts and says, never reading its columns as this layout's."""
    from daemon.wire.cycle_layout import MODES, CycleLayout
    from hal.declare import declare

    def layout_of(name: str) -> CycleLayout:
        rig = config.load(name)
        return CycleLayout.of(declare(rig, [c for j in rig.joints for _, c in j.output_channels()]))
    arm, axis = layout_of("sim"), layout_of("sim-axis")
    record = axis.record()
    record[axis["mode"].index] = float(MODES.index("enabled"))
    record[axis["cycle"].index] = 7.0
    view = View({"cycle_layout": arm.describe(), "command_interfaces": []})
    view.take("state", {"seq": 1, "layout": axis.id, **axis.columns([record])})
    assert view.state is None and view.foreign == 1
    assert "1 state messages of another layout not shown" in rendered(view)
