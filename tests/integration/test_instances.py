"""Instance leases (tests/integration/instances.py): what lets test files run side by side on pytest-xdist workers.

Policy: nothing flies; a child process holds a block of the machine's instance locks as another worker would.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from sitl.process.ports import PX4_INSTANCES
from tests.integration.conftest import INSTANCES_PER_WORKER
from tests.integration.instances import HIGHEST_INSTANCE, _cursor, lease, leases
from tests.integration.sitl_process import instance_is_clear_of_user_ports
from tests.integration.test_many_drones_ports import DRONES as MANY_DRONES

pytestmark = pytest.mark.timeout(60)
HIGH = 150
SWEPT = 100  # the sweeper's range: high up, as HIGH, and clear of it

HOLDER = textwrap.dedent(
    """
    import sys
    from gcs.sweep.instance_locks import InstanceLocks
    locks, first = InstanceLocks(int(sys.argv[2])), int(sys.argv[1])
    for start in range(first, first + 100):  # the first block from ``first`` up nobody holds (others may run)
        held = locks.try_hold(start)  # kept: the locks go with their files
        if held is not None:
            print(start, flush=True)
            break
    else:
        print("taken", flush=True)
    sys.stdin.read()  # hold the locks until the test closes our stdin
    """
)

CHURNER = textwrap.dedent(
    """
    import sys, time
    from gcs.sweep.instance_locks import InstanceLocks
    one, first, stop_at = InstanceLocks(1), int(sys.argv[1]), time.monotonic() + float(sys.argv[2])
    held = one.try_hold(first)
    print("held" if held is not None else "taken", flush=True)
    turn = 1
    while time.monotonic() < stop_at:  # take the other instance before letting go of this one, as tests overlap
        taken = one.try_hold(first + turn % 2)
        turn += 1
        time.sleep(0.3)
        for handle in held or ():
            handle.close()
        held = taken
        time.sleep(0.3)
    """
)

SWEEPER = textwrap.dedent(
    """
    import sys, time
    from gcs.sweep.instance_locks import InstanceLocks
    locks, first, stop_at = InstanceLocks(2), int(sys.argv[1]), time.monotonic() + float(sys.argv[2])
    held, said = [], False
    while time.monotonic() < stop_at:  # a sweep's runs, two side by side: each takes the lowest block free
        for start in range(first, first + 40, 2):
            if (taken := locks.try_hold(start)) is not None:
                held.append(taken)
                break
        if len(held) == 2:
            if not said:
                print("sweeping", flush=True)  # both runs under way: a lease from now on meets them
                said = True
            time.sleep(0.5)
            for handle in held.pop(0):
                handle.close()
        else:
            time.sleep(0.05)
    """
)


def test_leases_are_disjoint_clear_of_user_ports_and_skip_a_block_another_process_holds() -> None:
    # (high up: clear of where sweeps, campaigns and the 42-drone test's reservation take their blocks)
    with leases(lowest=HIGH) as take:
        # GIVEN a block leased here, and the next free block after it held by another process (as another worker
        # would)
        first = take(4)
        holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(first + 4), "4"], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, text=True)  # fmt: skip
        try:
            assert holder.stdout is not None
            other = int(holder.stdout.readline())
            # WHEN more blocks are leased
            firsts = [take(4) for _ in range(3)]
            # THEN none overlaps this process's own blocks or the other process's, none reaches a user's ports
            # or the sysids the tests' stand-ins use
            blocks = [set(range(f, f + 4)) for f in (first, *firsts)]
            taken = set(range(other, other + 4))
            for i, block in enumerate(blocks):
                assert not block & taken, (block, taken)
                assert all(not block & b for b in blocks[i + 1 :])
                assert all(instance_is_clear_of_user_ports(n) and n <= HIGHEST_INSTANCE for n in block)
        finally:
            assert holder.stdin is not None
            holder.stdin.close()
            holder.wait(10)
    # AND once given back, a block can be leased again by anyone (here: held at once by a new process)
    again = subprocess.run([sys.executable, "-c", HOLDER, str(first), "4"], input="", capture_output=True, text=True,
                           timeout=30)  # fmt: skip
    assert again.stdout.strip() == str(first), again


def test_a_lease_that_must_contain_an_instance_spans_it() -> None:
    # GIVEN a test of what changes at instance 40 (the port scheme's boundary) WHEN it leases 6 instances round it
    held = lease(6, containing=PX4_INSTANCES)
    try:
        # THEN the block holds the boundary
        assert PX4_INSTANCES in held.instances
    finally:
        held.release()


def test_a_lease_for_the_whole_session_is_taken_from_the_top_clear_of_the_large_blocks_low_down() -> None:
    # GIVEN the round robin's place in this process
    before = _cursor.next_first
    # WHEN a block is leased for a whole session (as each worker's allocator is)
    held = lease(INSTANCES_PER_WORKER, from_top=True)
    try:
        # THEN it lies above every block of 42 that holds instance 38 (the 42-drone test's, which no reservation could
        # get while a session-long lease sat inside it), and the round robin of the other leases is where it was
        assert held.first > PX4_INSTANCES - 2 + MANY_DRONES - 1, held
        assert _cursor.next_first == before
    finally:
        held.release()


def _lease_beside(script: str, first: int, ready: str, count: int, timeout_s: float) -> range:
    """Lease ``count`` instances from ``first`` while another process runs ``script`` over them (it prints ``ready``
    once it holds some); the instances leased. A lease that does not come within ``timeout_s`` is a LeaseError."""
    other = subprocess.Popen([sys.executable, "-c", script, str(first), "40"], stdout=subprocess.PIPE, text=True)
    try:
        assert other.stdout is not None and other.stdout.readline().strip() == ready
        held = lease(count, lowest=first, containing=first, timeout_s=timeout_s)
        held.release()
        return held.instances
    finally:
        other.kill()
        other.wait(10)


def test_a_block_is_reserved_while_other_processes_keep_taking_small_blocks_inside_it() -> None:
    # GIVEN two instances another process keeps holding by turns, always one at least (as workers do that lease small
    # blocks one after another)
    with leases() as take:
        first = take(2)
    # WHEN a test needs both at once THEN it gets them, by holding each as it comes free, long before 20 s
    assert _lease_beside(CHURNER, first, "held", 2, timeout_s=20) == range(first, first + 2)


def test_a_reserved_block_is_not_starved_by_runs_that_keep_taking_the_lowest_blocks_inside_it() -> None:
    # GIVEN a sweep-like process whose runs, two at a time, always take the lowest free blocks of a range (as a sweep's
    # or a campaign's flights do from instance 20 up, where the 42-drone test's block lies)
    # WHEN a test needs a block of 12 at the bottom of that range THEN it reserves it, the runs go around it, and it
    # has it long before 30 s (without the reservation, it chased the runs' blocks up the range until it timed out)
    assert _lease_beside(SWEEPER, SWEPT, "sweeping", 12, timeout_s=30) == range(SWEPT, SWEPT + 12)
