"""Controller internals a lab can see (issue: controllers at the rig's edges): each built-in
names its internal signals in ``describe`` and publishes them on the ``internals`` topic at
a decimated rate while the arm is enabled, and the parts add up to the output they make."""
import math

import pytest

from bench import scenarios as S
from controllers import registry
from controllers.trajectory import JointMove
from daemon.testing.loop import make_loop

BUILT_IN = ["pid", "smc", "smc_dob", "sac", "lti", "lti_dob"]


@pytest.mark.parametrize("name", BUILT_IN)
def test_the_internals_named_in_describe_are_published_while_enabled(name):
    loop, captured, _ = make_loop()
    loop.run(100)
    assert not captured.of("internals")  # idle: nothing to see
    loop.enable()
    loop.switch(registry.build(name, loop.context, options=S.example_options(name)))
    start = JointMove(list(loop.angles), [loop.angles[0] + math.radians(5.0), loop.angles[1]], 1.0)
    loop.set_trajectory(start, "move")
    loop.run(1000)
    named = [s["name"] for s in registry.load(name).describe()["internals"]]
    assert named and all(s["unit"] and s["doc"] for s in registry.load(name).describe()["internals"])
    samples = [m for m in captured.of("internals") if m["controller"] == name]
    assert 90 <= len(samples) <= 101  # one per 10-cycle state batch
    for m in samples:
        assert list(m["signals"]) == named
        assert all(len(v) == loop.n and all(math.isfinite(x) for x in v) for v in m["signals"].values())
    seqs = [m["seq"] for m in captured.of("internals")]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))


@pytest.mark.parametrize("name,parts", [("pid", ("p", "i", "d")), ("smc", ("u_eq", "u_reach"))])
def test_the_published_parts_add_up_to_the_output(name, parts):
    loop = S.make_loop(name)
    loop.set_trajectory(JointMove(list(loop.angles), [loop.angles[0] + math.radians(3.0), loop.angles[1]], 3.0),
                        "move")
    checked = 0
    for _ in range(300):
        loop.run(10)
        signals = dict(zip((s.name for s in loop.controller.internals), loop.controller.internal_signals()))
        for j in range(loop.n):
            total = sum(signals[p][j] for p in parts)
            if loop.context.u_min[j] < total < loop.context.u_max[j]:  # unclamped: the output is the sum
                assert loop.u[j] == pytest.approx(total, abs=1e-9)
                checked += 1
    assert checked > 400


def test_a_plugins_unreadable_or_mismatched_internals_publish_nothing_and_numpy_values_are_numbers():
    import numpy as np

    loop, captured, _ = make_loop()
    loop.enable()
    pid = loop.controller
    shapes = {"float32": lambda: [np.array([1.5, -2.0], dtype=np.float32)] * len(pid.internals),
              "ragged": lambda: [[1.0, 2.0], [3.0]] + [[0.0, 0.0]] * (len(pid.internals) - 2),
              "too few": lambda: [[1.0, 2.0]],
              "raises": lambda: 1 / 0}
    windows = {}
    for name, signals in shapes.items():
        pid.internal_signals = signals
        first = loop.cycle
        loop.run(20)
        windows[name] = (first, loop.cycle)
    loop.run(10)  # the last window's sample is sent a few cycles after it is taken
    published = {name: [m for m in captured.of("internals") if first < m["cycle"] <= last]  # by the cycle sampled
                 for name, (first, last) in windows.items()}
    assert published["float32"] and all(m["signals"][pid.internals[0].name] == [1.5, -2.0]
                                         for m in published["float32"])
    assert not published["ragged"] and not published["too few"] and not published["raises"]
    assert loop.state.value == "enabled"  # a plugin's bad signals never take the loop down


def test_a_sample_carries_the_cycle_it_was_taken_at_though_sent_cycles_later():
    """The sample is taken in one cycle of a batch and sent in a later one (so no cycle carries
    two of the telemetry's costs): its cycle and time are those of the taking, its values too,
    and the two never fall in the cycle that flushes the state batch."""
    loop, captured, _ = make_loop()
    loop.enable()
    pid = loop.controller
    pid.internal_signals = lambda: [[float(loop.cycle)] * loop.n] * len(pid.internals)
    loop.run(200)
    samples = captured.of("internals")
    assert len(samples) >= 15
    flushed = {state["cycle"][-1] for state in captured.of("state")}
    for m in samples:
        assert m["signals"][pid.internals[0].name] == [float(m["cycle"])] * loop.n
        assert m["cycle"] not in flushed and m["cycle"] + 3 not in flushed
    times = {c: t for state in captured.of("state") for c, t in zip(state["cycle"], state["t"])}
    assert all(m["t"] == pytest.approx(times[m["cycle"]], abs=1e-9) for m in samples)  # the virtual clock: one time
