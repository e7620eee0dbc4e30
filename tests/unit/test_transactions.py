"""The retry timing the ground station's three MAVLink clients share (gcs/mavlink/transactions.py): a try waits its
timeout, a timed-out try is sent again at most ``retries`` times, progress starts the count afresh, an outcome waits
to be taken once, and cancelled work is forgotten. The clients' own tests check the protocols on top of it."""

from __future__ import annotations

from dataclasses import dataclass

from gcs.mavlink.transactions import Transactions


@dataclass(slots=True)
class Work:
    name: str
    due_s: float = 0.0
    retries_left: int = 0


def core() -> Transactions[str, Work, str, str]:
    return Transactions(timeout_s=0.5, retries=3)


def test_a_silent_try_is_sent_again_three_times_then_ends_unanswered() -> None:
    c = core()
    c.begin("a", "a", Work("a"), 10.0)
    assert c.next_due_s() == 10.5
    assert c.timed_out(10.49) == []
    seen = []
    now = 10.5
    while (timed := c.timed_out(now)) and not timed[0][1]:
        seen.append(now)
        now = c.next_due_s()
    assert seen == [10.5, 11.0, 11.5]  # three tries more, each timed from the one before
    assert now == 12.0 and timed[0][1]  # the fourth timeout ends it
    c.finish("a", "a", "no answer")
    assert c.take("a") == "no answer" and c.take("a") is None  # taken once


def test_progress_starts_the_count_afresh_and_cancelled_work_is_forgotten() -> None:
    c = core()
    work = c.begin("a", "a", Work("a"), 0.0)
    c.timed_out(0.5)
    c.timed_out(1.0)
    assert work.retries_left == 1
    c.fresh(work, 1.2)
    assert (work.retries_left, work.due_s) == (3, 1.7)
    c.begin("b", "b", Work("b"), 0.0)
    c.cancel("a", "a")
    assert c.running("a") is None and [w.name for w, _ in c.timed_out(5.0)] == ["b"]


def test_outcomes_may_be_kept_finer_than_the_work_and_a_new_begin_drops_a_stale_one() -> None:
    c: Transactions[int, Work, tuple[int, int], str] = Transactions(timeout_s=1.0, retries=0)
    c.begin(7, (7, 0), Work("mission"), 0.0)
    c.finish(7, (7, 0), "uploaded")
    c.begin(7, (7, 1), Work("fence"), 1.0)
    assert c.take((7, 0)) == "uploaded"  # the mission's outcome survives the fence transfer begun after it
    c.finish(7, (7, 1), "first")
    c.begin(7, (7, 1), Work("fence"), 2.0)
    assert c.take((7, 1)) is None  # begun again before it was taken: the old outcome is gone
