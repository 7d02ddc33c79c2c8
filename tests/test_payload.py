"""Payload identification by torque balance (controllers.payload, daemon.client.payload_routine):
the three steps against exact and noisy torques, the identifiability it must refuse, the
unloaded reference's file, and the whole routine on the simulated arm through the real loop."""
from __future__ import annotations

import math

import numpy as np
import pytest

from bench.payload import measure, rig_text
from controllers.payload import NOT_IDENTIFIABLE, Posture, identify
from daemon.client import payload_routine
from hal import config
from hal.kinematics import payload_torques

LENGTHS = (0.1, 0.1)  # the pure identification tests' own arm (the simulated one's: the rig's arm.link_lengths_m)
G = (0.0, -9.81)


def rows(targets_deg, mass, com_m, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for q in targets_deg:
        q_rad = tuple(math.radians(a) for a in q)
        exact = payload_torques(q_rad, LENGTHS, mass, com_m, G)
        out.append(Posture(q_rad, tuple(t * (1.0 + rng.normal(0.0, noise)) for t in exact)))
    return out


def test_the_three_steps_recover_mass_and_centre_and_say_the_third_axis_is_not_identifiable():
    targets = payload_routine.postures(config.load())
    found = identify(rows(targets, 0.2, (0.015, -0.008)), LENGTHS, G)
    assert found.mass_kg == pytest.approx(0.2, rel=1e-9)
    assert found.com_m == pytest.approx((0.015, -0.008), abs=1e-9)
    assert found.out_of_plane == NOT_IDENTIFIABLE
    noisy = identify(rows(targets, 0.2, (0.015, -0.008), noise=0.05, seed=3), LENGTHS, G)
    assert abs(noisy.mass_kg - 0.2) < 3 * noisy.mass_std_kg + 1e-3  # the stated sigma covers the miss
    assert abs(noisy.com_m[0] - 0.015) < 3 * noisy.com_std_m[0] + 5e-4


def test_postures_that_cannot_tell_the_unknowns_apart_are_refused_with_the_reason():
    turned_alike = [(90.0 + a, -a) for a in (0.0, 10.0, 20.0)]  # the last link keeps one direction
    with pytest.raises(ValueError, match="centre of mass is not identifiable"):
        identify(rows(turned_alike, 0.2, (0.01, 0.0)), LENGTHS, G)
    upright = [(90.0, b) for b in (-30.0, -60.0, -90.0)]  # the first link along gravity: no moment arm
    with pytest.raises(ValueError, match="mass is not identifiable"):
        identify(rows(upright, 0.2, (0.01, 0.0)), LENGTHS, G)
    with pytest.raises(ValueError, match="two at least"):
        identify(rows([(120.0, -60.0)], 0.2, (0.01, 0.0)), LENGTHS, G)


def test_the_reference_file_belongs_to_its_rig(tmp_path):
    rig = config.load()
    path = tmp_path / "ref.json"
    readings = [payload_routine.Reading([100.1, -60.2], [0.1, 0.2])]
    payload_routine.save_reference(path, rig, [[100.0, -60.0]], readings)
    assert payload_routine.load_reference(path, rig) == ([[100.0, -60.0]], readings)
    with pytest.raises(ValueError, match="another arm"):
        payload_routine.load_reference(path, config.load("sim-3joint"))
    with_payload = config.parse(rig_text(0.1, (10.0, 0.0)), "payload")  # the same arm, a payload on it
    assert payload_routine.load_reference(path, with_payload)[1] == readings
    path.write_text(path.read_text()[:40])
    with pytest.raises(ValueError, match="not a readable payload reference"):
        payload_routine.load_reference(path, rig)


def dither_samples(latency_s: float, balance_v: float = -0.45, hold_v: float = 0.6, step_s: float = 0.02,
                   seconds: float = 30.0):
    """A client's samples (remaining_s, u_volts, angle_deg) of a dither lasting ``seconds``
    (a sine of 0.67 V about ``balance_v`` at the routine's frequency), taken ``latency_s``
    late, so its last ones are the holding controller's ``hold_v`` after the dither's end."""
    out = []
    for k in range(int(seconds / step_s) + 10):
        elapsed = k * step_s + latency_s  # the dither's own clock
        if elapsed < seconds:
            u = balance_v + 0.67 * math.sin(2 * math.pi * payload_routine.DITHER_HZ * elapsed)
            out.append((seconds - elapsed, u, 120.0))
        else:
            out.append((0.0, hold_v, 120.0))
    return out


@pytest.mark.parametrize("latency_s", [0.0, 0.013, 0.05, 0.4])
def test_the_balance_window_is_placed_on_the_dithers_clock_whatever_the_clients_latency(latency_s):
    """Whatever the client's lag, the mean is the balance to 1 mV: no sample after the
    dither's end counts (a window on the client's clock took in 50 ms of the holding
    controller's V_MV, a volt off: 5 mN m on the bottom joint)."""
    u, angle = payload_routine.window_mean(dither_samples(latency_s), 24.0, "bottom")
    assert u == pytest.approx(-0.45, abs=1e-3)
    assert angle == 120.0


def test_a_dither_cut_short_or_a_window_half_seen_is_an_error_not_a_mean():
    cut = [row if row[0] > 12.0 else (0.0, 0.6, 120.0) for row in dither_samples(0.0)]  # aborted 12 s before its end
    with pytest.raises(RuntimeError, match="did not run through its averaging window"):
        payload_routine.window_mean(cut, 24.0, "bottom")
    late = [row for row in dither_samples(0.0) if row[0] < 20.0]  # sampling began inside the window
    with pytest.raises(RuntimeError, match="bottom did not run through"):
        payload_routine.window_mean(late, 24.0, "bottom")


@pytest.mark.slow(seconds=25)
def test_the_dithered_balance_torques_carry_the_payloads_moment():
    """The routine's measurement on the simulated arm (vertical plane, the rig's noise and
    friction), through the loop: each joint's loaded minus unloaded balance torque against
    the payload's true moment, friction (0.27 and 0.22 N m of breakaway) dithered out, to
    2 mN m (about 2 g of mass; a window that overran the dither's end was up to 5 mN m off).
    One posture, where both joints carry a moment well beyond that tolerance (bench.payload
    runs them all; two here took the suite's in-process share 55 s)."""
    rig = config.load()
    targets = payload_routine.postures(rig)[:1]
    unloaded = measure(rig_text(0.0, (0.0, 0.0)), targets)
    loaded = measure(rig_text(0.15, (20.0, -10.0)), targets)
    for before, after in zip(unloaded, loaded):
        moment = payload_torques([math.radians(a) for a in after.angles_deg], rig.arm.link_lengths_m, 0.15,
                                 (0.02, -0.01), G)
        for j in range(2):
            measured = after.torques_nm[j] - before.torques_nm[j]
            assert measured == pytest.approx(-moment[j], abs=0.002), (j, measured, -moment[j])
            assert abs(moment[j]) > 0.04  # a moment the test can see, beyond its tolerance


def test_the_routines_estimate_counts_the_dithers_the_daemon_runs():
    """The estimate printed before a run that takes minutes: its dither per joint is the one
    the daemon plans for the routine's request, and each posture adds its unhurried move."""
    from daemon.testing.loop import dealer, make_loop, ok
    loop, _, srv = make_loop(server=True)
    try:
        sock = dealer(srv)
        lease = ok(loop, sock, "lease.acquire", {"ttl_s": 60.0})["lease"]
        ok(loop, sock, "enable", lease=lease)
        for joint in loop.rig.joints:
            planned = ok(loop, sock, "excite", payload_routine.dither_args(loop.rig, joint.name), lease)["duration_s"]
            assert payload_routine.dither_s(loop.rig, joint.name) == pytest.approx(planned, abs=0.01)
            ok(loop, sock, "abort", lease=lease)
    finally:
        srv.close()
    rig = config.load()
    targets = payload_routine.postures(rig)
    here = [j.neutral_deg for j in rig.joints]
    estimates = payload_routine.posture_estimates_s(rig, targets, here)
    dithers = sum(payload_routine.dither_s(rig, j.name) for j in rig.joints)
    assert len(estimates) == len(targets) and all(e > dithers + payload_routine.REST_S for e in estimates)
