"""The orchestration pieces ``swarm fly``, ``swarm up`` and ``swarm bench`` share (gcs/command/procedures.py,
recorder)."""

from __future__ import annotations

from gcs.command.procedures import ALT_HOLD_S, ALT_TOLERANCE_M, SteadyAltitude
from gcs.record.recorder import CollisionPairs


def at(alt_m: float, *sysids: int) -> dict[int, tuple[float, float, float]]:
    return {s: (float(s), 0.0, -alt_m) for s in sysids}


def test_the_takeoff_is_done_once_every_drone_has_held_the_altitude_for_the_hold_time() -> None:
    steady = SteadyAltitude(3.0)
    assert not steady.update(at(3.0, 1, 2), 2, 10.0)
    assert not steady.update(at(3.0 + 0.9 * ALT_TOLERANCE_M, 1, 2), 2, 10.0 + 0.5 * ALT_HOLD_S)
    assert steady.update(at(3.0 - 0.9 * ALT_TOLERANCE_M, 1, 2), 2, 10.0 + ALT_HOLD_S)


def test_one_drone_out_of_tolerance_restarts_the_hold() -> None:
    steady = SteadyAltitude(3.0)
    steady.update(at(3.0, 1, 2), 2, 0.0)
    outside = at(3.0, 1) | at(3.0 + 1.1 * ALT_TOLERANCE_M, 2)
    assert not steady.update(outside, 2, 0.5)
    assert not steady.update(at(3.0, 1, 2), 2, 0.6)  # the hold starts again here
    assert not steady.update(at(3.0, 1, 2), 2, 0.6 + 0.9 * ALT_HOLD_S)
    assert steady.update(at(3.0, 1, 2), 2, 0.6 + ALT_HOLD_S)


def test_a_drone_without_a_position_yet_keeps_the_takeoff_from_being_done() -> None:
    steady = SteadyAltitude(3.0)
    steady.update(at(3.0, 1), 2, 0.0)
    assert not steady.update(at(3.0, 1), 2, 5.0)


def test_a_collision_is_counted_once_per_pair_whichever_drone_reports_it() -> None:
    pairs = CollisionPairs()
    assert pairs.observe(1, "Collision with drone 2 at 0.61 m") is True
    assert pairs.observe(2, "Collision with drone 1 at 0.61 m") is False  # the other side of the same collision
    assert pairs.observe(3, "Takeoff detected") is None
    assert pairs.observe(3, "Collision with drone 1") is True
    assert len(pairs) == 2
