"""``pneumad run --plotjuggler EP`` (daemon/messenger/plotjuggler.py): single-frame msgpack rows, one per
loop cycle, each with its own time field, as PlotJuggler's ZMQ source and msgpack parser take
them; and an endpoint PlotJuggler could reach without keys is refused unless --insecure."""
import math
import time

import msgpack
import pytest
import zmq

from daemon.client.client import Client
from daemon.loop.port import ZmqServer
from daemon.testing.daemons import STOP_WAIT_S
from hal.errors import ConfigError
from tests.daemons import real_daemon, wait_for_own_daemon

pytestmark = pytest.mark.slow


def flatten(prefix: str, value, out: dict) -> None:
    """What PlotJuggler's parser does with a map: one series per leaf, named by its path."""
    if isinstance(value, dict):
        for key, item in value.items():
            flatten(f"{prefix}/{key}", item, out)
    else:
        assert isinstance(value, (int, float)) and not isinstance(value, bool), (prefix, value)
        out[prefix] = value


def test_rows_carry_their_own_time_one_per_cycle(tmp_path):
    endpoint = f"ipc://{tmp_path}/plotjuggler"
    daemon, eps = real_daemon(tmp_path, "--plotjuggler", endpoint)
    sub = zmq.Context.instance().socket(zmq.SUB)
    sub.setsockopt(zmq.LINGER, 0)
    sub.setsockopt(zmq.SUBSCRIBE, b"")  # PlotJuggler's default: every message
    sub.connect(endpoint)
    try:
        with Client(**eps, timeout=5.0) as client:
            wait_for_own_daemon(client, daemon)
            client.acquire_lease()
            client.keep_lease()
            client.enable()
            joints = client.status()["joints"]
            target = [joints["bottom"]["position"], joints["middle"]["position"] + 1.0]  # [deg]
            client.set(target, duration_s=1.0)
            # Rows until the 1 s move has ended and 1000 state rows are in (2 s on a quiet machine;
            # a busy one's loop skips cycles, so the rows are waited for, up to a bound for a hang).
            rows, end, arrived, ended = [], time.monotonic() + 60.0, 0, False
            while time.monotonic() < end and not (arrived > 1000 and ended):
                if sub.poll(100):
                    frames = sub.recv_multipart()
                    assert len(frames) == 1  # no topic frame: every PlotJuggler version parses it
                    rows.append(row := msgpack.unpackb(frames[0], raw=False))
                    if "cycle" in row:
                        arrived += 1
                        ended = ended or abs(row["middle"]["setpoint_deg"] - target[1]) < 0.01
    finally:
        sub.close()
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
    series = [{} for _ in rows]
    for row, out in zip(rows, series):
        flatten("", row, out)
        assert isinstance(row["t"], float)
    state = [r for r in rows if "cycle" in r]
    cycles = [r["cycle"] for r in state]
    assert len(state) > 1000 and cycles == list(range(cycles[0], cycles[0] + len(cycles)))
    steps = [b["t"] - a["t"] for a, b in zip(state, state[1:])]
    assert min(steps) > 0 and sorted(steps)[len(steps) // 2] == pytest.approx(1e-3, rel=0.2)
    moving = state[-1]["middle"]
    assert set(moving) == {"position_deg", "setpoint_deg", "error_deg", "velocity_deg_s", "u.v_mv_V", "p_head_cmd_kPa",
                           "p_rod_cmd_kPa"}  # the layout's fields (no shadow run: its NaN left out)
    assert moving["error_deg"] == pytest.approx(moving["setpoint_deg"] - moving["position_deg"])
    assert min(abs(r["middle"]["setpoint_deg"] - target[1]) for r in state) < 0.01  # it saw the move end
    internals = [s for s, r in zip(series, rows) if "internals" in r]
    assert internals and {"/internals/p/bottom", "/internals/i/middle"} <= set(internals[-1])
    stats = [r["stats"] for r in rows if "stats" in r]
    assert stats and all(math.isfinite(s["latency_us_p99"]) for s in stats)


def test_an_endpoint_reachable_from_the_network_is_refused_without_insecure():
    with pytest.raises(ConfigError, match="PlotJuggler cannot use keys"):
        ZmqServer("tcp://127.0.0.1:*", "tcp://127.0.0.1:*", "tcp://127.0.0.1:*", plotjuggler="tcp://0.0.0.0:9872")
