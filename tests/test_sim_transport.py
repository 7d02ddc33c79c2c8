"""The simulated transport: seeded noise, converters, clocks and injected faults, seen
through the real drivers (hal.rig.RigIO) as the daemon will see them."""
import dataclasses
import math
import os
import statistics
import threading
import time

import pytest

from hal.errors import CommandError, ConfigError, TransportError, TransportTimeout
from hal.rig import RigIO
from hal.kinematics import jacobian
from sim_backend.plant_thread import PlantThread
from sim_backend.transport import SimTransport, converter, quantise
from daemon.testing.simrig import DT, make_rig


def run(sim, seconds, v_mv=(0.0, 0.0)):
    snaps = []
    for _ in range(int(round(seconds / DT))):
        sim.io.write_pressures(*sim.actuation.outputs(v_mv))
        sim.clock.sleep_until(sim.clock.now() + DT)
        snaps.append(sim.io.read())
    return snaps


def test_same_seed_same_run_different_seed_different_noise():
    a, b, c = make_rig(), make_rig(), make_rig(replace={"seed = 1": "seed = 2"})
    va = [s.volts for s in run(a, 0.2, (1.0, 0.5))]
    assert va == [s.volts for s in run(b, 0.2, (1.0, 0.5))]
    assert va != [s.volts for s in run(c, 0.2, (1.0, 0.5))]


def test_noise_has_the_configured_size():
    sim = make_rig(replace={"adc_noise_volts = 0.0005": "adc_noise_volts = 0.01"})
    supply = [s.volts[2] for s in run(sim, 1.0)]  # inputs: ai0, ai1, ai6 (supply), ai7
    assert statistics.pstdev(supply) == pytest.approx(0.01, rel=0.15)
    assert statistics.fmean(supply) == pytest.approx(5.0, abs=0.002)


def test_adc_resolution_is_applied():
    sim = make_rig("adc_bits = 8", replace={"adc_noise_volts = 0.0005": "adc_noise_volts = 0.0"})
    lsb = 10.0 / 255
    for v in run(sim, 0.05)[-1].volts:
        assert abs(v / lsb - round(v / lsb)) < 1e-9
    assert quantise(3.3, *converter(0.0, 10.0, 8)) == pytest.approx(round(3.3 / lsb) * lsb)
    assert quantise(12.0, *converter(0.0, 10.0, 8)) == 10.0


def test_dac_resolution_is_applied():
    sim = make_rig("dac_bits = 4")
    sim.io.write_pressures(*sim.actuation.outputs([0.3, 0.0]))
    lsb = 10.0 / 15
    for v in sim.transport.output_volts:
        assert abs(v / lsb - round(v / lsb)) < 1e-9


def test_out_of_range_or_wrong_length_output_is_refused_whole():
    sim = make_rig()
    before = sim.transport.output_volts
    with pytest.raises(CommandError, match="ao1"):
        sim.transport.write([1.0, 11.0, 1.0, 1.0])
    with pytest.raises(CommandError, match="expected 4"):
        sim.transport.write([1.0])
    with pytest.raises(CommandError, match="non-finite"):
        sim.io.write_pressures([math.nan, 0.3e6], [0.3e6, 0.3e6])
    assert sim.transport.output_volts == before


def test_disconnected_sensor_is_a_fault_not_an_angle():
    sim = make_rig()
    sim.transport.inject("disconnect", "ai0")
    snap = run(sim, 0.01)[-1]
    assert math.isnan(snap.angles[0]) and not math.isnan(snap.angles[1])
    assert any("bottom" in f and "rail" in f for f in snap.faults)
    sim.transport.clear()
    snap = run(sim, 0.01)[-1]
    assert snap.faults == () and not math.isnan(snap.angles[0])


def test_stuck_sensor_holds_while_the_joint_moves():
    sim = make_rig()
    run(sim, 0.01)
    sim.transport.inject("stuck", "ai0")
    snaps = run(sim, 1.0, (3.0, 0.0))
    assert len({s.volts[0] for s in snaps}) == 1  # the wiper channel is frozen
    # the angle still moves by the supply's noise (ratiometric reading), but not with the joint
    assert max(abs(s.angles[0] - snaps[0].angles[0]) for s in snaps) < math.radians(0.2)
    assert sim.arm.joints[0].th - math.degrees(snaps[0].angles[0]) > 5.0  # the real joint moved


def test_noise_burst_ends_after_its_samples():
    sim = make_rig(replace={"adc_noise_volts = 0.0005": "adc_noise_volts = 0.0"})
    run(sim, 0.01)
    sim.transport.inject("noise_burst", "ai6", sigma_volts=0.5, samples=50)
    burst = [s.volts[2] for s in run(sim, 0.05)]
    after = [s.volts[2] for s in run(sim, 0.05)]
    assert statistics.pstdev(burst) > 0.2
    assert statistics.pstdev(after) == 0.0


def test_transport_timeout_raises_and_is_counted():
    sim = make_rig()
    sim.transport.inject("timeout")
    with pytest.raises(TransportTimeout):
        sim.io.read()
    with pytest.raises(TransportTimeout):
        sim.io.write_safe()
    assert sim.transport.health().errors == 2
    sim.transport.clear("timeout")
    assert sim.io.read().faults == ()


def test_supply_lost_exhausts_the_chambers():
    sim = make_rig()
    sim.transport.inject("supply_lost")
    run(sim, 1.0)
    joint = sim.arm.joints[0]
    assert joint.p_head < 1e3 and joint.p_rod < 1e3
    sim.transport.clear("supply_lost")
    run(sim, 1.0)
    assert joint.p_head > 0.3e6


def test_unknown_fault_or_channel_is_refused():
    sim = make_rig()
    with pytest.raises(ValueError, match="unknown fault"):
        sim.transport.inject("gremlins")
    with pytest.raises(ConfigError, match="no input channel 'ao0'"):
        sim.transport.inject("stuck", "ao0")


def test_virtual_clock_lockstep_steps_once_per_millisecond():
    sim = make_rig()
    run(sim, 0.5)
    assert sim.arm.joints[0]._k == 500


def real_time_rig(beside: str = "always") -> RigIO:
    """The built-in rig's simulated transport on the real-time clock, as the daemon opens it."""
    from hal import config
    rig = config.load()
    rig = dataclasses.replace(rig, transport=dataclasses.replace(
        rig.transport, options={**rig.transport.options, "beside_loop": beside}))
    transport = SimTransport.from_config(rig, time.monotonic)
    transport.open()
    return RigIO(rig, transport)


def wait_for(predicate, timeout_s: float = 30.0) -> None:
    give_up = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < give_up, "timed out"
        time.sleep(0.005)


@pytest.mark.parametrize("beside", ["always", "never"], ids=["beside the loop", "in the read"])
def test_real_time_mode_follows_the_wall_clock(beside):
    io = real_time_rig(beside)
    try:
        io.read()
        time.sleep(0.05)
        io.read()
        assert io.transport.arm.joints[0]._k >= 40  # most of 50 ms, however loaded the machine
    finally:
        io.transport.close()


def test_beside_the_loop_the_plant_steps_on_its_own_and_takes_each_write_from_its_time():
    io = real_time_rig()
    transport = io.transport
    try:
        first = io.read()
        wait_for(lambda: transport._latest.seq > first.seq + 20)  # sweeps come with no read asking for them
        assert "plant_ticks_in_cycle" not in transport.health().counters
        start = io.read().angles[0]
        head = list(io.safe_pressures[0])
        head[0] += 0.15e6  # the bottom joint's head chamber up 0.15 MPa: the joint opens
        written = time.monotonic()
        io.write_pressures(head, io.safe_pressures[1])
        wait_for(lambda: transport.output_volts != io.safe_volts)
        wait_for(lambda: abs(io.read().angles[0] - start) > math.radians(2.0))
        assert io.read().angles[0] > start
        # the plant took the write from when it was written: its DAC changed within a step of it
        assert transport.arm.joints[0]._k * transport.options.step_s >= written - transport._t0 - 0.002
        io.write_safe()  # the daemon's last write at shutdown, just before it closes the transport
    finally:
        transport.close()
    assert not transport._thread.alive  # closing stops the plant's thread
    assert transport.output_volts == pytest.approx(io.safe_volts, abs=1e-3)  # and the last write took effect


def test_beside_the_loop_every_read_is_a_new_sample_even_with_the_thread_stopped():
    io = real_time_rig()
    transport = io.transport
    try:
        io.read()
        transport._thread.close()  # as a thread starved by a loaded machine would stop ticking
        time.sleep(0.01)
        snaps = [io.read() for _ in range(3)]
        assert time.monotonic() - snaps[0].t < 0.005  # fresh: the read took it in the cycle
        assert snaps[0].seq < snaps[1].seq < snaps[2].seq and snaps[0].t < snaps[1].t < snaps[2].t
        assert transport.health().counters["plant_ticks_in_cycle"] == 3
    finally:
        transport.close()


def test_beside_the_loop_a_sweep_older_than_a_step_and_a_half_is_taken_in_the_read():
    io = real_time_rig()
    transport = io.transport
    try:
        io.read()
        transport._thread.close()
        transport.tick()  # a sweep the loop has not read, then the loop held up (both threads, say)
        time.sleep(0.01)
        snap = io.read()
        assert time.monotonic() - snap.t < 0.005  # not the 10 ms old one: stale input would trip the arm
        assert transport.health().counters["plant_ticks_in_cycle"] == 1
    finally:
        transport.close()


def test_by_default_the_plant_steps_beside_the_loop_only_at_a_real_time_priority():
    io = real_time_rig("realtime")
    try:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        io.read()
        assert io.transport._thread is None  # no priority for a thread to take: the read steps the plant
    finally:
        io.transport.close()
    io = real_time_rig("realtime")
    policy = []

    def read_at_real_time():  # as the daemon's loop reads: at SCHED_FIFO (a thread's own policy, on Linux)
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        except PermissionError:
            return
        io.read()
        policy.append(os.sched_getscheduler(io.transport._thread._thread.native_id))

    try:
        reader = threading.Thread(target=read_at_real_time)
        reader.start()
        reader.join()
        if not policy:
            pytest.skip("SCHED_FIFO is not permitted here (not root, no CAP_SYS_NICE)")
        assert policy == [os.SCHED_FIFO]  # the plant's thread took the loop's real-time policy
    finally:
        io.transport.close()


def test_beside_the_loop_a_failed_plant_thread_is_a_transport_error():
    io = real_time_rig()
    transport = io.transport
    try:
        io.read()
        transport.arm.joints[0].step = None  # a plant that cannot step: the thread's tick raises
        wait_for(lambda: not transport._thread.alive)
        with pytest.raises(TransportError, match="plant's thread failed: TypeError"):
            io.read()
    finally:
        transport.close()


def test_the_plant_runs_on_through_a_stall_and_pauses_only_beyond_max_catch_up():
    sim = make_rig()
    sim.clock.sleep_until(5.0)  # a 5 s stall: the plant moves on under the held outputs, as a real arm
    sim.io.read()
    assert sim.arm.joints[0]._k == 5000 and "plant_steps_skipped" not in sim.transport.health().counters
    sim.clock.sleep_until(5.0 + 40.0)  # beyond max_catch_up_s = 30 s: the rest is skipped and counted
    sim.io.read()
    assert sim.arm.joints[0]._k == 5000 + 30000
    assert sim.transport.health().counters["plant_steps_skipped"] == 10000


def test_wall_contact_reads_on_the_force_sensor():
    sim = make_rig()
    q = sim.arm.angles_rad()
    x, y = sim.arm.tip_m()
    dx, dy = jacobian(q, sim.arm.lengths)[0]  # where the tip goes when the bottom joint opens
    norm = math.hypot(dx, dy)
    px, py = (x + 0.002 * dx / norm) * 1e3, (y + 0.002 * dy / norm) * 1e3
    wall = (f"\n[transport.options.wall]\nenabled = true\npoint_mm = [{px}, {py}]\n"
            f"normal = [{-dx / norm}, {-dy / norm}]\nstiffness_n_per_mm = 2.0")
    sim = make_rig(wall)
    free = run(sim, 0.5)[-1]
    assert free.force == pytest.approx(0.0, abs=0.05)
    pressed = run(sim, 4.0, (3.0, 0.0))[-1]
    assert 1.0 < pressed.force < 27.44
    assert pressed.force == pytest.approx(sim.arm.contact_force_n, abs=0.05)
    sim.io.tare_force()
    assert sim.io.read().force == pytest.approx(0.0, abs=0.05)


def test_a_command_acts_from_when_it_is_written_not_from_the_read_before_it():
    """Behind a wire the loop's write comes milliseconds after its read: the plant must have
    run those milliseconds under the old outputs, or every dead time it shows is shorter."""
    late, prompt = make_rig(), make_rig()
    for sim in (late, prompt):
        sim.io.read()
        sim.clock.sleep_until(0.3)
    prompt.io.read()  # the same instant as the write below, read first
    for sim in (late, prompt):
        sim.io.write_pressures(*sim.actuation.outputs([3.0, 0.0]))
        sim.clock.sleep_until(0.45)
        sim.io.read()
    assert late.arm.joints[0]._k == prompt.arm.joints[0]._k == 450
    head = [sim.arm.joints[0].p_head for sim in (late, prompt)]  # [Pa]
    assert head[0] == pytest.approx(head[1], rel=1e-9)
    resting = make_rig()
    resting.clock.sleep_until(0.45)
    resting.io.read()
    assert abs(head[0] - resting.arm.joints[0].p_head) > 1e3  # the command did act within 150 ms [Pa]


def test_the_plant_thread_ticks_once_after_each_write_also_a_late_one_and_after_a_held_up_tick():
    """On a scripted clock (the thread's sleeps move it): writes 0.09 ms into each 1 ms period,
    the fourth 0.26 ms late, and the tick after the second held up 0.6 ms; every write is
    followed by exactly one tick before the next, so each of the loop's reads finds a new sweep."""
    h = 1e-3
    writes = [k * h + 0.09e-3 for k in range(12)]
    writes[4] += 0.26e-3
    now, ticks = [0.0], []

    def wrote_at():
        return max((w for w in writes if w <= now[0]), default=-1.0)

    def tick():
        ticks.append(now[0])
        if len(ticks) == 3:
            now[0] += 0.6e-3  # held up (the GIL, a loaded machine)

    def sleep(seconds):
        now[0] += seconds
        if now[0] > writes[-1] + 0.5 * h:
            thread._running = False
        time.sleep(0)

    thread = PlantThread(tick, h, lambda: now[0], wrote_at, sleep)
    thread.start()
    thread._thread.join(30.0)
    assert not thread.alive and thread.failure is None
    for before, after in zip(writes, writes[1:] + [math.inf]):
        assert len([t for t in ticks if before <= t < after]) == 1, (before, ticks)
    lags = [t - max(w for w in writes if w <= t) for t in ticks if t > writes[0]]
    # phased on its write: 0.05 ms after it, and never more than half a period (the one after
    # the late write is on the grid that write set, 0.31 ms after the next)
    assert statistics.median(lags) <= 0.06e-3 and max(lags) <= 0.5 * h, lags
