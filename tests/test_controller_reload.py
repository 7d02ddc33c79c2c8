"""A controller directory's plugin changed without a restart (``pneumad --controller-dir``,
``controller.reload``): a real daemon, a plugin file in the test's directory edited while its
first version runs, read again, shadowed and committed; a request that names a path or a module
refused; a broken edit refused with its import error while the running controller runs on; a
file that fails at start said in the log and the status. The daemon and the reload are the
lines of docs/writing-controllers.md ("Changing it without a restart")."""
import json
import subprocess
import time

import pytest

from daemon.client.client import Client, RemoteError
from daemon.recordings.reading import open_run
from tests import doc_blocks, doc_runs
from tests.daemons import endpoint_env, private_endpoints, tolerant_rig, tolerant_rig_text, wait_for_own_daemon

DOC = "docs/writing-controllers.md"
RELOAD = "Changing it without a restart"

VERSION_1 = '''"""A lab's PD + integral controller, first version."""
from controllers.pid import PID


class LabPD(PID):
    """Lab PD, version 1."""

    name = "lab_pd"
'''

VERSION_2 = '''"""A lab's PD + integral controller, second version: a gain on the reference's velocity."""
from controllers.base import ParamSpec
from controllers.pid import PID


class LabPD(PID):
    """Lab PD, version 2."""

    name = "lab_pd"
    params = (*PID.params, ParamSpec("Kv", "V s/rad", 0.0, 100.0, (0.0,), "the reference's velocity fed forward"))

    def step(self, state, reference):
        out = super().step(state, reference)
        kv = self.p("Kv")
        return [min(max(u + k * v, lo), hi) for u, k, v, lo, hi in zip(out, kv, reference.velocities, self.u_lo,
                                                                       self.u_hi)]
'''

BROKEN = VERSION_2.replace("from controllers.pid import PID", "from controllers.pid import PID\nimport lab_missing_dependency")
FAILS_AT_START = 'raise RuntimeError("this file fails as it is imported")\n'


@pytest.fixture
def daemon(tmp_path):
    """The guide's daemon line, run in a directory whose ``lab-controllers`` holds lab_pd's
    first version and a file that fails; its log in ``tmp_path/daemon.log``."""
    work = tmp_path / "work"
    plugins = work / "lab-controllers"
    plugins.mkdir(parents=True)
    (plugins / "lab_pd.py").write_text(VERSION_1)
    (plugins / "fails.py").write_text(FAILS_AT_START)
    eps = private_endpoints(tmp_path)
    line, = doc_blocks.commands(DOC, RELOAD, match="^pneumad ", rig=str(tolerant_rig(tmp_path)),
                                recordings=str(tmp_path / "recordings"),
                                endpoints=" ".join(f"--{k} {v}" for k, v in eps.items()))
    log = tmp_path / "daemon.log"
    with open(log, "w") as stderr:
        process = subprocess.Popen(["bash", "-c", "exec " + line.text], cwd=work, stderr=stderr)
    try:
        with Client(**eps, timeout=30.0) as client:
            wait_for_own_daemon(client, process)
            yield client, (plugins / "lab_pd.py").resolve(), log, endpoint_env(eps), work
    finally:
        process.terminate()
        process.wait(30)


def listed(client: Client, name: str) -> dict:
    return next(c for c in client.controllers()["available"] if c["name"] == name)


def wait_for_log(log, text: str, limit_s: float = 30.0) -> str:
    """The daemon's log once it holds ``text`` (the messenger writes it beside the loop)."""
    end = time.monotonic() + limit_s
    while text not in (got := log.read_text()):
        assert time.monotonic() < end, f"{text!r} not in the log:\n{got}"
        time.sleep(0.1)
    return got


@pytest.mark.slow(seconds=10)
def test_an_edited_plugin_is_reloaded_shadowed_and_committed_without_a_restart(daemon):
    client, path, log, env, work = daemon
    pid = client.call("ping")["daemon"]["pid"]
    first = listed(client, "lab_pd")["source"]
    assert first["file"] == str(path) and listed(client, "lab_pd")["doc"] == "Lab PD, version 1."
    client.acquire_lease(60.0)
    client.enable()
    switched = client.switch_controller("lab_pd")
    assert switched["active"] == "lab_pd" and client.controller()["source"] == first
    path.write_text(VERSION_2)
    sub = client.subscribe((b"event",))
    sub.wait_until_heard()
    line, = doc_blocks.commands(DOC, RELOAD, match="reload")  # pneumactl controller reload lab_pd
    done = doc_runs.run(line, work, env)
    assert done.returncode == 0, done.explain()
    reloaded = json.loads(done.stdout)
    assert reloaded["previous_sha256"] == first["sha256"] != reloaded["sha256"] and not reloaded["unchanged"]
    assert reloaded["controllers"] == ["lab_pd"] and reloaded["file"] == str(path)
    # the running controller runs on: the first version's class, its hash
    assert client.controller()["source"] == first and "Kv" not in client.controller()["params"]
    second = listed(client, "lab_pd")
    assert second["source"]["sha256"] == reloaded["sha256"] and second["doc"] == "Lab PD, version 2."
    assert client.shadow("lab_pd", {"Kv": 0.5})["shadow"] == "lab_pd"
    time.sleep(0.5)
    client.commit()
    now = client.controller()
    assert now["source"]["sha256"] == reloaded["sha256"] and now["params"]["Kv"] == [0.5, 0.5]
    kinds = {}
    end = time.monotonic() + 30.0
    while not {"reload", "controller"} <= set(kinds):
        assert time.monotonic() < end, kinds
        got = sub.receive(1.0)
        # the first switch's event may come after the subscription on a loaded PC: the commit's is named
        if got is not None and (got[1]["kind"] == "reload" or got[1].get("cause") == "shadow commit"):
            kinds[got[1]["kind"]] = got[1]
    assert kinds["reload"]["action"] == "loaded" and kinds["reload"]["sha256"] == reloaded["sha256"]
    assert kinds["controller"]["source"]["sha256"] == reloaded["sha256"]  # the commit's switch event
    assert client.status()["state"] == "enabled" and client.call("ping")["daemon"]["pid"] == pid  # no restart
    client.record_start("after-reload")
    time.sleep(0.5)
    stopped = client.record_stop("after-reload")
    assert open_run(stopped["file"]).controller["source"] == now["source"]  # the recording's provenance
    wait_for_log(log, f"reload: loaded lab_pd: {path} sha256 {reloaded['sha256'][:12]}")
    sub.close()


@pytest.mark.slow(seconds=5)
@pytest.mark.parametrize("name", ["/tmp/lab_pd.py", "lab_pd.py", "controllers.pid", "controllers.pid:PID",
                                  "../controllers/lab_pd"])
def test_a_reload_naming_a_path_or_a_module_is_refused(daemon, name):
    client, path, *_ = daemon
    with pytest.raises(RemoteError) as refused:
        client.reload_controller(name)
    assert refused.value.code == "bad_args" and refused.value.data["argument"] == "name"
    assert "never a path or a module" in str(refused.value)


@pytest.mark.slow(seconds=5)
def test_only_a_directory_plugin_reloads(daemon):
    client, *_ = daemon
    with pytest.raises(RemoteError, match=r"'pid' is not from a controller directory: only those reload \(from: "
                                           r"fails, lab_pd\)") as refused:
        client.reload_controller("pid")
    assert refused.value.data["allowed"] == ["fails", "lab_pd"]


@pytest.mark.slow(seconds=10)
def test_a_broken_edit_is_refused_with_its_import_error_and_the_running_controller_runs_on(daemon):
    client, path, log, *_ = daemon
    client.acquire_lease(60.0)
    client.enable()
    client.switch_controller("lab_pd")
    first = client.controller()["source"]
    path.write_text(BROKEN)
    with pytest.raises(RemoteError) as refused:
        client.reload_controller("lab_pd")
    expected = f"{path}, line 4: ModuleNotFoundError: No module named 'lab_missing_dependency'"
    assert refused.value.code == "refused" and expected in str(refused.value)
    assert "the version loaded before stays: lab_pd runs on" in str(refused.value)
    status = client.status()
    assert status["state"] == "enabled" and status["controller"] == "lab_pd"
    assert client.controller()["source"] == first and listed(client, "lab_pd")["source"] == first
    assert client.switch_controller("lab_pd")["active"] == "lab_pd"  # the last good version builds
    assert client.controller()["source"] == first
    wait_for_log(log, f"reload: refused lab_pd ({expected})")


@pytest.mark.slow(seconds=5)
def test_a_file_that_fails_at_start_is_said_in_the_log_and_the_status_and_reloads_once_fixed(daemon):
    client, path, log, *_ = daemon
    fails = path.parent / "fails.py"
    error = f"{fails}, line 1: RuntimeError: this file fails as it is imported"
    assert {"name": "fails", "file": str(fails), "error": error} in client.status()["controllers_refused"]
    wait_for_log(log, f"controller fails refused: {error}")
    fails.write_text(VERSION_1.replace('"lab_pd"', '"fixed"'))
    assert client.reload_controller("fails")["controllers"] == ["fixed"]
    assert client.status()["controllers_refused"] == [] and listed(client, "fixed")["source"]["file"] == str(fails)


def test_the_rig_files_controller_dirs_are_read_relative_to_it(tmp_path, capsys):
    """``[rig] controller_dirs`` names directories beside the rig file, wherever the daemon starts."""
    from daemon.main import main

    (tmp_path / "lab").mkdir()
    (tmp_path / "lab" / "lab_pd.py").write_text(VERSION_1)
    rig = tmp_path / "rig.toml"
    text = tolerant_rig_text()
    assert text.count("[rig]\n") == 1
    rig.write_text(text.replace("[rig]\n", '[rig]\ncontroller_dirs = ["lab"]\n'))
    assert main(["--check", "--config", str(rig), "--controller", "lab_pd"]) == 0
    assert "controller lab_pd" in capsys.readouterr().out


@pytest.mark.slow(seconds=5)
def test_a_file_put_in_the_directory_after_the_start_loads_at_its_first_reload_by_its_name(daemon):
    """A new plugin file dropped in beside the others, its class without a docstring: reloaded by
    the file's name (no path in the request), listed with an empty doc, not refused, and built."""
    client, path, *_ = daemon
    new = path.parent / "lab_new.py"
    new.write_text(VERSION_1.replace('"lab_pd"', '"lab_new"').replace('    """Lab PD, version 1."""\n\n', ""))
    loaded = client.reload_controller("lab_new")
    assert loaded["controllers"] == ["lab_new"] and loaded["file"] == str(new) and loaded["previous_sha256"] is None
    entry = listed(client, "lab_new")
    assert entry["doc"] == "" and "error" not in entry and entry["source"]["file"] == str(new)
    assert "lab_new" not in [r["name"] for r in client.status()["controllers_refused"]]
    client.acquire_lease(60.0)
    client.enable()
    assert client.switch_controller("lab_new")["active"] == "lab_new"
    with pytest.raises(RemoteError, match="is not from a controller directory"):
        client.reload_controller("lab_absent")  # no such file: still refused

