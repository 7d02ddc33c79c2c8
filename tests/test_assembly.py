"""The one assembler (daemon/assembly.py): what it builds, once, and `pneumad --check` built
through it without opening anything."""
from __future__ import annotations

import sys

import pytest

from daemon import assembly, main
from daemon.loop.clock import VirtualClock
from hal import config
from hal.regulator import ITV0051


def test_each_regulator_is_built_once_and_shared_by_the_io_and_the_command_interfaces(monkeypatch):
    built = []  # the regulators the hal's drivers build (a nominal model's constants are the controllers')
    original = ITV0051.__init__

    def counted(self, *args, **kwargs):
        if sys._getframe(1).f_globals["__name__"].startswith("hal."):
            built.append(self)
        original(self, *args, **kwargs)

    monkeypatch.setattr(ITV0051, "__init__", counted)
    rig = config.load()
    loop = assembly.build_loop(rig, VirtualClock(), 0.001, "pid")
    try:
        assert len(built) == 2 * len(rig.joints)  # a head and a rod regulator per cylinder joint
        assert loop.io.head + loop.io.rod == built
        # V_MV -> head pressure goes through the very regulator the output sweep uses
        loop.start()
        p_head, _, _ = loop.actuation.outputs([0.5] * loop.actuation.width)
        assert p_head == [reg.pressure(j.head.bias_volts + 0.5) for reg, j in zip(loop.io.head, rig.joints)]
    finally:
        loop.shutdown("test")


def test_the_loop_runs_on_the_parts_the_assembler_built():
    rig = config.load()
    parts = assembly.loop_parts(rig, 0.002, "hold")
    assert parts.context.dt == 0.002 and parts.controller.name == "hold" and parts.fallback is None
    loop = assembly.build_loop(rig, VirtualClock(), 0.002, "hold")
    try:
        assert loop.period == 0.002 and loop.controller.name == "hold"
        assert loop.context.u_min == parts.context.u_min
    finally:
        loop.shutdown("test")


def test_the_help_names_every_built_in_rig(capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "400")  # an option a line: no name broken at its hyphen
    with pytest.raises(SystemExit):
        main.main(["run", "--help"])
    lines = capsys.readouterr().out.splitlines()
    config_help = next(line for line in lines if line.lstrip().startswith("--config CONFIG"))
    assert all(name in config_help for name in config.BUILTIN_RIGS)


def test_check_builds_the_controller_and_opens_nothing(capsys, caplog, tmp_path):
    # a serial transport to a port that does not exist: --check never opens it
    assert main.main(["--check", "--transport", "serial", "--transport-option", "port=/nonexistent/pneumad"]) == 0
    out = capsys.readouterr().out
    assert "transport serial, controller pid" in out and "joint bottom" in out
    assert main.main(["--check", "--controller", "no-such-controller"]) == 2
    assert main.main(["--check", "--transport-option", "port=x"]) == 2  # not an option of the rig file's transport
    # what the start would refuse, --check refuses: a backend's name, its options, a frame source
    builtin = config.load().source
    for rig_text, problem in ((builtin.replace('backend = "sim"', 'backend = "simm"', 1), "unknown backend 'simm'"),
                              (builtin + '\n[contact_sensor]\nsource = "pad9"\n', "contact_sensor.source: unknown")):
        rig = tmp_path / "rig.toml"
        rig.write_text(rig_text)
        caplog.clear()
        assert main.main(["--check", "--config", str(rig)]) == 2
        assert problem in caplog.text
    caplog.clear()
    assert main.main(["--check", "--transport", "serial", "--transport-option", "prot=/dev/ttyACM0"]) == 2
    assert "transport.options.prot: unknown key" in caplog.text


def test_the_messenger_waits_out_the_pause_the_rig_file_allows_before_answering_for_the_loop(tmp_path):
    # a rig whose loop may wake up to 0.5 s late (it trips itself then, and cycles on): the
    # messenger must not refuse requests as `loop_stalled` before the loop's own limit has come
    slow = tmp_path / "slow.toml"
    slow.write_text(config.load().source.replace("stall_after_s = 0.05", "stall_after_s = 0.5"))
    endpoints = [f"--{name}=ipc://{tmp_path}/{name}" for name in ("command", "control", "telemetry")]
    for rig_file, watch_s in ((None, 0.5), (slow, 1.0)):
        args = main.parser().parse_args(["run", *endpoints, "--record-dir", "none"]
                                        + ([] if rig_file is None else ["--config", str(rig_file)]))
        rig = assembly.rig_of(args)
        with assembly.messenger(args, rig) as server:
            assert server.messenger.stall_s == watch_s


def test_a_transport_option_without_transport_replaces_one_of_the_rig_files_transport(capsys):
    """``pneumad run --transport-option compiled=true``: the rig file's own backend, that option
    replaced (and said in --help); the rig's hash tells the run apart."""
    args = main.parser().parse_args(["run", "--transport-option", "compiled=true"])
    rig, plain = assembly.rig_of(args), config.load()
    assert rig.transport.backend == plain.transport.backend == "sim"
    assert rig.transport.options == {**plain.transport.options, "compiled": True} and rig.hash != plain.hash
    with pytest.raises(SystemExit):
        main.parser().parse_args(["run", "--help"])
    assert "without --transport, one of the rig file's own transport replaced" in " ".join(capsys.readouterr().out.split())
