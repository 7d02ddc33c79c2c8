"""The loop's timing statistics: counted by the loop into shared banks, summarised beside it."""
import math

import pytest

from daemon.loop.stats import LoopStats
from daemon.wire.loop_stats import BINS, WINDOW, StatsBanks, summarise


def _samples(stats: LoopStats, latencies_us):
    for us in latencies_us:
        stats.latency.add(us * 1e-6)
        stats.record_cycle(0.0, 10e-6, 20e-6, 30e-6, 40e-6, 50e-6 + us * 1e-6)
        stats.cycles += 1


def test_a_window_is_summarised_beside_the_loop_with_the_percentiles_of_its_samples(tmp_path):
    banks = StatsBanks.in_directory(str(tmp_path), create=True)
    stats = LoopStats(banks)
    _samples(stats, [1.5] * 1979 + [30.5] * 20 + [25000.0])  # the last beyond the 20 ms range
    window = stats.close_window(t=12.0, period=0.001)
    assert len(window) == WINDOW.size  # fixed size: closing a window costs the loop nothing that grows
    beside = StatsBanks.in_directory(str(tmp_path), create=False)  # the messenger's own map
    summary = summarise(beside, window)
    assert summary["cycles"] == 2000 and summary["t"] == 12.0 and summary["seq"] == 1
    assert summary["latency_us"] == {"p50": 2.0, "p99": 31.0, "p99.9": 31.0, "max": pytest.approx(25000.0)}
    assert summary["compute_us"]["read"]["p50"] == 11.0
    assert summary["compute_us"]["total"]["max"] == pytest.approx(25050.0)
    # the bank was cleared and handed back: the next window through it starts from nothing
    assert beside.free(0) and not any(beside.counts(0, h).any() for h in range(8))
    _samples(stats, [3.5] * 10)
    assert summarise(beside, stats.close_window(t=13.0, period=0.001))["latency_us"]["max"] == pytest.approx(3.5)
    _samples(stats, [7.5] * 10)
    third = summarise(beside, stats.close_window(t=14.0, period=0.001))
    assert third["latency_us"]["p50"] == 8.0 and third["cycles"] == 10 and third["seq"] == 3


def test_a_bank_not_handed_back_makes_the_window_run_on_instead_of_losing_samples():
    stats = LoopStats()
    _samples(stats, [2.5] * 10)
    first = stats.close_window(t=1.0, period=0.001)
    _samples(stats, [4.5] * 10)
    assert stats.close_window(t=2.0, period=0.001) is None  # bank 0 still unsummarised: bank 1 goes on
    _samples(stats, [4.5] * 5)
    summarise(stats.banks, first)
    second = summarise(stats.banks, stats.close_window(t=3.0, period=0.001))
    assert second["cycles"] == 15 and second["latency_us"]["p50"] == 5.0 and second["seq"] == 2


def test_a_restarted_messenger_reclaims_the_bank_whose_window_was_lost(tmp_path):
    banks = StatsBanks.in_directory(str(tmp_path), create=True)
    stats = LoopStats(banks)
    _samples(stats, [2.5] * 10)
    assert stats.close_window(t=1.0, period=0.001) is not None  # its message lost with the messenger
    _samples(stats, [6.5] * 10)
    assert stats.close_window(t=2.0, period=0.001) is None
    StatsBanks.in_directory(str(tmp_path), create=False).reclaim()  # the next messenger's start
    summary = summarise(banks, stats.close_window(t=3.0, period=0.001))
    assert summary["cycles"] == 10 and summary["latency_us"]["p50"] == 7.0


def test_an_empty_window_has_no_percentiles():
    stats = LoopStats()
    summary = summarise(stats.banks, stats.close_window(t=1.0, period=0.001))
    assert math.isnan(summary["latency_us"]["p50"]) and summary["latency_us"]["max"] == 0.0
    assert BINS == 20000
