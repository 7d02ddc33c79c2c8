"""README.md's "Reaching the rig through a real wire" lines, run as written: each peer, the
daemon pointed at it, the arm enabled and moved, and the daemon still enabled 10 s after the
enable with nothing tripped.

What a test must change in them is declared in tests/doc_claims.toml, with its reason: the
wire's address (a link under the test's directory, a free port, a multicast group of its own:
the README's are a lab PC's), the daemon's endpoints (private, reached through the
environment), and the machine's load: the lines' 50 ms stale limit is a quiet PC's, and this
suite runs beside other work (two CPU hogs held a wire's peer for over a second), so the daemon
is given the limits the other wire tests use. What is checked is that the lines work, not this
machine's latency (`pneumad latency`, bench.transport_cost measure that)."""
from __future__ import annotations

import subprocess

import pytest

from tests import doc_blocks
from tests.doc_blocks import BIN
from tests.test_doc_wires import fills, pair_up, run_pair

pytestmark = pytest.mark.slow(seconds=20)


@pytest.mark.parametrize("wire", ["serial", "modbus", "can"])
def test_the_readme_wire_lines_run_as_written(wire, tmp_path):
    values = fills(tmp_path)
    pairs = pair_up(doc_blocks.commands("README.md", "Reaching the rig through a real wire", **values))
    assert len(pairs) == 3
    peer, daemon_line = next(pair for pair in pairs if f"--transport {wire}" in pair[1].written)

    def move(client, env):
        assert client.describe()["transport"]["backend"] == wire
        line = "set 130 -85 --duration 8 --wait"
        done = subprocess.run(["bash", "-c", f"{BIN}pneumactl {line}"], env=env, capture_output=True, text=True,
                              timeout=120)
        assert done.returncode == 0, (line, done.stderr, client.status()["cause"])

    status = run_pair(peer, daemon_line.text, values, tmp_path, hold_s=10.0, move=move)  # the move among the 10 s
    assert abs(status["joints"]["bottom"]["position"] - 130.0) < 1.0  # [deg]: the joint's unit
    assert status["transport"]["reads"] > 1000 and status["transport"]["errors"] == 0, status["transport"]
