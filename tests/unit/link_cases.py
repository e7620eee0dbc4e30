"""One table of link settings and what both sides say about them: the drone's ``--link`` (sitl/world/linkmodel.py) and
the ground station's ``--link-*`` options and ``[swarm.links]`` (gcs/fleet/links.py) must accept and refuse alike."""

from __future__ import annotations

# (key, value as typed, the one-line message; None when the value is good)
VALUE_CASES: list[tuple[str, str, str | None]] = [
    ("loss", "0.2", None),
    ("loss", "0", None),
    ("loss", "1", None),
    ("loss", "1.5", "loss must be in [0, 1], got 1.5"),
    ("loss", "-0.1", "loss must be in [0, 1], got -0.1"),
    ("loss", "abc", "loss must be a number, got 'abc'"),
    ("loss", "nan", "loss must be a finite number, got nan"),
    ("burst_loss", "2", "burst_loss must be in [0, 1], got 2"),
    ("latency_ms", "40", None),
    ("latency_ms", "-3", "latency_ms must be >= 0, got -3"),
    ("latency_ms", "inf", "latency_ms must be a finite number, got inf"),
    ("jitter_ms", "-1", "jitter_ms must be >= 0, got -1"),
    ("burst_good_s", "-5", "burst_good_s must be >= 0, got -5"),
    ("burst_bad_s", "-0.5", "burst_bad_s must be >= 0, got -0.5"),
    ("bandwidth_bps", "57600", None),
    ("bandwidth_bps", "0", "bandwidth_bps must be > 0 (leave it out for no cap), got 0"),
]

# Whole settings of one class that are each fine key by key but no link together.
PAIR_CASES: list[tuple[dict[str, float], str]] = [
    ({"burst_good_s": 3.0}, "burst_good_s and burst_bad_s must both be > 0 (bursts) or both 0 (none), got 3 and 0"),
    ({"burst_bad_s": 0.5}, "burst_good_s and burst_bad_s must both be > 0 (bursts) or both 0 (none), got 0 and 0.5"),
]
