"""The documents' `pneumactl` and tool lines outside README.md, run as written (read through
tests/doc_blocks.py, with what tests/doc_claims.toml declares): against a real daemon on
private endpoints, from a directory of the test's."""
from __future__ import annotations

import tomllib

import numpy as np
import pytest

from daemon.client import payload_routine
from daemon.client.client import Client
from daemon.testing.daemons import STOP_WAIT_S
from hal import config
from tests import doc_blocks, doc_runs
from tests.daemons import endpoint_env, real_daemon, wait_for_own_daemon
from tests.doc_blocks import ROOT


def test_the_lti_design_line_runs_on_the_design_the_document_shows(tmp_path):
    """The design the section shows, saved as the line's file: the line checks it and saves
    what the daemon would run; and the design is the worked example's, as the section says."""
    section = "LTI designs from a file"
    shown, = [b for b in doc_blocks.blocks("docs/controllers.md") if b.section == section and b.kind == "toml"]
    example = tomllib.loads((ROOT / "controllers" / "designs" / "pi_thesis.toml").read_text())
    bottom = tomllib.loads(shown.text)["joints"]["bottom"]
    assert bottom.items() <= example["joints"]["bottom"].items()  # the example's, its defaults left out
    (tmp_path / "my_mu_design.toml").write_text(shown.text)
    line, = doc_blocks.commands("docs/controllers.md", section)
    done = doc_runs.run(line, tmp_path, timeout=120)
    assert done.returncode == 0, done.explain()
    saved = np.load(tmp_path / "my_mu_design_1khz.npz")
    assert saved["bottom.A"].shape == (1, 1) and float(saved["bottom.dt"]) == 0.001


@pytest.mark.slow(seconds=25)
def test_the_payload_and_identify_lines_run_against_a_daemon(tmp_path):
    """estimation.md's payload lines and identification.md's identify line: the one-shot lines
    to their end; the routines, which run for minutes, until they have said their plan and
    begun (then Ctrl-C, as tests/doc_claims.toml declares): each stops what it started, says
    so, and leaves the arm enabled and holding."""
    work = tmp_path / "work"
    work.mkdir()
    # the loaded run's unloaded reference, as `payload identify --unloaded` would have stored it
    # after its 10 minutes (the values matter only to the estimate, which an interrupted run never makes)
    rig = config.load()
    targets = payload_routine.postures(rig)
    readings = [payload_routine.Reading(list(t), [0.0] * len(t)) for t in targets]
    payload_routine.save_reference(work / "payload-reference.json", rig, targets, readings)
    daemon, eps = real_daemon(tmp_path)
    env = endpoint_env(eps)
    sections = [doc_blocks.commands("docs/estimation.md", "Payload identification by torque balance (rig-facts §4)",
                                    match=r"^pneumactl "),
                doc_blocks.commands("docs/estimation.md", "The payload as a known load: gravity feed-forward"),
                doc_blocks.commands("docs/identification.md", "Identifying a joint")]
    assert sum(line.interrupt_after is not None for lines in sections for line in lines) == 4
    try:
        with Client(**eps, timeout=5.0) as client:
            wait_for_own_daemon(client, daemon)
            for line in (line for lines in sections for line in lines):
                if line.written == "pneumactl enable" and client.status()["state"] == "enabled":
                    client.acquire_lease()  # a section that starts with it starts disabled
                    client.disable()
                    client.release_lease()
                done = doc_runs.run(line, work, env=env, timeout=300)
                if line.interrupt_after is None:
                    assert done.returncode == 0, done.explain()
                else:  # Ctrl-C: it said what it stopped, and the exit code says it was interrupted
                    assert done.returncode == 130 and "interrupted: " in done.stderr, done.explain()
                    assert client.status()["reference"] in ("", "hold", None), (line.written, client.status())
                status = client.status()
                assert status["state"] == "enabled" and status["trips"] == 0, (line.written, status["cause"])
                if line.written.startswith("pneumactl load set"):
                    assert status["load"]["mass_kg"] == pytest.approx(0.1), status["load"]
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
