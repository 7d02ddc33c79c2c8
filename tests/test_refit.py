"""``pneumactl identify JOINT --from RECORDING`` on closed-loop recordings (daemon/client/refit.py,
controllers/identification/closed_loop.py, docs/identification.md "From any recording"),
on the simulated rig: waypoints recorded as the daemon records them are fitted to
near the simulator's plant from a stale prior (within the uncertainty the fit states), the arm
held still is refused with the joint and what is missing, and a cut file is a clear error."""
import json
import math
import shutil
import subprocess
import sys
import time

import pytest

from controllers.drift import band_of
from daemon.client.client import Client
from hal import config
from daemon.testing.daemons import STOP_WAIT_S
from daemon.testing.drift import swing
from tests import doc_blocks, doc_runs
from tests.daemons import real_daemon, tolerant_rig_text, wait_for_own_daemon
from tests.test_recorder import finished

pytestmark = pytest.mark.slow(seconds=300)

STALE = {"D": 1.5, "K": 0.7, "Fs": 1.3, "T_dly": 1.3}  # the prior the rig file gives: not the plant


def stale_rig_text() -> str:
    """The stall-tolerant built-in rig whose bottom joint's model (what the fit starts from) is
    STALE times the simulator's plant, which stays the built-in model."""
    truth = config.load().joint_models["bottom"]
    text = tolerant_rig_text().replace('name = "bottom"\n', 'name = "bottom"\nmodel = "bottom-stale"\n', 1)
    text = text.replace("\n[arm]\n", '\n[transport.options.joints.bottom]\nmodel = "bottom"\n\n[arm]\n', 1)
    return text + '\n[models.bottom-stale]\nbased_on = "bottom"\n' + "".join(
        f"{k} = {f * getattr(truth, k)!r}\n" for k, f in STALE.items())


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """Waypoints recorded as the daemon's recorder writes them, on the daemon's own loop on the
    virtual clock (daemon/testing/drift.py: what is fitted is the plant, not how late a loaded
    test machine ran the loop: `identify` says that apart), the arm at rest first; and the
    daemon's recording of the arm held still."""
    tmp = tmp_path_factory.mktemp("refit")
    swing(stale_rig_text(), 38.0, record=tmp / "waypoints.mcap")
    (tmp / "rig.toml").write_text(stale_rig_text())
    daemon, eps = real_daemon(tmp, "--config", str(tmp / "rig.toml"))
    client = Client(**eps, timeout=5.0)
    try:
        wait_for_own_daemon(client, daemon)
        client.acquire_lease(ttl_s=60.0)
        client.keep_lease()
        client.enable()
        time.sleep(2.0)  # at rest under feedback
        client.record_start(name="still", seconds=20.0)  # (of wall time: a loaded machine's loop runs late)
        still = finished(client, "still")
        status = client.status()
        assert status["state"] == "enabled" and status["trips"] == 0, status["cause"]
    finally:
        client.close()
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
    return {"still": still, "waypoints": str(tmp / "waypoints.mcap")}


def identify(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "daemon.client.ctl", "identify", *args], capture_output=True,
                          text=True, timeout=900)


def test_a_recorded_path_is_fitted_near_the_simulators_plant_within_the_stated_uncertainty(recordings, tmp_path):
    """docs/identification.md "From any recording"'s line, as written (the fit run to convergence)."""
    (tmp_path / "recordings").mkdir()
    shutil.copy(recordings["waypoints"], tmp_path / "recordings" / "waypoints.mcap")
    line, = doc_blocks.commands("docs/identification.md", "From any recording")
    done = doc_runs.run(line, tmp_path, timeout=900)
    assert done.returncode == 0, done.explain()
    tmp_path = tmp_path / "refit-bottom"
    print(json.dumps({k: v for k, v in json.loads((tmp_path / "report.json").read_text()).items()
                      if k in ("params", "stated_std", "heldout_fit_percent", "prior_heldout_fit_percent", "judged",
                               "closed_loop", "wall_s", "generations")}))  # the figures docs/identification.md quotes
    report = json.loads((tmp_path / "report.json").read_text())
    truth = config.load().joint_models["bottom"]
    found, std = report["params"], report["stated_std"]
    # the noise is the potentiometer's (0.5 mV: RMS about 0.04 deg), and the fit's stated 1 sigma
    # (the Jacobian's scaled for correlated residuals, the population's spread, the lag/dead-time
    # ridge's optima the data cannot tell apart and the model's own approximations) is what it
    # makes of it: each parameter the run settles within 3 of it (up to six settled parameters each
    # held within 2 would miss one in five runs by chance alone; within 3, about one in a hundred)
    # (searched as logarithms: a relative sigma; the dead time in s). Waypoints 2 s apart do
    # not settle the regulator's lag against the dead time: the report names what they leave
    # unsettled, and the two's sum, the lag a slow path sees, within 3 sigma or the fit's
    # mechanics step of 5 ms. The damping shows in every swing: always settled
    unsettled = set(report["closed_loop"]["unsettled"])
    assert {"T_ep", "T_dly"} & unsettled and "D" not in unsettled, report["closed_loop"]
    for name in {"D", "K", "T_ep", "Fs"} - unsettled:
        miss = math.log(found[name] / getattr(truth, name))
        assert abs(miss) <= 3.0 * std[name], (name, found, std)
    if "T_dly" not in unsettled:
        assert abs(found["T_dly"] - truth.T_dly) <= 3.0 * std["T_dly"], (found, std)
    if not {"Fs", "Fc_ratio"} & unsettled:
        assert abs(found["Fc"] / found["Fs"] - truth.Fc / truth.Fs) <= 3.0 * std["Fc_ratio"], (found, std)
    lag = found["T_ep"] + found["T_dly"]
    lag_std = math.hypot(std["T_ep"] * found["T_ep"], std["T_dly"])
    assert abs(lag - (truth.T_ep + truth.T_dly)) <= max(3.0 * lag_std, 0.005), (found, std)
    # judged on the run's held-out end, it explains what the stale prior does not (the thesis's
    # fits: 66-90 %; here 90-99 %, the less where a loaded machine ran the loop late)
    assert report["heldout_fit_percent"][0] > 85.0 and report["beats_prior"], report
    assert 0.0 < report["judged"]["heldout_rms_deg"] < 1.0, report["judged"]
    assert report["closed_loop"]["from_rest"]
    rig = config.parse((tmp_path / "rig.toml").read_text())
    written = rig.models["bottom-identified"]
    assert written["heldout_rms_deg"] == pytest.approx(report["judged"]["heldout_rms_deg"])
    band, source = band_of(rig, next(j for j in rig.joints if j.name == "bottom"))  # the model beside the arm's
    assert band == pytest.approx(3.0 * written["heldout_rms_deg"]) and source.startswith("identification")
    assert (tmp_path / "run-bottom.png").stat().st_size > 10_000
    assert "held out" in done.stderr and "apart least" in done.stderr and "unsettled" in done.stderr


def test_a_recording_of_the_arm_held_still_is_refused_naming_the_joint_and_what_is_missing(recordings, tmp_path):
    done = identify("middle", "--from", recordings["still"], "--out", str(tmp_path))
    assert done.returncode == 1, done.stderr
    assert "joint middle: it moved" in done.stderr and "too little to fit" in done.stderr, done.stderr
    assert "pneumactl identify middle" in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "rig.toml").exists()


def test_a_cut_recording_is_a_clear_error(recordings, tmp_path):
    cut = tmp_path / "cut.mcap"
    shutil.copy(recordings["waypoints"], cut)
    with open(cut, "r+b") as f:
        f.truncate(cut.stat().st_size // 2)
    done = identify("bottom", "--from", str(cut), "--out", str(tmp_path / "out"))
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr
    assert "is cut" in done.stderr and "identification fits a whole recording" in done.stderr, done.stderr
