"""A second daemon given a running one's endpoints: ZeroMQ would take an ``ipc://`` endpoint
over without a word (it unlinks the socket file), leaving the first daemon's loop running and
unreachable; the second refuses to start instead, naming who holds the endpoint."""
from __future__ import annotations

import subprocess
import sys

from daemon.client.client import Client
from daemon.testing.daemons import STOP_WAIT_S
from tests.daemons import real_daemon, wait_for_own_daemon


def test_a_second_daemon_on_a_running_ones_ipc_endpoints_refuses_to_start_naming_the_holder(tmp_path):
    first, eps = real_daemon(tmp_path)
    try:
        with Client(**eps, timeout=20.0) as client:
            wait_for_own_daemon(client, first)
            second = subprocess.run([sys.executable, "-m", "daemon.main", "run", "--no-rt", "--record-dir",
                                     str(tmp_path / "second"), *sum(([f"--{k}", v] for k, v in eps.items()), [])],
                                    capture_output=True, text=True, timeout=120)
            assert second.returncode == 4, second.stderr  # the endpoints refused (daemon/main.py)
            assert f"cannot bind the command endpoint {eps['command']}: in use by pid " in second.stderr, second.stderr
            assert "daemon" in second.stderr.split("in use by pid ", 1)[1].splitlines()[0]  # the holder's command line
            assert "Traceback" not in second.stderr
            assert client.ping()["daemon"]["pid"] == first.pid  # the first still answers on its endpoints
    finally:
        first.terminate()
        first.wait(STOP_WAIT_S)
