"""What the daemon refuses, and the data each refusal carries, over real ZeroMQ sockets with the
loop on a virtual clock: the documented order of checks (docs/protocol.md, "The order of
checks"), the catalog's refusals in every state, the rig's and the planner's with their numbers,
and an e-stop never refused (a bad set-point on a shared loop: tests/test_protocol.py)."""
import math

import pytest

from daemon.loop.safety import State
from daemon.testing.loop import call, dealer, leased, ok, served_loop
from daemon.wire import protocol as P


@pytest.fixture
def daemon():
    with served_loop() as served:
        yield served


def test_an_infeasible_path_is_refused_with_the_numbers_and_the_shortest_duration(daemon):
    loop, _, srv = daemon
    sock = dealer(srv)
    lease = leased(loop, sock)
    ok(loop, sock, "enable", lease=lease)
    reply = call(loop, sock, "path", {"name": "circle", "duration_s": 5.0, "approach_s": 30.0}, lease)
    assert reply["error"]["code"] == P.REFUSED
    message = reply["error"]["message"]
    assert "joint " in message and "needs V_MV" in message and "deg/s" in message
    shortest = reply["error"]["data"]["shortest_s"]
    assert f"shortest feasible duration is {shortest:.1f} s" in message and 5.0 < shortest <= 20.0  # the thesis's 20 s runs
    assert loop.trajectory_name == "hold"  # nothing started
    started = ok(loop, sock, "path", {"name": "circle", "duration_s": shortest, "approach_s": 30.0}, lease)
    assert started["duration_s"] == shortest
    ok(loop, sock, "abort")
    slow = call(loop, sock, "set", {"angles_deg": [100.0, -60.0], "duration_s": 0.5}, lease)
    assert slow["error"]["code"] == P.REFUSED and "shortest feasible duration" in slow["error"]["message"]


def test_an_estop_is_never_refused_for_its_arguments(daemon):
    """Whatever a panicking client puts beside it, an e-stop stops the arm."""
    loop, _, srv = daemon
    sock = dealer(srv)
    lease = leased(loop, sock)
    ok(loop, sock, "enable", lease=lease)
    result = ok(loop, dealer(srv, "control"), "estop", {"who": {"not": "a string"}, "speed": float("nan")})
    assert result["state"] == "estop" and loop.state is State.ESTOP
    assert loop.supervisor.cause.startswith("e-stop from {")


def test_the_order_of_checks_is_the_documented_one(daemon):
    """Envelope, command, arguments (the catalog's), role, lease, state, then what needs the
    rig: catalog-refused arguments are bad_args in every state; rig-refused ones wait for
    the state (docs/protocol.md, "The order of checks")."""
    loop, _, srv = daemon
    sock = dealer(srv)
    bad = {"angles_deg": [120.0, -80.0], "speed": 3}
    idle = call(loop, sock, "set", bad)  # no lease, idle: the arguments are checked first
    assert idle["error"]["code"] == P.BAD_ARGS and idle["error"]["data"] == {"argument": "speed"}
    assert call(loop, sock, "set", {"angles_deg": [120.0, -80.0]})["error"]["code"] == P.NO_LEASE
    lease = leased(loop, sock)
    assert call(loop, sock, "set", bad, lease)["error"]["code"] == P.BAD_ARGS
    three = {"angles_deg": [120.0, -80.0, 3.0]}  # one angle per joint: the rig's to say, after the state
    assert call(loop, sock, "set", three, lease)["error"]["data"] == {"reason": "state", "state": "idle"}
    ok(loop, sock, "enable", lease=lease)
    refused = call(loop, sock, "set", three, lease)["error"]
    assert refused["code"] == P.BAD_ARGS and refused["data"] == {"argument": "angles_deg", "expected_items": 2}


CATALOG_REFUSED = [  # each argument the catalog refuses, and the data its refusal carries
    ("waypoints", {"angles_deg": [[120.0, -80.0], [121.0, -80.0]], "durations_s": [0.001]},
     {"argument": "durations_s", "index": [0], "low": 0.01, "high": 3600.0}),
    ("steps", {"angles_deg": [[120.0, -80.0]], "hold_s": [0.0001]},
     {"argument": "hold_s", "index": [0], "low": 0.001, "high": 3600.0}),
    ("excite", {"side": "input", "signal": "steps", "joint": "middle", "amplitude_v": 0.5, "levels": [2]},
     {"argument": "levels", "index": [0], "low": -1.0, "high": 1.0}),
    ("waypoints", {"angles_deg": [[120.0, -80.0], [121.0, "x"]], "durations_s": [1.0]},
     {"argument": "angles_deg", "index": [1, 1], "expected": "number"}),
    ("waypoints", {"angles_deg": [[120.0, -80.0], [121.0, -80.0], [122.0, -80.0]], "durations_s": [1.0]},
     {"argument": "durations_s", "expected_items": 2}),
    ("excite", {"signal": "steps", "joint": "middle", "amplitude_deg": 1.0, "levels": [0.5]},
     {"argument": "signal", "allowed": ["chirp", "prbs", "multisine"]}),
    ("excite", {"signal": "chirp", "joint": "middle", "amplitude_deg": 1.0, "order": 8}, {"argument": "order"}),
    ("set", {"duration_s": 1.0}, {"argument": "angles_deg"}),  # none of angles_deg, angles_rad, xy_mm
    ("load.set", {"mass_kg": 0}, {"argument": "mass_kg", "low": 0.0, "high": 1000.0}),
]


def test_a_list_element_out_of_its_catalog_bounds_is_bad_args_in_every_state(daemon):
    """What the catalog refuses (a list's element out of its bounds or not a number, lengths
    that do not go together, a variant's arguments) is bad_args in every state, idle and
    enabled alike: the messenger checks it before the loop checks the state."""
    loop, _, srv = daemon
    sock = dealer(srv)
    lease = leased(loop, sock)
    for state in ("idle", "enabled"):
        if state == "enabled":
            ok(loop, sock, "enable", lease=lease)
        for cmd, args, data in CATALOG_REFUSED:
            error = call(loop, sock, cmd, args, lease)["error"]
            assert (error["code"], error["data"]) == (P.BAD_ARGS, data), (state, cmd, args, error)
            assert loop.state.value == state


def test_refusals_carry_data_naming_the_argument(daemon):
    """bad_args always has data: a controller's parameter with its joint and bounds, a
    missing design, an unknown controller, an element of a list; an authority refusal says
    which duration its shortest_s is for; an excite's limits refusal gives the angle."""
    loop, _, srv = daemon
    sock = dealer(srv)
    lease = leased(loop, sock)
    ok(loop, sock, "enable", lease=lease)
    spec = ok(loop, sock, "controller.get")["spec"][0]
    high = call(loop, sock, "controller.set", {"params": {spec["name"]: spec["high"] * 2 + 1}}, lease)["error"]
    assert high["code"] == P.BAD_ARGS
    assert high["data"] == {"argument": "params", "parameter": spec["name"], "joint": "bottom", "low": spec["low"],
                            "high": spec["high"], "unit": spec["unit"]}
    design = call(loop, sock, "controller.switch", {"name": "lti"}, lease)["error"]
    assert design["code"] == P.BAD_ARGS and design["data"] == {"argument": "options", "option": "design"}
    refused = call(loop, sock, "controller.switch", {"name": "lti", "options": {"design": {"joints": {}}}}, lease)
    assert refused["error"]["data"] == {"argument": "options", "option": "design"}, refused
    unknown = call(loop, sock, "controller.switch", {"name": "nonesuch"}, lease)["error"]
    assert unknown["data"]["argument"] == "name" and "pid" in unknown["data"]["allowed"]
    steps = call(loop, sock, "steps", {"angles_deg": [[120.0, -80.0], [121.0, -80.0]], "hold_s": [1.0, 0.0]},
                 lease)["error"]
    assert steps["data"] == {"argument": "hold_s", "index": [1], "low": 0.001, "high": 3600.0}
    approach = call(loop, sock, "path", {"name": "translation", "approach_s": 0.01}, lease)["error"]
    assert approach["code"] == P.REFUSED and approach["data"]["shortest_for"] == "approach_s"
    assert approach["data"]["shortest_s"] > 0.01
    path = call(loop, sock, "path", {"name": "circle", "duration_s": 1.0, "approach_s": 30.0}, lease)["error"]
    assert path["data"]["shortest_for"] == "duration_s" and path["data"]["shortest_s"] > 1.0
    multisine = {"signal": "multisine", "joint": "middle", "amplitude_deg": 0.5, "period_s": 20.0, "f0_hz": 0.04}
    below = call(loop, sock, "excite", multisine, lease)["error"]  # f0_hz under one cycle per period
    assert below["code"] == P.BAD_ARGS and below["data"] == {"argument": "f0_hz", "low": 0.05, "high": 100.0} and "1 / 20 s" in below["message"]
    bottom = loop.reference[0][0]  # at 141.8 deg: 45 deg up leaves its 85..175 deg
    swing = call(loop, sock, "excite", {"signal": "chirp", "joint": "bottom", "amplitude_deg": 45.0}, lease)["error"]
    assert swing["code"] == P.REFUSED and swing["data"]["reason"] == "limits"
    lo, hi = swing["data"]["limits_deg"]
    assert swing["data"]["angle_deg"] in (pytest.approx(math.degrees(bottom) - 45.0),
                                          pytest.approx(math.degrees(bottom) + 45.0))
    assert not lo <= swing["data"]["angle_deg"] <= hi


@pytest.mark.parametrize("args, words", [
    ({"positions": [-1e308, -80.0]}, "joint bottom set-point -1e+308 deg is outside its limits 85.0..175.0 deg"),
    ({"angles_deg": [1e300, -80.0]}, "joint bottom set-point 1e+300 deg is outside"),
    ({"xy_mm": [1e308, 1.0]}, "point (1e+308, 1.0) mm is out of reach (1e+308 mm from the base;"),
])
def test_a_huge_number_in_a_refusal_reads_in_a_few_digits(daemon, args, words):
    """A mistyped exponent (``pneumactl set -- -1e308``) is refused in a line, not with its
    300 integer digits."""
    loop, _, srv = daemon
    sock = dealer(srv)
    lease = leased(loop, sock)
    ok(loop, sock, "enable", lease=lease)
    message = call(loop, sock, "set", args, lease)["error"]["message"]
    assert words in message and len(message) < 200, message
