"""The drone process's IO shell: pacing against the wall clock, signals, and the main loop.

Everything that flies is in the pure Simulation; this module only decides when to step it and when to stop.
"""

from __future__ import annotations

import logging
import selectors
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from types import FrameType

from sitl.pacing import Pacer
from sitl.simulation import Simulation

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True, kw_only=True)
class RunOptions:
    speed_factor: float = 1.0
    duration_s: float | None = None  # stop after this much simulation time


class StopFlag:
    """Set by SIGINT/SIGTERM; the loop finishes its batch and exits cleanly."""

    def __init__(self) -> None:
        self.stopped = False
        self.signal_name = ""

    def install(self) -> None:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._handler)

    def _handler(self, signum: int, _frame: FrameType | None) -> None:
        self.stopped = True
        self.signal_name = signal.Signals(signum).name


def run_loop(
    sim: Simulation,
    options: RunOptions,
    stop: StopFlag,
    on_step: Callable[[], None] | None = None,
    finished: Callable[[], bool] | None = None,
) -> None:
    """Step the simulation paced to the wall clock until stopped, finished, or the duration is reached."""
    pacer = Pacer(options.speed_factor, sim.dt_s, time.monotonic())
    selector = selectors.DefaultSelector()  # IO sources register here; with none it is just a precise sleep
    try:
        while not stop.stopped:
            due = pacer.steps_due(time.monotonic(), sim.time_s)
            for _ in range(due):
                sim.step()
                if on_step is not None:
                    on_step()
                if (finished is not None and finished()) or (
                    options.duration_s is not None and sim.time_s >= options.duration_s - 1e-9
                ):
                    return
            if not pacer.unpaced:
                wait_s = pacer.wall_time_of(sim.time_s + sim.dt_s) - time.monotonic()
                if wait_s > 0:
                    if selector.get_map():
                        selector.select(wait_s)
                    else:
                        time.sleep(wait_s)
    finally:
        selector.close()
        if pacer.dropped_s > 0:
            log.warning("fell behind real time by %.2f s of simulation time in total", pacer.dropped_s)
