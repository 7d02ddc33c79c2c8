"""Hot swap through the command protocol: controllers are built off the loop and swapped in
at a cycle boundary, a candidate can run in shadow and be committed, and a failing
candidate only ends its own run. The real loop on a virtual clock, real ZeroMQ sockets."""
import logging
import math
import os
import signal
import time

import msgpack
import pytest

from controllers import lti_design
from daemon.planner.process import BUILD_NICE, Preparer
from daemon.testing.daemons import STOP_WAIT_S
from daemon.wire import protocol as P
from tests import plugins
from daemon.client.client import Client
from daemon.testing.loop import call, dealer, make_loop, ok, run_seconds
from tests.daemons import real_daemon, wait_for_own_daemon


# the misbehaving controllers of tests/plugins.py, registered as the daemon's configuration would
TEST_PLUGINS = {name: f"tests.plugins:{name}" for name in ("Raising", "DiesWhenBuilt", "HangsWhenBuilt",
                                                            "UnsendableWhenBuilt", "Contrary")}


@pytest.fixture
def enabled():
    """Enabled under PID at rest, the lease held: for what needs the loop and its worker
    running but not the arm moving (refusals, parameter changes, the worker's failures)."""
    loop, captured, srv = make_loop(server=True, plugins=TEST_PLUGINS)
    sock = dealer(srv)
    lease = ok(loop, sock, "lease.acquire", {"ttl_s": 60.0})["lease"]
    ok(loop, sock, "enable", lease=lease)
    yield loop, captured, sock, lease
    srv.close()


@pytest.fixture
def moving(enabled):
    """As ``enabled``, and halfway along the translation path: for what a swap does to a moving
    arm (its 12 s of cycles are the costly part of a test's set-up)."""
    loop, _, sock, lease = enabled
    ok(loop, sock, "path", {"name": "translation", "approach_s": 6.0}, lease=lease)
    run_seconds(loop, 12.0)
    return enabled


def assert_bumpless(loop, captured, cycle):
    """The swap a reply reports at ``cycle`` took effect at that cycle's end, so the state row
    of cycle + 1 holds the new controller's first output: within 1 % of the command range of
    the last output of the old one."""
    loop.run(20)  # flush the telemetry batch
    u = dict(captured.series(captured.fields("command")))
    span = [hi - lo for lo, hi in zip(loop.context.u_min, loop.context.u_max)]
    before, after = u[cycle], u[cycle + 1]
    assert all(abs(a - b) <= 0.01 * s for a, b, s in zip(after, before, span)), (before, after)


@pytest.mark.slow(seconds=3)  # a few seconds: kept out of the fast subset
def test_a_switch_is_built_off_the_loop_and_replied_once_it_is_in_force(moving):
    loop, captured, sock, lease = moving
    sent_at = loop.cycle
    result = ok(loop, sock, "controller.switch", {"name": "smc"}, lease)
    assert result["active"] == "smc" and loop.controller.name == "smc"
    assert result["cycle"] > sent_at  # the loop kept cycling while the worker built it
    assert loop.stats.overruns_total == 0
    loop.run(1)  # the event of a swap at a cycle's end goes out with the next cycle's
    switch = [e for e in captured.of("event") if e.get("kind") == "controller"]
    assert switch[-1]["to"] == "smc" and switch[-1]["cause"] == "switch"


def test_a_second_build_while_one_is_prepared_is_refused_as_busy(enabled):
    loop, _, sock, lease = enabled
    sock.send(P.encode_request(1, "controller.switch", {"name": "smc"}, lease))
    sock.send(P.encode_request(2, "controller.switch", {"name": "sac"}, lease))
    replies = {}
    deadline = time.monotonic() + 120  # both replies waited for: a busy machine builds slowly
    while len(replies) < 2 and time.monotonic() < deadline:
        loop.run(1)
        while sock.poll(0):
            reply = msgpack.unpackb(sock.recv_multipart()[-1], raw=False)
            replies[reply["id"]] = reply
        sock.poll(0.1)
    assert replies[1]["ok"] and replies[1]["result"]["active"] == "smc"
    assert replies[2]["error"]["code"] == P.BUSY
    assert loop.controller.name == "smc" and loop.state.value == "enabled"


def test_a_controller_that_cannot_be_built_is_refused_and_the_active_one_stays(enabled):
    loop, _, sock, lease = enabled
    for args, code, text in (({"name": "nope"}, P.BAD_ARGS, "nope"),
                             ({"name": "smc", "params": {"eps": -1}}, P.BAD_ARGS, "eps"),
                             ({"name": "lti"}, P.BAD_ARGS, "option 'design' is required"),
                             ({"name": "lti", "options": {"design": {"joints": {}}}}, P.BAD_ARGS, "no controller for"),
                             ({"name": "smc", "params": []}, P.BAD_ARGS, "must be a map")):
        reply = call(loop, sock, "controller.switch", args, lease)
        assert reply["error"]["code"] == code and text in reply["error"]["message"], reply
    assert loop.controller.name == "pid" and loop.state.value == "enabled"


@pytest.mark.slow(seconds=3)  # a few seconds: kept out of the fast subset
def test_an_lti_design_sent_over_the_wire_takes_over_bumplessly(moving):
    loop, captured, sock, lease = moving
    design = lti_design.read_file(lti_design.EXAMPLE)
    result = ok(loop, sock, "controller.switch", {"name": "lti_dob", "options": {"design": design}}, lease)
    assert loop.controller.name == "lti_dob"
    assert_bumpless(loop, captured, result["cycle"])
    run_seconds(loop, 3.0)
    assert max(abs(math.degrees(r - q)) for r, q in zip(loop.reference[0], loop.angles)) < 3.0


@pytest.mark.slow(seconds=3)  # a few seconds: kept out of the fast subset
def test_a_shadow_run_publishes_what_it_would_command_and_commits_bumplessly(moving):
    loop, captured, sock, lease = moving
    assert ok(loop, sock, "controller.shadow", {"name": "smc_dob"}, lease)["shadow"] == "smc_dob"
    run_seconds(loop, 2.0)
    status = ok(loop, sock, "status")
    loop.run(20)  # flush the telemetry batch that holds the status's cycle
    # The rows of exactly the cycles the status covers (the virtual-clock loop runs on while a
    # reply travels in real time, so a count taken before the request would cover fewer).
    commands, shadow = captured.fields("command"), captured.fields("shadow")
    rows = [(v[:len(commands)], v[len(commands):]) for c, v in captured.series(commands + shadow)
            if not math.isnan(v[-1]) and c <= status["cycle"]]
    assert len(rows) > 1500 and loop.controller.name == "pid"
    assert status["shadow"]["controller"] == "smc_dob" and status["shadow"]["cycles"] == len(rows)
    for j in range(loop.n):  # the run's comparison is that of the published outputs
        diffs = [abs(sh[j] - u[j]) for u, sh in rows]
        assert status["shadow"]["max_diff_volts"][j] == pytest.approx(max(diffs), abs=1e-12)
        rms = math.sqrt(sum(d * d for d in diffs) / len(diffs))
        assert status["shadow"]["rms_diff_volts"][j] == pytest.approx(rms, rel=1e-9)
    # SMC+DOB's output is 0.3-6 V RMS from a PID that saturates on the middle joint, depending on
    # the part of the path the run saw (on a busy machine the run starts later along it): past
    # half the range a commit needs force, which is what a user is told; here it is given
    committed = ok(loop, sock, "controller.commit", {"force": True}, lease)
    assert committed["active"] == "smc_dob" and committed["cycles"] >= len(rows)
    assert_bumpless(loop, captured, committed["cycle"])
    run_seconds(loop, 3.0)
    cycles = [c for m in captured.of("state") for c in m["cycle"]]
    assert cycles == list(range(cycles[0], cycles[0] + len(cycles)))  # no cycle missed across it all
    assert loop.stats.overruns_total == 0
    assert loop.state.value == "enabled" and loop.controller.name == "smc_dob" and loop.shadow_run is None
    assert max(abs(math.degrees(r - q)) for r, q in zip(loop.reference[0], loop.angles)) < 3.0
    kinds = [(e["kind"], e.get("action")) for e in captured.of("event")]
    assert ("shadow", "start") in kinds and ("shadow", "commit") in kinds


def test_a_commit_past_a_shadow_run_far_from_the_active_controller_needs_force(enabled):
    """A candidate as wrong as a sign error (it commands the rail furthest from PID's output)
    is not committed without a word; with force it is."""
    loop, _, sock, lease = enabled
    ok(loop, sock, "controller.shadow", {"name": "Contrary"}, lease)
    run_seconds(loop, 1.0)
    refused = call(loop, sock, "controller.commit", {}, lease)["error"]
    assert refused["code"] == P.REFUSED and refused["data"]["reason"] == "shadow_difference", refused
    span = loop.context.u_max[0] - loop.context.u_min[0]
    assert refused["data"]["rms_diff"] > refused["data"]["limit"] == pytest.approx(0.5 * span)
    assert "--force" in refused["message"] and loop.shadow_run is not None  # the run goes on: discard or force
    assert ok(loop, sock, "controller.commit", {"force": True}, lease)["active"] == "contrary"
    assert loop.shadow_run is None


def test_a_failing_shadow_ends_its_own_run_and_nothing_else(enabled):
    loop, captured, sock, lease = enabled
    ok(loop, sock, "controller.shadow", {"name": "Raising"}, lease)
    run_seconds(loop, 0.1)
    assert loop.shadow_run is None and loop.controller.name == "pid" and loop.state.value == "enabled"
    failed = [e for e in captured.of("event") if e.get("kind") == "shadow" and e.get("action") == "failed"]
    assert failed and "controller bug" in failed[0]["cause"]
    assert call(loop, sock, "controller.commit", {}, lease)["error"]["code"] == P.BAD_STATE


def test_a_discarded_shadow_run_reports_its_comparison_and_changes_nothing(moving):
    loop, _, sock, lease = moving
    ok(loop, sock, "controller.shadow", {"name": "pid", "params": {"Kp": [60.0, 60.0]}}, lease)
    run_seconds(loop, 1.0)
    summary = ok(loop, sock, "controller.discard", {}, lease)
    assert summary["controller"] == "pid" and summary["cycles"] >= 990
    assert max(summary["max_diff_volts"]) > 0.0  # other gains, other outputs
    assert loop.shadow_run is None and loop.controller.get_params()["Kp"] != [60.0, 60.0]


def test_parameters_set_on_a_controller_come_back_with_it_and_the_switch_says_so(enabled):
    loop, _, sock, lease = enabled
    ok(loop, sock, "controller.set", {"params": {"Kp": [60.0, 55.0]}}, lease)
    assert ok(loop, sock, "controller.switch", {"name": "smc"}, lease)["carried"] == {}
    back = ok(loop, sock, "controller.switch", {"name": "pid", "params": {"Ti": [1.5, 2.5]}}, lease)
    assert back["carried"] == {"Kp": [60.0, 55.0]}  # what was set is kept, and said
    assert loop.controller.p("Kp") == (60.0, 55.0) and loop.controller.p("Ti") == (1.5, 2.5)
    ok(loop, sock, "controller.switch", {"name": "smc"}, lease)
    again = ok(loop, sock, "controller.switch", {"name": "pid", "params": {"Kp": 40.0}}, lease)
    assert again["carried"] == {"Ti": [1.5, 2.5]}  # a parameter the request gives is the request's
    assert loop.controller.p("Kp") == (40.0, 40.0) and loop.controller.p("Ti") == (1.5, 2.5)
    shadow = ok(loop, sock, "controller.shadow", {"name": "pid"}, lease)
    assert shadow["carried"] == {"Kp": 40.0, "Ti": [1.5, 2.5]}  # a candidate starts from them too
    ok(loop, sock, "controller.discard", {}, lease)
    assert ok(loop, sock, "controller.switch", {"name": "pid"}, lease)["reset"] == {}  # the same controller
    # a switch to another controller that has a parameter of the same name says it starts it afresh
    ok(loop, sock, "controller.switch", {"name": "smc", "params": {"switch_volts": [2.0, 2.5]}}, lease)
    other = ok(loop, sock, "controller.switch", {"name": "sac"}, lease)
    assert other["reset"] == {"switch_volts": {"was": [2.0, 2.5], "now": list(loop.controller.p("switch_volts"))}}
    assert loop.controller.p("switch_volts") != (2.0, 2.5)


def test_a_parameter_change_is_derived_off_the_loop_and_applied_whole(enabled):
    loop, _, sock, lease = enabled
    ok(loop, sock, "controller.switch", {"name": "smc"}, lease)
    result = ok(loop, sock, "controller.set", {"params": {"eps": [2.0, 1.0]}}, lease)
    assert result["params"]["eps"] == [2.0, 1.0] and loop.controller.get_params()["eps"] == [2.0, 1.0]
    before = loop.controller.get_params()
    reply = call(loop, sock, "controller.set", {"params": {"eps": [2.0, 500.0]}}, lease)
    assert reply["error"]["code"] == P.BAD_ARGS and "eps[middle] = 500.0" in reply["error"]["message"]
    assert loop.controller.get_params() == before


@pytest.mark.parametrize("plugin, text", [("DiesWhenBuilt", "worker died (exit code 3)"),
                                          ("HangsWhenBuilt", "took longer than 2 s"),
                                          ("UnsendableWhenBuilt", "could not be sent back")])
@pytest.mark.slow  # long: kept out of the fast subset
def test_a_build_that_kills_hangs_or_cannot_return_is_refused_and_the_next_one_works(enabled, plugin, text,
                                                                                      monkeypatch):
    """The build runs in a worker process: whatever it does there, the loop keeps its
    controller and its period, the request gets a clear refusal and the next switch works."""
    loop, captured, sock, lease = enabled
    preparer = loop.server.commands.preparer
    preparer.warm().result(timeout=120)  # a worker up and warm: the limit below times the build alone
    if plugin == "HangsWhenBuilt":
        monkeypatch.setattr(preparer, "time_limit_s", 2.0)  # "hung" after 2 s here, not the daemon's 30 s
    reply = call(loop, sock, "controller.switch", {"name": plugin}, lease)
    assert reply["error"]["code"] == P.REFUSED and text in reply["error"]["message"], reply
    monkeypatch.undo()
    # The failed worker's replacement, spawned and warm (however long that takes on a busy
    # machine) before the next switch is timed by the loop's cycles.
    preparer.warm().result(timeout=120)
    if plugin != "UnsendableWhenBuilt":  # the worker is replaced, and the event says who ended it
        replaced = planner_event(loop, captured, preparer.health()["restarts"])
        assert ("stopped by the daemon with SIGKILL" in replaced) == (plugin == "HangsWhenBuilt"), replaced
        assert "from outside the daemon" not in replaced, replaced
    assert loop.controller.name == "pid" and loop.state.value == "enabled"
    assert ok(loop, sock, "controller.switch", {"name": "smc"}, lease)["active"] == "smc"
    assert loop.stats.overruns_total == 0


def planner_event(loop, captured, restart: int, limit_s: float = 180.0) -> str:
    """The cause of the ``planner`` event of the worker's ``restart``-th replacement, the loop
    run until it looks (the replacement's warm-up beside two CPU hogs: however long it takes).
    The session's worker is shared: an earlier test's replacements are not this one's."""
    end = time.monotonic() + limit_s
    while True:
        causes = [m["cause"] for m in captured.of("event") if m["kind"] == "planner"]
        mine = [c for c in causes if c.endswith(f"(restart {restart})")]
        if mine:
            return mine[0]
        assert time.monotonic() < end, f"no planner event for restart {restart}: {causes}"
        loop.run(100)  # the loop looks every 100 cycles
        time.sleep(0.02)


def test_a_worker_that_dies_while_idle_is_reported_and_replaced_warm_before_the_next_request(enabled):
    """Killed between two requests: the courier sees it end at once and starts another,
    warmed; the loop's next look makes it a ``planner`` event and the status says so. The
    next request is neither refused nor made to wait for a worker. (The log line: below, in
    a real daemon.)"""
    loop, captured, sock, lease = enabled
    preparer = loop.server.commands.preparer
    preparer.warm().result(timeout=120)
    before = ok(loop, sock, "status")["helpers"]["planner"]
    assert before["running"]
    os.kill(before["pid"], signal.SIGKILL)
    cause = planner_event(loop, captured, before["restarts"] + 1)
    assert "died while idle (exit code -9: SIGKILL from outside the daemon)" in cause, cause
    assert "started and warmed" in cause and "stopped by the daemon" not in cause, cause
    after = ok(loop, sock, "status")["helpers"]["planner"]
    assert after["running"] and after["pid"] != before["pid"] and after["restarts"] == before["restarts"] + 1
    assert after["last_exit_code"] == -signal.SIGKILL
    started = loop.cycle
    assert ok(loop, sock, "controller.switch", {"name": "smc"}, lease)["active"] == "smc"
    assert loop.cycle - started < 5000  # built by a warm worker: no imports (a cold one: 1.5-20 s of them)


@pytest.mark.slow(seconds=20)
def test_a_daemon_logs_a_planner_worker_that_died_and_the_next_request_works(tmp_path):
    """In a real daemon: the worker killed while idle is an event, a line in the daemon's log
    (its stderr: the journal) and the status's ``helpers.planner``; the next switch works."""
    log = tmp_path / "daemon.log"
    with open(log, "w") as stderr:
        daemon, eps = real_daemon(tmp_path, stderr=stderr)
    try:
        with Client(**eps, timeout=10.0) as client:
            wait_for_own_daemon(client, daemon)
            sub = client.subscribe((b"event",))
            sub.wait_until_heard()
            before = client.status()["helpers"]["planner"]
            assert before["running"]  # warmed before the daemon said it was ready: idle now
            os.kill(before["pid"], signal.SIGKILL)
            end = time.monotonic() + 180.0  # a warm-up beside two CPU hogs: however long it takes
            while (got := sub.receive(1.0)) is None or got[1]["kind"] != "planner":
                assert time.monotonic() < end, "no planner event"
            assert "died while idle (exit code -9: SIGKILL from outside the daemon)" in got[1]["cause"]
            after = client.status()["helpers"]["planner"]
            assert after["running"] and after["restarts"] == 1 and after["pid"] != before["pid"]
            client.acquire_lease()
            assert client.switch_controller("smc")["active"] == "smc"
            sub.close()
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
    assert "pneumad messenger ERROR: planner: the planner worker died while idle (exit code -9: SIGKILL from " \
           "outside the daemon); another was " \
           "started and warmed (restart 1)" in log.read_text()


def test_a_parameter_change_for_a_controller_built_from_options_is_derived_by_its_twin(enabled):
    """The worker rebuilds the running controller from its class, options and current values
    and derives the change there; what comes back is applied to the running one."""
    loop, _, sock, lease = enabled
    design = lti_design.read_file(lti_design.EXAMPLE)
    ok(loop, sock, "controller.switch", {"name": "lti", "options": {"design": design}}, lease)
    running = loop.controller
    result = ok(loop, sock, "controller.set", {"params": {"gain": [0.5, 0.8]}}, lease)
    assert loop.controller is running and result["params"]["gain"] == [0.5, 0.8]
    assert list(running.k["gain"]) == [0.5, 0.8]  # the derived constants came back and are in use


@pytest.mark.parametrize("name, module", [("tests.planted:Anything", "tests.planted"), ("this:Controller", "this"),
                                          ("controllers.pid:PID", None)])
def test_a_request_never_chooses_a_module_to_import(enabled, name, module):
    """A request names a registered controller; a module:Class path, even one that exists,
    is refused, and its module is never imported in the worker that builds controllers."""
    loop, _, sock, lease = enabled
    for cmd in ("controller.switch", "controller.shadow"):
        reply = call(loop, sock, cmd, {"name": name}, lease)
        assert reply["error"]["code"] == P.BAD_ARGS and "daemon's own configuration" in reply["error"]["message"]
    if module is not None:
        asked = loop.server.commands.preparer.submit(lambda found: found, plugins.imported, module)
        assert asked.future.result(timeout=30) is False
    assert loop.controller.name == "pid"
    assert ok(loop, sock, "controller.switch", {"name": "smc"}, lease)["active"] == "smc"


def test_the_worker_warms_at_the_daemons_priority_and_builds_at_build_nice():
    """A build after the warm-up runs at BUILD_NICE: below the courier and a --no-rt loop,
    not so far below that other work on the PC starves it (daemon/planner/process.py)."""
    preparer = Preparer(time_limit_s=60.0)
    try:
        assert preparer.warm().result(timeout=120.0) is None
        build = preparer.submit(dict, os.getpriority, os.PRIO_PROCESS, 0)
        assert build.future.result(timeout=120.0) == BUILD_NICE == 10 > os.getpriority(os.PRIO_PROCESS, 0)
    finally:
        preparer.close()


def test_a_plugin_that_fails_to_load_is_said_at_start_in_the_log_an_event_and_the_status(caplog):
    """Said before only in controller.list's answer: a plugin that cannot be loaded (no such
    class, or a module that raises as it is imported) is refused, the daemon starts, and its log,
    a ``plugin`` event and ``status.controllers_refused`` say which and why."""
    from tests.schemas import schema

    caplog.set_level(logging.WARNING, logger="pneumad")
    loop, captured, srv = make_loop(server=True, plugins={"missing": "tests.plugins:NoSuchController",
                                                          "raises": "tests.broken_plugin:Controller"})
    try:
        loop.run(20)
        status = ok(loop, dealer(srv), "status")
        listed = ok(loop, dealer(srv), "controller.list")["available"]
    finally:
        srv.close()
    refused = {c["name"]: c["error"] for c in status["controllers_refused"]}
    assert set(refused) == {"missing", "raises"}, refused
    assert "NoSuchController" in refused["missing"] and "fails as it is imported" in refused["raises"]
    assert [c for c in listed if "error" in c] == status["controllers_refused"]
    schema("results", "status").validate(status)
    events = [e for e in captured.of("event") if e["kind"] == "plugin"]
    assert {e["name"]: e["cause"] for e in events} == refused
    for event in events:
        schema("telemetry", "event").validate(event)
    logged = [r.getMessage() for r in caplog.records if r.name == "pneumad"]
    assert all(any(f"controller {name} refused: {error}" in line for line in logged) for name, error in refused.items())
