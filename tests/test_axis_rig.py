"""The built-in linear axis (``sim-axis``, hal/sim_axis.toml) through the simulated transport and
the real drivers, as the daemon sees it: the valve's volts move the piston the right way, every
sensor reads the plant through its own calibration with the simulator's noise, injected faults
are seen as on the arm, the plant steps in lockstep and in real time, and the loop holds it."""
import dataclasses
import math
import statistics
import time

import pytest

from daemon.testing.loop import run_seconds, virtual_loop
from daemon.testing.simrig import DT, make_rig
from hal import config
from hal.errors import ConfigError
from hal.rig import RigIO
from sim_backend.transport import SimTransport

ATM = 101_325.0


def run(sim, seconds, valve=0.0):
    """``seconds`` of lockstep with the valve commanded ``valve`` [V] about its centre."""
    snaps = []
    for _ in range(int(round(seconds / DT))):
        sim.io.write_pressures(*sim.actuation.outputs([valve]))
        sim.clock.sleep_until(sim.clock.now() + DT)
        snaps.append(sim.io.read())
    return snaps


def axis(**replace):
    return make_rig(name="sim-axis", replace=replace)


def test_the_valve_moves_the_piston_the_right_way_and_the_chambers_follow():
    """+1 V about the centre opens supply to the head and the rod to exhaust: the piston extends
    (the position grows), the head's pressure rises and the rod's falls; -1 V the reverse."""
    sim = axis()
    start = run(sim, 0.2, sim.actuation.neutral[0])[-1]
    assert start.angles[0] == pytest.approx(0.100, abs=0.5e-3) and start.faults == ()
    out = run(sim, 0.3, 1.0)
    p_head, p_rod, supply = out[-1].measured
    assert out[-1].angles[0] > start.angles[0] + 0.030  # about 0.15 m/s for 0.3 s (K_v = 0.146 m/s per V)
    assert out[-1].angles[0] == pytest.approx(sim.arm.joints[0].position_m, abs=0.2e-3)
    assert p_head > start.measured[0] + 10e3 and p_rod < start.measured[1] - 10e3
    assert supply == pytest.approx(0.6e6, abs=5e3)
    back = run(sim, 0.3, -1.0)
    assert back[-1].angles[0] < out[-1].angles[0] - 0.020  # retracting is slower: the rod side's smaller area
    assert back[-1].measured[0] < start.measured[0] - 10e3 and back[-1].measured[1] > start.measured[1] + 10e3
    # the chamber transmitters read the plant's gauge pressures through their calibration
    m = sim.arm.joints[0]
    assert back[-1].measured[:2] == pytest.approx((m.p_head_pa - ATM, m.p_rod_pa - ATM), abs=3e3)


def test_every_sensor_reads_with_the_simulators_noise_and_quantisation():
    quiet = run(axis(**{"adc_noise_volts = 0.0005": "adc_noise_volts = 0.0"}), 0.2, -0.01)
    noisy = run(axis(**{"adc_noise_volts = 0.0005": "adc_noise_volts = 0.01"}), 0.5, -0.01)
    for channel in range(5):  # ai0 position, ai1, ai2 chambers, ai4 the potentiometer's supply, ai3 supply pressure
        assert statistics.pstdev(s.volts[channel] for s in quiet[-100:]) < 1e-3
        assert statistics.pstdev(s.volts[channel] for s in noisy[-400:]) == pytest.approx(0.01, rel=0.25)


def test_a_disconnected_or_stuck_position_sensor_is_a_fault_or_a_frozen_reading_as_on_the_arm():
    sim = axis()
    run(sim, 0.05, -0.01)
    sim.transport.inject("disconnect", "ai0")
    snap = run(sim, 0.01, -0.01)[-1]
    assert math.isnan(snap.angles[0]) and any(f.startswith("joint axis position sensor: wiper at the rail")
                                              for f in snap.faults), snap.faults
    sim.transport.clear()
    assert run(sim, 0.01, -0.01)[-1].faults == ()
    sim.transport.inject("stuck", "ai0")
    snaps = run(sim, 0.5, 1.0)
    assert len({s.volts[0] for s in snaps}) == 1
    assert sim.arm.joints[0].position_m - snaps[0].angles[0] > 0.02  # the piston moved, its reading did not


def test_a_lost_supply_reads_on_the_supply_transmitter_and_the_axis_cannot_push():
    sim = axis()
    run(sim, 0.1, -0.01)
    sim.transport.inject("supply_lost")
    snaps = run(sim, 1.0, 1.0)
    assert snaps[-1].measured[2] == pytest.approx(0.0, abs=5e3)
    assert max(snaps[-1].measured[:2]) < 60e3  # both chambers venting through the valve (from 0.4-0.5 MPa)
    sim.transport.clear("supply_lost")
    assert run(sim, 0.5, -0.01)[-1].measured[2] == pytest.approx(0.6e6, abs=5e3)


def test_the_plant_takes_its_own_options_a_plant_off_the_nominal_and_refuses_a_bad_one():
    heavy = axis(**{"adc_noise_volts = 0.0005": "adc_noise_volts = 0.0005\n\n[transport.options.joints.axis]\n"
                                               "overrides = {load_mass_kg = 20.0}\ninitial_position_mm = 50.0"})
    assert heavy.arm.joints[0].params.load_mass_kg == 20.0 and heavy.rig.joints[0].linear_axis.load_mass_kg == 1.0
    assert run(heavy, 0.05, -0.01)[-1].angles[0] == pytest.approx(0.050, abs=0.5e-3)
    with pytest.raises(ConfigError, match=r"transport\.options\.joints\.axis\.overrides: load_mas_kg: unknown key"):
        axis(**{"adc_noise_volts = 0.0005": "adc_noise_volts = 0.0005\n\n[transport.options.joints.axis]\n"
                                           "overrides = {load_mas_kg = 2.0}"})


def test_in_real_time_the_plant_steps_beside_the_loop_on_the_wall_clock():
    rig = config.load("sim-axis")
    rig = dataclasses.replace(rig, transport=dataclasses.replace(
        rig.transport, options={**rig.transport.options, "beside_loop": "always"}))
    transport = SimTransport.from_config(rig, time.monotonic)
    transport.open()
    io = RigIO(rig, transport)
    try:
        start = io.read().angles[0]
        io.write_pressures([0.0], [0.0], [1.0])
        give_up = time.monotonic() + 30.0
        while io.read().angles[0] < start + 0.01:  # the thread steps it, whatever the machine's load
            assert time.monotonic() < give_up
            time.sleep(0.005)
        io.write_safe()
    finally:
        transport.close()
    assert not transport._thread.alive and transport.output_volts == pytest.approx(io.safe_volts, abs=1e-3)


def test_the_loop_enables_the_axis_from_its_safe_state_and_holds_it():
    """``pneumad --config sim-axis --controller hold``'s loop on the virtual clock: idle, the
    valve at its safe command (the null); enabled, hold keeps that command and the axis stays
    within a fraction of a millimetre for 5 s."""
    loop = virtual_loop(config.load("sim-axis"), "hold")
    try:
        loop.start()
        run_seconds(loop, 0.3)
        assert list(loop.io.last_volts) == [4.99] and loop.state.value == "idle"
        start = loop.angles[0]
        loop.enable()
        run_seconds(loop, 5.0)
        assert loop.state.value == "enabled", loop.supervisor.cause
        assert loop.io.last_volts == pytest.approx([4.99]) and abs(loop.angles[0] - start) < 0.5e-3
    finally:
        loop.shutdown("test")
