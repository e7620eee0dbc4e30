"""Reproducible lockstep and the link model, judged by real ``swarm fly`` runs and their flight reports.

- The same lockstep mission with the same seeds flies the same: two runs of the antipodal swap (neighbours relayed
  and heard over the mesh, on a lossy and late neighbour link), the second with both CPUs kept busy by other work,
  give the same MAVLink messages in their flight logs, message for message, and the same report.
- Lossy and late links (the link model acting on every drone's traffic, both ways) still fly the shipped missions
  without a collision, and the report counts what the model did.

Policy: loopback only (--no-forward); leased instances (tests/integration/instances.py); lockstep, so no outcome
depends on the machine's load; a time limit on every test; the CPU burners (low priority) are stopped by PID and
reaped.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from pymavlink import mavutil

from tests.integration.instances import Leases
from tests.integration.mission_flight import MISSIONS, fly_mission, mission_drones

pytestmark = [pytest.mark.sim_only]

# A process that only spins, at the lowest priority: it takes every moment the swarm's processes are not running
# (and their caches with it) and is preempted at each of their wake-ups, so the order and timing of everything on
# the machine changes, yet the flight still ends within the test's time. At the same priority each hand-over between
# the supervisor and a drone waits for a burner's time slice, and the flight takes half an hour; at nice 10 the
# loaded flight took 3.5 min, at nice 19 1.8 min. Where the kernel shares the CPU between sessions first (autogroup,
# sitl/harness/zygote.py), a process's nice value ranks it only within its session: a burner in the test's session took
# the whole session's share from the drones (in theirs), so each burner has a session of its own, niced as a whole.
BURN = """import contextlib, os
os.nice(19)
with contextlib.suppress(OSError), open("/proc/self/autogroup", "w") as autogroup:
    autogroup.write("19")
while True:
    pass
"""


def tlog_messages(path: Path) -> list[tuple[int, str, bytes]]:
    """Every message of a flight log: sender, type and bytes (the log's own timestamps left out)."""
    log = mavutil.mavlogfile(str(path))
    out: list[tuple[int, str, bytes]] = []
    while (msg := log.recv_match()) is not None:
        if msg.get_type() != "BAD_DATA":
            out.append((msg.get_srcSystem(), msg.get_type(), bytes(msg.get_msgbuf())))
    return out


@dataclass
class Load:
    cpu_s: float = 0.0  # CPU time the burners got, once the block has ended
    wall_s: float = 0.0
    busy: float = 0.0  # the machine's CPUs, busy for this fraction of the block (all of them, whoever ran)


def cpu_jiffies() -> tuple[int, int]:
    """The machine's CPU time so far, in clock ticks: (idle and waiting for IO, total), from /proc/stat."""
    fields = [int(v) for v in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    return fields[3] + fields[4], sum(fields)


def cpu_time_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime + stime


@contextmanager
def busy_cpus() -> Iterator[Load]:
    """Every CPU kept busy by a process that only spins (BURN), for as long as the block runs."""
    load = Load()
    start = time.monotonic()
    idle_before, total_before = cpu_jiffies()
    burners = [subprocess.Popen([sys.executable, "-c", BURN], start_new_session=True)
               for _ in range(os.cpu_count() or 2)]  # fmt: skip
    try:
        yield load
    finally:
        load.wall_s = time.monotonic() - start
        load.cpu_s = sum(cpu_time_s(proc.pid) for proc in burners)
        idle_after, total_after = cpu_jiffies()
        load.busy = 1.0 - (idle_after - idle_before) / max(total_after - total_before, 1)
        for proc in burners:
            proc.kill()
        for proc in burners:
            proc.wait(timeout=10)


def fly(mission: str, tmp_path: Path, instances: Leases | int, *extra: str) -> tuple[dict[str, Any], Path]:
    args = ["--lockstep", "--drones-per-process", "auto", *extra]
    metrics, _ = fly_mission(mission, args, tmp_path, 600, instances)
    return metrics, tmp_path / "report"


# The swap with neighbours heard both ways (the relay and a 10 m mesh, so the drones across the circle, 12 m apart, are
# out of radio range at first) over a lossy, late, jittery neighbour link: every path a message can take between
# drones is in the flight, so one pair of runs judges the lockstep delivery of all of them.
BOTH_WAYS = """
neighbours = "both"

[swarm.mesh]
range_m = 10

[swarm.links.neighbour]
loss = 0.1
latency_ms = 30
jitter_ms = 20
"""


@pytest.mark.timeout(1300)
@pytest.mark.acceptance  # CPU burners on every core, and two flights of the swap
def test_the_same_lockstep_mission_flies_the_same_on_an_idle_and_a_loaded_machine(
    tmp_path: Path, instances: Leases
) -> None:
    # GIVEN the antipodal swap flown in lockstep with the default seeds, its neighbours relayed and heard over the mesh
    text = (MISSIONS / "antipodal_swap.toml").read_text()
    assert text.count("[swarm]\n") == 1 and "[[steps]]" in text
    mission = tmp_path / "antipodal_swap.toml"
    swarm_end = text.index("[[steps]]")
    mission.write_text(text[:swarm_end] + BOTH_WAYS + "\n" + text[swarm_end:])
    same_instances = instances(mission_drones(mission))  # and the same sysids both times
    first, first_report = fly(str(mission), tmp_path / "idle", same_instances)
    # WHEN it is flown again with the same seeds (on the same instances) while other processes keep every CPU busy
    with busy_cpus() as load:
        second, second_report = fly(str(mission), tmp_path / "loaded", same_instances)
    # (the machine was loaded: no CPU idled while the swarm flew. The burners take every moment the swarm leaves
    # free, but what they get depends on what else runs: alone with the swarm they had 44 of the 90 CPU seconds of a
    # 45 s run; beside another test's flight on the second CPU, 4 of 32)
    assert load.busy > 0.95, load
    # THEN the mesh delivered, and lost reports for every reason the mission allows
    mesh = first["links"]["neighbour mesh"]
    assert mesh["frames_delivered"] > 1000 and mesh["lost_range"] > 0 and mesh["lost_path"] > 0, mesh
    assert mesh["lost_model"] > 0 and mesh["frames_delayed"] > 0, mesh
    # AND both flight logs hold the same messages in the same order
    a, b = tlog_messages(first_report / "flight.tlog"), tlog_messages(second_report / "flight.tlog")
    assert len(a) > 10_000
    first_difference = next((k for k, (x, y) in enumerate(zip(a, b, strict=False)) if x != y), None)
    assert first_difference is None, (first_difference, a[first_difference][:2], b[first_difference][:2])
    assert len(a) == len(b)
    # AND the reports agree to the last digit
    for key in ("min_separation_m", "collisions", "avoidance_events", "distance_flown_m", "steps", "links"):
        assert first[key] == second[key], key


@pytest.mark.timeout(600)
def test_nine_drones_fly_grid_to_circle_with_a_fifth_of_every_link_lost(tmp_path: Path, instances: Leases) -> None:
    # GIVEN every link of every drone losing 20 % of its frames, both ways
    metrics, _ = fly("grid_to_circle.toml", tmp_path, instances, "--link-loss", "0.2")
    # THEN the mission completes without a collision and the circle still holds to 0.3 m RMS
    assert metrics["collisions"] == 0, metrics["collision_events"]
    # (and no drone was ever lost: they all stream enough to be heard within 3 s through any run of lost frames)
    assert metrics["losses"] == [] and metrics["regained"] == [], (metrics["losses"], metrics["regained"])
    circle = next(s for s in metrics["steps"] if s["name"] == "circle")
    assert circle["formation_rms_m"] is not None and circle["formation_rms_m"] < 0.3, circle
    # AND the report counts about a fifth of the frames lost on every channel that carried traffic
    links = metrics["links"]
    assert {"gcs up", "gcs down", "neighbour up"} <= set(links), links
    for name in ("gcs up", "gcs down", "neighbour up"):
        assert links[name]["frames_offered"] > 1000, (name, links[name])
        assert 0.17 < links[name]["loss_rate"] < 0.23, (name, links[name])


@pytest.mark.timeout(600)
def test_the_swap_holds_with_late_and_jittery_neighbour_positions(tmp_path: Path, instances: Leases) -> None:
    # GIVEN neighbour positions arriving 200 ms late with 50 ms of jitter (and so out of order)
    mission = (Path(__file__).resolve().parents[2] / "missions" / "antipodal_swap.toml").read_text()
    mission += "\n[swarm.links.neighbour]\nlatency_ms = 200\njitter_ms = 50\n"
    path = tmp_path / "late_neighbours.toml"
    path.write_text(mission)
    metrics, _ = fly(str(path), tmp_path, instances)
    # THEN nobody collided, and the report shows the delay on neighbour traffic alone
    assert metrics["collisions"] == 0, metrics["collision_events"]
    links = metrics["links"]
    assert set(links) == {"neighbour up"}, links  # only relayed positions go through the neighbour channel
    assert 180.0 < links["neighbour up"]["mean_delay_ms"] < 220.0, links
