"""Wall-clock pacing: how many physics steps are due, catch-up after a stall, when the next step is due, and the
fast-forwarded boot."""

from __future__ import annotations

import math

import pytest

from sitl.process.pacing import Pacer
from sitl.process.runtime import BOOT_FAST_FORWARD_MAX_S, WallClockSteps

pytestmark = pytest.mark.timeout(10)

DT_S = 1.0 / 400.0


def test_at_speed_1_the_steps_due_match_the_wall_time_elapsed() -> None:
    # GIVEN a pacer at real time, started at wall time 100 s
    pacer = Pacer(1.0, DT_S, start_wall_s=100.0)
    # WHEN 0.1 s of wall time has passed and no step has run
    # THEN 0.1 s of simulation (40 steps) is due
    assert pacer.steps_due(100.1, 0.0) == 40
    # and once they have run, nothing more is due until the wall clock moves on
    assert pacer.steps_due(100.1, 40 * DT_S) == 0
    assert pacer.steps_due(100.1 + DT_S, 40 * DT_S) == 1


def test_at_speed_5_five_times_as_many_steps_are_due() -> None:
    pacer = Pacer(5.0, DT_S, start_wall_s=0.0)
    assert pacer.steps_due(0.04, 0.0) == 80  # 0.2 s of simulation in 40 ms
    assert pacer.steps_due(0.04, 80 * DT_S) == 0
    assert pacer.dropped_s == 0.0


def test_a_simulation_ahead_of_the_wall_clock_gets_no_steps() -> None:
    pacer = Pacer(1.0, DT_S, start_wall_s=0.0)
    assert pacer.steps_due(0.01, 0.5) == 0


def test_a_batch_never_exceeds_max_batch() -> None:
    pacer = Pacer(1.0, DT_S, start_wall_s=0.0)
    assert pacer.steps_due(0.2, 0.0, max_batch=8) == 8
    assert pacer.steps_due(0.2, 8 * DT_S, max_batch=8) == 8
    assert pacer.dropped_s == 0.0


def test_unpaced_always_runs_a_full_batch_and_never_waits() -> None:
    pacer = Pacer(0.0, DT_S, start_wall_s=0.0)
    assert pacer.unpaced
    assert pacer.steps_due(0.0, 1000.0, max_batch=123) == 123
    assert pacer.wall_time_of(1000.0) == -math.inf


def test_after_a_stall_it_catches_up_at_most_the_limit_and_drops_the_rest() -> None:
    # GIVEN a real-time pacer with a 0.25 s catch-up limit that has kept up for 1 s
    pacer = Pacer(1.0, DT_S, start_wall_s=0.0, max_catchup_s=0.25)
    assert pacer.steps_due(1.0, 1.0) == 0
    # WHEN the machine stalls for 2 s
    due = pacer.steps_due(3.0, 1.0)
    # THEN only 0.25 s of simulation is due, and the other 1.75 s is recorded as dropped
    assert due == 100
    assert pacer.dropped_s == pytest.approx(1.75)


def test_after_re_anchoring_pacing_continues_from_the_new_anchor() -> None:
    # GIVEN a pacer that re-anchored after a 2 s stall and has run the 0.25 s catch-up
    pacer = Pacer(1.0, DT_S, start_wall_s=0.0, max_catchup_s=0.25)
    pacer.steps_due(3.0, 1.0)
    sim_s = 1.0 + 100 * DT_S
    # WHEN the wall clock has not moved on
    # THEN nothing more is due (no second burst for the dropped time)
    assert pacer.steps_due(3.0, sim_s) == 0
    # and afterwards steps are due at the normal rate again, with nothing further dropped
    assert pacer.steps_due(3.1, sim_s) == 40
    assert pacer.dropped_s == pytest.approx(1.75)
    assert pacer.wall_time_of(sim_s + DT_S) == pytest.approx(3.0 + DT_S)


def test_wall_time_of_tells_when_a_simulation_time_is_due() -> None:
    real_time = Pacer(1.0, DT_S, start_wall_s=50.0)
    assert real_time.wall_time_of(2.0) == pytest.approx(52.0)
    fast = Pacer(5.0, DT_S, start_wall_s=50.0)
    assert fast.wall_time_of(2.0) == pytest.approx(50.4)
    # and the step due at that wall time is exactly the one asked about
    assert fast.steps_due(fast.wall_time_of(2.0), 2.0 - DT_S) == 1


@pytest.mark.parametrize("speed", [-1.0, math.inf, math.nan])
def test_a_negative_or_non_finite_speed_factor_is_refused(speed: float) -> None:
    with pytest.raises(ValueError, match="speed factor"):
        Pacer(speed, DT_S, start_wall_s=0.0)


def test_rebase_paces_on_from_a_simulation_time_reached_unpaced() -> None:
    # GIVEN a pacer started at wall 0 whose drone ran 4 s of simulation unpaced by wall time 0.05 s
    pacer = Pacer(1.0, DT_S, start_wall_s=0.0)
    pacer.rebase(0.05, 4.0)
    # THEN 4 s is due at wall 0.05 s, and the next 10 ms of simulation 10 ms later, with no time counted as dropped
    assert pacer.steps_due(0.05, 4.0) == 0
    assert pacer.steps_due(0.06, 4.0) == 4
    assert pacer.wall_time_of(4.5) == pytest.approx(0.55)
    assert pacer.dropped_s == 0.0


def test_a_booting_drone_runs_unpaced_then_paces_from_where_boot_ended() -> None:
    # GIVEN a real-time clock whose drone is booting until simulated time 3 s
    sim_s = 0.0
    clock = WallClockSteps(1.0, DT_S, booting=lambda: sim_s < 3.0)
    # WHEN it is asked for steps while booting, THEN a full batch is due every time, with no wall time passing
    while sim_s < 3.0:
        assert clock.steps_due(sim_s, 0, 8) == 8
        sim_s += 8 * DT_S
    # and once booted it paces from there: nothing is due before the wall clock moves on
    assert clock.steps_due(sim_s, 0, 8) == 0
    assert clock.pacer.wall_time_of(sim_s + 1.0) == pytest.approx(clock.pacer.wall_time_of(sim_s) + 1.0)
    # A boot that never ends is cut off after BOOT_FAST_FORWARD_MAX_S
    never = WallClockSteps(1.0, DT_S, booting=lambda: True)
    assert never.steps_due(BOOT_FAST_FORWARD_MAX_S - DT_S, 0, 8) == 8
    assert never.steps_due(BOOT_FAST_FORWARD_MAX_S, 0, 8) == 0
