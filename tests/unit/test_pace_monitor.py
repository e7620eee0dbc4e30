"""The pace monitor: the slowest drone's clock against the wall clock, over a sliding window."""

from __future__ import annotations

import pytest

from gcs.fleet.pace_monitor import PaceMonitor

pytestmark = pytest.mark.timeout(10)


def test_the_rate_is_measured_over_a_full_window_only() -> None:
    monitor = PaceMonitor(1.0, window_s=5.0)
    for k in range(5):  # 4 s of wall time: not yet a window
        monitor.observe(float(k), 0.5 * k)
    assert monitor.rate() is None
    for k in range(5, 21):  # then half speed for 20 s of wall time
        monitor.observe(float(k), 0.5 * k)
    assert monitor.rate() == pytest.approx(0.5)


def test_the_window_slides_so_a_recovery_shows() -> None:
    monitor = PaceMonitor(1.0, window_s=5.0)
    drone = 0.0
    for k in range(11):  # 10 s at half speed
        monitor.observe(float(k), drone)
        drone += 0.5
    for k in range(11, 30):  # then at full speed
        monitor.observe(float(k), drone)
        drone += 1.0
    assert monitor.rate() == pytest.approx(1.0)


def test_a_swarm_that_falls_behind_is_warned_about_once_and_one_that_keeps_up_never() -> None:
    slow = PaceMonitor(4.0, window_s=2.0)
    warnings = [slow.update(0.1 * k, 0.3 * k) for k in range(60)]  # 3x real time when 4x was asked for
    said = [w for w in warnings if w is not None]
    assert len(said) == 1
    assert "3.00x real time" in said[0] and "requested 4x" in said[0] and "--lockstep" in said[0]
    assert "--drones-per-process auto" in said[0]  # each drone has its own process: hosting is the first remedy
    hosted = PaceMonitor(4.0, window_s=2.0, hosted=True)
    said = [w for k in range(60) if (w := hosted.update(0.1 * k, 0.3 * k)) is not None]
    assert len(said) == 1 and "--drones-per-process" not in said[0]  # already hosted: the other remedies only
    fine = PaceMonitor(4.0, window_s=2.0)
    assert all(fine.update(0.1 * k, 0.39 * k) is None for k in range(60))  # 3.9x: within 10 %


def test_an_unknown_drone_time_is_skipped() -> None:
    monitor = PaceMonitor(1.0, window_s=1.0)
    monitor.observe(0.0, None)
    monitor.observe(0.5, 0.5)
    monitor.observe(1.0, None)
    monitor.observe(1.6, 1.6)
    assert monitor.rate() == pytest.approx(1.0)
