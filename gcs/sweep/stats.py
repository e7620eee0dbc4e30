"""A sweep's numbers (pure): each run's row from its metrics.json, and per setting the distribution of every metric
with 95 % confidence intervals.

Intervals:

- the mean of a metric: a percentile bootstrap (BOOTSTRAP_RESAMPLES resamples of the runs, drawn with a fixed seed,
  so the same runs give the same interval on every machine); no assumption of normality, which minimum separations
  and times to formation do not meet;
- the share of runs with at least one event (collision, failsafe, loss): Wilson's score interval, which stays
  inside [0, 1] and is honest for 0 of 20;
- events per 100 flights: 100 times the mean count, with the bootstrap interval of the mean.

A metric a run could not measure (no two drones airborne together: no separation) is left out of that metric's
figures, and the count says how many runs it covers.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

BOOTSTRAP_RESAMPLES: Final = 2000
BOOTSTRAP_SEED: Final = 20_261_125
Z95: Final = 1.959963984540054  # the standard normal's 97.5 % quantile
EVENT_METRICS: Final = ("collisions", "failsafes", "losses", "violations")
FLIGHT_METRICS: Final = ("collisions", "min_separation_m", "failsafes", "losses", "violations", "avoidance_events",
                         "duration_s")  # fmt: skip
# Per formation step: the step's name, then one of these (``circle:time_to_formation_s``)
STEP_METRICS: Final = ("time_to_formation_s", "formation_rms_m")
STEP_KINDS: Final = ("formation", "swap", "flock", "follow")


def run_metrics(metrics: Mapping[str, Any]) -> dict[str, float | None]:
    """One run's figures from its metrics.json: the flight's and, per formation-like step, its own."""
    out: dict[str, float | None] = {
        "collisions": float(metrics["collisions"]),
        "min_separation_m": metrics.get("min_separation_m"),
        "failsafes": float(len(metrics.get("failsafes", []))),
        "losses": float(len(metrics.get("losses", []))),
        "violations": float(len(metrics.get("violations", []))),  # invariants broken (docs/invariants.md)
        "avoidance_events": float(metrics.get("avoidance_events", 0)),
        "duration_s": metrics.get("duration_s"),
    }
    seen: dict[str, int] = {}
    for step in metrics.get("steps", []):
        if step.get("kind") not in STEP_KINDS:
            continue
        name = step["name"]
        seen[name] = seen.get(name, 0) + 1
        label = name if seen[name] == 1 else f"{name}#{seen[name]}"
        for key in STEP_METRICS:
            out[f"{label}:{key}"] = step.get(key)
    return out


@dataclass(frozen=True, slots=True)
class Distribution:
    n: int  # runs that measured it
    mean: float | None
    ci_low: float | None  # 95 % interval of the mean
    ci_high: float | None
    std: float | None
    median: float | None
    p5: float | None
    p95: float | None
    min: float | None
    max: float | None

    def to_json(self) -> dict[str, Any]:
        return {
            "n": self.n, "mean": _r(self.mean), "ci95": [_r(self.ci_low), _r(self.ci_high)], "std": _r(self.std),
            "median": _r(self.median), "p5": _r(self.p5), "p95": _r(self.p95), "min": _r(self.min),
            "max": _r(self.max),
        }  # fmt: skip


def _r(value: float | None) -> float | None:
    return None if value is None else round(value, 6)


def bootstrap_mean_ci(values: Sequence[float]) -> tuple[float, float]:
    """95 % percentile bootstrap interval of the mean (the same for the same values, in any order)."""
    data = np.sort(np.asarray(values, dtype=float))
    if data.size == 1:
        return float(data[0]), float(data[0])
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    means = data[rng.integers(0, data.size, size=(BOOTSTRAP_RESAMPLES, data.size))].mean(axis=1)
    low, high = np.percentile(means, [2.5, 97.5])
    return float(low), float(high)


def wilson_ci(successes: int, n: int) -> tuple[float, float]:
    """95 % Wilson score interval of a proportion."""
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    centre = (p + Z95 * Z95 / (2 * n)) / (1 + Z95 * Z95 / n)
    half = Z95 * math.sqrt(p * (1 - p) / n + Z95 * Z95 / (4 * n * n)) / (1 + Z95 * Z95 / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def distribution(values: Sequence[float | None]) -> Distribution:
    data = np.array([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    if data.size == 0:
        return Distribution(0, None, None, None, None, None, None, None, None, None)
    low, high = bootstrap_mean_ci(data.tolist())
    p5, median, p95 = np.percentile(data, [5, 50, 95])
    return Distribution(n=int(data.size), mean=float(data.mean()), ci_low=low, ci_high=high,
                        std=float(data.std(ddof=1)) if data.size > 1 else 0.0, median=float(median), p5=float(p5),
                        p95=float(p95), min=float(data.min()), max=float(data.max()))  # fmt: skip


@dataclass(frozen=True, slots=True)
class EventRate:
    runs: int
    runs_with: int  # runs with at least one
    share_ci: tuple[float, float]  # Wilson 95 % interval of runs_with / runs
    per_100_flights: float
    per_100_ci: tuple[float, float]

    def to_json(self) -> dict[str, Any]:
        return {"runs": self.runs, "runs_with": self.runs_with,
                "share": _r(self.runs_with / self.runs) if self.runs else None,
                "share_ci95": [_r(v) for v in self.share_ci], "per_100_flights": _r(self.per_100_flights),
                "per_100_flights_ci95": [_r(v) for v in self.per_100_ci]}  # fmt: skip


def event_rate(counts: Sequence[float | None]) -> EventRate:
    data = [c for c in counts if c is not None]
    n = len(data)
    with_events = sum(1 for c in data if c > 0)
    low, high = bootstrap_mean_ci(data) if data else (0.0, 0.0)
    per_100 = 100.0 * (sum(data) / n if n else 0.0)
    return EventRate(runs=n, runs_with=with_events, share_ci=wilson_ci(with_events, n), per_100_flights=per_100,
                     per_100_ci=(100.0 * low, 100.0 * high))  # fmt: skip


def metric_names(rows: Sequence[Mapping[str, float | None]]) -> list[str]:
    """Every metric of the rows: the flight's first, in their fixed order, then the steps' in order of appearance."""
    names = list(FLIGHT_METRICS)
    for row in rows:
        names += [k for k in row if k not in names]
    return names


def summarise(rows: Sequence[Mapping[str, float | None]]) -> dict[str, Any]:
    """One setting's figures over its runs' rows: a distribution per metric, and the event rates."""
    names = metric_names(rows)
    return {
        "runs": len(rows),
        "metrics": {name: distribution([row.get(name) for row in rows]).to_json() for name in names},
        "events": {name: event_rate([row.get(name) for row in rows]).to_json() for name in EVENT_METRICS},
    }
