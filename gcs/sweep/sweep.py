"""A sweep from start (or where it stopped) to its summary: the runs not yet complete, flown side by side on this
machine (``--jobs``) or on a Ray cluster (``--ray``, gcs/sweep/cluster.py), each result kept as it comes, with a
progress line and an estimate of the time left.

The output folder holds sweep.json (what the sweep is), runs/<setting>/seed-<n>/ (each run's report, fly.log and,
once complete, run.json) and the summary. Run again with the same folder, the sweep flies only the runs without a
run.json; a folder holding another sweep (another mission, seeds or values), or the same sweep flown by code that
flies differently (sweep.json's ``flight_version``), is refused rather than mixed.
"""

from __future__ import annotations

import concurrent.futures
import json
import math
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Final, Protocol, TextIO

from gcs.sweep.instance_locks import InstanceLocks
from gcs.sweep.plan import Run, SweepError, SweepPlan, describe, other_flights, saved_plan
from gcs.sweep.runs import Flight, RunResult, Stopped, completed, fly

PLAN_FILE: Final = "sweep.json"
RUNS_DIR: Final = "runs"


def run_dir(out: Path, run: Run) -> Path:
    return out / RUNS_DIR / run.setting_key / f"seed-{run.seed:04d}"


class SweepInterrupted(Exception):
    """Ctrl-C (or SIGTERM) during a sweep: the runs under way were stopped; what completed is kept."""

    def __init__(self, complete: int, total: int) -> None:
        super().__init__(f"interrupted with {complete} of {total} runs complete")
        self.complete, self.total = complete, total


class Progress:
    """One line per finished run (or an updating line on a terminal): done/total, failures, time left."""

    def __init__(self, total: int, already: int, stream: TextIO = sys.stderr) -> None:
        self.total, self.done, self.failed = total, already, 0
        self._flown = 0
        self._started = time.monotonic()
        self._stream = stream
        self._tty = stream.isatty()

    def update(self, result: RunResult) -> None:
        self.done += 1
        self._flown += 1
        self.failed += not result.ok
        elapsed = time.monotonic() - self._started
        left = elapsed / self._flown * (self.total - self.done)
        width = 30
        filled = round(width * self.done / self.total)
        bar = "#" * filled + "." * (width - filled)
        failed = f", {self.failed} failed" if self.failed else ""
        line = (f"sweep [{bar}] {self.done}/{self.total}{failed}, {_clock(elapsed)} elapsed, about "
                f"{_clock(left)} left  ({result.name}: {'ok' if result.ok else 'FAILED'})")  # fmt: skip
        self._stream.write(("\r" + line + "\033[K") if self._tty else line + "\n")
        if self._tty and self.done == self.total:
            self._stream.write("\n")
        self._stream.flush()


def _clock(seconds: float) -> str:
    seconds = max(0, round(seconds))
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


@dataclass(frozen=True, slots=True)
class SweepOutcome:
    results: list[RunResult]  # every run's, complete ones from earlier included, in run order
    flown: int  # runs flown by this call
    skipped: int  # runs already complete


def prepare(plan: SweepPlan, out: Path) -> None:
    """Make the output folder hold ``plan`` (new, or the same sweep resumed); SweepError for another sweep, or for
    the same one flown by code that flies differently (``other_flights``)."""
    path = out / PLAN_FILE
    saved = saved_plan(path) if path.exists() else None
    if path.exists() and (saved is None or not plan.same_runs_as(saved)):
        raise SweepError(f"{out} holds another sweep ({path}): give another --out, or remove it")
    if saved is not None and (why := other_flights(saved, out)) is not None:
        raise SweepError(why)
    out.mkdir(parents=True, exist_ok=True)
    if saved is None:
        path.write_text(json.dumps(plan.to_json(), indent=1) + "\n")


class Flyer(Protocol):
    """Flies flights (side by side on this machine, or on a cluster)."""

    def __call__(self, flights: list[Flight], finished: Callable[[RunResult], None], stop: threading.Event) -> None:
        """Fly ``flights``, calling ``finished`` with each result as it comes, until all are flown or ``stop`` is
        set."""

    def close(self) -> None:
        """Let go of what the flyer holds (a cluster it joined)."""


def run_sweep(plan: SweepPlan, out: Path, flyer: Flyer, say: Callable[[str], None]) -> SweepOutcome:
    """Fly every run of ``plan`` that ``out`` does not hold complete, with ``flyer`` (local or cluster)."""
    prepare(plan, out)
    runs = plan.runs()
    done: dict[int, RunResult] = {}
    for run in runs:
        result = completed(run_dir(out, run))
        if result is not None and result.ok:
            done[run.index] = result
    pending = [r for r in runs if r.index not in done]
    say(f"sweep: {describe(plan)}; {len(done)} complete already, {len(pending)} to fly; results in {out}")
    progress = Progress(len(runs), len(done))
    lock = threading.Lock()
    flown: dict[int, RunResult] = {}

    def finished(result: RunResult) -> None:
        with lock:
            flown[result.index] = result
            progress.update(result)

    stop = threading.Event()
    try:
        flyer([Flight(plan, run, run_dir(out, run)) for run in pending], finished, stop)
    except KeyboardInterrupt:
        stop.set()
        raise SweepInterrupted(len(done) + sum(r.ok for r in flown.values()), len(runs)) from None
    results = {**done, **flown}
    return SweepOutcome(results=[results[k] for k in sorted(results)], flown=len(flown), skipped=len(done))


class LocalFlyer:
    """Flights side by side on this machine, ``jobs`` at a time, each on instances no other flight holds."""

    def __init__(self, jobs: int) -> None:
        self.jobs = jobs
        self._locks: dict[int, InstanceLocks] = {}
        self._guard = threading.Lock()

    def _one(self, flight: Flight, stop: threading.Event) -> RunResult:
        with self._guard:
            sized = self._locks.setdefault(flight.plan.n_drones, InstanceLocks(flight.plan.n_drones))
        with sized.block(stop) as block:
            return fly(flight.plan, flight.run, flight.folder, block.first, stop, lock_fds=block.fds)

    def __call__(self, flights: list[Flight], finished: Callable[[RunResult], None], stop: threading.Event) -> None:
        pool = concurrent.futures.ThreadPoolExecutor(max_workers=self.jobs, thread_name_prefix="sweep")
        futures = [pool.submit(self._one, flight, stop) for flight in flights]
        try:
            for future in concurrent.futures.as_completed(futures):
                try:
                    finished(future.result())
                except (Stopped, InterruptedError):
                    continue
        except BaseException:
            stop.set()  # every run under way stops its swarm (SIGTERM: drones landed, stopped) and ends
            raise
        finally:
            pool.shutdown(wait=True, cancel_futures=True)

    def close(self) -> None:
        pass


def cpus_per_run(n_drones: int, drones_per_process: int) -> int:
    """The CPUs one run needs: one per drone process it starts (the local default and each Ray task's size)."""
    return max(1, math.ceil(n_drones / drones_per_process))


def default_jobs(usable_cpus: int, n_drones: int, drones_per_process: int) -> int:
    """Runs side by side by default: as many as the machine has CPUs for."""
    return max(1, usable_cpus // cpus_per_run(n_drones, drones_per_process))
