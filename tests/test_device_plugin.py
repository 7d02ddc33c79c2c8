"""A sensor kind added by a package from outside pneumad's tree (tests/device_plugin.py: a
wheel pip installs), found through the entry-point group ``pneumad.devices`` as the built-in kinds
are: declared by the rig that names it, read on the simulator, accepted by ``pneumad --check``;
and a plugin that fails to import refused at ``--check`` with its own error."""
import json
import os
import subprocess
import sys

import pytest

from daemon.testing.loop import run_seconds, virtual_loop
from hal import config
from hal.declare import declare
from hal.devices import kinds
from hal.errors import ConfigError
from hal.plugins import installed
from hal.transport import GROUP, load_backend
from sim_backend.transport import SimTransport
from tests import device_plugin, doc_blocks

AXIS = config.load("sim-axis").source


def check(rig_path, site) -> subprocess.CompletedProcess:
    """``pneumad --check`` on a rig file, the plugin's directory on the daemon's path."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")]))}
    return subprocess.run([sys.executable, "-m", "daemon.main", "--check", "--config", str(rig_path)], env=env,
                          capture_output=True, text=True, timeout=120)


def test_a_kind_installed_from_outside_the_tree_is_declared_read_and_checked(tmp_path, monkeypatch):
    """The kind docs/rigs.md shows ("Add a device kind"), installed as its package."""
    module = doc_blocks.snippet("docs/rigs.md", "Add a device kind").text
    assert module == device_plugin.MODULE.rstrip()  # the helper's copy (for other tests) is the document's
    text = device_plugin.rig_text(AXIS)
    with pytest.raises(ConfigError, match=r"inputs\[0\]\.device: unknown device kind 'ad8495'"):
        config.parse(text)  # not installed yet
    site = device_plugin.install(tmp_path, module=module)
    monkeypatch.syspath_prepend(str(site))
    assert "ad8495" in kinds()
    rig = config.parse(text)
    interfaces = declare(rig, ["ao0"])
    oil = interfaces.rig[-1]
    assert (oil.owner, oil.name, oil.unit, oil.low, oil.high) == ("", "oil_temperature", "K", 253.15, 423.15)
    loop = virtual_loop(rig, "hold")  # the simulator has no model of it: it reads its range's middle
    try:
        loop.start()
        run_seconds(loop, 0.2)
        assert loop.snapshot.measured[-1] == pytest.approx(338.15, abs=0.2) and loop.snapshot.faults == ()
        loop.io.transport.inject("disconnect", "ai5")  # 0 V: -250 degC, no thermocouple reads that
        run_seconds(loop, 0.01)
        assert any(f.startswith("input oil_temperature: -250.0 degC is outside -20..150 degC")
                   for f in loop.snapshot.faults), loop.snapshot.faults
    finally:
        loop.shutdown("test")
    rig_path = tmp_path / "axis-with-oil.toml"
    rig_path.write_text(text)
    done = check(rig_path, site)
    assert done.returncode == 0, done.stderr
    assert "rig: measures supply_pressure [Pa], oil_temperature [K]" in done.stdout


def test_a_plugin_that_fails_to_import_is_refused_at_check_with_its_own_error(tmp_path):
    site = device_plugin.install(tmp_path, broken=True)
    rig_path = tmp_path / "axis-with-oil.toml"
    rig_path.write_text(device_plugin.rig_text(AXIS))
    done = check(rig_path, site)
    assert done.returncode == 2, done
    assert ("inputs[0].device: device kind 'ad8495' (lab_sensors:AD8495 from the package lab-sensors 0.1.0) failed "
            "to load: ModuleNotFoundError: No module named 'lab_sensors_missing_dependency' (fix or reinstall that "
            "package, or name another device kind)") in done.stderr


def test_the_built_in_transports_are_entry_points_too():
    assert sorted(installed(GROUP)) == ["can", "modbus", "serial", "sim"]
    assert load_backend("sim") is SimTransport
    with pytest.raises(ConfigError, match=r"transport\.backend: unknown backend 'warp' \(installed: can, modbus, "
                                          r"serial, sim; a backend of your own is a package with an entry point in the group 'pneumad\.transports'"):
        load_backend("warp")


@pytest.mark.slow(seconds=5)
def test_a_plugins_further_input_reaches_every_reader_of_the_cycle_record(tmp_path, monkeypatch):
    """The plugin's thermocouple, declared by the rig file and nothing else: a field of the cycle
    layout, so it is in describe, every state message, status, a recording's samples, its
    numpy columns and CSV, and the Foxglove channels, with no code that names it."""
    from daemon.recordings import mcap_log, reading
    from daemon.recordings.channels import SENSORS, Frames, json_schemas
    from daemon.testing.loop import dealer, make_loop, ok

    monkeypatch.syspath_prepend(str(device_plugin.install(tmp_path)))
    loop, captured, srv = make_loop(device_plugin.rig_text(AXIS), server=True, controller="hold")
    try:
        sock = dealer(srv)
        describe, controller = ok(loop, sock, "describe"), ok(loop, sock, "controller.get")
        run_seconds(loop, 0.2)
        status = ok(loop, sock, "status")
    finally:
        srv.close()
    oil = 338.15  # [K]: the simulator reads the middle of its range
    field = next(f for f in describe["cycle_layout"] if f["name"] == "oil_temperature")
    assert (field["unit"], field["group"], field["owner"]) == ("K", "measured", "")
    state = captured.of("state")[-1]
    assert state["layout"] == describe["cycle_layout_id"] and state["oil_temperature"][-1] == pytest.approx(oil, abs=0.2)
    assert status["rig"]["oil_temperature"] == pytest.approx(oil, abs=0.2)
    assert status["joints"]["axis"]["unit"] == "mm"  # a linear joint in its own unit
    path = tmp_path / "oil.mcap"
    with open(path, "wb") as f:
        recording = mcap_log.McapRecording(f, describe, controller)
        for topic, message in captured.messages:
            recording.write(topic, message)
        recording.finish()
    run = reading.open_run(path)
    assert run.layout.id == describe["cycle_layout_id"]
    assert run.samples[-1]["oil_temperature"] == pytest.approx(oil, abs=0.2)
    assert reading.load(path)["oil_temperature"][-1] == pytest.approx(oil, abs=0.2)
    reading.export_csv(path, tmp_path / "oil.csv")
    header, *rows = (tmp_path / "oil.csv").read_text().splitlines()
    column = header.split(",").index("oil_temperature [K]")
    assert float(rows[-1].split(",")[column]) == pytest.approx(oil, abs=0.2)
    assert "oil_temperature" in json_schemas(describe)[SENSORS]["properties"]
    frames = [data for topic, _, data in Frames(describe).state(state, rows=[0]) if topic == SENSORS]
    assert json.loads(frames[0])["oil_temperature"] == pytest.approx(oil, abs=0.2)
