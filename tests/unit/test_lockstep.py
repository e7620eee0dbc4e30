"""Lockstep through the shared world: nobody runs more than one step ahead, the gate holds everyone, leavers free
the others. Members are driven by hand here, exactly as the drone loop drives them (steps_allowed, completed)."""

from __future__ import annotations

import contextlib
import random
from collections.abc import Iterator

import pytest

from sitl.world.lockstep import LockstepGate, LockstepMember
from sitl.world.shared import SharedWorld

DT_S = 1.0 / 400.0


@pytest.mark.parametrize("quantum", [1, 4])
def test_no_member_gets_more_than_a_quantum_ahead_under_any_interleaving(quantum: int) -> None:
    world = SharedWorld.create()
    try:
        gate = LockstepGate(world, DT_S)
        members = [LockstepMember(SharedWorld.attach(world.name), i, quantum) for i in (0, 3, 7)]
        for m in members:
            m.join()
        gate.open_until(0.5)  # 200 steps
        done = [0, 0, 0]
        rng = random.Random(1)
        for _ in range(5000):  # a random scheduler: any member may get the CPU next
            k = rng.randrange(3)
            due, _gated = members[k].steps_allowed(done[k])
            for _ in range(min(due, rng.randint(1, 3))):
                done[k] += 1
                members[k].completed(done[k])
            assert max(done) - min(done) <= quantum, done
        # every member reached the gate, none passed it, and the gate's clock agrees
        assert done == [200, 200, 200]
        assert gate.completed_steps() == 200 and abs(gate.time_s() - 0.5) < 1e-12
        assert members[0].steps_allowed(200) == (0, True)  # held by the gate, not by a peer
    finally:
        world.close()


def test_nothing_moves_before_the_gate_opens_and_the_gate_never_moves_back() -> None:
    world = SharedWorld.create()
    try:
        gate = LockstepGate(world, DT_S)
        member = LockstepMember(world, 0)
        member.join()
        assert gate.members() == 1
        assert member.steps_allowed(0) == (0, True)
        gate.open_until(0.01)
        done = 0
        while (due := member.steps_allowed(done)[0]) > 0:  # alone: a step at a time, up to the gate
            assert due == 1
            done += 1
            member.completed(done)
        assert done == 4
        gate.open_until(0.005)
        assert member.steps_allowed(4) == (0, True)
    finally:
        world.close()


def test_a_member_that_leaves_or_is_removed_holds_nobody_back() -> None:
    world = SharedWorld.create()
    try:
        gate = LockstepGate(world, DT_S)
        a, b, c = (LockstepMember(world, i) for i in range(3))
        for m in (a, b, c):
            m.join()
        gate.open_until(1.0)
        a.completed(1)
        assert a.steps_allowed(1)[0] == 0 and not a.steps_allowed(1)[1]  # waiting for b and c, not the gate
        b.leave()
        gate.remove(2)  # c died without leaving
        assert gate.members() == 1
        assert a.steps_allowed(1) == (1, False)
        assert gate.completed_steps() == 1
    finally:
        world.close()


def test_a_member_knows_whether_it_holds_the_whole_lockstep_once_the_gate_has_opened() -> None:
    # (a member alone looks again before it sleeps, while a CPU is idle: sitl/process/runtime.py LockstepSteps.wait)
    world = SharedWorld.create()
    try:
        gate = LockstepGate(world, DT_S)
        host = LockstepMember(world, [0, 1])  # one process hosting two drones
        host.join()
        assert host.alone() is None  # before the gate opens another member may still join
        gate.open_until(0.01)
        assert host.alone() is True
        other = LockstepMember(world, 2)
        other.join()
        assert host.alone() is False
        other.leave()
        assert host.alone() is True
    finally:
        world.close()


def test_the_member_that_completes_the_common_step_wakes_the_one_waiting_for_it() -> None:
    world = SharedWorld.create()
    try:
        gate = LockstepGate(world, DT_S)
        fast, slow = LockstepMember(world, 0), LockstepMember(world, 1)
        fast.join()
        slow.join()
        gate.open_until(1.0)
        fast.completed(1)
        assert fast.steps_allowed(1)[0] == 0
        fast.begin_wait()  # it sleeps on its wake socket...
        slow.completed(1)  # ...until the slow one catches up, which wakes it
        fast.wake_socket.settimeout(1.0)
        assert fast.wake_socket.recv(16) == b""
        fast.wake_socket.setblocking(False)
        fast.end_wait()
        assert fast.steps_allowed(1)[0] == 1
        # nobody waits: completing a step sends nothing
        fast.completed(2)
        slow.completed(2)
        with pytest.raises(BlockingIOError):
            fast.wake_socket.recv(16)
        fast.leave()
        slow.leave()
    finally:
        gate.close()
        world.close()


@pytest.fixture
def gate_and_pair() -> Iterator[tuple[LockstepGate, LockstepMember, LockstepMember]]:
    """A supervisor's gate and two members that have joined, all closed afterwards."""
    world = SharedWorld.create()
    gate = LockstepGate(world, DT_S)
    a, b = LockstepMember(world, 0), LockstepMember(world, 1)
    a.join()
    b.join()
    try:
        yield gate, a, b
    finally:
        a.leave()
        b.leave()
        gate.close()
        world.close()


def test_the_last_member_to_reach_the_gate_wakes_the_supervisor_once(
    gate_and_pair: tuple[LockstepGate, LockstepMember, LockstepMember],
) -> None:
    gate, a, b = gate_and_pair
    gate.open_until(2 * DT_S)  # two steps
    a.completed(1)
    b.completed(1)
    a.completed(2)
    # a is at the gate but b is not: the supervisor is not woken yet
    with pytest.raises(BlockingIOError):
        gate.wake_socket.recv(16)
    b.completed(2)  # the last one arrives: one wake-up
    assert gate.wake_socket.recv(16) == b""
    with pytest.raises(BlockingIOError):
        gate.wake_socket.recv(16)


def test_the_supervisor_is_woken_at_the_gate_alone(
    gate_and_pair: tuple[LockstepGate, LockstepMember, LockstepMember],
) -> None:
    gate, a, b = gate_and_pair
    gate.open_until(10 * DT_S)
    woken_at = []
    for steps in range(1, 11):
        a.completed(steps)
        b.completed(steps)
        with contextlib.suppress(BlockingIOError):
            gate.wake_socket.recv(16)
            woken_at.append(steps)
    # the pipelined frame moves the gate once every member stands at it: an earlier wake-up would find nothing to do
    assert woken_at == [10]
    assert gate.all_at_gate() and gate.gate_step() == 10


def test_the_gate_knows_when_every_member_stands_at_it(
    gate_and_pair: tuple[LockstepGate, LockstepMember, LockstepMember],
) -> None:
    gate, a, b = gate_and_pair
    assert not gate.is_open() and not gate.all_at_gate() and gate.gate_step() == 0
    gate.open_until(2 * DT_S)
    a.completed(1)
    b.completed(1)
    a.completed(2)
    assert gate.is_open() and not gate.all_at_gate()  # b is a step short
    b.completed(2)
    assert gate.all_at_gate()
