"""The rig file's keys (docs/rigs.md): a joint's kind and its own limit keys, position sensors by
device kind, transmitters on a cylinder's chambers and on the supply, further analog inputs,
the 5/3 valve; every mistake refused by its key's name with the fix; and what each built-in
rig declares (hal.declare), which the cycle record and every reader follow."""
import subprocess
import sys
from pathlib import Path

import pytest

from daemon import assembly
from daemon.testing.loop import run_seconds, virtual_loop
from hal import config
from hal.declare import declare
from hal.errors import ConfigError
from hal.rig import RigIO
from hal.transport import create_transport, safe_outputs

ROOT = Path(__file__).resolve().parents[1]
ONE_JOINT = ROOT / "examples" / "rigs" / "one_joint.toml"
ARM, AXIS, MUSCLE = (config.load(name).source for name in ("sim", "sim-axis", "sim-muscle"))


def with_(text: str, old: str, new: str):
    assert old in text, old
    return config.parse(text.replace(old, new, 1))


def declared(rig) -> dict:
    """What a rig declares, in short: per joint (kind, actuation, state as name [unit], commands),
    and the rig's state."""
    outputs = [ch.name for ch in create_transport(rig, lambda: 0.0).outputs]
    d = declare(rig, outputs)
    return {"joints": {j.name: (j.kind, j.actuation, [f"{s.name} [{s.unit}]" for s in j.state],
                                [f"{c.name} [{c.unit}] {c.low:g}..{c.high:g}" for c in j.commands],
                                list(j.commanded_pressures)) for j in d.joints},
            "rig": [f"{s.name} [{s.unit}]" for s in d.rig], "outputs": list(d.outputs)}


BUILT_IN = {
    "sim": {"joints": {"bottom": ("rotary", "cylinder", ["position [rad]", "velocity [rad/s]"], ["v_mv [V] -4..6"],
                                  ["head", "rod"]),
                       "middle": ("rotary", "cylinder", ["position [rad]", "velocity [rad/s]"], ["v_mv [V] -4..6"],
                                  ["head", "rod"])},
            "rig": ["force [N]"], "outputs": ["ao0", "ao1", "ao2", "ao3"]},
    "sim-muscle": {"joints": {"elbow": ("rotary", "muscle_pair",
                                        ["position [rad]", "velocity [rad/s]", "p_a [Pa]", "p_b [Pa]"],
                                        ["pressure_a [Pa] 0..600000", "pressure_b [Pa] 0..600000",
                                         "brake [N m] 0..2"], ["a", "b"])},
                   "rig": [], "outputs": ["ao0", "ao1", "ao2"]},
    "sim-axis": {"joints": {"axis": ("linear", "valve", ["position [m]", "velocity [m/s]", "p_head [Pa]", "p_rod [Pa]"],
                                     ["valve [V] -5..5"], [])},
                 "rig": ["supply_pressure [Pa]"], "outputs": ["ao0"]},
}


@pytest.mark.parametrize("name", sorted(BUILT_IN))
def test_each_built_in_rig_declares_its_joints_kinds_sensors_and_commands(name):
    assert declared(config.load(name)) == BUILT_IN[name]


def test_the_linear_axis_declares_its_position_in_metres_shown_in_millimetres_within_its_limits():
    joint = declare(config.load("sim-axis"), ["ao0"]).joint("axis")
    position, velocity = joint.state[:2]
    assert (position.low, position.high) == pytest.approx((0.010, 0.190)) and position.display == ("mm", 1000.0)
    assert (velocity.low, velocity.high) == pytest.approx((-1.0, 1.0)) and velocity.display == ("mm/s", 1000.0)


def test_a_cylinder_joint_with_a_transmitter_on_each_chamber_declares_and_reads_them():
    """The rig the lab could not describe before: one rotary cylinder joint with chamber
    transmitters, a supply transmitter and a temperature input (examples/rigs/one_joint.toml).
    On the simulator its measured chamber pressures follow the commanded ones."""
    rig = config.load(ONE_JOINT)
    assert declared(rig) == {
        "joints": {"bottom": ("rotary", "cylinder", ["position [rad]", "velocity [rad/s]", "p_head [Pa]", "p_rod [Pa]"],
                              ["v_mv [V] -4..6"], ["head", "rod"])},
        "rig": ["supply_pressure [Pa]", "line_temperature [K]"], "outputs": ["ao0", "ao1"]}
    loop = virtual_loop(rig, "pid")
    try:
        loop.start()
        run_seconds(loop, 0.2)
        loop.enable()
        run_seconds(loop, 2.0)
        snap = loop.snapshot
        p_head, p_rod, supply, temperature = snap.measured
        assert loop.state.value == "enabled" and snap.faults == ()
        assert p_head == pytest.approx(loop.p_head[0], abs=5e3) and p_rod == pytest.approx(loop.p_rod[0], abs=5e3)
        assert snap.pressures == (p_head, p_rod)  # the pair a controller reads
        assert supply == pytest.approx(1.0e6, abs=5e3)  # the simulator's regulator supply
        assert temperature == pytest.approx(318.15, abs=0.1)  # an input the plant has no model of: mid-range
    finally:
        loop.shutdown("test")


LINEAR_JOINT = '[[joints]]\nname = "axis"\nkind = "linear"\n'
MUSCLE_DEVICES = '[joints.pressure_a]              # 1-5 V over 0-1 MPa\nchannel = "ai1"'


@pytest.mark.parametrize("text, old, new, message", [
    (AXIS, 'kind = "linear"', 'kind = "prismatic"', r'joints\[0\]\.kind: must be "rotary" or "linear"'),
    (AXIS, "max_speed_mm_s = 1000.0", "max_speed_deg_s = 60.0",
     r"joints\[0\]\.max_speed_deg_s: a linear joint has no max_speed_deg_s \(a linear joint's limits are "
     r"min_position_mm, max_position_mm, max_speed_mm_s"),
    (AXIS, "min_position_mm = 10.0", "min_angle_deg = 10.0", r"joints\[0\]\.min_angle_deg: a linear joint has no"),
    (ARM, "max_angle_deg = 175.0", "max_angle_deg = 175.0\nmax_position_mm = 20.0",
     r'joints\[0\]\.max_position_mm: a rotary joint has no max_position_mm \(set kind = "linear" for a linear joint'),
    (AXIS, "min_position_mm = 10.0", "", r"joints\[0\]\.min_position_mm: missing required key \(a linear joint's "
                                         r"limits: min_position_mm, max_position_mm\)"),
    (AXIS, "max_position_mm = 190.0", "max_position_mm = 250.0",
     r"joints\[0\]\.max_position_mm: the limits 10\.\.250 mm must lie within the cylinder's stroke, 0\.\.200 mm"),
    (AXIS, 'device = "linear_potentiometer"', 'device = "rdc506"',
     r"joints\[0\]\.sensor\.device: device kind 'rdc506' reads rad, but joint 'axis''s position \(linear\) is in m: "
     r"name a kind that reads m \(device = 'linear_potentiometer'\)"),
    (ARM, 'channel = "ai0"', 'device = "linear_potentiometer"\nchannel = "ai0"',
     r"joints\[0\]\.sensor\.device: device kind 'linear_potentiometer' reads m, but joint 'bottom''s position "
     r"\(rotary\) is in rad: name a kind that reads rad \(device = 'rdc506'\)"),
    (AXIS, 'device = "linear_potentiometer"', 'device = "lvdt9000"',
     r"joints\[0\]\.sensor\.device: unknown device kind 'lvdt9000' \(installed: analog, asfs, linear_potentiometer, "
     r"pressure_transmitter, rdc506"),
    (AXIS, "mm_per_ratio = 225.0", "", r"joints\[0\]\.sensor\.mm_per_ratio: missing required key"),
    (AXIS, '[joints.pressure_rod]\nchannel = "ai2"', '[joints.pressure_rod]\nchanel = "ai2"',
     r"joints\[0\]\.pressure_rod\.chanel: unknown key \(allowed here: channel, device, margin_mpa, mpa_per_volt"),
    (AXIS, '[joints.pressure_rod]\nchannel = "ai2"', '[joints.pressure_b]\nchannel = "ai2"',
     r"joints\[0\]\.pressure_b: a 5/3 valve \(valve\)'s chamber transmitters are pressure_head and pressure_rod "
     r"\(pressure_b is a muscle pair"),
    (MUSCLE, MUSCLE_DEVICES, '[joints.pressure_head]\nchannel = "ai1"',
     r"joints\[0\]\.pressure_head: a muscle pair .*'s chamber transmitters are pressure_a and pressure_b"),
    (AXIS, '[joints.pressure_head]       # 1-5 V over 0-1 MPa gauge\nchannel = "ai1"',
     '[joints.pressure_head]\nchannel = "ai1"\ndevice = "asfs"',
     r"joints\[0\]\.pressure_head\.device: device kind 'asfs' reads N, but a chamber's pressure is in Pa"),
    (AXIS, "[joints.valve]", "[joints.head]\nchannel = \"ao1\"\n\n[joints.valve]",
     r"joints\[0\]\.valve: a joint is a cylinder \(head, rod\) or a 5/3 valve \(valve\), not both \(head and valve given\)"),
    (AXIS, '[joints.valve]               # Festo MPYE-5-M5-010-B: 0-10 V, 5 V the closed centre, 100 l/min\n'
           'channel = "ao0"\ncentre_volts = 5.0\nsafe_volts = 4.99',
     '[joints.head]\nchannel = "ao0"\n[joints.rod]\nchannel = "ao1"',
     r"joints\[0\]\.head: a linear joint is driven by a 5/3 proportional valve \(\[joints\.valve\]\)"),
    (AXIS, "safe_volts = 4.99", "safe_volts = 12.0", r"joints\[0\]\.valve\.safe_volts: must be within 0\.0-10\.0 V"),
    (AXIS, "stroke_m = 0.200", "stroke_m = 0.200\nbore_mm = 25", r"joints\[0\]\.linear_axis\.bore_mm: unknown key"),
    (ARM, "[force_sensor]", "[supply_pressure]\nchannel = \"ai7\"\n\n[force_sensor]",
     r"supply_pressure\.channel: channel 'ai7' is already mapped to force_sensor"),
    (AXIS, '[supply_pressure]            # the supply line, after the service unit\nchannel = "ai3"',
     '[supply_pressure]\nchannel = "ai3"\n\n[[inputs]]\nname = "line_pressure"\nchannel = "ai5"\nunit = "bar"\n'
     'per_volt = 1.0\nlow = 0.0\nhigh = 10.0',
     r"inputs\[0\]\.unit: 'bar' is not SI: state the reading in Pa \(multiply per_volt, low and high by 100000\)"),
    (AXIS, '[supply_pressure]            # the supply line, after the service unit\nchannel = "ai3"',
     '[supply_pressure]\nchannel = "ai3"\n\n[[inputs]]\nname = "force"\nchannel = "ai5"\nunit = "N"\n'
     'per_volt = 1.0\nlow = 0.0\nhigh = 10.0',
     r"inputs\[0\]\.name: 'force' is a name the rig reports already"),
    (AXIS, "[joints.pressure_rod]", '[[joints.inputs]]\nname = "p_head"\nchannel = "ai5"\nunit = "Pa"\n'
                                    'per_volt = 1.0\nlow = 0.0\nhigh = 1.0\n\n[joints.pressure_rod]',
     r"joints\[0\]\.inputs\[0\]\.name: 'p_head' is a name the rig reports already"),
    (AXIS, "[joints.pressure_rod]", '[[joints.inputs]]\nname = "stroke"\nchannel = "ai5"\nunit = "mm"\n'
                                    'per_volt = 1.0\nlow = 0.0\nhigh = 1.0\n\n[joints.pressure_rod]',
     r"joints\[0\]\.inputs\[0\]\.unit: 'mm' is not SI: state the reading in m"),
    (AXIS, "[joints.pressure_rod]", '[[joints.inputs]]\nname = "rod_temp"\nchannel = "ai5"\nunit = "K"\n'
                                    'per_volt = 1.0\nlow = 300.0\nhigh = 200.0\n\n[joints.pressure_rod]',
     r"joints\[0\]\.inputs\[0\]\.high: the plausible range is inverted"),
    (AXIS, "[transport]\n", "[arm]\nlink_lengths_mm = [100.0]\n\n[transport]\n",
     r"arm: a rig with a linear joint \(axis\) is not a planar arm of rotary joints: leave \[arm\] out"),
    (AXIS, "tracking_error_mm = 10.0 ", "tracking_error_mm = -1.0 ", r"safety\.tracking_error_mm: must be within"),
])
def test_a_mistake_in_a_rig_file_is_refused_by_its_keys_name_with_the_fix(text, old, new, message):
    with pytest.raises(ConfigError, match=message):
        with_(text, old, new)


def test_a_rig_of_linear_joints_states_no_arm_and_one_of_rotary_joints_must(tmp_path):
    path = tmp_path / "axis.toml"
    path.write_text(AXIS)
    assert config.load(path).arm.link_lengths_mm == ()  # a user's file: [arm] not asked for
    start = ARM.index("[arm]\n")
    path.write_text(ARM[:start] + ARM[ARM.index("\n[", start) + 1:])  # the arm's file without its [arm] table
    with pytest.raises(ConfigError, match=r"\[arm\]: missing: a rig file must state it"):
        config.load(path)


def test_a_controller_that_cannot_drive_the_rigs_interface_is_refused_at_check_naming_those_that_can():
    """pid drives regulator pairs: on the valve-driven axis ``--check`` refuses it and says
    which controllers drive a valve (the registry knows each controller's actuation)."""
    done = subprocess.run([sys.executable, "-m", "daemon.main", "--check", "--config", "sim-axis", "--controller", "pid"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done
    assert "--controller: pid drives cylinder joints; joint 'axis' is a valve (controllers for it: hold" in done.stderr
    with pytest.raises(ConfigError, match=r"controllers for it: hold"):
        assembly.loop_parts(config.load("sim-axis"), 0.001, "muscle_eq")


def test_the_valve_is_the_command_the_io_writes_about_its_centre_and_its_safe_state_is_the_null():
    rig = config.load("sim-axis")
    io = RigIO(rig, create_transport(rig, lambda: 0.0))
    parts = assembly.loop_parts(rig, 0.001, "hold")
    assert io.safe_volts == (4.99,)
    assert parts.actuation.neutral == pytest.approx((-0.01,))  # enabled from the safe state: bumpless
    assert io.volts_for(*parts.actuation.outputs([1.5])) == [6.5]
    assert io.volts_for(*parts.actuation.outputs([-7.0])) == [0.0]  # clamped to the valve's 0-10 V
    centred = with_(AXIS, "safe_volts = 4.99", "")
    assert RigIO(centred, create_transport(centred, lambda: 0.0)).safe_volts == (5.0,)  # default: the closed centre


@pytest.mark.parametrize("name", [*sorted(BUILT_IN), str(ONE_JOINT)])
def test_the_safe_state_a_transport_writes_before_the_loop_is_the_ios_own(name):
    """hal.transport.safe_outputs (what a Modbus worker writes until the loop writes) and the
    drivers' safe state (what the loop writes outside enabled) are one sweep."""
    rig = config.load(name)
    assert safe_outputs(rig) == pytest.approx(RigIO(rig, create_transport(rig, lambda: 0.0)).safe_volts)
