"""pneumad under Bluesky across rigs (daemon/client/bluesky, docs/bluesky.md), each test with
daemons of its own: bluesky-queueserver, with a real Redis, runs a queue across two daemons
(the cylinder arm and the muscle joint) into a real Tiled server, and a trip fails its item and
stops the queue; a rig with an array sensor reads its contact estimate as a device's signals."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests import extras

if extras.missing("bluesky"):
    pytest.skip(extras.reason("bluesky"), allow_module_level=True)

import bluesky.plan_stubs as bps  # noqa: E402
from bluesky import RunEngine  # noqa: E402
from tiled.client import from_uri  # noqa: E402
from tiled.server import SimpleTiledServer  # noqa: E402

from daemon.client.bluesky import plans  # noqa: E402
from daemon.client.bluesky.device import PneumadRig  # noqa: E402
from daemon.client.client import Client  # noqa: E402
from daemon.testing.daemons import STOP_WAIT_S
from tests.daemons import free_tcp_ports, real_daemon, tolerant_rig_text, wait_for_own_daemon  # noqa: E402

# slow: each test's share of the file's ~80 s on a 2-core machine (tests/conftest.py orders files by the sum)
pytestmark = [pytest.mark.slow(seconds=40), pytest.mark.bluesky]


def test_a_rig_with_an_array_sensor_reads_its_contact_estimate(tmp_path):
    from tests.test_contact_daemon import SENSOR
    rig_path = tmp_path / "rig.toml"
    rig_path.write_text(tolerant_rig_text() + SENSOR)
    daemon, eps = real_daemon(tmp_path, "--config", str(rig_path))
    try:
        with Client(**eps, timeout=5.0) as client:
            wait_for_own_daemon(client, daemon)
        rig = PneumadRig.connect_to("arm", hdf5_directory=str(tmp_path), **eps)
        engine, seen = RunEngine({}), []

        def until_touched():
            for _ in range(600):  # the simulated impacts come once a second
                force = yield from bps.rd(rig.contact_force_n)
                if force == force:
                    seen.append((force, (yield from bps.rd(rig.contact_cx))))
                    return
                yield from bps.sleep(0.05)
        engine(until_touched())
        rig.close()
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
    assert seen and seen[0][0] > 0.0 and abs(seen[0][1]) < 0.1, seen  # a force [N] at a centre on the pad [m]
    assert rig.contact_force_n.source == f"pneumad://{rig.link.rig_name}/contact/force_n"


@pytest.mark.skipif(shutil.which("redis-server") is None, reason="no redis-server (Debian: apt-get install redis-server)")
def test_a_queue_runs_plans_across_two_daemons_into_tiled(tmp_path):
    from bluesky_queueserver_api import BPlan
    from bluesky_queueserver_api.zmq import REManagerAPI
    processes = []
    try:
        redis_port, control, info = free_tcp_ports(3)
        processes.append(subprocess.Popen(["redis-server", "--port", str(redis_port), "--bind", "127.0.0.1", "--save", "",
                                           "--appendonly", "no", "--dir", str(tmp_path)], stdout=subprocess.DEVNULL))
        rigs = {}
        for name, options in (("arm", ()), ("muscle", ("--config", "sim-muscle", "--safety", "stall_after_s=5.0"))):
            (tmp_path / name).mkdir()
            daemon, eps = real_daemon(tmp_path / name, *options)
            processes.append(daemon)
            with Client(**eps, timeout=5.0) as client:
                wait_for_own_daemon(client, daemon)
            rigs[name] = eps
        (tmp_path / "h5").mkdir()
        server = SimpleTiledServer(directory=tmp_path / "tiled", readable_storage=[tmp_path / "h5"])
        settings = tmp_path / "bluesky.json"
        settings.write_text(json.dumps({"rigs": rigs, "tiled": {"uri": server.uri}, "hdf5_directory": str(tmp_path / "h5")}))
        permissions = Path(plans.__file__).with_name("permissions.yaml")
        processes.append(subprocess.Popen(
            [os.path.join(os.path.dirname(sys.executable), "start-re-manager"),
             "--startup-module", "daemon.client.bluesky.queue_startup", "--redis-addr", f"127.0.0.1:{redis_port}",
             "--zmq-control-addr", f"tcp://127.0.0.1:{control}", "--zmq-info-addr", f"tcp://127.0.0.1:{info}",
             "--use-ipython-kernel", "OFF", "--zmq-publish-console", "OFF", "--user-group-permissions", str(permissions),
             "--existing-plans-devices", str(tmp_path / "existing.yaml"), "--update-existing-plans-devices",
             "ENVIRONMENT_OPEN"], env={**os.environ, "PNEUMAD_BLUESKY_CONFIG": str(settings)}, cwd=tmp_path,
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        manager = REManagerAPI(zmq_control_addr=f"tcp://127.0.0.1:{control}", zmq_info_addr=f"tcp://127.0.0.1:{info}",
                               timeout_recv=60.0)  # its default 2 s is a fast machine's
        deadline = time.monotonic() + 60.0
        while True:
            try:
                manager.status()
                break
            except manager.RequestTimeoutError:
                assert time.monotonic() < deadline, "the queue's manager did not answer within 60 s"
        manager.environment_open()
        manager.wait_for_idle(timeout=180)
        assert sorted(manager.devices_allowed()["devices_allowed"]) == ["arm", "muscle"]
        manager.item_add(BPlan("step_response", "arm", "bottom", 3.0))
        manager.item_add(BPlan("step_response", "muscle", "elbow", 5.0))
        manager.item_add(BPlan("step_response", "arm", "nowhere", 1.0))  # no such joint: that item fails alone
        manager.queue_start()
        manager.wait_for_idle(timeout=300)
        history = manager.history_get()["items"]
        assert [item["result"]["exit_status"] for item in history] == ["completed", "completed", "failed"], \
            [item["result"]["msg"] for item in history]
        assert "nowhere" in history[2]["result"]["msg"]
        tiled = from_uri(server.uri)
        for item, rig_name in zip(history[:2], ("sim-2joint", "sim-muscle")):
            (uid,) = item["result"]["run_uids"]
            run = tiled[uid]
            assert run.metadata["start"]["rig"] == rig_name
            cycle = np.asarray(run["record"][f"{item['args'][0]}_record_cycle"].read())
            t = np.asarray(run["record"][f"{item['args'][0]}_record_t"].read())
            assert np.all(np.diff(cycle) == 1) and t[-1] - t[0] > 3.0  # every cycle the loop ran, 3 s past the end
        # A trip while an item runs: the queue's suspender pauses it (an unattended queue does not
        # go on past a tripped rig, nor lose its items), the plan hands the rig's lease back;
        # once someone resets and enables the arm, the path is flown again from its checkpoint
        # and the queue goes on.
        manager.queue_clear()
        manager.item_add(BPlan("path_run", "arm", "translation"))
        manager.item_add(BPlan("step_response", "muscle", "elbow", 2.0))
        done = len(manager.history_get()["items"])
        with Client(**rigs["arm"], timeout=5.0) as arm:
            manager.queue_start()
            deadline = time.monotonic() + 120.0
            while not (arm.status()["state"] == "enabled" and arm.status()["reference_remaining_s"] > 0.0):
                assert time.monotonic() < deadline, "the path never started"
                time.sleep(0.05)
            arm.estop("a test's e-stop in the queue")
            deadline = time.monotonic() + 60.0
            while arm.status()["lease_held"]:  # handed back by the suspended plan
                assert time.monotonic() < deadline, "the suspended plan kept the lease"
                time.sleep(0.05)
            assert manager.status()["manager_state"] == "executing_queue"  # paused, not failed
            assert len(manager.history_get()["items"]) == done
            arm.acquire_lease()
            arm.reset()
            arm.enable()
            arm.release_lease()
            manager.wait_for_idle(timeout=300)
            resumed = manager.history_get()["items"][done:]
            assert [(item["name"], item["result"]["exit_status"]) for item in resumed] == \
                [("path_run", "completed"), ("step_response", "completed")], [item["result"] for item in resumed]
            status = arm.status()
            assert status["state"] == "enabled" and status["lease_held"] is False, status
        manager.environment_close()
        manager.wait_for_idle(timeout=60)
        manager.close()
        server.close()
    finally:
        for process in reversed(processes):
            process.terminate()
            try:
                process.wait(STOP_WAIT_S)
            except subprocess.TimeoutExpired:
                process.kill()
