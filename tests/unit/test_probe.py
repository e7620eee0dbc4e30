"""The relay probe's statistics (pure)."""

from __future__ import annotations

import math

from gcs.bench.probe import latency_stats


def test_stats_are_nearest_rank_percentiles_in_milliseconds() -> None:
    hops_s = [i * 1e-3 for i in range(1, 101)]  # 1..100 ms
    stats = latency_stats(hops_s[::-1], sent=102)
    assert (stats.median_ms, stats.p95_ms, stats.max_ms) == (50.0, 95.0, 100.0)
    assert stats.received == 100 and stats.lost == 2


def test_nothing_back_is_nan_not_an_error() -> None:
    stats = latency_stats([], sent=5)
    assert stats.received == 0 and stats.lost == 5
    assert math.isnan(stats.median_ms) and math.isnan(stats.max_ms)


def test_a_single_hop_is_every_percentile() -> None:
    stats = latency_stats([0.002], sent=1)
    assert stats.median_ms == stats.p95_ms == stats.max_ms == 2.0
