"""Land detection from the estimate and the controller's collective: touchdown, no false landings, takeoff."""

from __future__ import annotations

import numpy as np
import pytest

from sitl.autopilot.land_detector import LandDetector, LandDetectorConfig

pytestmark = pytest.mark.timeout(10)

DT_S = 1.0 / 400.0
CONFIG = LandDetectorConfig()


def _airborne() -> LandDetector:
    detector = LandDetector(CONFIG)
    detector.reset(landed=False)
    return detector


def _feed(
    detector: LandDetector, start_s: float, duration_s: float, vel_down_mps: float, thrust_ratio: float, agl_m: float
) -> float | None:
    """Feed constant inputs every step; returns the time the landed state first changed (None if it never did)."""
    initial = detector.landed
    for k in range(round(duration_s / DT_S)):
        now = start_s + k * DT_S
        if detector.update(now, vel_down_mps, thrust_ratio, agl_m) != initial:
            return now
    return None


def test_touchdown_is_reported_once_still_with_low_thrust_for_the_dwell_time() -> None:
    # GIVEN a flying vehicle
    detector = _airborne()
    # WHEN it sits still while the controller pushes down (collective well below hover) for a second
    changed_at = _feed(detector, 10.0, 1.0, vel_down_mps=0.02, thrust_ratio=0.3, agl_m=0.0)
    # THEN it is reported landed after the dwell time, not before
    assert changed_at is not None
    assert changed_at - 10.0 == pytest.approx(CONFIG.trigger_time_s, abs=DT_S)
    assert detector.landed


def test_a_bounce_restarts_the_dwell_timer() -> None:
    detector = _airborne()
    assert _feed(detector, 0.0, 0.3, vel_down_mps=0.0, thrust_ratio=0.3, agl_m=0.0) is None
    # WHEN it bounces (moving up at 0.5 m/s) for one step
    assert not detector.update(0.3, -0.5, 0.3, 0.05)
    # THEN a full dwell time is needed again
    changed_at = _feed(detector, 0.3 + DT_S, 1.0, vel_down_mps=0.0, thrust_ratio=0.3, agl_m=0.0)
    assert changed_at is not None
    assert changed_at - (0.3 + DT_S) == pytest.approx(CONFIG.trigger_time_s, abs=DT_S)


def test_a_slow_steady_descent_is_not_a_landing() -> None:
    # GIVEN a vehicle descending at 0.2 m/s (below the "still" speed) with hover thrust, as a slow landing does
    detector = _airborne()
    # WHEN that lasts 20 s
    # THEN it is never reported landed: the thrust is not below hover
    assert _feed(detector, 0.0, 20.0, vel_down_mps=0.2, thrust_ratio=0.98, agl_m=3.0) is None


def test_a_noisy_hover_is_not_a_landing() -> None:
    detector = _airborne()
    rng = np.random.default_rng(3)
    for k in range(round(20.0 / DT_S)):
        vz = float(rng.normal(0.0, 0.1))
        thrust = float(1.0 + rng.normal(0.0, 0.08))
        assert not detector.update(k * DT_S, vz, thrust, 3.0), f"false landing at {k * DT_S:.2f} s"


def test_falling_with_low_thrust_is_not_a_landing() -> None:
    # Motors nearly off while dropping at 2 m/s: not still, so not landed.
    assert _feed(_airborne(), 0.0, 5.0, vel_down_mps=2.0, thrust_ratio=0.2, agl_m=5.0) is None


def test_a_brief_thrust_dip_while_hovering_is_not_a_landing() -> None:
    detector = _airborne()
    assert _feed(detector, 0.0, CONFIG.trigger_time_s - 0.05, vel_down_mps=0.0, thrust_ratio=0.5, agl_m=3.0) is None
    assert _feed(detector, 0.3, 5.0, vel_down_mps=0.0, thrust_ratio=1.0, agl_m=3.0) is None


def test_takeoff_is_detected_at_once_when_thrust_is_high_and_it_climbs() -> None:
    # GIVEN a landed vehicle
    detector = LandDetector(CONFIG)
    assert detector.landed
    # WHEN the collective is above the takeoff ratio and it climbs at 0.5 m/s
    # THEN it is airborne at the first such step
    assert _feed(detector, 0.0, 1.0, vel_down_mps=-0.5, thrust_ratio=1.1, agl_m=0.05) == 0.0
    assert not detector.landed


def test_takeoff_is_detected_from_height_even_without_vertical_speed() -> None:
    detector = LandDetector(CONFIG)
    assert _feed(detector, 0.0, 1.0, vel_down_mps=0.0, thrust_ratio=1.0, agl_m=0.5) == 0.0


def test_spinning_up_on_the_ground_is_not_a_takeoff() -> None:
    # High thrust but no climb and no height: still on the ground.
    assert _feed(LandDetector(CONFIG), 0.0, 3.0, vel_down_mps=0.0, thrust_ratio=1.2, agl_m=0.0) is None
    # Climbing with low thrust (being lifted, or estimator noise at idle): still landed.
    assert _feed(LandDetector(CONFIG), 0.0, 3.0, vel_down_mps=-0.5, thrust_ratio=0.3, agl_m=0.5) is None


def test_reset_sets_the_state_and_clears_the_timer() -> None:
    detector = _airborne()
    _feed(detector, 0.0, 0.3, vel_down_mps=0.0, thrust_ratio=0.3, agl_m=0.0)
    detector.reset(landed=False)
    changed_at = _feed(detector, 0.3, 1.0, vel_down_mps=0.0, thrust_ratio=0.3, agl_m=0.0)
    assert changed_at is not None and changed_at - 0.3 == pytest.approx(CONFIG.trigger_time_s, abs=DT_S)
