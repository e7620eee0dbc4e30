"""Helpers the shipped onboard behaviours share: points carried in MAVLink parameters, and 2-D vector arithmetic on
plain tuples (a behaviour steps one drone at a time: numpy's per-call cost would dominate such small sums).

A list of up to ``MAX_POINTS`` points (north, east, metres in the drone's own local frame) is stored as parameters
``<PREFIX>_CNT`` (how many) and ``<PREFIX><k>_N``, ``<PREFIX><k>_E`` for k = 1..MAX_POINTS: parameters, not
messages, because a parameter set is acknowledged (PARAM_VALUE) and survives a lossy link, and every ground
station can read back what a drone was told.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Final

Vec2 = tuple[float, float]

MAX_POINTS: Final = 6
POINT_LIMIT_M: Final = 10_000.0  # the range of a point parameter: far beyond any flight here


def point_params(prefix: str) -> dict[str, tuple[float, float, float]]:
    """The ``PARAMS`` entries of a point list: its count, then north and east of each point."""
    table: dict[str, tuple[float, float, float]] = {f"{prefix}_CNT": (0.0, 0.0, float(MAX_POINTS))}
    for k in range(1, MAX_POINTS + 1):
        table[f"{prefix}{k}_N"] = (0.0, -POINT_LIMIT_M, POINT_LIMIT_M)
        table[f"{prefix}{k}_E"] = (0.0, -POINT_LIMIT_M, POINT_LIMIT_M)
    return table


def read_points(params: Mapping[str, float], prefix: str) -> tuple[Vec2, ...]:
    """The points a drone's parameters hold now."""
    count = min(int(params[f"{prefix}_CNT"]), MAX_POINTS)
    return tuple((params[f"{prefix}{k}_N"], params[f"{prefix}{k}_E"]) for k in range(1, count + 1))


def add(a: Vec2, b: Vec2) -> Vec2:
    return (a[0] + b[0], a[1] + b[1])


def sub(a: Vec2, b: Vec2) -> Vec2:
    return (a[0] - b[0], a[1] - b[1])


def scale(a: Vec2, k: float) -> Vec2:
    return (a[0] * k, a[1] * k)


def norm(a: Vec2) -> float:
    return math.hypot(a[0], a[1])


def limit_norm(a: Vec2, max_norm: float) -> Vec2:
    """``a`` scaled down to at most ``max_norm``, direction kept."""
    length = norm(a)
    return a if length <= max_norm else scale(a, max_norm / max(length, 1e-12))


def priority_sum(priority: Vec2, extra: Vec2, max_norm: float) -> Vec2:
    """``priority + s * extra`` with the largest s in [0, 1] within ``max_norm``; a priority longer than the limit is
    cut to it and the extra dropped (the law of gcs/flight/behaviours.py ``priority_sum``, for one drone)."""
    p2 = priority[0] ** 2 + priority[1] ** 2
    m2 = max_norm * max_norm
    if p2 >= m2:
        return limit_norm(priority, max_norm)
    e2 = extra[0] ** 2 + extra[1] ** 2
    pe = priority[0] * extra[0] + priority[1] * extra[1]
    s = 1.0 if e2 <= 1e-18 else min(max((-pe + math.sqrt(max(pe * pe - e2 * (p2 - m2), 0.0))) / e2, 0.0), 1.0)
    return limit_norm(add(priority, scale(extra, s)), max_norm)
