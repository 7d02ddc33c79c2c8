"""The antagonistic muscle rig (rig-facts §2): its devices, the muscle statics and the
equilibrium model, the rig file, the controllers on the simulated joint through the real
loop (steps, stiffness, a plant off the nominal model, a sensor fault), and refusals."""
import math

import pytest

from bench import muscle_steps
from bench.scenarios import make_loop
from controllers import registry
from controllers.base import ParamError
from controllers.trajectory import JointMove
from hal import config
from hal.errors import CommandError, ConfigError
from hal.mr_brake import BrakeConfig, MRBrake
from hal.muscle import MuscleConfig, MuscleJoint, MusclePair
from hal.pressure_sensor import PressureSensor, PressureSensorConfig
from hal.valve import ProportionalValve, ValveConfig
from daemon.testing.simrig import make_rig

DEG = math.pi / 180.0
RIG = config.load("sim-muscle")


def test_the_valve_converts_both_ways_clamps_to_its_range_and_refuses_nan():
    valve = ProportionalValve(ValveConfig("ao0", mpa_per_volt=0.06, max_mpa=0.6))
    assert valve.volts(0.3e6) == pytest.approx(5.0)
    assert valve.pressure(valve.volts(0.42e6)) == pytest.approx(0.42e6)
    assert valve.volts(2.0e6) == pytest.approx(10.0) and valve.volts(-1e5) == 0.0
    with pytest.raises(CommandError, match="valve ao0: non-finite"):
        valve.volts(math.nan)


def test_the_pressure_sensor_flags_what_cannot_be_true():
    sensor = PressureSensor(PressureSensorConfig("ai1"))
    assert sensor.convert(sensor.volts_for(0.25e6)) == pytest.approx(0.25e6)
    assert math.isnan(sensor.convert(0.0))  # a broken wire reads 0 V, below the 1 V live zero
    assert "below zero" in sensor.diagnose(0.0)
    assert math.isnan(sensor.convert(9.9)) and "over the sensor" in sensor.diagnose(9.9)


@pytest.mark.parametrize("exponent", [1.0, 2.0])
def test_the_brake_calibration_is_invertible_and_clamped(exponent):
    brake = MRBrake(BrakeConfig("ao2", max_nm=2.0, exponent=exponent))
    assert brake.torque(brake.volts(0.7)) == pytest.approx(0.7)
    assert brake.volts(5.0) == 10.0 and brake.volts(-1.0) == 0.0
    with pytest.raises(CommandError):
        brake.volts(math.inf)


@pytest.mark.parametrize("angle_deg", [0.0, 30.0, 45.0, 80.0, 100.0])
@pytest.mark.parametrize("stiffness_nm_deg", [0.2, 0.5])
def test_the_equilibrium_pressures_give_back_the_torque_and_stiffness_asked_for(angle_deg, stiffness_nm_deg):
    pair = MusclePair(MuscleConfig())
    theta, k, torque = angle_deg * DEG, stiffness_nm_deg / DEG, 1.5
    pa, pb = pair.equilibrium(theta, k, torque)
    assert pa > 0 and pb > 0
    assert pair.torque(pa, pb, theta) == pytest.approx(torque, rel=1e-9)
    assert pair.stiffness(pa, pb, theta) == pytest.approx(k, rel=1e-9)
    # the stiffness range's ends put a pressure on a bound (0 or the maximum)
    lo, hi = pair.stiffness_range(theta, torque, 0.6e6)
    for end in (lo, hi):
        ends = pair.equilibrium(theta, end, torque)
        assert min(abs(ends[0]), abs(ends[1]), abs(ends[0] - 0.6e6), abs(ends[1] - 0.6e6)) < 1.0


def test_gravity_pulls_the_link_back_to_hanging():
    joint = MuscleJoint.from_rig(RIG, RIG.joints[0])
    assert joint.gravity_torque(0.0) == pytest.approx(0.0, abs=1e-12)
    weight = (0.168 * 0.240 + 16.66 / 9.81 * 0.250) * 9.81
    assert joint.gravity_torque(90 * DEG, 16.66) == pytest.approx(-weight)


def test_a_joint_is_a_cylinder_or_a_muscle_pair_and_names_every_device_of_it():
    text = RIG.source
    no_valve_b = text.replace('[joints.valve_b]\nchannel = "ao1"\nmpa_per_volt = 0.06\nmax_mpa = 0.6\nsafe_mpa = 0.0', "")
    with pytest.raises(ConfigError, match=r"joints\[0\]\.valve_b: missing: a muscle-pair joint names"):
        config.parse(no_valve_b, "bad.toml")
    both = text.replace("[joints.sensor]", '[joints.head]\nchannel = "ao7"\n\n[joints.sensor]', 1)
    with pytest.raises(ConfigError, match="a cylinder .* or a muscle pair"):
        config.parse(both, "bad.toml")
    clash = text.replace('[joints.pressure_b]\nchannel = "ai2"', '[joints.pressure_b]\nchannel = "ai1"')
    with pytest.raises(ConfigError, match="already mapped"):
        config.parse(clash, "bad.toml")


def test_controllers_are_refused_on_joints_they_do_not_drive():
    muscle = make_rig(name="sim-muscle").context()
    with pytest.raises(ParamError, match="pid drives cylinder joints; joint 'elbow' is a muscle_pair .*muscle_eq"):
        registry.build("pid", muscle)
    with pytest.raises(ParamError, match="muscle_eq drives muscle_pair joints"):
        registry.build("muscle_eq", make_rig().context())
    assert registry.build("hold", muscle).step is not None  # hold repeats any rig's output
    with pytest.raises(ParamError, match="no brake"):
        registry.build("muscle_eq", make_rig(name="sim-muscle", replace={
            '[joints.brake]                   # MR brake: 0-2 N m over 0-10 V\nchannel = "ao2"\nmax_nm = 2.0\n'
            'safe_nm = 2.0': ""}).context(), {"brake_linear": [0.5]})


@pytest.mark.parametrize("controller, start, end", [("muscle_eq", 0.0, 45.0), ("muscle_eq", 0.0, 90.0),
                                                    ("muscle_eq", 90.0, 45.0), ("muscle_pid", 0.0, 45.0)])
def test_a_step_settles_within_the_chapters_times_and_holds(controller, start, end):
    (t, q, pa, pb), settling = muscle_steps.step_case(controller, start, end, 0.3, 0.0)
    assert 0.708 <= settling <= 1.614  # between the chapter's fastest simulated and slowest measured step
    assert max(abs(v - start) for v in q) <= 1.05 * abs(end - start)  # no more than the band's overshoot
    assert abs(sum(q[-500:]) / 500 - end) < 1.0  # and creeping in: within 1 deg 5 s on
    assert all(0.0 <= p <= 0.6 for p in pa + pb)


def test_a_planned_move_is_tracked_without_the_reference_models_lag():
    loop = make_loop("muscle_eq", None, rig="sim-muscle")
    muscle_steps.hold_at(loop, 10.0, 0.3, 1.0)
    loop.set_trajectory(JointMove([10 * DEG], [70 * DEG], 2.0), "move")  # peak 45 deg/s
    worst = 0.0
    for _ in range(2500):
        loop.run(1)
        worst = max(worst, abs(loop.reference[0][0] - loop.angles[0]) / DEG)
    assert worst < 8.0  # the model's 2 x 0.27 s lag alone: about 20 deg behind at the peak speed


@pytest.mark.parametrize("stiffness, load", [(0.2, 4.0), (0.5, 8.33)])
def test_a_tip_load_step_deflects_the_held_joint_by_load_torque_over_stiffness(stiffness, load):
    moved, predicted, _ = muscle_steps.stiffness_case("muscle_eq", 45.0, stiffness, load)
    assert moved < 0 and abs(moved - predicted) <= 0.1 * abs(predicted)


@pytest.mark.slow  # long: kept out of the fast subset
def test_a_heavier_load_or_a_softer_joint_settles_later_under_position_control():
    light = muscle_steps.step_case("muscle_eq", 0.0, 45.0, 0.5, 16.66)[1]
    soft = muscle_steps.step_case("muscle_eq", 0.0, 45.0, 0.2, 16.66)[1]
    assert soft > light + 1.0


def test_a_plant_weaker_than_the_model_still_reaches_its_set_point():
    loop = make_loop("muscle_eq", {"compliant": [0.0]}, rig="sim-muscle", plant={"muscle": {"force_scale": 0.85}})
    loop.set_trajectory(JointMove(list(loop.reference[0]), [60 * DEG], 1.0), "move", stiffness=[0.4 / DEG])
    loop.run(6000)
    assert loop.supervisor.enabled and abs(loop.angles[0] / DEG - 60.0) < 1.0


@pytest.mark.parametrize("name", ["muscle_eq", "muscle_pid"])
def test_the_stiffness_parameter_is_in_the_unit_the_set_point_takes(name):
    """``controller set stiffness=0.5`` and ``set --stiffness 0.5`` both mean 0.5 N m/deg: the
    same valve commands follow from either."""
    by_parameter = make_loop(name, {"stiffness": [0.5]}, rig="sim-muscle")
    by_set_point = make_loop(name, rig="sim-muscle")
    specs = {p["name"]: p for p in by_parameter.controller.describe()["params"]}
    assert specs["stiffness"]["unit"] == "N m/deg" and by_parameter.controller.p("stiffness") == (0.5,)
    by_parameter.set_trajectory(JointMove(list(by_parameter.reference[0]), [50 * DEG], 1.0), "move")
    by_set_point.set_trajectory(JointMove(list(by_set_point.reference[0]), [50 * DEG], 1.0), "move",
                                stiffness=[0.5 / DEG])  # the set command's N m/deg, in N m/rad inside
    by_parameter.run(1500)
    by_set_point.run(1500)
    assert by_parameter.u == pytest.approx(by_set_point.u, rel=1e-9)


def test_a_broken_pressure_sensor_trips_and_the_valves_vent_with_the_brake_on():
    loop = make_loop("muscle_eq", rig="sim-muscle")
    loop.set_trajectory(JointMove(list(loop.reference[0]), [45 * DEG], 1.0), "move")
    loop.run(2000)
    loop.io.transport.inject("disconnect", "ai2")
    loop.run(20)
    assert loop.state.value == "fault" and "pressure sensor" in loop.supervisor.cause
    volts = loop.io.transport.output_volts
    assert volts[0] == volts[1] == 0.0 and volts[2] == pytest.approx(10.0)  # vent, brake at its safe 2 N m


def test_the_mr_brake_damps_the_swing_a_hung_load_starts():
    def overshoot(params):
        """How far past its final deflection the held joint swings when a load is hung on it [deg]."""
        loop = make_loop("muscle_eq", params, rig="sim-muscle")
        muscle_steps.hold_at(loop, 45.0, 0.2, 3.0)
        loop.io.transport.arm.joint.tip_load_n = 8.33
        seen = []
        for _ in range(4000):
            loop.run(1)
            seen.append(loop.angles[0] / DEG)
        final = sum(seen[-500:]) / 500
        return final - min(seen)

    free, braked = overshoot({}), overshoot({"brake_linear": [1.0]})
    assert free > 1.0 and braked < 0.5 * free


def test_telemetry_and_recordings_carry_the_muscle_commands_by_name():
    from daemon.recordings import mcap_log
    from daemon.loop.telemetry import Telemetry
    from daemon.testing.loop import Captured

    loop = make_loop("muscle_eq", rig="sim-muscle")
    captured = Captured()
    captured.follow(loop)
    loop.telemetry = Telemetry(captured, loop.layout)
    loop.set_trajectory(JointMove(list(loop.reference[0]), [30 * DEG], 0.5), "move")
    loop.run(1500)
    columns = captured.of("state")[-1]
    assert [n for n in columns if n.startswith("elbow.u.")] == ["elbow.u.pressure_a", "elbow.u.pressure_b",
                                                                 "elbow.u.brake"]  # no V_MV on a muscle joint
    assert columns["elbow.p_a_cmd"][-1] == pytest.approx(columns["elbow.u.pressure_a"][-1], rel=0.05)  # a's command
    assert columns["elbow.p_a"][-1] != columns["elbow.p_a_cmd"][-1]  # measured: the muscle's own, lagging
    sample = next(mcap_log.state_samples(loop.layout, columns))
    assert set(sample) == set(loop.layout.names) and sample["elbow.u.brake"] == columns["elbow.u.brake"][0]
