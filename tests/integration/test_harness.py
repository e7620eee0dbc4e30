"""The simulation harness on its own, through the face the ground station uses (gcs/fleet/harness.py): it starts real
drones, runs their lockstep clock, says which ended and why, kills one on request and leaves nothing behind.

Policy: loopback only; two leased instances (tests/integration/instances.py); lockstep, so nothing depends on the
machine's load.
"""

from __future__ import annotations

import math
import os
import select
import socket
import time
from collections.abc import Callable, Iterator
from multiprocessing import resource_tracker
from pathlib import Path

import pytest

from gcs.fleet.harness import SimulationHarness
from sitl.dynamics.plant import DEFAULT_HOME
from sitl.harness import LaunchPlan, SitlHarness
from tests.integration.instances import Leases

LEAD_S = 0.02

pytestmark = pytest.mark.timeout(150)


@pytest.fixture(scope="module", autouse=True)
def shared_memory_tracker() -> Iterator[None]:
    """The harness creates the shared world in this process, which starts Python's shared-memory tracker, a child
    process that lives as long as the interpreter; started before the leak check's snapshot, it is no leftover."""
    resource_tracker.ensure_running()
    yield


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except OSError:
        return False


def _run_until(harness: SimulationHarness, done: Callable[[float], bool], wall_s: float) -> float:
    """Move the lockstep clock on as the ground station does (wait on the wake-up descriptor between moves) until
    ``done()`` holds; returns the common time. Fails after ``wall_s`` wall seconds."""
    fd = harness.wake_fileno()
    assert fd is not None
    end = time.monotonic() + wall_s
    while time.monotonic() < end:
        now = harness.advance_lockstep(LEAD_S)
        if now is not None and done(now):
            return now
        select.select([fd], [], [], 0.005)
    raise AssertionError(f"not done within {wall_s:g} wall seconds (common time {harness.lockstep_time_s():.3f} s)")


def test_the_harness_runs_kills_reports_and_stops_its_drones(tmp_path: Path, instances: Leases) -> None:
    first = instances(2)
    second_sysid = first + 2  # the second drone's (instance first + 1)
    plan = LaunchPlan(origin=DEFAULT_HOME, offsets_ne_m=((0.0, 0.0), (0.0, 4.0)), lockstep=True, speed_factor=0.0,
                      first_instance=first, log_dir=tmp_path)  # fmt: skip
    harness: SimulationHarness = SitlHarness(plan)  # the face, as the ground station is handed it
    ground_station = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ground_station.bind(("127.0.0.1", 0))
    pids: set[int] = set()
    try:
        # GIVEN two drones started in lockstep
        assert harness.launch(ground_station.getsockname()[1]) == [first + 1, second_sysid]
        pids = set(harness.process_ids().values())
        assert len(pids) == 2 and all(_alive(p) for p in pids)
        # WHEN the clock is moved on THEN both drones run on it, together, and publish their clocks
        t = _run_until(harness, lambda now: now >= 1.0, 90.0)
        drone_time = harness.drone_time_s()
        assert drone_time is not None and drone_time <= t + LEAD_S + 0.02
        times, steps = harness.clock_columns()
        assert len(times) == 2 and float(steps.max() - steps.min()) <= 1.0
        assert harness.cpu_parts_s().shape == (2, 4) and float(harness.cpu_parts_s()[:, 0].min()) > 0.0
        assert harness.ended() == {}
        # WHEN the second drone's flight software is crashed
        done = harness.kill(second_sysid)
        assert done is not None and done.startswith("process ") and " killed with SIGKILL at the lockstep gate" in done
        # THEN the harness reports it ended, killed, once every drone stands at the gate, and it holds nobody back
        _run_until(harness, lambda _now: second_sysid in harness.ended(), 20.0)
        assert harness.ended() == {second_sysid: "process killed by SIGKILL"}
        assert f"drone {first + 1} (sysid {second_sysid}) exited with code -9" in harness.end_report(second_sysid)
        assert harness.kill(second_sysid) is None  # nothing left to kill
        later = harness.lockstep_time_s() + 0.5
        _run_until(harness, lambda now: now >= later, 30.0)
        # AND its body lies where it stood (it never took off), 4 m east of the origin
        down = harness.grounded_body_geo(second_sysid, harness.lockstep_time_s())
        assert down is not None
        east_m = math.radians(down[1] - DEFAULT_HOME.lon_deg) * 6.378e6 * math.cos(math.radians(DEFAULT_HOME.lat_deg))
        assert abs(east_m - 4.0) < 0.5, down
    finally:
        harness.close()
        ground_station.close()
    # AND once closed, no drone process is left
    assert not [p for p in pids if _alive(p)]
    assert os.path.exists(tmp_path / f"drone-{first}.log")
