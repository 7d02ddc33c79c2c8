"""bench.side_by_side reads what bench.loop_latency prints, and says plainly when it cannot."""
from __future__ import annotations

import argparse

import pytest

from bench import loop_latency
from bench.side_by_side import Run, export, parse, ratios


def _printed(capsys, compute_us: dict[str, dict[str, float]], overruns: int) -> str:
    args = argparse.Namespace(seconds=20.0, priority=80)
    stats = {"cycles": 20000, "overruns": overruns, "latency_us": {"p50": 1.0, "p99": 2.0, "p99.9": 6.0, "max": 40.0},
             "compute_us": compute_us}
    loop_latency.report(args, stats, None, [0.0009, 0.0011], [], [])
    return capsys.readouterr().out


def test_the_figures_loop_latency_prints_are_the_ones_read(capsys):
    stages = ("compute", "read", "control", "write", "telemetry", "commands", "total")
    compute_us = {s: {"p50": 10.0 + i, "p99": 100.0 + 7 * i, "p99.9": 150.0 + i, "max": 300.5 + i}
                  for i, s in enumerate(stages)}
    run = parse(_printed(capsys, compute_us, overruns=13))
    assert run.compute == (10.0, 100.0)
    assert run.stages == {s: (v["p50"], v["p99"]) for s, v in compute_us.items()}
    assert run.overruns == 13


def test_output_without_the_compute_row_is_an_error_that_shows_it(capsys):
    args = argparse.Namespace(seconds=20.0, priority=80)
    loop_latency.report(args, None, None, [], [], [])
    printed = capsys.readouterr().out
    with pytest.raises(ValueError, match="no 'compute compute' row") as failure:
        parse(printed)
    assert "no stats message from the daemon" in str(failure.value)


def test_ratios_pool_each_percentile_and_take_the_median_of_rounds():
    def run(p50, p99):
        return Run({"compute": (p50, p99)}, 0)
    pairs = [(run(40.0, 100.0), run(30.0, 60.0)), (run(40.0, 200.0), run(20.0, 180.0)),
             (run(20.0, 100.0), run(20.0, 80.0))]
    pooled, median = ratios(pairs)
    assert pooled == pytest.approx(320.0 / 400.0)
    assert median == pytest.approx(0.8)  # of 0.6, 0.9, 0.8
    pooled, median = ratios(pairs, column=0)
    assert pooled == pytest.approx(70.0 / 100.0)
    assert median == pytest.approx(0.75)  # of 0.75, 0.5, 1.0


def test_a_base_git_cannot_find_is_refused_in_its_words(tmp_path):
    with pytest.raises(SystemExit, match="cannot export 'no-such-commit' .*not a valid object name"):
        export("no-such-commit", tmp_path)
    assert not any(tmp_path.iterdir())
