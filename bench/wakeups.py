"""Benchmark: what sleeping and waking costs a drone on this machine, apart from the drone's own work.

A paced drone runs a few physics steps, sleeps until more are due, and wakes again. On a quiet machine a wake-up
should cost a few microseconds; on a virtual machine, or one shared with other jobs, a process that slept comes back
to caches (and a CPU) that others have used, and pays to fetch its working set again. This script puts a number on
that for the flight code alone (the closed loop of bench/one_drone.py: no MAVLink, no camera, no shared world), so
that a swarm's figures can be read against what the machine charges, and compared between machines:

1. **unpaced**: one process stepping as fast as it can: the work itself.
2. **paced, one drone**: the same flight at real time, sleeping until the next ``W`` steps are due (W = 2, 8, 32,
   125); the CPU above the unpaced figure, divided by the wake-ups, is what one wake-up costs.
3. **paced, a crowd**: K such processes at once (``--crowd``), as a swarm of K drones would be, at W = 8 and 32.
4. **unpaced, a crowd**: K processes that never sleep; the scheduler gives each a few milliseconds at a time, so
   this is what K processes sharing two cores' caches cost without wake-ups.

Every process is forked from this one after the imports (as the drone factory does) and builds its own simulation,
boots, arms and climbs to 3 m unpaced before its clock starts; it reports its process CPU time per simulated second.

    python bench/wakeups.py [--sim-seconds 10] [--crowd 9,30]
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NoReturn

from one_drone import arm_and_take_off_when_ready  # this directory is on the path of a script run from it

from sitl.drone.closed_loop import PHYSICS_RATE_HZ, ClosedLoop, SimConfig
from sitl.dynamics.airframe import load_airframe

CLIMB_S = 3.0  # simulated seconds of climb after take-off, before the clock starts
LONE_WAKE_STEPS = (2, 8, 32, 125)
CROWD_WAKE_STEPS = (8, 32)
CHILD_TIMEOUT_S = 600.0


@dataclass(frozen=True, slots=True)
class RunSpec:
    processes: int
    wake_steps: int | None  # None: unpaced

    @property
    def label(self) -> str:
        who = "1 process" if self.processes == 1 else f"{self.processes} processes"
        return f"{who}, unpaced" if self.wake_steps is None else f"{who}, paced, wake every {self.wake_steps} steps"


@dataclass(frozen=True, slots=True)
class RunResult:
    spec: RunSpec
    cpu_ms_per_sim_s: tuple[float, ...]  # one per process
    wakes_per_sim_s: float  # 0 unpaced

    @property
    def mean_ms(self) -> float:
        return statistics.fmean(self.cpu_ms_per_sim_s)


def extra_per_wake_ms(paced_ms: float, unpaced_ms: float, wakes_per_sim_s: float) -> float:
    """CPU per wake-up beyond the work: what pacing adds to a simulated second, shared out over its wake-ups."""
    if wakes_per_sim_s <= 0:
        raise ValueError("a paced run wakes at least once per simulated second")
    return (paced_ms - unpaced_ms) / wakes_per_sim_s


def _flying_sim(seed: int) -> ClosedLoop:
    """A simulation armed, taken off and climbing for CLIMB_S, run unpaced: the measured stretch is flight."""
    sim = ClosedLoop(SimConfig(airframe=load_airframe(), seed=seed))
    while not arm_and_take_off_when_ready(sim):
        sim.step()
    for _ in range(round(CLIMB_S / sim.dt_s)):
        sim.step()
    return sim


def _fly(sim: ClosedLoop, sim_seconds: float, wake_steps: int | None) -> float:
    """Process CPU seconds to fly ``sim_seconds``: unpaced, or at real time sleeping until ``wake_steps`` are due."""
    steps = round(sim_seconds / sim.dt_s)
    dt_s = sim.dt_s
    done = 0
    cpu0 = time.process_time()
    wall0 = time.monotonic()
    while done < steps:
        if wake_steps is not None:
            due = int((time.monotonic() - wall0) / dt_s) - done
            if due <= 0:
                time.sleep(max(0.0, wall0 + (done + wake_steps) * dt_s - time.monotonic()))
                continue
        else:
            due = steps
        batch = min(due, steps - done)
        for _ in range(batch):
            sim.step()
        done += batch
    return time.process_time() - cpu0


def _child(seed: int, sim_seconds: float, wake_steps: int | None, out_fd: int) -> None:
    """A forked flight: one line on ``out_fd`` (short enough to be written atomically), then exit."""
    status = 1
    try:
        cpu_s = _fly(_flying_sim(seed), sim_seconds, wake_steps)
        os.write(out_fd, f"{cpu_s / sim_seconds * 1e3:.4f}\n".encode())
        status = 0
    except BaseException as exc:  # the parent reports the missing figure; say why here
        print(f"flight {seed}: {exc!r}", file=sys.stderr)
    finally:
        os._exit(status)


def run(spec: RunSpec, sim_seconds: float) -> RunResult:
    """Fork ``spec.processes`` flights at once and collect each one's CPU per simulated second."""
    read_fd, write_fd = os.pipe()
    pids: list[int] = []
    try:
        for i in range(spec.processes):
            pid = os.fork()
            if pid == 0:
                os.close(read_fd)
                _child(i, sim_seconds, spec.wake_steps, write_fd)
            pids.append(pid)
        os.close(write_fd)
        write_fd = -1
        chunks = []
        while chunk := os.read(read_fd, 1 << 16):
            chunks.append(chunk)
        for pid in list(pids):
            os.waitpid(pid, 0)
            pids.remove(pid)
    finally:
        for pid in pids:  # interrupted: stop the flights this run started, and reap them
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        os.close(read_fd)
        if write_fd >= 0:
            os.close(write_fd)
    figures = tuple(float(line) for line in b"".join(chunks).decode().split())
    if len(figures) != spec.processes:
        raise RuntimeError(f"{spec.label}: {spec.processes - len(figures)} flights failed")
    wakes = 0.0 if spec.wake_steps is None else PHYSICS_RATE_HZ / spec.wake_steps
    return RunResult(spec, figures, wakes)


def specs(crowd: Sequence[int]) -> list[RunSpec]:
    out = [RunSpec(1, None)] + [RunSpec(1, w) for w in LONE_WAKE_STEPS]
    for k in crowd:
        out += [RunSpec(k, w) for w in CROWD_WAKE_STEPS] + [RunSpec(k, None)]
    return out


def _crowd_sizes(text: str) -> list[int]:
    try:
        sizes = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected process counts like 9,30, got {text!r}") from None
    if not sizes or any(k < 2 or k > 100 for k in sizes):
        raise argparse.ArgumentTypeError(f"crowd sizes are 2..100, got {text!r}")
    return sizes


class _OneLineParser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        print(f"wakeups.py: error: {message}", file=sys.stderr)
        sys.exit(2)


def main(argv: Sequence[str] | None = None) -> int:
    parser = _OneLineParser(prog="wakeups.py", description=__doc__.splitlines()[0])
    parser.add_argument("--sim-seconds", type=float, default=10.0, help="simulated seconds measured per flight")
    parser.add_argument("--crowd", type=_crowd_sizes, default=[9, 30], help="crowd sizes (default 9,30)")
    args = parser.parse_args(argv)
    if not 0.5 <= args.sim_seconds <= 600:
        parser.error("--sim-seconds must be within 0.5..600")
    unpaced_ms: dict[int, float] = {}
    print(f"{args.sim_seconds:g} simulated seconds of flight per process, CPU ms per simulated second")
    print(f"{'run':<46} {'mean':>7} {'min':>7} {'max':>7} {'wakes/s':>8} {'extra/wake':>11}")
    for spec in specs(args.crowd):
        result = run(spec, args.sim_seconds)
        extra = ""
        if spec.wake_steps is None:
            unpaced_ms[spec.processes] = result.mean_ms
        else:
            extra = f"{extra_per_wake_ms(result.mean_ms, unpaced_ms[1], result.wakes_per_sim_s):8.3f} ms"
        figures = result.cpu_ms_per_sim_s
        print(
            f"{spec.label:<46} {result.mean_ms:7.1f} {min(figures):7.1f} {max(figures):7.1f}"
            f" {result.wakes_per_sim_s:8.1f} {extra:>11}",
            flush=True,
        )
    print("extra/wake: (paced mean - one unpaced process) / wake-ups per simulated second")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:
        sys.exit(130)
