"""docs/bluesky.md's set-up and Python snippets, read from the document and run as written
against two real daemons (the cylinder arm and the muscle joint, each with its keys): Redis,
the Tiled server and the queue's manager started by the document's shell lines, its JSON as
the queue's settings, its RunEngine snippet (a step response on the arm, read back from Tiled)
and its queue snippet (plans on both rigs, each run read back from Tiled).

Only hosts, ports, paths and keys are replaced: each daemon on private ipc endpoints (where
the document has ``tcp://arm-pc:5560`` ...), the servers on free loopback ports (where it has
6379, 8000, 60615 and every interface), the document's absolute paths under the test's
directory, ``.venv/bin/`` this interpreter's bin directory. The shell lines run as one script
in a working directory of their own, the last (the queue's manager) in the foreground as in a
terminal. Its install line (``.venv/bin/pip install -e '.[bluesky]'``) is not run here: it is
.ci/run's second step."""
from __future__ import annotations

import json
import os
import re
import secrets
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from tests import doc_blocks, extras

if extras.missing("bluesky"):
    pytest.skip(extras.reason("bluesky"), allow_module_level=True)

from tiled.client import from_uri  # noqa: E402

from daemon.client.client import Client  # noqa: E402
from daemon.testing.daemons import STOP_WAIT_S
from daemon.wire import keys  # noqa: E402
from tests.daemons import free_tcp_ports, real_daemon, wait_for_own_daemon  # noqa: E402

# slow: each test's share of the file's ~180 s on a loaded 2-core machine (tests/conftest.py orders files by the sum)
pytestmark = [pytest.mark.slow(seconds=90), pytest.mark.bluesky]

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "bluesky.md"
BIN = str(Path(sys.executable).parent) + "/"
API_KEY = secrets.token_hex(16)  # Tiled takes letters and digits only
# What may not remain once hosts, ports and paths are replaced: the document's hosts, the default
# ports of the daemon, Redis, Tiled and the queue's manager, and binding every interface.
LEFT = re.compile(r"\b[\w-]+-pc\b|:(5560|5561|5562|6379|8000|60615)\b|--port (6379|8000)\b|0\.0\.0\.0|\*:|(^|[\s(])\.venv/", re.M)
DOC_NAME = "docs/bluesky.md"
QUEUE = "One queue for several rigs"


def document_blocks() -> dict[str, str]:
    """What this test runs of docs/bluesky.md, read through tests/doc_blocks.py: the RunEngine
    snippet (section "The plans"), the queue's settings (its JSON block), the set-up's shell
    lines as one script and the queue snippet (section "One queue for several rigs")."""
    setup = doc_blocks.commands(DOC_NAME, QUEUE)
    settings = [b for b in doc_blocks.blocks(DOC_NAME) if b.section == QUEUE and b.kind == "json"]
    assert len(settings) == 1, f"{DOC_NAME}: {len(settings)} JSON blocks in {QUEUE!r}, not the queue's one settings file"
    return {"engine": doc_blocks.snippet(DOC_NAME, "The plans (`daemon/client/bluesky/plans.py`)").written,
            "settings": settings[0].text, "set-up": "\n".join(c.written for c in setup),
            "queue": doc_blocks.snippet(DOC_NAME, QUEUE).written}


def substituted(text: str, replacements: dict[str, str]) -> str:
    """``text`` with each key of ``replacements`` replaced, all at once (a replacement is never
    replaced again), longest first; nothing of the document's hosts and ports left."""
    pattern = re.compile("|".join(map(re.escape, sorted(replacements, key=len, reverse=True))))
    text = pattern.sub(lambda found: replacements[found.group(0)], text)
    assert not LEFT.search(text), f"left unreplaced: {LEFT.search(text).group(0)!r} in\n{text}"
    return text


def make_keys(directory: Path, out: Path, *clients: str) -> list[Path]:
    """A daemon's key directory, and in ``out`` a key file for each client (``<client>.key_secret``,
    allowed under the name before its first '-')."""
    keys.init_server(str(directory))
    out.mkdir(parents=True, exist_ok=True)
    made = []
    for client in clients:
        (out / client).mkdir()
        path = Path(keys.make_client(str(directory), client.split("-")[0], keys.OPERATOR, str(out / client)))
        made.append(path.rename(out / f"{client}.key_secret"))
    return made


def wait_until(check, what: str, limit_s: float = 120.0) -> None:
    deadline = time.monotonic() + limit_s
    while True:
        try:
            if check():
                return
        except OSError:
            pass
        assert time.monotonic() < deadline, f"{what} did not come up within {limit_s:.0f} s"
        time.sleep(0.5)


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """The two rigs' daemons, then the document's set-up lines, running; what replaces the
    document's hosts, ports, paths and keys."""
    tmp = tmp_path_factory.mktemp("bluesky-docs")
    blocks = document_blocks()
    arm_queue, ana = make_keys(tmp / "arm-keys", tmp / "etc" / "pneumad", "queue-arm", "ana")
    (muscle_queue,) = make_keys(tmp / "muscle-keys", tmp / "etc" / "pneumad", "queue-muscle")
    processes, setup, log = [], None, open(tmp / "set-up.log", "w")
    try:
        eps = {}
        for name, options, key in (("arm", (), ana), ("muscle", ("--config", "sim-muscle", "--safety", "stall_after_s=5.0"),
                                                         muscle_queue)):
            (tmp / name).mkdir()
            daemon, eps[name] = real_daemon(tmp / name, "--keys", str(tmp / f"{name}-keys"), *options)
            processes.append(daemon)
            with Client(**eps[name], key_file=str(key), timeout=5.0) as client:
                wait_for_own_daemon(client, daemon)
        redis, tiled, manager = free_tcp_ports(3)
        replacements = {".venv/bin/": BIN, "ana.key_secret": str(ana),
                        "/data/": f"{tmp}/data/", "/etc/pneumad/": f"{tmp}/etc/pneumad/",
                        "/var/lib/pneumad": f"{tmp}/var/lib/pneumad",
                        "--port 6379": f"--port {redis}", "127.0.0.1:6379": f"127.0.0.1:{redis}",
                        "--host 0.0.0.0 --port 8000": f"--host 127.0.0.1 --port {tiled}",
                        "http://data-pc:8000": f"http://127.0.0.1:{tiled}", '"..."': json.dumps(API_KEY),
                        "tcp://*:60615": f"tcp://127.0.0.1:{manager}", "tcp://data-pc:60615": f"tcp://127.0.0.1:{manager}"}
        for name in ("arm", "muscle"):
            replacements.update({f"tcp://{name}-pc:{port}": eps[name][socket]
                                 for port, socket in (("5560", "command"), ("5561", "control"), ("5562", "telemetry"))})
        settings = json.loads(substituted(blocks["settings"], replacements))
        assert settings["rigs"]["arm"]["key_file"] == str(arm_queue)
        (tmp / "etc" / "pneumad" / "bluesky.json").write_text(json.dumps(settings))
        work = tmp / "work"
        work.mkdir()
        # The set-up's lines as one script, as a terminal runs them: the servers in the background,
        # the queue's manager in the foreground; a session of their own, ended whole.
        setup = subprocess.Popen(["bash", "-ec", substituted(blocks["set-up"], replacements)], cwd=work,
                                 env={**os.environ, "TILED_API_KEY": API_KEY}, stdout=log, stderr=subprocess.STDOUT,
                                 start_new_session=True)

        def running() -> None:
            assert setup.poll() is None, f"the set-up ended ({setup.returncode}):\n" + \
                (tmp / "set-up.log").read_text()[-3000:]
        wait_until(lambda: running() or urllib.request.urlopen(f"http://127.0.0.1:{tiled}/healthz", timeout=5).status
                   == 200, "the Tiled server")
        from bluesky_queueserver_api.zmq import REManagerAPI
        probe = REManagerAPI(zmq_control_addr=f"tcp://127.0.0.1:{manager}", timeout_recv=5.0)
        deadline = time.monotonic() + 120.0
        while True:
            running()
            try:
                probe.status()
                break
            except probe.RequestTimeoutError:
                assert time.monotonic() < deadline, "the queue's manager did not answer within 120 s"
        probe.close()
        yield replacements
    finally:
        if setup is not None:
            try:
                os.killpg(setup.pid, signal.SIGTERM)
                deadline = time.monotonic() + 30
                while time.monotonic() < deadline and group_alive(setup.pid):
                    time.sleep(0.2)
                os.killpg(setup.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        for process in processes:
            process.terminate()
            process.wait(STOP_WAIT_S)
        log.close()


def group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
        return True
    except ProcessLookupError:
        return False


def test_the_documents_runengine_snippet_runs_a_step_and_reads_its_1khz_record_back_from_tiled(lab):
    replacements = lab
    namespace = {}
    try:
        exec(compile(substituted(document_blocks()["engine"], replacements), str(DOC), "exec"), namespace)
    finally:
        if "arm" in namespace:
            namespace["arm"].close()
    t, angle = np.asarray(namespace["t"]), np.degrees(np.asarray(namespace["angle"]))  # [s], [deg]
    assert t[-1] - t[0] > 3.0 and np.median(np.diff(t)) == pytest.approx(0.001, abs=1e-5)  # 1 kHz, 3 s after the step
    start = namespace["run"].metadata["start"]
    assert start["rig"] == "sim-2joint" and start["controller"] == "pid" and start["operator"] == "ana"
    assert angle[-1] - angle[0] == pytest.approx(3.0, abs=0.6)  # the step, settled


def test_the_documents_queue_runs_plans_on_both_rigs_into_tiled(lab):
    replacements = lab
    namespace = {}
    try:
        exec(compile(substituted(document_blocks()["queue"], replacements), str(DOC), "exec"), namespace)
        history = namespace["RM"].history_get()["items"]
        namespace["RM"].environment_close()
        namespace["RM"].wait_for_idle(timeout=60)
    finally:
        if "RM" in namespace:
            namespace["RM"].close()
    assert [(item["name"], item["args"][0], item["result"]["exit_status"]) for item in history] == [
        ("step_response", "arm", "completed"), ("step_response", "muscle", "completed"),
        ("path_run", "arm", "completed")], [item["result"]["msg"] for item in history]
    tiled = from_uri(replacements["http://data-pc:8000"], api_key=API_KEY)
    for item, rig in zip(history, ("sim-2joint", "sim-muscle", "sim-2joint")):
        (uid,) = item["result"]["run_uids"]
        run = tiled[uid]
        assert run.metadata["start"]["rig"] == rig and run.metadata["start"]["plan_name"] == item["name"]
        device = item["args"][0]
        cycle = np.asarray(run["record"][f"{device}_record_cycle"].read())
        t = np.asarray(run["record"][f"{device}_record_t"].read())
        assert np.all(np.diff(cycle) == 1) and t[-1] - t[0] > 3.0  # every cycle the loop ran, 3 s past the end
        assert np.asarray(run["primary"][f"{device}-joints-0-position"].read()).shape == (2,)  # before and after
    muscle = tiled[history[1]["result"]["run_uids"][0]]["primary"]
    pressures = np.array([np.asarray(muscle[f"muscle-joints-0-p_{m}"].read()) for m in ("a", "b")]).T
    # the muscle pair's measured pressures [kPa], before and after: after the step both muscles hold
    # pressure (before it, the arm may just have been enabled, its valves still filling)
    assert pressures.shape == (2, 2) and np.all(np.isfinite(pressures)) and np.all(pressures[1] > 0), pressures
