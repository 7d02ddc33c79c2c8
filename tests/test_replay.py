"""``pneumactl replay`` (daemon/replay, docs/model.md): a run recorded on the simulated rig,
replayed on the rig's model with its recorded controller and parameters, comes out within the
noise (Fit stated); on a rig file whose model differs it shows where the two part; a recording
without what a replay needs is refused with what is missing."""
import json
import shutil
import signal
import subprocess
import sys

import numpy as np
import pytest

from daemon.recordings.reading import Run, open_run
from daemon.replay.run import Refused, missing, parted, replay
from daemon.testing.drift import drifted_rig, swing
from hal import config
from tests import doc_blocks, doc_runs
from tests.doc_runs import restore_sigint

pytestmark = pytest.mark.slow(seconds=60)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    path = tmp_path_factory.mktemp("replay") / "swing.mcap"
    swing(drifted_rig(), 12.0, record=path)
    return path


def damped_rig() -> str:
    """The built-in rig whose bottom joint's model has three times the damping D."""
    rig = config.load()
    return rig.source.replace('name = "bottom"\n', 'name = "bottom"\nmodel = "bottom-damped"\n', 1) + \
        f'\n[models.bottom-damped]\nbased_on = "bottom"\nD = {3.0 * rig.joint_models["bottom"].D}\n'


def pneumactl(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "daemon.client.ctl", "replay", *args], capture_output=True, text=True,
                          timeout=600)


def test_a_recorded_run_replayed_on_its_rigs_model_comes_out_within_the_noise(recorded, tmp_path):
    done = pneumactl(str(recorded), "--out", str(tmp_path / "out"))
    assert done.returncode == 0, done.stderr
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["controller"] == "pid" and not report["tripped"]
    for joint in ("bottom", "middle"):
        figures = report["joints"][joint]
        assert figures["fit_percent"] > 95.0, figures  # the noise of two reads of the potentiometer: RMS ~0.05 deg
        assert figures["rms_deg"] < 0.1 and figures["parted_s"] is None, figures
        assert (tmp_path / "out" / f"replay-{joint}.png").stat().st_size > 10_000
    assert "bottom: Fit" in done.stdout and "never parted" in done.stdout


def test_a_replay_on_a_rig_file_whose_model_differs_shows_where_they_part(recorded, tmp_path):
    text = damped_rig()
    (tmp_path / "damped.toml").write_text(text)
    result = replay(open_run(recorded), text)
    bottom, middle = result["joints"]["bottom"], result["joints"]["middle"]
    assert bottom["parted_s"] is not None and bottom["parted_s"] < 4.0, bottom  # the first swing moves it
    assert bottom["fit_percent"] < 90.0 and bottom["max_deg"] > 1.0, bottom
    assert middle["fit_percent"] > 90.0, middle
    done = pneumactl(str(recorded), "--config", str(tmp_path / "damped.toml"), "--out", str(tmp_path / "out"))
    assert done.returncode == 0 and "bottom: Fit" in done.stdout and "parted at" in done.stdout, done.stderr


def test_the_documents_replay_lines_run_on_a_recording_and_a_rig_file_whose_model_differs(recorded, tmp_path):
    (tmp_path / "recordings").mkdir()
    shutil.copy(recorded, tmp_path / "recordings" / "swing.mcap")
    (tmp_path / "damped.toml").write_text(damped_rig())
    lines = doc_blocks.commands("docs/model.md", "Replaying a run")
    assert len(lines) == 2
    own, damped = (doc_runs.run(line, tmp_path, timeout=600) for line in lines)
    for done in (own, damped):
        assert done.returncode == 0 and "bottom: Fit" in done.stdout, (done.command.text, done.stderr)
    assert "never parted" in own.stdout.splitlines()[0] and "parted at" in damped.stdout.splitlines()[0]
    assert (tmp_path / "swing-damped" / "replay-bottom.png").exists()


def test_a_run_whose_loop_fell_behind_its_period_or_whose_telemetry_was_lost_replays_at_its_own_times(tmp_path):
    """A loop that skipped deadlines (every third cycle two periods late: ~600 cycles a second)
    recorded a swing; and the same recording with a second of its samples lost. Each recorded
    cycle is replayed at its recorded time and the lost ones in between: the model comes out
    within the noise, where one model cycle a sample ran the model ever later (Fit below 0)."""
    path = tmp_path / "behind.mcap"
    swing(drifted_rig(), 12.0, record=path, behind=True)
    run = open_run(path)
    gaps = np.diff([s["t"] for s in run.samples])
    assert gaps.mean() > 1.5e-3  # the recorded loop did fall behind
    lost = Run(run.describe, run.controller, [s for s in run.samples if not 5.0 < s["t"] < 6.0], run.messages,
               layout=run.layout)
    for case in (run, lost):
        result = replay(case)
        for joint in ("bottom", "middle"):
            figures = result["joints"][joint]
            assert figures["fit_percent"] > 95.0 and figures["parted_s"] is None, (joint, figures)


def test_an_open_loop_experiment_and_a_cut_file_are_said(recorded, tmp_path):
    """An open-loop input experiment's span is refused (its output was the signal, not the
    controller's); a cut file replays as far as it goes, says so and exits 3."""
    run = open_run(recorded)
    t = run.samples[len(run.samples) // 2]["t"]
    experiment = {"kind": "experiment", "action": "open_loop", "joint": "bottom", "t": t, "cycle": 0}
    opened = Run(run.describe, run.controller, run.samples,
                 {**run.messages, "event": [*run.messages.get("event", []), experiment]}, layout=run.layout)
    with pytest.raises(Refused, match="joint bottom's output was an open-loop input experiment's signal"):
        replay(opened)
    cut = tmp_path / "cut.mcap"
    data = recorded.read_bytes()
    cut.write_bytes(data[:len(data) * 2 // 3])
    done = pneumactl(str(cut), "--out", str(tmp_path / "out"))
    assert done.returncode == 3, done.stderr
    assert "cut.mcap is cut" in done.stderr and "bottom: Fit" in done.stdout


def test_a_recording_without_what_a_replay_needs_is_refused_with_what_is_missing(recorded):
    run = open_run(recorded)
    bare = Run({**run.describe, "rig": {**run.describe["rig"], "source": ""}}, {"name": ""},
               [{**s, "mode": "idle"} for s in run.samples[:10]], layout=run.layout)
    lacking = missing(bare)
    assert any("rig file" in m for m in lacking) and any("controller" in m for m in lacking)
    assert any("enabled" in m for m in lacking)
    with pytest.raises(Refused, match="cannot replay this recording: it has no the rig file"):
        replay(bare)
    done = pneumactl(str(recorded) + ".missing")
    assert done.returncode == 2 and "error:" in done.stderr


def test_parting_is_the_first_time_the_difference_stays_beyond_the_limit():
    t = np.arange(0, 2.0, 0.001)
    d = np.where((t > 0.5) & (t < 0.6), 2.0, 0.0) + np.where(t > 1.2, 1.5, 0.0)  # a blip, then for good
    assert parted(t, d, 1.0) == pytest.approx(1.201, abs=1e-3)
    assert parted(t, d * 0.5, 1.0) is None


def test_ctrl_c_during_a_replay_ends_it_with_one_line_and_no_report(recorded, tmp_path):
    """A replay interrupted once it says it is replaying (the model's run takes seconds): exit
    130, one line saying what stopped, no traceback, no report.json."""
    proc = subprocess.Popen([sys.executable, "-m", "daemon.replay", str(recorded), "--out", str(tmp_path / "out")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=restore_sigint)
    first = proc.stderr.readline()  # the line it prints before the model's run starts
    assert first.startswith(f"replaying {recorded.name} on the recorded rig's model"), first
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, (out, err)
    assert "Traceback" not in err and err.strip().splitlines()[-1].startswith("interrupted: the replay stopped")
    assert not (tmp_path / "out" / "report.json").exists()
