"""Assertions on a flight's outcome, for users' own tests (the pytest plugin exports them; any test runner can use
them): each raises AssertionError with one line saying what happened, when and to whom.

They read the flight report's figures (``FlightResult.metrics``, the content of metrics.json), so a failing test
points at a report the user can open.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from gcs.api.types import DroneState, FlightResult
from gcs.flight.frames import Vec3


def _metrics(result: FlightResult) -> Mapping[str, object]:
    if not result.metrics:
        raise AssertionError("the session wrote no flight report: launch it with report_dir (the plugin does)")
    return result.metrics


def assert_no_collisions(result: FlightResult) -> None:
    """No two drones (nor a drone and an obstacle) touched."""
    events = _metrics(result)["collision_events"]
    assert isinstance(events, list)
    if events:
        first = events[0]
        raise AssertionError(f"{len(events)} collision event(s); the first at t={first['time_s']:.1f} s: drone "
                             f"{first['sysid']}: {first['text']} (report: {result.report_dir})")  # fmt: skip


def assert_min_separation(result: FlightResult, min_m: float) -> None:
    """No two drones came closer than ``min_m`` (centre to centre) while they flew."""
    metrics = _metrics(result)
    seen = metrics["min_separation_m"]
    if seen is not None and float(seen) < min_m:  # type: ignore[arg-type]
        raise AssertionError(f"drones {metrics['min_separation_pair']} came {seen} m apart at "
                             f"t={metrics['min_separation_time_s']} s, closer than {min_m:g} m "
                             f"(report: {result.report_dir})")  # fmt: skip


def assert_no_failsafe(result: FlightResult) -> None:
    """No drone entered a failsafe (PX4's MAV_STATE_CRITICAL) and none was lost."""
    metrics = _metrics(result)
    failsafes, losses = metrics["failsafes"], metrics["losses"]
    assert isinstance(failsafes, list) and isinstance(losses, list)
    if failsafes:
        first = failsafes[0]
        raise AssertionError(f"{len(failsafes)} failsafe(s); the first at t={first['time_s']:.1f} s: drone "
                             f"{first['sysid']}: {first['text']} (report: {result.report_dir})")  # fmt: skip
    if losses:
        first = losses[0]
        raise AssertionError(f"{len(losses)} drone(s) lost; the first at t={first['time_s']:.1f} s: drone "
                             f"{first['sysid']}: {first['cause']} (report: {result.report_dir})")  # fmt: skip


def assert_reached(drones: Mapping[int, DroneState], goals_ned_m: Mapping[int, Vec3], tolerance_m: float) -> None:
    """Every drone of ``goals_ned_m`` is within ``tolerance_m`` of its goal (swarm frame) in ``drones`` (a
    session's ``drones()``)."""
    far = {}
    for sysid, goal in goals_ned_m.items():
        state = drones.get(sysid)
        distance = math.dist(state.pos_ned_m, goal) if state is not None else math.inf
        if not distance <= tolerance_m:
            far[sysid] = distance
    if far:
        worst = max(far, key=lambda s: far[s])
        raise AssertionError(f"{len(far)} drone(s) not within {tolerance_m:g} m of their goals; the farthest, "
                             f"drone {worst}, is {far[worst]:.2f} m away")  # fmt: skip
