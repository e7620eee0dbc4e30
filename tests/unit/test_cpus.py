"""Whether a CPU is idle, and looking again while one is (swarmcommon/cpus.py): a lockstep waiter that looks again
never does so while another task waits for a CPU, and gives up after its budget."""

from __future__ import annotations

import time
from pathlib import Path

from swarmcommon.cpus import RunQueue, look_again, usable_cpus


class _Queue(RunQueue):
    """A run queue whose answer the test sets, and counts how often it was asked."""

    def __init__(self, crowded: bool) -> None:
        super().__init__(path="/nonexistent/loadavg")  # nothing opened: the answer is the test's
        self.is_crowded = crowded
        self.asked = 0

    def crowded(self) -> bool:
        self.asked += 1
        return self.is_crowded


def _queue_reading(tmp_path: Path, name: str, line: str) -> RunQueue:
    loadavg = tmp_path / name
    loadavg.write_text(line)
    return RunQueue(path=str(loadavg))


def test_the_run_queue_counts_the_runnable_tasks_against_this_process_cpus(tmp_path: Path) -> None:
    cpus = usable_cpus()
    fits = _queue_reading(tmp_path, "fits", f"0.42 1.42 1.78 {cpus}/110 19598\n")
    over = _queue_reading(tmp_path, "over", f"0.42 1.42 1.78 {cpus + 1}/110 19598\n")
    garbled = _queue_reading(tmp_path, "garbled", "not a load average\n")
    try:
        assert not fits.crowded()  # as many runnable (the caller among them) as CPUs: none waits
        assert over.crowded()  # one more: a task waits for a CPU
        assert garbled.crowded()  # unreadable: every CPU counts as taken
    finally:
        for queue in (fits, over, garbled):
            queue.close()
    assert fits.crowded()  # closed, too
    assert RunQueue(path="/nonexistent/loadavg").crowded()  # none to read (not Linux)


def test_looking_again_ends_when_the_condition_holds() -> None:
    calls = iter([False, False, True])
    assert look_again(lambda: next(calls), _Queue(crowded=False))


def test_a_crowded_machine_is_never_looked_at_again() -> None:
    queue = _Queue(crowded=True)
    asked = []
    assert not look_again(lambda: asked.append(1) or False, queue)
    assert asked == [] and queue.asked == 1  # gave up before asking the condition once


def test_looking_again_gives_up_after_its_budget_or_once_a_task_waits() -> None:
    start = time.perf_counter()
    assert not look_again(lambda: False, _Queue(crowded=False), budget_s=0.002)
    assert time.perf_counter() - start < 0.5
    queue = _Queue(crowded=False)

    def ready() -> bool:
        queue.is_crowded = True  # another task became runnable while this one looked
        return False

    assert not look_again(ready, queue, budget_s=10.0)
