"""Lockstep: every drone of a swarm advances simulated time together, as fast as the CPU allows.

Paced drones each follow the wall clock on their own, so their simulated clocks drift apart by whatever each
process's scheduling costs, and nothing can run faster than the slowest drone keeps up with. In lockstep the clock
lives in the shared world instead (sitl/world/shared.py): every member publishes how many physics steps it has
completed, and a member may complete step k + 1 only when every other member has completed step k and the supervisor's
gate allows k + 1. Hence

- no member is ever more than one physics step ahead of any other (skew <= one step, by construction), and
- the supervisor, which moves the gate after each of its own loop iterations, is never more than its lead behind
  the drones: its setpoint streaming, timeouts and mission timing all run on the same simulated clock.

Waiting costs nothing: a member that may not step sets its WAITING flag and sleeps on a datagram socket of its own
(abstract Unix address derived from the world's name); the member whose step moves the common time on - the last
laggard - and the supervisor when it moves the gate wake exactly the members that wait. Polling instead (sleeping
0.2 ms and looking again) cost more than the simulation itself with nine drones on two cores
(docs/benchmark-history.md).
The supervisor sleeps the same way: the last member to reach the gate wakes it. Before, it looked again only when
MAVLink traffic arrived or its 5 ms wait ran out, which capped a single drone at 4x real time once its telemetry left
in fewer datagrams. It used to be woken two steps before the gate too, so that it could move the gate while the
drones still ran; the pipelined frame (gcs/fleet/pump.py) moves the gate the moment every member stands at it and
does its own work while they fly the next frame, so there is nothing left for an early wake-up to win.
The flag is set before the last look at the clock, so a wake-up can be missed only through store-load reordering
between two cores; a sleep never lasts longer than ``MAX_SLEEP_S``, which bounds that rare case.

A quantum of Q steps generalises the rule: every member runs to the next multiple of Q past the slowest one, then
waits, so the skew is at most Q steps and each process sleeps and wakes once per Q steps instead of every step. With
more drones than cores every step otherwise costs each drone a context switch and a cold cache, which costs more than
the step itself (docs/benchmarks.md); Q = 1 is the default and the strict form.

All members must share one physics rate and one quantum (the supervisor starts them so). A row that is no member
holds an infinite step count, so the common time is simply the column's minimum; a member that leaves (exits, or is
killed and removed by the supervisor) goes back to infinity and no longer holds anyone back. Step counts only grow
and every cell has a single writer, so a stale read can only make a member wait a little longer, never run ahead; no
lock is needed.
"""

from __future__ import annotations

import contextlib
import math
import socket
from collections.abc import Sequence

import numpy as np

from sitl.world.shared import GATE_OPEN, GATE_STEP, STEP, WAITING, SharedWorld

MAX_SLEEP_S = 0.005


def wake_address(world_name: str, instance: int) -> bytes:
    """Abstract Unix socket address (no file to clean up) of a member's wake-up socket."""
    return f"\0swarm-lockstep-{world_name.lstrip('/')}-{instance}".encode()


def gate_address(world_name: str) -> bytes:
    """Abstract Unix socket address of the supervisor's wake-up socket (the gate's)."""
    return f"\0swarm-lockstep-{world_name.lstrip('/')}-gate".encode()


class _Waker:
    """Sends the empty datagrams that wake sleeping members."""

    def __init__(self, world: SharedWorld) -> None:
        self._world_name = world.name
        self._waiting = world.table[:, WAITING]
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self._sock.setblocking(False)

    def wake_waiting(self) -> None:
        for instance in np.flatnonzero(self._waiting == 1.0):
            with contextlib.suppress(OSError):  # gone, or its queue full: it is awake anyway
                self._sock.sendto(b"", wake_address(self._world_name, int(instance)))

    def wake_gate(self) -> None:
        with contextlib.suppress(OSError):  # no supervisor listening, or its queue full: it is awake anyway
            self._sock.sendto(b"", gate_address(self._world_name))

    def close(self) -> None:
        self._sock.close()


class LockstepMember:
    """One process's side: join, ask how many steps it may take, publish each completed step, leave.

    A process hosting several drones (sitl/host.py) is one member with several rows: its drones step together, so
    every row it owns holds the same count, and it sleeps and is woken once for all of them, on the wake-up address
    of its first row (the row whose WAITING flag it sets). A hosted drone that ends ``drop``s its row."""

    def __init__(self, world: SharedWorld, instances: int | Sequence[int], quantum_steps: int = 1) -> None:
        if quantum_steps < 1:
            raise ValueError(f"a lockstep quantum is at least one step, got {quantum_steps}")
        rows = [instances] if isinstance(instances, int) else list(instances)
        if not rows:
            raise ValueError("a lockstep member has at least one row")
        self.world = world
        self.instance = rows[0]  # the row whose WAITING flag and wake-up address stand for the whole member
        self.quantum = quantum_steps
        self._rows = np.array(rows, dtype=np.intp)
        self._steps = world.table[:, STEP]  # a view: reading it costs one reduction, no copy
        self._waiting = world.table[:, WAITING]
        self._header = world.header
        self.wake_socket = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.wake_socket.bind(wake_address(world.name, self.instance))
        self.wake_socket.setblocking(False)
        self._waker = _Waker(world)

    def join(self) -> None:
        self._waiting[self.instance] = 0.0
        self._steps[self._rows] = 0.0

    def steps_allowed(self, completed: int) -> tuple[int, bool]:
        """(steps this member may take now, whether the supervisor's gate is what holds it).

        Everyone runs to the end of the current quantum (the next multiple of ``quantum`` steps past the common
        time, i.e. past the slowest member) and no further; its own count is in the column too, which only matters
        when it is the slowest, and then the quantum it is in is the one it may finish."""
        header = self._header
        gate = float(header[GATE_STEP]) if header[GATE_OPEN] == 1.0 else 0.0
        q = self.quantum
        peers = float((int(self._steps.min()) // q + 1) * q)
        limit = min(peers, gate)
        return max(0, int(limit) - completed), gate <= peers

    def completed(self, steps: int) -> None:
        """Publish a completed step; the last member to finish a quantum wakes whoever waits at its end, and the
        last to reach the gate wakes the supervisor, which would otherwise only look again when its own wait for
        traffic ran out."""
        steps_column = self._steps
        rows = self._rows
        if len(rows) == 1:
            steps_column[rows[0]] = float(steps)
        else:
            steps_column[rows] = float(steps)
        end_of_quantum = steps % self.quantum == 0
        wake_gate = steps >= self._header[GATE_STEP]
        if (end_of_quantum or wake_gate) and steps_column.min() >= steps:
            if end_of_quantum:
                self._waker.wake_waiting()
            if wake_gate:
                self._waker.wake_gate()

    def alone(self) -> bool | None:
        """Whether this member holds every row in the lockstep (one process hosts the whole swarm); None before the
        gate has opened, when others may not have joined yet (the gate opens only once every drone has)."""
        if self._header[GATE_OPEN] != 1.0:
            return None
        return int(np.count_nonzero(np.isfinite(self._steps))) <= len(self._rows)

    def drop(self, instance: int) -> None:
        """Row ``instance`` no longer advances (its hosted drone ended): it holds nobody back from now on."""
        self._rows = self._rows[self._rows != instance]
        self._steps[instance] = math.inf
        self._waker.wake_waiting()

    def begin_wait(self) -> None:
        self._waiting[self.instance] = 1.0

    def end_wait(self) -> None:
        self._waiting[self.instance] = 0.0
        with contextlib.suppress(BlockingIOError):
            while True:
                self.wake_socket.recv(16)

    def leave(self) -> None:
        self._waiting[self.instance] = 0.0
        self._steps[self._rows] = math.inf
        self._waker.wake_waiting()  # whoever waited for this member may go on
        self._waker.close()
        self.wake_socket.close()


class LockstepGate:
    """The supervisor's side: how far the members have got, and how far they may go."""

    def __init__(self, world: SharedWorld, dt_s: float) -> None:
        self.world = world
        self.dt_s = dt_s
        self._waker = _Waker(world)
        # The last member to reach the gate sends an empty datagram here: the supervisor waits on this socket
        # with its MAVLink socket and moves the gate at once.
        self.wake_socket = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.wake_socket.bind(gate_address(world.name))
        self.wake_socket.setblocking(False)

    def drain_wakes(self) -> None:
        with contextlib.suppress(BlockingIOError):
            while True:
                self.wake_socket.recv(16)

    def members(self) -> int:
        return int(np.count_nonzero(np.isfinite(self.world.table[:, STEP])))

    def completed_steps(self) -> int:
        """Steps every member has completed (the swarm's common time, in steps); 0 before anyone joined."""
        low = float(self.world.table[:, STEP].min())
        return int(low) if math.isfinite(low) else 0

    def time_s(self) -> float:
        return self.completed_steps() * self.dt_s

    def is_open(self) -> bool:
        """Whether the supervisor has opened the gate (the common clock runs)."""
        return bool(self.world.header[GATE_OPEN] == 1.0)

    def gate_step(self) -> int:
        """The step every member may complete and then waits at (0 before the gate opens)."""
        return int(self.world.header[GATE_STEP]) if self.is_open() else 0

    def all_at_gate(self) -> bool:
        """Every member stands at the open gate: none steps again until the supervisor moves it, so what is done to
        the world now (a stop, a kill) meets every member at the same step in every run."""
        return self.is_open() and self.completed_steps() >= self.gate_step()

    def open_until(self, sim_time_s: float) -> None:
        """Let every member run until ``sim_time_s`` (the gate never moves back)."""
        step = math.floor(sim_time_s / self.dt_s + 1e-9)
        header = self.world.header
        opened = header[GATE_OPEN] != 1.0
        if step > header[GATE_STEP]:
            header[GATE_STEP] = float(step)
            opened = True
        header[GATE_OPEN] = 1.0
        if opened:
            self._waker.wake_waiting()

    def remove(self, instance: int) -> None:
        """A member that died without leaving must not hold the others back."""
        self.world.table[instance, STEP] = math.inf
        self._waker.wake_waiting()

    def close(self) -> None:
        self._waker.close()
        self.wake_socket.close()
