"""``pneumactl plot``'s pictures never mislead (daemon/client/plots.py), on runs made here: each
internal signal's unit from the controller that published it, identical runs drawn once and
named together, V_MV only where it was written and between its limits, the approach/path
boundary, and the tip path's start and direction."""
import math

import matplotlib.pyplot as plt
import pytest

from daemon.client import plots
from daemon.recordings.reading import Run
from daemon.wire.cycle_layout import CycleLayout
from hal import config
from hal.declare import declare

RIG = config.load("sim")
LAYOUT = CycleLayout.of(declare(RIG, [c for j in RIG.joints for _, c in j.output_channels()]))
DESCRIBE = {
    "period_s": 0.001,
    "joints": [{"name": "bottom"}, {"name": "middle"}],
    "command_interfaces": [{"joint": name, "name": "v_mv", "unit": "V", "low": -4.0, "high": 6.0}
                           for name in ("bottom", "middle")],
    "arm": {"link_lengths_mm": [100.0, 100.0]},
    # as describe lists them: a lookup by signal name across controllers finds muscle_pid's Pa for pid's i
    "controllers": [{"name": "pid", "internals": [{"name": "p", "unit": "V"}, {"name": "i", "unit": "V"}]},
                    {"name": "muscle_pid", "internals": [{"name": "i", "unit": "Pa"}]}],
    "cycle_layout": LAYOUT.describe(),
}


def run(gain: float = 1.0, modes=None, approach_s=None, n: int = 400) -> Run:
    """A run of ``n`` cycles: the bottom joint sweeps, V_MV = 2 V x gain; ``modes`` by cycle."""
    samples = []
    for k in range(n):
        t = 10.0 + k * 1e-3
        q = [math.radians(120 + 20 * k / n), math.radians(-80.0)]
        mode = modes(k) if modes else "enabled"
        sample = {name: float("nan") for name in LAYOUT.names}
        sample.update({"cycle": k, "t": t, "mode": "enabled" if mode is None else mode})
        for j, name in enumerate(("bottom", "middle")):
            sample.update({f"{name}.position": q[j] * gain, f"{name}.setpoint": q[j], f"{name}.error": q[j] * (1 - gain),
                           f"{name}.u.v_mv": 2.0 * gain, f"{name}.p_head_cmd": 4e5, f"{name}.p_rod_cmd": 3e5,
                           f"{name}.velocity": 0.0})
        samples.append(sample)
    events = [{"t": 10.0, "kind": "reference", "action": "start", "name": "translation", "generation": 1,
               "duration_s": 0.4, "approach_s": approach_s}] if approach_s else []
    internals = [{"t": 10.0 + k * 0.01, "controller": "pid", "signals": {"p": [0.1, 0.2], "i": [0.3, 0.4]}}
                 for k in range(n // 10)]
    return Run(DESCRIBE, {"name": "pid"}, samples, {"event": events, "internals": internals})


@pytest.fixture(autouse=True)
def close_figures():
    yield
    plt.close("all")


def test_each_internal_signals_unit_is_its_own_controllers():
    fig = plots.figures([("a", run())])["internals"]
    assert [ax.get_ylabel() for ax in fig.axes] == ["p [V]", "i [V]"]  # not muscle_pid's i [Pa]


def test_pressures_are_drawn_in_kpa_as_the_labs_gauges_read():
    """The run commands 4e5 and 3e5 Pa: drawn as 400 and 300 on axes labelled kPa; a controller's
    internal signal declared in Pa is drawn in kPa too."""
    fig = plots.figures([("a", run())])["pressures"]
    assert {ax.get_ylabel() for ax in fig.axes} == {"pressure [kPa]"}
    drawn = {line.get_label().split(" ", 1)[1]: line.get_ydata() for line in fig.axes[0].get_lines()}
    assert set(drawn["commanded p_head"]) == {400.0} and set(drawn["commanded p_rod"]) == {300.0}
    muscle = run()
    muscle.describe = {**DESCRIBE, "controllers": [{"name": "pid", "internals": [{"name": "p", "unit": "V"},
                                                                                {"name": "i", "unit": "Pa"}]}]}
    fig = plots.figures([("a", muscle)])["internals"]
    assert [ax.get_ylabel() for ax in fig.axes] == ["p [V]", "i [kPa]"]
    assert list(fig.axes[1].get_lines()[0].get_ydata()[:2]) == pytest.approx([0.3e-3, 0.3e-3])


def test_identical_runs_are_drawn_once_and_named_together():
    made = plots.figures([("a (pid)", run()), ("b (lti)", run()), ("c (smc)", run(gain=0.9))])
    ax = made["errors"].axes[0]
    labels = [line.get_label() for line in ax.get_lines()]
    assert labels == ["a (pid) = b (lti) (identical)", "c (smc)"]  # two lines, each visible, all three named
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert legend == labels


def test_v_mv_is_drawn_only_where_written_and_between_its_limits():
    made = plots.figures([("a", run(modes=lambda k: "estop" if k >= 200 else None))])
    ax = made["output"].axes[0]
    assert ax.get_ylabel() == "command [V]"
    v_mv = next(line for line in ax.get_lines() if line.get_label() == "a command v_mv")
    y = v_mv.get_ydata()
    assert all(v == 2.0 for v in y[:200]) and all(math.isnan(v) for v in y[200:])  # no +2 V during the e-stop
    limits = sorted(line.get_ydata()[0] for line in ax.get_lines() if line.get_linestyle() == "--")
    assert limits == [-4.0, 6.0]
    assert "v_mv limits" in [t.get_text() for t in ax.get_legend().get_texts()]


def test_the_approach_path_boundary_and_the_tip_paths_start_and_direction():
    made = plots.figures([("a", run(approach_s=0.15))])
    ax = made["joints"].axes[0]
    boundary = [line for line in ax.get_lines() if line.get_label() == "approach ends, path begins"]
    assert len(boundary) == 1 and boundary[0].get_xdata()[0] == pytest.approx(0.151)  # start + a cycle + 0.15 s
    tip = made["tip"].axes[0]
    labels = [line.get_label() for line in tip.get_lines()]
    assert "a start" in labels and "a path begins (approach ends)" in labels
    arrows = [c for c in tip.get_children() if type(c).__name__ == "Annotation"]
    assert len(arrows) >= 3
    (x0, y0), (x1, y1) = arrows[0].xyann, arrows[0].xy  # from, to: along the sweep (the bottom joint rising)
    start = [line for line in tip.get_lines() if line.get_label() == "a start"][0]
    assert math.hypot(x0 - start.get_xdata()[0], y0 - start.get_ydata()[0]) < math.hypot(
        x1 - start.get_xdata()[0], y1 - start.get_ydata()[0])


def test_the_payload_noise_figure_says_why_the_papers_figures_are_scaled():
    from bench import payload
    rows = [(level, 1.0, 1.0, 0.001) for level in sorted(payload.PAPER_NOISE)]
    fig = payload.figure(rows, 0.4, 0.2 / 3.0, 0.2)
    caption = " ".join(t.get_text() for t in fig.texts)
    assert "reach, 0.20 m / 0.50 m = x0.40" in caption and "capacity, 0.2 kg / 3 kg = x0.067" in caption
    legend = [t.get_text() for ax in fig.axes for t in ax.get_legend().get_texts()]
    assert all("ratio" in label for label in legend if "paper" in label)


def test_runs_a_figure_cannot_tell_apart_are_merged_and_say_by_how_much():
    a = [[0.0, 1.0], [1.0, 2.0], [2.0, 3.0]]
    near = [[0.0, 1.0], [1.005, 2.0], [2.0, 3.0]]  # 0.5 % of the first column's range
    far = [[0.0, 1.0], [1.5, 2.0], [2.0, 3.0]]
    assert plots.merge_identical(["pid", "lti", "smc"], [a, near, far], within=0.01) == [
        ("pid ≈ lti (within 1% of the range)", 0), ("smc", 2)]
    assert plots.merge_identical(["pid", "lti"], [a, near]) == [("pid", 0), ("lti", 1)]  # exact unless asked


def test_a_hole_in_the_data_breaks_the_lines_is_shaded_and_said():
    """Half a second of telemetry a slow client lost (cycles 100-599) is a gap with a shaded "no
    data" span, said in the legend and in words, never a straight ramp across it."""
    whole = run(n=1000)
    holed = Run(DESCRIBE, {"name": "pid"}, whole.samples[:100] + whole.samples[600:], whole.messages)
    made = plots.figures([("a", holed)])
    for name, label in (("joints", "a position"), ("errors", "a"), ("output", "a command v_mv"),
                        ("pressures", "a commanded p_head")):
        ax = made[name].axes[0]
        line = next(line for line in ax.get_lines() if line.get_label() == label)
        x, y = line.get_xdata(), line.get_ydata()
        gaps = [i for i in range(len(y)) if math.isnan(y[i])]
        assert gaps == [100] and x[99] == pytest.approx(0.099) and x[101] == pytest.approx(0.600), name  # no ramp
        spans = [p for p in ax.patches if p.get_label().startswith("no data")]
        assert len(spans) == 1, name
        left, right = spans[0].get_extents().x0, spans[0].get_extents().x1  # display units: back to data
        data = ax.transData.inverted()
        assert data.transform((left, 0))[0] == pytest.approx(0.099, abs=1e-3)
        assert data.transform((right, 0))[0] == pytest.approx(0.600, abs=1e-3)
        assert "no data (1 hole, 0.50 s)" in [t.get_text() for t in ax.get_legend().get_texts()], name
    tip = made["tip"].axes[0]
    drawn = next(line for line in tip.get_lines() if line.get_label() == "a tip")
    assert sum(math.isnan(v) for v in drawn.get_xdata()) == 1  # the path stops at the hole too
    assert any("no data (1 hole, 0.50 s)" in t.get_text() for t in tip.get_legend().get_texts())
    assert plots.hole_notes("a.mcap", holed) == [
        "a.mcap: no data in 1 hole, 0.50 s in all (0.50 s at 0.10 s; 500 cycles missing): drawn as gaps, shaded"]
    assert plots.hole_notes("a.mcap", whole) == [] and not any(
        p.get_label().startswith("no data") for p in plots.figures([("a", whole)])["joints"].axes[0].patches)


def test_overlaid_runs_line_up_on_their_paths_start_with_the_approach_before_it():
    """Two runs of a path whose approaches took different times: overlaid, each is drawn from
    its path's own start (t = 0, one boundary for both), its approach at negative times."""
    made = plots.figures([("a", run(approach_s=0.1)), ("b", run(approach_s=0.25, gain=0.9))])
    top, bottom = made["joints"].axes
    assert bottom.get_xlabel() == "time from the path's start [s]"
    boundary = [line for line in top.get_lines() if line.get_label() == "approach ends, path begins"]
    assert len(boundary) == 1 and boundary[0].get_xdata()[0] == 0.0
    starts = {label: next(line for line in top.get_lines() if line.get_label() == f"{label} position").get_xdata()[0]
              for label in ("a", "b")}
    assert starts == {"a": pytest.approx(-0.101), "b": pytest.approx(-0.251)}  # start event + a cycle + the approach
    one = plots.figures([("a", run(approach_s=0.1))])["joints"].axes[-1]
    assert one.get_xlabel() == "time [s]"  # one run: from its first sample, the boundary where the path began
