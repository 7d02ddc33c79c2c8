"""``pneumactl watch``'s live view, rendered from real telemetry and a real status of the
in-process loop: state, controller, lease, per-joint numbers (through the cycle record's
layout, in display units) and command bars, loop health."""
import math

from rich.console import Console

from controllers.trajectory import JointMove
from daemon.client.watch import View, _bar
from daemon.testing.loop import dealer, exchange, make_loop, ok
from daemon.wire import protocol


def moving_bottom(step_deg: float, move_s: float):
    """An in-process daemon, enabled under a lease, its bottom joint moving ``step_deg`` [deg]
    in ``move_s`` [s]: (loop, captured, server, socket, describe, lease)."""
    loop, captured, srv = make_loop(server=True)
    sock = dealer(srv)
    describe = ok(loop, sock, "describe")
    lease = ok(loop, sock, "lease.acquire", {"ttl_s": 60.0})["lease"]
    ok(loop, sock, "enable", lease=lease)
    loop.set_trajectory(JointMove(list(loop.angles), [loop.angles[0] + math.radians(step_deg), loop.angles[1]], move_s),
                        "move")
    return loop, captured, srv, sock, describe, lease


def rendered(describe: dict, captured, status: dict) -> tuple[View, Console]:
    """The live view fed every captured telemetry message and ``status``, rendered once onto a
    recording console: (view, console), for more events and renders after."""
    view = View(describe)
    for topic, message in captured.messages:
        view.take(topic, message)
    view.status = status
    console = Console(record=True, width=140)
    console.print(view.render())
    return view, console


def test_the_live_view_shows_the_arm_as_telemetry_and_status_have_it():
    loop, captured, srv, sock, describe, lease = moving_bottom(5.0, 2.0)
    loop.run(1500)  # a stats window and then some
    status = ok(loop, sock, "status")
    srv.close()
    view, console = rendered(describe, captured, status)
    text = console.export_text()
    assert "enabled" in text and "controller pid" in text and "reference move" in text
    assert "lease held" in text
    last = captured.of("state")[-1]
    for name in ("bottom", "middle"):
        assert name in text and f"v_mv {last[f'{name}.u.v_mv'][-1]:.2f} V" in text
        assert f"{math.degrees(last[f'{name}.position'][-1]):.2f} deg" in text
        assert f"p_head_cmd {last[f'{name}.p_head_cmd'][-1] / 1e3:.2f} kPa" in text  # pressures as gauges read them
    assert "loop: wake-up p99" in text and "faults: none" in text
    assert "idle -> enabled (enabled)" in text  # the events
    assert "recording: none" in text
    # The recorder's events (their fields as docs/protocol.md gives them) say what is recorded.
    view.take("event", {"kind": "record", "action": "start", "name": "step-1", "who": "alice", "source": "recorder"})
    console.print(view.render())
    assert "recording: step-1 (alice)" in console.export_text()
    view.take("event", {"kind": "record", "action": "failed", "name": "step-1", "cause": "write error: disk full"})
    console.print(view.render())
    text = console.export_text()
    assert "recording: none" in text and "record failed: step-1 write error: disk full" in text


def test_an_output_bar_is_full_at_either_limit_and_marks_zero():
    full_high, full_low, zero = (str(_bar(u, -4.0, 6.0)) for u in (6.0, -4.0, 0.0))
    assert full_high.rstrip("]").endswith("█") and full_low.lstrip("[").startswith("█")
    assert zero.count("█") == 0 and zero.count("|") == 1


def test_status_and_watch_show_the_safe_state_written_in_an_estop_not_the_controllers_last_v_mv():
    loop, captured, srv, sock, describe, lease = moving_bottom(10.0, 1.0)
    loop.run(600)
    written = [loop.u[0]]  # the V_MV of every cycle the exchange runs: the reply is built in one of them
    reply = exchange(loop, sock, protocol.encode_request(1, "status"), each_cycle=lambda: written.append(loop.u[0]))
    moving = reply["result"]["joints"]["bottom"]
    assert moving["output"] == "controller" and moving["commands"]["v_mv"] in written
    ok(loop, sock, "estop")
    loop.run(50)
    last_u = loop.u[0]
    assert abs(last_u) > 0.05  # the controller's last V_MV is still there: what the old view showed
    status = ok(loop, sock, "status")
    srv.close()
    bottom = status["joints"]["bottom"]
    safe = dict(zip([o[0] for o in describe["transport"]["outputs"]], loop.io.safe_volts))
    assert bottom["output"] == "safe state" and bottom["commands"]["v_mv"] is None
    assert bottom["written_volts"] and all(v == safe[ch] for ch, v in bottom["written_volts"].items())
    _, console = rendered(describe, captured, status)
    text = console.export_text()
    assert "safe state" in text and f"v_mv {last_u:.2f} V" not in text
    written = "  ".join(f"{name} {v:.2f} V" for name, v in safe.items())
    assert f"outputs written: {written}  (safe state)" in text


def test_no_tracking_error_is_shown_while_the_arm_is_not_enabled():
    """Disabled halfway through a move, the arm vents away from the set-point the move left:
    nothing tracks it, so the view shows no error (it showed a red one, e.g. 11.7 deg, while idle)."""
    loop, captured, srv, sock, describe, lease = moving_bottom(10.0, 1.0)
    loop.run(500)
    ok(loop, sock, "disable", lease=lease)
    loop.run(2000)
    status = ok(loop, sock, "status")
    srv.close()
    last = captured.of("state")[-1]
    assert last["mode"][-1] == "idle"
    stale = [math.degrees(last[f"{j}.error"][-1]) for j in ("bottom", "middle")]
    assert max(abs(e) for e in stale) > 2.0  # what the old view showed, in red
    _, console = rendered(describe, captured, status)
    rows = [line for line in console.export_text().splitlines() if line.strip(" │").startswith(("bottom ", "middle "))]
    assert len(rows) == 2
    for row, error in zip(rows, stale):
        assert f" {error:.2f} deg" not in row and " - " in row, row
