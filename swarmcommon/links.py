"""Link impairment and mesh radio settings, as both sides read them: the keys, their ranges and the one-line
messages (docs/links.md). The ground station checks a mission's ``[swarm.links]`` and ``--link-*`` options with
them before anything is spawned; a drone checks its ``--link`` and ``--mesh`` options with them."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Final, Literal

LinkClass = Literal["gcs", "api", "neighbour"]
# The link classes, in the order that is part of a drone's seeding (a class's index goes into its seed): append,
# never reorder.
LINK_CLASSES: Final[tuple[LinkClass, ...]] = ("gcs", "api", "neighbour")
LINK_KEYS: Final = ("loss", "latency_ms", "jitter_ms", "burst_good_s", "burst_bad_s", "burst_loss", "bandwidth_bps")
_PROBABILITIES: Final = ("loss", "burst_loss")
_NONNEGATIVE: Final = ("burst_good_s", "burst_bad_s", "latency_ms", "jitter_ms")


def value_problem(key: str, value: object) -> str | None:
    """Why one link setting is not valid on its own (a whole line naming the key), or None."""
    if key not in LINK_KEYS:
        return f"unknown key {key!r} (keys: {', '.join(LINK_KEYS)})"
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return f"{key} must be a finite number, got {value!r}"
    if key in _PROBABILITIES and not 0 <= value <= 1:
        return f"{key} must be in [0, 1], got {value:g}"
    if key in _NONNEGATIVE and value < 0:
        return f"{key} must be >= 0, got {value:g}"
    if key == "bandwidth_bps" and value <= 0:
        return f"bandwidth_bps must be > 0 (leave it out for no cap), got {value:g}"
    return None


def parse_value(key: str, text: str, problem_of: Callable[[str, float], str | None] = value_problem) -> float:
    """A number for ``key`` from a command line's text, checked by ``problem_of``; ValueError with the one line that
    says why it is none."""
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{key} must be a number, got {text!r}") from None
    problem = problem_of(key, value)
    if problem is not None:
        raise ValueError(problem)
    return value


def settings_problem(values: Mapping[str, float]) -> str | None:
    """Why one link class's settings (key -> number; keys absent take the perfect link's) make no link: each key
    alone, then the burst pair; or None."""
    for key, value in values.items():
        problem = value_problem(key, value)
        if problem is not None:
            return problem
    good, bad = values.get("burst_good_s", 0.0), values.get("burst_bad_s", 0.0)
    if (good > 0) != (bad > 0):
        return f"burst_good_s and burst_bad_s must both be > 0 (bursts) or both 0 (none), got {good:g} and {bad:g}"
    return None


# ---- the drone-to-drone mesh radio (docs/links.md "Mesh") --------------------------------------------------------
MESH_KEYS: Final = ("range_m", "exponent")
DEFAULT_MESH_RANGE_M: Final = 15.0
DEFAULT_MESH_EXPONENT: Final = 4.0
MAX_MESH_EXPONENT: Final = 20.0  # beyond this the path-loss rule is a step at the range: no use for a larger one


def mesh_value_problem(key: str, value: object) -> str | None:
    """Why one mesh setting is not valid (a whole line naming the key), or None."""
    if key not in MESH_KEYS:
        return f"unknown key {key!r} (keys: {', '.join(MESH_KEYS)})"
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return f"{key} must be a finite number, got {value!r}"
    if key == "range_m" and value <= 0:
        return f"range_m must be > 0, got {value:g}"
    if key == "exponent" and not 0 < value <= MAX_MESH_EXPONENT:
        return f"exponent must be in (0, {MAX_MESH_EXPONENT:g}], got {value:g}"
    return None
