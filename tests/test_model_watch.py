"""The rig's model beside the arm (controllers/drift.py, docs/model.md): fed the real loop's state
messages on the virtual clock, the identified model predicts the simulated arm within its noise,
and each of the four drifts the simulator injects (a potentiometer offset of 2 deg, a 10 % leak in
the head chamber, a regulator gain of 0.8, friction x2) is flagged within its stated time, the
best of the candidate causes the one injected."""
import math

import numpy as np
import pytest

from daemon.testing.drift import DRIFTS, drifted_rig, swing, watch
from daemon.testing.simrig import sim_of
from hal import config
from hal.errors import ConfigError

pytestmark = pytest.mark.slow(seconds=120)
ONSET_S = 8.0  # the drift starts at this time of the plant's clock [s]
FLAGGED_WITHIN_S = {"offset": 2.0, "leak_head": 3.0, "gain": 4.0, "friction": 8.0}  # docs/model.md's table


@pytest.fixture(scope="module")
def nominal():
    text = drifted_rig()
    states = swing(text, 40.0)
    return text, watch(text, states), states


def test_on_the_simulator_the_model_predicts_the_arm_within_its_noise_and_raises_no_flag(nominal):
    """The model is the simulator's own plant: what is left is the potentiometers' noise
    (0.5 mV of 5 V over 333 deg: about 0.03 deg RMS)."""
    text, watched, _ = nominal
    assert not watched.verdicts
    t = np.asarray(watched.times)
    for name, r in watched.residuals.items():
        r = np.asarray(r)
        anchored = np.isfinite(r)
        assert anchored[t > 1.0].all(), name  # started within its settle time
        assert np.sqrt(np.mean(r[anchored] ** 2)) < 0.08, name
    rms = [j["rms_deg"] for m in watched.messages for j in m["joints"].values() if j["window_fill"] == 1.0]
    assert max(rms) < config.parse(text).model_watch.band_deg / 3


def test_a_stall_is_no_drift(nominal):
    """The loop held off its cycles for a second (a stall: the samples jump in time, the arm as
    it was, as a simulated plant that skipped its steps meanwhile has it): the model starts again
    from the arm and raises no flag, where stepping it over the gap gave a false offset."""
    text, _, states = nominal
    cut = next(k for k, m in enumerate(states) if m["t"][0] >= 12.0)
    shifted = [{**m, "t": [t + 1.0 for t in m["t"]]} for m in states[cut:]]
    watched = watch(text, states[:cut] + shifted)
    assert not watched.verdicts, watched.verdicts


def test_a_model_an_identification_wrote_brings_its_band_and_says_so(nominal):
    """The band from the held-out residual RMS the identification wrote into the model's table
    (3 x 0.01 deg here: under the potentiometer's noise, so the nominal run leaves it), where
    the model carries one; the rig file's elsewhere. The model topic says which, per joint."""
    text, _, states = nominal
    identified = text.replace('name = "bottom"\n', 'name = "bottom"\nmodel = "bottom-identified"\n', 1) + \
        '\n[models.bottom-identified]\nbased_on = "bottom"\nheldout_rms_deg = 0.01\n'
    watched = watch(identified, states)
    assert {v.joint for _, v in watched.verdicts if v.action == "drift"} == {"bottom"}
    bottom, middle = watched.messages[-1]["joints"]["bottom"], watched.messages[-1]["joints"]["middle"]
    assert bottom["band_deg"] == pytest.approx(0.03) and bottom["band_from"].startswith("identification: 3 x")
    assert "models.bottom-identified" in bottom["band_from"]
    assert middle["band_deg"] == 0.3 and middle["band_from"] == "rig file: [model_watch] band_deg"


@pytest.mark.parametrize("drift", list(DRIFTS))
def test_each_drift_is_flagged_within_its_time_and_its_cause_named(drift):
    text = drifted_rig(DRIFTS[drift], at_s=ONSET_S)
    watched = watch(text, swing(text, ONSET_S + 24.0))
    bottom = [(t, v) for t, v in watched.verdicts if v.joint == "bottom"]
    assert not [v for _, v in watched.verdicts if v.joint == "middle"]
    flagged = [t for t, v in bottom if v.action == "drift"]
    assert flagged and ONSET_S < flagged[0] <= ONSET_S + FLAGGED_WITHIN_S[drift], bottom
    last = [v for _, v in bottom if v.action in ("drift", "cause")][-1]  # named again on its first 10 s
    # the best candidate is the drift injected, and no other is named (where two explain the
    # residual within MARGIN of each other the cause is said to be unclear: friction's, at times)
    assert last.details["best"] == drift and last.details["likely"] in (drift, None), [v.cause for _, v in bottom]
    onset = [v.details["onset_t"] for _, v in bottom if v.action == "drift"][0]
    assert ONSET_S - 0.1 <= onset <= flagged[0]


def test_the_size_of_an_offset_is_measured():
    text = drifted_rig("sensor_offset_deg = -1.5\noffset_ramp_s = 0.1", at_s=3.0)
    watched = watch(text, swing(text, 8.0))
    (t, drift), = [(t, v) for t, v in watched.verdicts if v.action == "drift"]
    # within 10 % at the flag: its ramp is in the fit
    assert drift.details["likely"] == "offset" and math.isclose(drift.details["size"], -1.5, abs_tol=0.15)


@pytest.mark.parametrize("line, message", [
    ("band_deg = 0", "model_watch.band_deg: must be > 0"),
    ("history_s = 1.0", "model_watch.history_s: must be within window_s-600 s"),
])
def test_bad_model_watch_settings_are_refused_by_name(line, message):
    text = config.load().source.replace("band_deg = 0.3 ", line + " ", 1)
    with pytest.raises(ConfigError, match=message):
        config.parse(text)


@pytest.mark.parametrize("line, message", [
    ('leak = "both"', 'leak: must be "head" or "rod"'),
    ("regulator_gain = 0", r"regulator_gain: must be within \(0, 2\]"),
])
def test_bad_drifts_are_refused_by_name(line, message):
    with pytest.raises(ConfigError, match=message):
        sim_of(config.parse(drifted_rig(line)))


def test_check_says_the_injected_faults_and_the_timing_policy(tmp_path, capsys):
    """A rig file that injects a fault checks as what it is, not as a clean rig."""
    from daemon.main import main

    rig = tmp_path / "faulty.toml"
    rig.write_text(drifted_rig('leak = "head"', at_s=8.0))
    assert main(["--check", "--config", str(rig)]) == 0
    out = capsys.readouterr().out
    assert "simulator: joint bottom: a leak in the head chamber (10%) from 8 s of the plant's clock" in out
    assert "; policy warn" in out
