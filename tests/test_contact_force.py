"""The array pressure sensor's contact estimators (controllers.contact_force, the daemon's;
controllers.contact_paper, the paper's as read and plain WLS) against the simulated pad's
truth (sim_backend.contact_patch): impacts like the paper's, read through the sensor's noise,
quantisation, per-taxel calibration and dead taxels."""
from __future__ import annotations

import numpy as np
import pytest

from controllers.contact_force import MEMORY_S, ContactEstimator
from controllers.contact_model import contact_region
from controllers.contact_paper import PaperSWLS, PlainWLS
from hal.taxel_array import (
    ACCURACY_PA,
    PAD_M,
    TAXELS,
    Contact,
    TaxelArray,
    TaxelCalibration,
)
from sim_backend.contact_patch import Impact, SimTaxelPad, spread_calibration

FRAME_HZ = 4000.0
PITCH_M = PAD_M / TAXELS
PARAMS = ("a", "b", "p_max", "beta", "force_n")
SIGMAS = ("a_sd", "b_sd", "p_max_sd", "beta_sd", "force_sd_n")


def frames_of(impact: Impact, calibration: TaxelCalibration, seed: int, frame_hz: float = FRAME_HZ,
              noise_scale: float = 1.0):
    """(truth, frame [Pa]) at ``frame_hz`` over the impact and 10 ms after it."""
    pad, device = SimTaxelPad(calibration, seed, noise_scale), TaxelArray(calibration)
    for k in range(int((impact.duration_s + 0.01) * frame_hz)):
        truth = impact.at((k + 0.5) / frame_hz)
        yield truth, device.pressures(pad.frame_volts(truth))


def errors(frames, every: int = 1, **estimators) -> dict[str, np.ndarray]:
    """Per estimator (by default the daemon's, the paper's and plain WLS), the relative error of
    each parameter, the centre's miss over b, and z = error / the estimator's own sigma, on
    every frame where the true contact is at least two taxels in b; each estimator sees every
    ``every``-th frame and is told so."""
    estimators = estimators or {"ours": ContactEstimator(), "paper": PaperSWLS(), "wls": PlainWLS()}
    out = {name: [] for name in estimators}
    for k, (truth, frame) in enumerate(frames):
        if k % every:
            continue
        for name, estimator in estimators.items():
            found = estimator.update(frame, frames=every)
            if truth is None:
                assert found is None, f"{name} reports a contact where there is none"
            elif truth.b >= 2 * PITCH_M:
                assert found is not None, f"{name} lost the contact at frame {k}"
                out[name].append([getattr(found, p) / getattr(truth, p) - 1.0 for p in PARAMS]
                                 + [np.hypot(found.cx - truth.cx, found.cy - truth.cy) / truth.b]
                                 + [(getattr(found, p) - getattr(truth, p)) / getattr(found, s)
                                    for p, s in zip(PARAMS, SIGMAS)])
    return {name: np.array(rows) for name, rows in out.items()}


@pytest.mark.parametrize("speed", [0.03, 0.11])
@pytest.mark.slow  # long: kept out of the fast subset
def test_every_parameter_within_5_percent_and_better_than_the_papers_and_plain_wls(speed):
    """Every frame within 5 %; on the RMS over the impact, every parameter better than the
    paper's S-WLS + RLS as read (a single frame's worst is the noise's draw), and beta's worst
    frame less than half plain WLS's."""
    found = errors(frames_of(Impact(speed), spread_calibration(seed=1), seed=2))
    worst = {name: np.abs(e[:, :6]).max(axis=0) for name, e in found.items()}
    rms = {name: np.sqrt(np.mean(e[:, :6] ** 2, axis=0)) for name, e in found.items()}
    assert np.all(worst["ours"][:5] < 0.05), dict(zip(PARAMS, worst["ours"]))
    assert worst["ours"][5] < 0.05  # the centre, within 5 % of the semi-axis
    assert np.all(rms["ours"] < rms["paper"]), (rms["ours"], rms["paper"])
    assert worst["ours"][3] < 0.5 * worst["wls"][3]
    assert len(found["ours"]) > 0.5 * Impact(speed).duration_s * FRAME_HZ


@pytest.mark.slow  # long: kept out of the fast subset
def test_a_dead_taxel_at_the_contact_peak_and_a_slide_elsewhere_on_the_pad():
    """(The default pad already has a dead taxel inside the larger contacts.) With the peak's
    own taxel dead, beta loses its best-informed row and still stays within 5 %."""
    centre = (-0.004, 0.003)
    col, row = (int((c + PAD_M / 2) / PITCH_M) for c in centre)
    impact = Impact(0.08, centre_m=centre, slide_m_s=(-0.004, 0.006))
    found = errors(frames_of(impact, spread_calibration(seed=3, dead=((row, col), (row + 1, col - 2))), seed=4),
                   ours=ContactEstimator())
    assert np.abs(found["ours"][:, :6]).max() < 0.05


@pytest.mark.slow  # long: kept out of the fast subset
def test_the_rates_follow_a_growing_and_shrinking_contact_without_lag():
    """Noise-free frames of the fastest impact: the contact's size changes by up to 1 % a frame
    at its start and end. The daemon's estimator, which carries each parameter's rate, stays
    within 0.3 % of the truth; the paper's memories, which hold constant parameters, lag
    p_max and the force by over 1 %. (beta, noise-free, within 2 %: what is left is the
    parameters' curvature over the memory, which the few-taxel ambiguity multiplies.)"""
    found = errors(frames_of(Impact(0.11), spread_calibration(seed=5), seed=6, noise_scale=0.0),
                   ours=ContactEstimator(), paper=PaperSWLS())
    ours, paper = np.abs(found["ours"][:, :5]).max(axis=0), np.abs(found["paper"][:, :5]).max(axis=0)
    assert np.all(ours[[0, 1, 2, 4]] < 0.003), dict(zip(PARAMS, ours))
    assert ours[3] < 0.02
    assert paper[2] > 0.01 and paper[4] > 0.01  # p_max and the force: the lag a constant memory has


@pytest.mark.slow  # long: kept out of the fast subset
def test_its_own_sigma_tells_the_truth():
    """Over a slow and a fast impact, the errors divided by the estimator's own 1 sigma have an
    RMS near 1 and never reach 5: the sigma on the telemetry can be believed."""
    z = np.concatenate([errors(frames_of(Impact(speed, centre_m=(0.002, -0.001)), spread_calibration(seed=7), seed=8),
                               ours=ContactEstimator())["ours"][:, 6:] for speed in (0.03, 0.11)])
    rms = np.sqrt(np.mean(z ** 2, axis=0))
    assert np.all((rms > 0.5) & (rms < 1.5)), dict(zip(PARAMS, rms))
    assert np.abs(z).max() < 5.0


def test_a_track_that_no_longer_fits_starts_again_from_the_frame():
    """A contact that jumps to another place on the pad (a second impact as the first lifts):
    the track's residual is far beyond the noise's, and within three frames the estimator has
    started again on the new contact."""
    calibration = spread_calibration(seed=9)
    pad, device = SimTaxelPad(calibration, seed=10), TaxelArray(calibration)
    first, second = Contact(-0.006, 0.004, 0.009, 0.007, 4e5, 0.7), Contact(0.007, -0.005, 0.007, 0.006, 3e5, 0.6)
    estimator = ContactEstimator()
    for _ in range(200):
        assert estimator.update(device.pressures(pad.frame_volts(first))) is not None
    found = [estimator.update(device.pressures(pad.frame_volts(second))) for _ in range(40)]
    for name in ("cx", "cy"):
        assert getattr(found[3], name) == pytest.approx(getattr(second, name), abs=0.2 * PITCH_M)
    for name in ("a", "b", "p_max"):
        assert getattr(found[-1], name) == pytest.approx(getattr(second, name), rel=0.02)
    assert found[-1].beta == pytest.approx(second.beta, rel=0.05)


@pytest.mark.parametrize("stall_s", [0.064, 0.1])
def test_a_reader_that_stalls_mid_impact_starts_a_new_track_and_its_sigma_tells_the_truth_again(stall_s):
    """A sensor process that stalls for 64 or 100 ms in the middle of an impact (over 8 of its
    4 ms memories): the estimator starts a new track on the next frame instead of one step from
    its straight-line prediction that far on, and once the new track has estimated a memory's
    worth of frames its errors are within 5 % and 5 of its own sigma again."""
    estimator = ContactEstimator()
    frames = list(frames_of(Impact(0.11), spread_calibration(seed=13), seed=14))
    stall_from, stall = 1200, int(stall_s * FRAME_HZ)
    last, after = -1, []
    for k, (truth, frame) in enumerate(frames):
        if stall_from < k < stall_from + stall:
            continue  # the reader is stalled: these frames pass unread
        found = estimator.update(frame, frames=k - last)
        last = k
        if k >= stall_from + stall and truth is not None and truth.b >= 2.5 * PITCH_M:
            after.append((found, truth))
    assert after[0][0].track_frames == 1  # a new track, from the first frame after the stall
    settled = [(found, truth) for found, truth in after if found.track_frames >= MEMORY_S * FRAME_HZ]
    assert len(settled) > 100
    for found, truth in settled:
        for name, sd in zip(PARAMS, SIGMAS):
            assert getattr(found, name) == pytest.approx(getattr(truth, name), rel=0.05), name
            assert abs(getattr(found, name) - getattr(truth, name)) < 5 * getattr(found, sd), (found.track_frames, name)


@pytest.mark.parametrize("frame_hz, every", [(FRAME_HZ, 4), (1000.0, 1)])
def test_a_reader_that_skips_frames_or_a_slower_sensor_is_followed_at_its_own_pace(frame_hz, every):
    """Every 4th frame of a 4 kHz pad, each update told 4 periods passed (as the daemon's
    sensor process does when it falls behind), or a 1 kHz sensor: the rates are per frame
    period, so the contact is followed without lag; with a quarter of the frames, beta's
    noise doubles."""
    estimator = ContactEstimator(frame_hz=frame_hz)
    found = errors(frames_of(Impact(0.08), spread_calibration(seed=11), seed=12, frame_hz=frame_hz), every=every,
                   ours=estimator)["ours"]
    worst = np.abs(found[:, :6]).max(axis=0)
    assert np.all(worst[[0, 1, 2, 4, 5]] < 0.02), dict(zip(PARAMS, worst))
    assert worst[3] < 0.08
    assert abs(np.mean(found[:, 2])) < 0.003  # no lag in p_max on average: the prediction spans the gap


def test_noise_alone_is_no_contact_and_a_second_touch_is_left_out():
    calibration = spread_calibration(seed=5)
    pad, device = SimTaxelPad(calibration, seed=6), TaxelArray(calibration)
    estimator = ContactEstimator()
    assert all(estimator.update(device.pressures(pad.frame_volts(None))) is None for _ in range(200))
    main, other = Contact(0.004, 0.0, 0.010, 0.008, 5e5, 0.6), Contact(-0.014, -0.014, 0.004, 0.004, 1e5, 0.5)
    two = device.pressures(device.volts_for(np.clip(pad.pressures(main) + pad.pressures(other), 0, None)))
    region = contact_region(two)
    xs = (np.arange(TAXELS) + 0.5) * PITCH_M - PAD_M / 2
    assert region is not None and not region[np.abs(xs + 0.014) < PITCH_M][:, np.abs(xs + 0.014) < PITCH_M].any()
    for _ in range(100):
        found = estimator.update(two)
    assert abs(found.a / main.a - 1) < 0.01 and abs(found.p_max / main.p_max - 1) < 0.01


def test_bad_settings_are_refused_with_the_reason():
    with pytest.raises(ValueError, match=r"memory_s 0.0: must be within \(0, 1\] s"):
        ContactEstimator(memory_s=0.0)
    with pytest.raises(ValueError, match="beta_memory_s 5"):
        ContactEstimator(beta_memory_s=5)
    with pytest.raises(ValueError, match="frame rate 0"):
        ContactEstimator(frame_hz=0.0)
    with pytest.raises(ValueError, match="frames 0: at least one frame period"):
        ContactEstimator().update(np.zeros((TAXELS, TAXELS)), frames=0)


def test_the_device_masks_dead_taxels_and_refuses_frames_that_cannot_be_readings():
    device = TaxelArray(TaxelCalibration(dead=((2, 3),)))
    volts = np.full(TAXELS * TAXELS, 1.0)
    volts[2 * TAXELS + 3] = 99.0  # a broken trace reads anything
    p = device.pressures(volts)
    assert np.isnan(p[2, 3]) and np.isfinite(np.delete(p.ravel(), 2 * TAXELS + 3)).all()
    with pytest.raises(ValueError, match="255 values"):
        device.pressures(volts[:-1])
    volts[0] = 12.0  # a live taxel 20 % over full scale: a saturated multiplexer
    with pytest.raises(ValueError, match="outside 0..1025 kPa"):
        device.pressures(volts)
    volts[0] = float("nan")
    with pytest.raises(ValueError, match="nan"):
        device.pressures(volts)
    with pytest.raises(ValueError, match="outside the 16 x 16 pad"):
        TaxelCalibration(dead=((16, 0),))
    assert ACCURACY_PA == pytest.approx(5125.0)
