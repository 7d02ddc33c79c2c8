"""The model beside a real daemon (daemon/model/process.py, docs/model.md): a potentiometer that
starts reading 2 deg off on the simulated rig is a ``model`` event naming the joint and the
cause, a journal line, and the status field ``model``; the ``model`` topic carries each joint's
residual and its window's statistics, and the daemon's recordings keep it; the model's process
is one of the status field ``helpers``, and one killed is restarted with a ``model`` event."""
import os
import signal
import time
from pathlib import Path

import pytest

from daemon.client.client import Client
from daemon.recordings.reading import open_run
from daemon.testing.daemons import STOP_WAIT_S
from daemon.testing.drift import AXIS_DRIFTS, DRIFTS, axis_rig, drifted_rig
from hal import config
from tests.daemons import real_daemon, tolerant_rig_text, wait_for_own_daemon
from tests.schemas import schema
from tests.test_journal import journal_line, next_event

pytestmark = pytest.mark.slow(seconds=70)
# [s] of the plant's clock (from the transport's opening): well after the model has started (its
# process starts after the transport opens: 5-20 s on a loaded machine)
ONSET_S = 40.0


def test_a_drifting_potentiometer_is_a_model_event_a_journal_line_a_status_field_and_recorded(tmp_path):
    rig = tmp_path / "rig.toml"
    # the middle joint's model as an identification wrote it (the same numbers: the plant is
    # unchanged), its band 3 x 0.1 deg from the residual RMS it found; the bottom's the rig file's
    identified = tolerant_rig_text().replace('model = "middle-scaled"', 'model = "middle-identified"', 1) + \
        '\n[models.middle-identified]\nbased_on = "middle-scaled"\nheldout_rms_deg = 0.1\n'
    rig.write_text(drifted_rig(DRIFTS["offset"], joint="middle", at_s=ONSET_S, base=identified))
    log = tmp_path / "daemon.log"
    with open(log, "w") as stderr:
        daemon, eps = real_daemon(tmp_path, "--config", str(rig), "--log-level", "INFO", stderr=stderr)
    try:
        with Client(**eps, timeout=20.0) as client:
            wait_for_own_daemon(client, daemon)
            sub = client.subscribe((b"event", b"model"))
            sub.wait_until_heard()
            started = client.record_start(name="drift")
            model = None
            deadline = time.monotonic() + ONSET_S
            while model is None or not all(j["window_fill"] == 1.0 for j in model["joints"].values()):
                got = sub.receive(1.0)
                model = got[1] if got is not None and got[0] == "model" else model
                assert time.monotonic() < deadline, "no full model window"
            assert set(model["joints"]) == {"bottom", "middle"}
            schema("telemetry", "model").validate(model)
            assert all(j["rms_deg"] < model["band_deg"] and not j["flagged"] for j in model["joints"].values()), model
            assert all(len(j["residual_deg"]) > 0 for j in model["joints"].values())
            assert client.status()["model"]["joints"]["middle"]["drift"] is False
            for name, band, source in (("middle", 0.3, "identification: 3 x"), ("bottom", 0.3, "rig file")):
                for said in (model["joints"][name], client.status()["model"]["joints"][name]):
                    assert said["band_deg"] == pytest.approx(band) and said["band_from"].startswith(source), said
            event = next_event(sub, "model", action="drift", limit_s=60.0)
            assert event["joint"] == "middle" and event["likely"] == "offset", event
            schema("telemetry", "event").validate(event)
            assert "potentiometer offset" in event["cause"]
            line = journal_line(log, "WARNING", "model", event)
            assert "drift middle" in line and "potentiometer offset" in line
            status = client.status()
            schema("results", "status").validate(status)
            assert status["model"]["joints"]["middle"]["drift"] is True
            assert status["model"]["joints"]["middle"]["cause"] == "offset"
            assert abs(status["model"]["joints"]["middle"]["size"] - 2.0) < 0.3  # at the flag: its ramp in the fit
            assert status["model"]["joints"]["bottom"]["drift"] is False
            assert status["helpers"]["model"]["running"]
            os.kill(status["helpers"]["model"]["pid"], signal.SIGKILL)  # the model process dies
            restarted = next_event(sub, "model", action="restarted", limit_s=30.0)
            assert "model process exited" in restarted["cause"]
            journal_line(log, "WARNING", "model", restarted)
            client.record_stop(name="drift")
            sub.close()
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
    run = open_run(Path(started["file"]))
    recorded = run.messages["model"]
    assert recorded and any(m["joints"]["middle"]["flagged"] for m in recorded)
    assert any(m.get("kind") == "model" and m.get("joint") == "middle" for m in run.messages["event"])


def test_on_the_linear_axis_the_model_topic_status_and_event_are_in_mm(tmp_path):
    """sim-axis (stall-tolerant): the model beside the axis publishes its residual in mm within the
    band, the status field says the band_mm in force, and a position sensor reading 2 mm off is
    a ``model`` event naming an offset in mm."""
    rig = tmp_path / "sim-axis.toml"
    text = axis_rig(AXIS_DRIFTS["offset"], at_s=ONSET_S).replace("stall_after_s = 0.05\n", "stall_after_s = 5.0\n")
    assert "stall_after_s = 5.0" in text
    rig.write_text(text)
    log = tmp_path / "daemon.log"
    with open(log, "w") as stderr:
        daemon, eps = real_daemon(tmp_path, "--config", str(rig), "--log-level", "INFO", stderr=stderr)
    try:
        with Client(**eps, timeout=20.0) as client:
            wait_for_own_daemon(client, daemon)
            sub = client.subscribe((b"event", b"model"))
            sub.wait_until_heard()
            model = None
            deadline = time.monotonic() + ONSET_S
            while model is None or model["joints"]["axis"]["window_fill"] < 1.0:
                got = sub.receive(1.0)
                model = got[1] if got is not None and got[0] == "model" else model
                assert time.monotonic() < deadline, "no full model window"
            schema("telemetry", "model").validate(model)
            axis = model["joints"]["axis"]
            assert axis["unit"] == "mm" and axis["band_mm"] == 0.2 and "rms_deg" not in axis
            assert axis["rms_mm"] < 0.2 / 3 and not axis["flagged"] and len(axis["residual_mm"]) > 0, axis
            status = client.status()
            schema("results", "status").validate(status)
            said = status["model"]["joints"]["axis"]
            assert said["unit"] == "mm" and said["band_mm"] == 0.2 and said["drift"] is False, said
            event = next_event(sub, "model", action="drift", limit_s=60.0)
            assert event["joint"] == "axis" and event["likely"] == "offset", event
            assert "position-sensor offset" in event["cause"] and "mm" in event["cause"]
            journal_line(log, "WARNING", "model", event)
            said = client.status()["model"]["joints"]["axis"]
            assert said["drift"] is True and said["cause"] == "offset" and abs(said["size"] - 2.0) < 0.3, said
            sub.close()
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
