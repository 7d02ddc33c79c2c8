"""The loop's controls and its event log, at the loop itself (virtual clock, simulator): a plan
is installed only against the reference it was made from, and events carry who caused them."""
import math

import pytest

from controllers import trajectory
from daemon.loop.events import EventLog
from daemon.planner.plans import Plan
from daemon.testing.loop import make_loop
from daemon.wire import protocol as P
from daemon.wire.arguments import CommandFailed


def enabled_loop():
    loop, captured, _ = make_loop()
    loop.run(200)
    loop.enable()
    loop.run(500)
    return loop, captured


def plan_from_here(loop, degrees=3.0):
    """A move planned from the loop's set-point and generation now, as the planner makes one."""
    generation, setpoint = loop.view.reference_origin()
    target = [setpoint[0] + math.radians(degrees)] + setpoint[1:]
    return Plan(trajectory.JointMove(setpoint, target, 1.0), "set", {}, tuple(setpoint), generation=generation)


def refusal(loop, plan) -> CommandFailed:
    with pytest.raises(CommandFailed) as caught:
        loop.install(plan)
    return caught.value


def test_a_plan_made_against_the_reference_in_force_is_installed():
    loop, captured = enabled_loop()
    plan = plan_from_here(loop)
    loop.run(5)  # planned beside the loop meanwhile
    loop.install(plan)
    assert loop.trajectory_name == "set" and loop.reference_remaining() > 0.9
    loop.run(1)  # its events leave at the next cycle's drain
    starts = [e for e in captured.of("event") if e["kind"] == "reference" and e["action"] == "start"]
    assert starts[-1]["generation"] == plan.generation + 1


@pytest.mark.parametrize("overtake", ["abort", "another reference at the same set-point"])
def test_install_refuses_a_plan_overtaken_by_a_change_of_reference(overtake):
    loop, _ = enabled_loop()
    plan = plan_from_here(loop)
    if overtake == "abort":
        loop.hold()
    else:  # the same set-point: only the generation tells this plan is stale
        loop.set_trajectory(trajectory.Hold(list(loop.reference[0])), "hold")
        assert list(loop.reference[0]) == list(plan.start)
    before = loop.view.reference_origin()
    refused = refusal(loop, plan)
    assert refused.code == P.BAD_STATE and refused.data == {"reason": "overtaken"}
    assert "nothing was started" in refused.message
    assert loop.view.reference_origin() == before and loop.trajectory_name == "hold"


def test_install_refuses_a_plan_after_an_estop_or_a_disable():
    for stop in ("estop", "disable"):
        loop, _ = enabled_loop()
        plan = plan_from_here(loop)
        loop.estop("test") if stop == "estop" else loop.disable()
        refused = refusal(loop, plan)
        assert refused.code == P.BAD_STATE and refused.data["reason"] == "state", stop
        assert loop.trajectory_name == "hold"


def test_the_event_log_signs_only_the_events_added_while_a_request_is_handled():
    log, published = EventLog(), []
    log.add({"kind": "trip"})
    with log.signed("alice"):
        log.add({"kind": "state"})
        log.add({"kind": "estop", "who": "panel"})  # one that names its sender keeps it
        with log.signed("bob"):
            log.add({"kind": "params"})
        log.add({"kind": "load"})
    log.add({"kind": "unleased"})
    log.drain(published.append)
    assert [(e["kind"], e.get("who")) for e in published] == [
        ("trip", None), ("state", "alice"), ("estop", "panel"), ("params", "bob"), ("load", "alice"),
        ("unleased", None)]
    assert log.pending == []
    log.add({"kind": "trip"})
    log.drain(None)  # no telemetry: dropped, not kept
    assert log.pending == []


def test_an_estop_drained_at_once_still_carries_who_sent_it():
    loop, captured = enabled_loop()
    with loop.events.signed("alice"):
        loop.estop("alice (panel)")
        assert loop.events.pending == []  # published in this very cycle
    loop.run(5)
    events = [e for e in captured.of("event") if e["kind"] == "estop" or e.get("to") == "estop"]
    assert [(e["kind"], e["who"]) for e in events] == [("estop", "alice"), ("state", "alice")]
    assert events[0]["cause"] == "e-stop from alice (panel)"
