"""``swarm bench``: how the swarm scales with N, measured on this machine against bare JSBSim stepping.

For each swarm size N the harness spawns N drones and flies one fixed scenario twice:

- **paced** at speed 1.0: time to ready (first HEARTBEAT and pre-arm checks passed), then arm, take off to 3 m and
  fly a rotating circle with avoidance on for a fixed simulated time. Over that window it measures the real-time
  factor (the drones' own clocks from the shared world against the wall clock), CPU per drone per simulated second
  (/proc/<pid>/stat), its split into physics / control / perception / MAVLink (the drones' own counters in the
  shared world, used to share out the measured total), the supervisor's CPU, memory per drone (PSS), and the clock
  skew between drones. While the circle goes on, it times COMMAND_LONG -> COMMAND_ACK round trips and the relay hop
  (``python -m gcs.bench.probe`` in a process of its own).
- **lockstep** as fast as the CPU allows (SpawnPlan(lockstep=True, speed_factor=0)): the same flight, for the
  simulated seconds per wall second the machine can deliver and the lockstep skew in physics steps.

Every CPU figure is also given as a ratio to bare JSBSim stepping of the same airframe at the same physics rate,
measured in-process in the same run (bench/bare_jsbsim.py does the same in more detail): a machine-independent
way to read the numbers, since absolute milliseconds change with every CPU. The simulation measures that reference
and publishes the drones' clocks and CPU counters; the bench reads both through the harness (gcs/fleet/harness.py), and
everything else about the drones from outside, over MAVLink and /proc.

The module is in two halves: pure figures (statistics, window arithmetic, table, JSON) first, then the IO that
runs swarms and reads /proc. Method and limits are written up in docs/benchmarks.md ("swarm bench").
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.metadata
import json
import math
import os
import platform
import re
import resource
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import Any, Literal, NoReturn

import numpy as np
import numpy.typing as npt
from pymavlink.dialects.v20 import common as mavlink

from gcs.bench.probe import percentile, probe_sysids
from gcs.command.streamer import DEFAULT_LIMITS
from gcs.fleet.harness import MAX_DRONES, Simulation, SpawnError, SpawnPlan, parse_drones_per_process
from gcs.fleet.losses import LossPolicy
from gcs.fleet.relay import DEFAULT_RELAY_SCOPE, RELAY_SCOPE_HELP, RelayScope, scope_argument
from gcs.fleet.swarm import ARM_TIMEOUT_S, Swarm, SwarmError
from gcs.flight.formation import SETPOINT_STREAM_HZ, CircleSpec, FormationError, TransitionLimits
from gcs.flight.geodesy import DEFAULT_ORIGIN
from gcs.mavlink.commands import COMMAND_TIMEOUT_S
from gcs.missions.mission_file import TAKEOFF_ALT_M
from gcs.record.recorder import CollisionPairs
from gcs.record.recording import FlightRecording
from gcs.supervisor import requests as rq
from gcs.supervisor.session import FlightSession
from gcs.supervisor.verbs import carry_out, start

PerProcess = int | Literal["auto"]
DEFAULT_DRONE_COUNTS = (1, 3, 9, 20, 50, 100)
DEFAULT_MODES: tuple[PerProcess, ...] = (1, "auto")  # each N with a process per drone, then hosted
DEFAULT_SIM_SECONDS = 20.0
DEFAULT_FIRST_INSTANCE = 100  # well clear of a user's drones at 0 and of the test suites' blocks
MAX_BENCH_DRONES = MAX_DRONES  # as ``swarm up -n``
SPAWN_SPACING_M = 2.0
CIRCLE_RATE_RADPS = 0.2
CIRCLE_MIN_RADIUS_M = 3.0
CIRCLE_MIN_GAP_M = 2.0  # neighbours on the circle at least this far apart (chord)
LIMIT_HEADROOM = 1.25  # transition limits above the circle's own rim speed and acceleration
REAL_TIME_HELD = 0.98  # rtf_paced at or above this counts as holding real time
PROBE_SECONDS = 3.0
PROBE_EXTRA_WALL_S = 30.0  # the probe's own start-up (imports) on a loaded machine
RTT_MIN_SAMPLES = 20  # command round trips: every drone in turn, as many rounds as give at least this many
RTT_TIMEOUT_S = COMMAND_TIMEOUT_S  # wall seconds per command before it counts as lost (MAVSDK's per-try timeout)
TAKEOFF_BASE_S = 40.0  # the bench's takeoff wait, and TAKEOFF_PER_DRONE_S more per drone: a crowded start is slow
TAKEOFF_PER_DRONE_S = 0.2
CONSISTENT_READ_TRIES = 5
TIME_PUBLISH_STEPS = 4  # each drone publishes its simulated time every 4 physics steps (sitl/world/shared.py)
CPU_PARTS = ("physics", "control", "perception", "mavlink")
EXIT_USAGE = 2
EXIT_FAILED = 1

Say = Callable[[str], None]
FloatArray = npt.NDArray[np.float64]


def _quiet(_text: str) -> None:
    """What a verb says during a bench flight: the bench prints its own lines."""


class BenchUsageError(ValueError):
    """A bad argument: one line for the user."""


# =================================================================================================== pure figures


def parse_drone_counts(text: str) -> tuple[int, ...]:
    """'1,3,9' -> (1, 3, 9): distinct swarm sizes in 1..MAX_BENCH_DRONES, run smallest first."""
    counts: list[int] = []
    for item in text.split(","):
        item = item.strip()
        try:
            n = int(item)
        except ValueError:
            raise BenchUsageError(f"--drones must be whole numbers separated by commas, got {text!r}") from None
        if not 1 <= n <= MAX_BENCH_DRONES:
            raise BenchUsageError(f"--drones values must be in 1..{MAX_BENCH_DRONES}, got {n}")
        if n in counts:
            raise BenchUsageError(f"--drones lists {n} twice")
        counts.append(n)
    return tuple(sorted(counts))


def default_first_instance(largest_n: int, max_instances: int) -> int:
    """``DEFAULT_FIRST_INSTANCE``, or as much lower as the largest swarm needs to fit below ``max_instances``."""
    return max(0, min(DEFAULT_FIRST_INSTANCE, min(max_instances, MAX_DRONES) - largest_n))


def check_instances(first_instance: int, largest_n: int, max_instances: int) -> None:
    """Every drone needs an instance the simulation runs (0..max_instances - 1) and a sysid (instance + 1) that is
    not the ground station's (255). The relay probe's two vehicles take sysids no drone has (``swarm_probe_sysids``)."""
    last = first_instance + largest_n - 1
    top = min(max_instances, MAX_DRONES) - 1
    if first_instance < 0 or last > top:
        raise BenchUsageError(
            f"--first-instance {first_instance} with {largest_n} drones needs instances up to {last}; "
            f"they must lie in 0..{top}"
        )


def swarm_probe_sysids(plan: SpawnPlan) -> tuple[int, int] | None:
    """The relay probe's sysids beside this swarm (None: it leaves no two free, and the relay hop is not timed)."""
    return probe_sysids(range(plan.first_instance + 1, plan.first_instance + plan.n_drones + 1))


def spread(values: Iterable[float]) -> float:
    """max - min of the finite values (NaN when there are none)."""
    finite = [v for v in values if math.isfinite(v)]
    return max(finite) - min(finite) if finite else math.nan


def consistent_read(read: Callable[[], FloatArray], tries: int = CONSISTENT_READ_TRIES) -> FloatArray | None:
    """A column of counters that only grow, as it stood at one instant: read until two reads in a row agree.

    Each cell has its own writer, so one read may mix older and newer cells (a torn read: row a before a step,
    row b after the next one). If two successive reads are equal, every cell held its value from its first read to
    its second, and those intervals all contain the moment between the two reads: the values coexisted. None when
    the column kept moving for ``tries`` reads."""
    previous = read()
    for _ in range(tries - 1):
        current = read()
        if np.array_equal(previous, current):
            return current
        previous = current
    return None


def circle_radius_m(n: int, min_gap_m: float = CIRCLE_MIN_GAP_M, min_radius_m: float = CIRCLE_MIN_RADIUS_M) -> float:
    """Smallest radius at which n evenly spaced slots are at least ``min_gap_m`` apart (chord), and >= the minimum."""
    if n < 2:
        return min_radius_m
    return max(min_radius_m, min_gap_m / (2.0 * math.sin(math.pi / n)))


def circle_limits(radius_m: float, rate_radps: float) -> TransitionLimits:
    """Transition limits the rotating circle itself fits in: the streamer's defaults (1.5 m/s, 1 m/s^2), raised
    with some headroom where a large circle's rim speed (rate x radius) or centripetal acceleration exceeds them."""
    rim_speed = abs(rate_radps) * radius_m
    rim_accel = rate_radps * rate_radps * radius_m
    return dataclasses.replace(
        DEFAULT_LIMITS,
        max_speed_mps=max(DEFAULT_LIMITS.max_speed_mps, LIMIT_HEADROOM * rim_speed),
        max_accel_mps2=max(DEFAULT_LIMITS.max_accel_mps2, LIMIT_HEADROOM * rim_accel),
    )


def proc_stat_cpu_ticks(stat_text: str) -> int:
    """utime + stime (clock ticks) from a /proc/<pid>/stat line; the command name may hold spaces and ')'."""
    rest = stat_text.rpartition(")")[2].split()
    return int(rest[11]) + int(rest[12])  # fields 14 and 15; ``rest`` starts at field 3


def _kb_field(text: str, name: str) -> int | None:
    match = re.search(rf"^{name}:\s+(\d+)\s+kB", text, re.MULTILINE)
    return int(match.group(1)) if match else None


def memory_kb(smaps_rollup: str | None, status: str | None) -> tuple[float, str]:
    """(kB, "pss") from /proc/<pid>/smaps_rollup, else (kB, "rss") from /proc/<pid>/status, else (NaN, "")."""
    if smaps_rollup is not None:
        pss = _kb_field(smaps_rollup, "Pss")
        if pss is not None:
            return float(pss), "pss"
    if status is not None:
        rss = _kb_field(status, "VmRSS")
        if rss is not None:
            return float(rss), "rss"
    return math.nan, ""


@dataclass(frozen=True, slots=True, kw_only=True)
class DroneCounters:
    """One drone at one instant: its own counters from the shared world."""

    parts_s: tuple[float, float, float, float]  # physics, control, perception, MAVLink (drone's monotonic clock)
    sim_time_s: float


@dataclass(frozen=True, slots=True, kw_only=True)
class Snapshot:
    """Everything the window figures need, read at one instant (start or end of the measurement window). CPU is
    per process, in the processes' order of the swarm: one per drone, or fewer when processes host several."""

    wall_s: float
    supervisor_cpu_s: float
    drones: tuple[DroneCounters, ...]
    process_cpu_ticks: tuple[int, ...]


@dataclass(frozen=True, slots=True, kw_only=True)
class WindowFigures:
    """Rates over one measurement window, per drone per simulated second where it says so."""

    sim_s: float  # the slowest drone's simulated time advance
    wall_s: float
    rtf: float
    cpu_ms_per_drone_sim_s: float
    parts_ms_per_drone_sim_s: tuple[float, float, float, float]  # the total shared out in CPU_PARTS order
    parts_coverage: float  # the drones' own part counters / measured process CPU (see docs)
    supervisor_cpu_ms_per_drone_sim_s: float


def window_figures(before: Snapshot, after: Snapshot, clk_tck: float) -> WindowFigures:
    """Real-time factor and CPU rates between two snapshots of the same drones.

    Process CPU comes from the kernel (/proc ticks); the split uses the drones' own counters only as proportions of
    that total, because they are measured with a monotonic clock (time preempted by other processes counts) and
    do not cover the loop's bookkeeping."""
    if len(before.drones) != len(after.drones) or not before.drones:
        raise ValueError("both snapshots must hold the same, non-empty set of drones")
    if len(before.process_cpu_ticks) != len(after.process_cpu_ticks):
        raise ValueError("both snapshots must hold the same processes")
    n = len(before.drones)
    wall = after.wall_s - before.wall_s
    sim = min(d.sim_time_s for d in after.drones) - min(d.sim_time_s for d in before.drones)
    drone_sim = sum(a.sim_time_s - b.sim_time_s for b, a in zip(before.drones, after.drones, strict=True))
    ticks = zip(before.process_cpu_ticks, after.process_cpu_ticks, strict=True)
    cpu_s = sum((a - b) / clk_tck for b, a in ticks)
    parts = [
        sum(a.parts_s[k] - b.parts_s[k] for b, a in zip(before.drones, after.drones, strict=True)) for k in range(4)
    ]
    parts_total = sum(parts)
    cpu_ms = 1e3 * cpu_s / drone_sim if drone_sim > 0 else math.nan
    shares = [p / parts_total for p in parts] if parts_total > 0 else [math.nan] * 4
    supervisor = after.supervisor_cpu_s - before.supervisor_cpu_s
    return WindowFigures(
        sim_s=sim,
        wall_s=wall,
        rtf=sim / wall if wall > 0 else math.nan,
        cpu_ms_per_drone_sim_s=cpu_ms,
        parts_ms_per_drone_sim_s=(shares[0] * cpu_ms, shares[1] * cpu_ms, shares[2] * cpu_ms, shares[3] * cpu_ms),
        parts_coverage=parts_total / cpu_s if cpu_s > 0 else math.nan,
        supervisor_cpu_ms_per_drone_sim_s=1e3 * supervisor / (n * sim) if sim > 0 else math.nan,
    )


@dataclass(frozen=True, slots=True, kw_only=True)
class LatencyFigures:
    """Median / 95th percentile / maximum in milliseconds, with how many were sent and how many came back."""

    median_ms: float = math.nan
    p95_ms: float = math.nan
    max_ms: float = math.nan
    sent: int = 0
    received: int = 0


def latency_figures(latencies_s: Sequence[float], sent: int) -> LatencyFigures:
    ms = [v * 1e3 for v in latencies_s]
    return LatencyFigures(median_ms=percentile(ms, 0.5), p95_ms=percentile(ms, 0.95),
                          max_ms=max(ms) if ms else math.nan, sent=sent, received=len(ms))  # fmt: skip


@dataclass(frozen=True, slots=True, kw_only=True)
class PacedFigures:
    """The paced (speed 1.0) run of one swarm size."""

    ready_s: float
    window: WindowFigures
    memory_mb_mean: float
    memory_mb_max: float
    memory_kind: str  # "pss" or "rss" (fallback)
    command_rtt: LatencyFigures
    relay: LatencyFigures
    clock_skew_median_ms: float
    clock_skew_max_ms: float
    clock_skew_drift_ms: float  # spread at the window's end minus spread at its start
    clock_skew_samples: int
    collisions: int


@dataclass(frozen=True, slots=True, kw_only=True)
class LockstepFigures:
    """The lockstep (as fast as possible) run of one swarm size."""

    ready_s: float
    window: WindowFigures
    skew_max_steps: float
    skew_over_one: int  # samples with a skew above one step (none, if lockstep works)
    skew_samples: int
    collisions: int


@dataclass(frozen=True, slots=True, kw_only=True)
class BenchRow:
    n_drones: int
    circle_radius_m: float
    relay_scope: str  # as --relay-scope takes it
    bare_jsbsim_cpu_ms_per_sim_s: float
    paced: PacedFigures | None = None
    lockstep: LockstepFigures | None = None
    errors: tuple[str, ...] = ()
    drones_per_process: PerProcess = 1  # the setting
    hosts: int = 0  # simulation processes it gave (N for one process per drone)
    drones_per_host: int = 1  # the most drones one of them ran


# Figures in ms CPU per simulated second that are also given as a multiple of bare JSBSim stepping.
CPU_KEYS = (
    "cpu_ms_per_drone_sim_s",
    *(f"{part}_ms_per_drone_sim_s" for part in CPU_PARTS),
    "supervisor_cpu_ms_per_drone_sim_s",
    "cpu_ms_per_drone_sim_s_lockstep",
    "supervisor_cpu_ms_per_drone_sim_s_lockstep",
)


def _finite_or_none(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def row_json(row: BenchRow, physics_rate_hz: float) -> dict[str, Any]:
    """One flat JSON object per swarm size; figures that were not measured are null (JSON has no NaN)."""
    nan = math.nan
    paced, lock = row.paced, row.lockstep
    pw = paced.window if paced is not None else None
    lw = lock.window if lock is not None else None
    rtt = paced.command_rtt if paced is not None else LatencyFigures()
    relay = paced.relay if paced is not None else LatencyFigures()
    out: dict[str, Any] = {
        "n_drones": row.n_drones,
        "drones_per_process": row.drones_per_process,
        "hosts": row.hosts,
        "drones_per_host": row.drones_per_host,
        "ready_s": paced.ready_s if paced else nan,
        "rtf_paced": pw.rtf if pw else nan,
        "held_real_time": bool(pw is not None and pw.rtf >= REAL_TIME_HELD),
        "rtf_unpaced": lw.rtf if lw else nan,
        "cpu_ms_per_drone_sim_s": pw.cpu_ms_per_drone_sim_s if pw else nan,
        "bare_jsbsim_cpu_ms_per_sim_s": row.bare_jsbsim_cpu_ms_per_sim_s,
    }
    for part, value in zip(CPU_PARTS, pw.parts_ms_per_drone_sim_s if pw else (nan,) * 4, strict=True):
        out[f"{part}_ms_per_drone_sim_s"] = value
    out |= {
        "cpu_split_coverage": pw.parts_coverage if pw else nan,
        "supervisor_cpu_ms_per_drone_sim_s": pw.supervisor_cpu_ms_per_drone_sim_s if pw else nan,
        "memory_mb_per_drone": paced.memory_mb_mean if paced else nan,
        "memory_mb_max": paced.memory_mb_max if paced else nan,
        "memory_kind": paced.memory_kind if paced else "",
        "cmd_rtt_median_ms": rtt.median_ms,
        "cmd_rtt_p95_ms": rtt.p95_ms,
        "cmd_rtt_max_ms": rtt.max_ms,
        "cmd_rtt_sent": rtt.sent,
        "cmd_rtt_received": rtt.received,
        "relay_median_ms": relay.median_ms,
        "relay_p95_ms": relay.p95_ms,
        "relay_max_ms": relay.max_ms,
        "relay_sent": relay.sent,
        "relay_received": relay.received,
        "clock_skew_median_ms": paced.clock_skew_median_ms if paced else nan,
        "clock_skew_max_ms": paced.clock_skew_max_ms if paced else nan,
        "clock_skew_drift_ms": paced.clock_skew_drift_ms if paced else nan,
        "clock_skew_samples": paced.clock_skew_samples if paced else 0,
        "clock_skew_quantum_ms": 1e3 * TIME_PUBLISH_STEPS / physics_rate_hz,
        "sim_s_paced": pw.sim_s if pw else nan,
        "wall_s_paced": pw.wall_s if pw else nan,
        "collisions_paced": paced.collisions if paced else 0,
        "ready_s_lockstep": lock.ready_s if lock else nan,
        "sim_s_unpaced": lw.sim_s if lw else nan,
        "wall_s_unpaced": lw.wall_s if lw else nan,
        "cpu_ms_per_drone_sim_s_lockstep": lw.cpu_ms_per_drone_sim_s if lw else nan,
        "supervisor_cpu_ms_per_drone_sim_s_lockstep": lw.supervisor_cpu_ms_per_drone_sim_s if lw else nan,
        "lockstep_skew_max_steps": lock.skew_max_steps if lock else nan,
        "lockstep_skew_over_one": lock.skew_over_one if lock else 0,
        "lockstep_skew_samples": lock.skew_samples if lock else 0,
        "collisions_lockstep": lock.collisions if lock else 0,
        "circle_radius_m": row.circle_radius_m,
        "circle_rate_radps": CIRCLE_RATE_RADPS,
        "relay_scope": row.relay_scope,
        "errors": list(row.errors),
    }
    bare = row.bare_jsbsim_cpu_ms_per_sim_s
    for key in CPU_KEYS:
        value = out[key]
        out[f"{key}_x_bare"] = value / bare if bare > 0 and math.isfinite(value) else nan
    return {k: _finite_or_none(v) for k, v in out.items()}


def largest_real_time(rows: Sequence[Mapping[str, Any]]) -> int | None:
    """The largest N whose paced run held real time (rtf_paced >= 0.98)."""
    held = [r["n_drones"] for r in rows if r.get("held_real_time")]
    return max(held) if held else None


def largest_real_time_by_mode(rows: Sequence[Mapping[str, Any]]) -> dict[str, int | None]:
    """``largest_real_time`` for each drones-per-process setting benched (keys "1", "auto", ...)."""
    modes = dict.fromkeys(str(r.get("drones_per_process", 1)) for r in rows)
    return {m: largest_real_time([r for r in rows if str(r.get("drones_per_process", 1)) == m]) for m in modes}


def mode_label(mode: PerProcess | str) -> str:
    """How a drones-per-process setting is named in the summary line."""
    return "a process per drone" if str(mode) == "1" else f"{mode} drones per process"


def bench_document(rows: Sequence[BenchRow], machine: Mapping[str, Any], sim_seconds: float,
                   physics_rate_hz: float) -> dict[str, Any]:  # fmt: skip
    """The JSON file: ``{"rows": [...], "machine": {...}, ...}``."""
    flat = [row_json(r, physics_rate_hz) for r in rows]
    return {
        "rows": flat,
        "machine": dict(machine),
        "sim_seconds": sim_seconds,
        "real_time_threshold": REAL_TIME_HELD,
        "largest_n_real_time": largest_real_time_by_mode(flat),
    }


def _cell(value: Any, fmt: str) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return format(value, fmt)


# (header, JSON key or a pair of keys shown as a/b, format)
TABLE_COLUMNS: tuple[tuple[str, str | tuple[str, str], str], ...] = (
    ("N", "n_drones", "d"),
    ("hosts", "hosts", "d"),
    ("per host", "drones_per_host", "d"),
    ("ready s", "ready_s", ".1f"),
    ("rtf paced", "rtf_paced", ".3f"),
    ("rtf lockstep", "rtf_unpaced", ".2f"),
    ("cpu ms", "cpu_ms_per_drone_sim_s", ".1f"),
    ("x bare", "cpu_ms_per_drone_sim_s_x_bare", ".1f"),
    ("phys", "physics_ms_per_drone_sim_s", ".1f"),
    ("ctrl", "control_ms_per_drone_sim_s", ".1f"),
    ("perc", "perception_ms_per_drone_sim_s", ".1f"),
    ("link", "mavlink_ms_per_drone_sim_s", ".1f"),
    ("sup", "supervisor_cpu_ms_per_drone_sim_s", ".2f"),
    ("MB", "memory_mb_per_drone", ".0f"),
    ("cmd ms p50/p95", ("cmd_rtt_median_ms", "cmd_rtt_p95_ms"), ".1f"),
    ("relay ms p50/p95", ("relay_median_ms", "relay_p95_ms"), ".2f"),
    ("skew ms", "clock_skew_max_ms", ".0f"),
    ("ls skew", "lockstep_skew_max_steps", ".0f"),
)


def format_table(rows: Sequence[Mapping[str, Any]]) -> str:
    """One line per swarm size; '-' where a figure was not measured. CPU columns are ms per drone per sim second."""
    header = [h for h, _, _ in TABLE_COLUMNS] + ["held"]
    lines = [header]
    for r in rows:
        cells = []
        for _, key, fmt in TABLE_COLUMNS:
            if isinstance(key, tuple):
                cells.append(f"{_cell(r.get(key[0]), fmt)}/{_cell(r.get(key[1]), fmt)}")
            else:
                cells.append(_cell(r.get(key), fmt))
        cells.append("yes" if r.get("held_real_time") else "no")
        lines.append(cells)
    widths = [max(len(line[i]) for line in lines) for i in range(len(header))]
    return "\n".join("  ".join(c.rjust(w) for c, w in zip(line, widths, strict=True)) for line in lines)


# =================================================================================================== IO


def _read(path: str) -> str | None:
    try:
        with open(path) as handle:
            return handle.read()
    except OSError:
        return None


def _supervisor_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def take_snapshot(swarm: Swarm) -> Snapshot:
    """Every drone's process CPU (/proc), its CPU by part and its clock as it publishes them (through the harness),
    and the supervisor's own CPU."""
    harness = swarm.harness
    parts_s = harness.cpu_parts_s()
    times_s, _ = harness.clock_columns()
    drones = []
    for k in range(len(swarm.liveness.sysids)):
        parts = (float(parts_s[k, 0]), float(parts_s[k, 1]), float(parts_s[k, 2]), float(parts_s[k, 3]))
        drones.append(DroneCounters(parts_s=parts, sim_time_s=float(times_s[k])))
    ticks = []
    for pid in process_ids(swarm):
        text = _read(f"/proc/{pid}/stat")
        if text is None:
            raise SwarmError(f"drone process {pid} is gone: cannot measure it")
        ticks.append(proc_stat_cpu_ticks(text))
    return Snapshot(wall_s=time.monotonic(), supervisor_cpu_s=_supervisor_cpu_s(), drones=tuple(drones),
                    process_cpu_ticks=tuple(ticks))  # fmt: skip


def process_ids(swarm: Swarm) -> list[int]:
    """The processes that run the swarm's drones, each once (a host runs several), in spawn order."""
    return list(dict.fromkeys(swarm.harness.process_ids()[s] for s in swarm.liveness.sysids))


def drone_memory(swarm: Swarm) -> tuple[list[float], str]:
    """Each drone's proportional set size in MB (resident size where smaps_rollup is not available); a host's is
    shared out equally between its drones."""
    pids = swarm.harness.process_ids()
    per_process = {pid: sum(1 for s in swarm.liveness.sysids if pids[s] == pid) for pid in process_ids(swarm)}
    sizes, kinds = [], set()
    for pid, drones in per_process.items():
        kb, kind = memory_kb(_read(f"/proc/{pid}/smaps_rollup"), _read(f"/proc/{pid}/status"))
        sizes += [kb / 1024.0 / drones] * drones
        kinds.add(kind)
    return sizes, "rss" if "rss" in kinds else "pss"


def _package_version(name: str) -> str:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return ""


def machine_info(physics_rate_hz: float) -> dict[str, Any]:
    cpuinfo = _read("/proc/cpuinfo") or ""
    model = re.search(r"^model name\s*:\s*(.+)$", cpuinfo, re.MULTILINE)
    try:
        import jsbsim

        jsbsim_version = str(jsbsim.__version__)
    except ImportError:  # pragma: no cover - a dependency
        jsbsim_version = ""
    return {
        "cpu_model": model.group(1).strip() if model else platform.processor(),
        # the drones' compiled kernels and their arrays: read from the installed metadata, not imported
        "numba": _package_version("numba"),
        "numpy": _package_version("numpy"),
        "logical_cpus": os.cpu_count(),
        "usable_cpus": len(os.sched_getaffinity(0)),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "jsbsim": jsbsim_version,
        "physics_rate_hz": physics_rate_hz,
        "clk_tck": os.sysconf("SC_CLK_TCK"),
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


@dataclass(kw_only=True)
class BenchConfig:
    simulation: Simulation  # what starts the drones (gcs/composition.py)
    drone_counts: tuple[int, ...]
    sim_seconds: float
    # Each N is run with each of these drones-per-process settings (1: a process per drone; K; "auto")
    modes: tuple[PerProcess, ...] = DEFAULT_MODES
    first_instance: int = DEFAULT_FIRST_INSTANCE
    seed: int = 0
    json_path: Path | None = None
    plot_path: Path | None = None
    relay_scope: RelayScope = DEFAULT_RELAY_SCOPE  # as swarm up and swarm fly relay by default


@dataclass(kw_only=True)
class _ClockSamples:
    time_spreads_ms: list[float] = field(default_factory=list)
    step_spreads: list[float] = field(default_factory=list)


class ScenarioFlight:
    """One swarm flying the bench scenario: ready, arm, take off, rotating circle; measured from outside."""

    def __init__(self, n: int, config: BenchConfig, *, lockstep: bool, mode: PerProcess = 1) -> None:
        self.n = n
        self.lockstep = lockstep
        plan = SpawnPlan(
            n_drones=n,
            spacing_m=SPAWN_SPACING_M,
            origin=DEFAULT_ORIGIN,
            speed_factor=0.0 if lockstep else 1.0,
            lockstep=lockstep,
            first_instance=config.first_instance,
            seed=config.seed,
            drones_per_process=mode,
        )
        self.swarm = Swarm(plan, config.simulation.harness(plan), relay=config.relay_scope)
        self.radius_m = circle_radius_m(n)
        # a front-end like the others: a flight session, flown with requests (gcs/supervisor/requests.py); its clock
        # is the swarm's own (mission time zero at the swarm's zero), and nothing is recorded
        recording = FlightRecording(mission_name="bench", n_drones=n, collision_radius_m=0.0)
        self.session = FlightSession(self.swarm, _quiet, recording, LossPolicy.CONTINUE, t0_s=0.0,
                                     limits=circle_limits(self.radius_m, CIRCLE_RATE_RADPS))  # fmt: skip
        self.session.waiting_tick = self.tick
        self.sampling = False
        self.samples = _ClockSamples()
        self._collisions = CollisionPairs()
        self.swarm.router.listeners.append(self._on_message)

    @property
    def collisions(self) -> int:
        return len(self._collisions)

    def _on_message(self, msg: Any, _now: float) -> None:
        if msg.get_type() == "STATUSTEXT":
            self._collisions.observe(msg.get_srcSystem(), msg.text)

    def tick(self, now: float) -> None:
        """Stream setpoints; while measuring, sample every drone's clock (TIME) and lockstep step count (STEP)."""
        self.session.tick(now)
        if self.sampling:
            columns = self.swarm.harness.clock_columns
            times = consistent_read(lambda: columns()[0])
            if times is not None:
                self.samples.time_spreads_ms.append(1e3 * spread(times))
            if self.lockstep:
                steps = consistent_read(lambda: columns()[1])
                if steps is not None:
                    self.samples.step_spreads.append(spread(steps))

    def ready(self) -> float:
        """Spawn and wait for every drone's first HEARTBEAT and passed pre-arm checks; wall seconds from spawn."""
        start = time.monotonic()
        self.swarm.up(ready_timeout_s=30.0 + 2.0 * self.n)  # start-up is CPU-bound: N Python processes importing
        self.swarm.commands.wait_prearm(ARM_TIMEOUT_S + 1.0 * self.n, every=True)
        return time.monotonic() - start

    def take_off(self) -> None:
        takeoff = rq.Takeoff(timeout_s=TAKEOFF_BASE_S + TAKEOFF_PER_DRONE_S * self.n)  # to the usual altitude
        carry_out(start(self.session, takeoff), self._wait)

    def _wait(self, condition: Callable[[], bool], timeout_s: float) -> bool:
        return self.swarm.pump.wait_until(condition, timeout_s, tick=self.tick)

    def circle_window(self, sim_seconds: float) -> tuple[Snapshot, Snapshot]:
        """Command the rotating circle and fly it for ``sim_seconds`` (supervisor clock), snapshots at both ends."""
        spec = CircleSpec(radius_m=self.radius_m, alt_m=TAKEOFF_ALT_M, angular_rate_radps=CIRCLE_RATE_RADPS)
        start(self.session, rq.FlyFormation(formation=spec))
        before = take_snapshot(self.swarm)
        self.sampling = True
        self.swarm.pump.run_for(sim_seconds, tick=self.tick, tick_s=1.0 / SETPOINT_STREAM_HZ)
        self.sampling = False
        return before, take_snapshot(self.swarm)

    def keep_flying(self, seconds: float) -> None:
        self.swarm.pump.run_for(seconds, tick=self.tick, tick_s=1.0 / SETPOINT_STREAM_HZ)

    def command_round_trips(self) -> LatencyFigures:
        """COMMAND_LONG (REQUEST_MESSAGE for HOME_POSITION: harmless) to each drone in turn, timed to its ACK.

        Times are the supervisor's wall clock at send and at parsing the COMMAND_ACK, so they include the drone's
        wake-up, its handling and both UDP hops, as a ground station sees them."""
        swarm = self.swarm
        acked: dict[int, float] = {}
        command = mavlink.MAV_CMD_REQUEST_MESSAGE

        def on_ack(msg: Any, _now: float) -> None:
            if msg.get_type() == "COMMAND_ACK" and msg.command == command:
                acked.setdefault(msg.get_srcSystem(), time.monotonic())

        swarm.router.listeners.append(on_ack)
        rtts: list[float] = []
        sent = 0
        next_tick = swarm.clock.now()
        try:
            for _ in range(math.ceil(RTT_MIN_SAMPLES / self.n)):
                for sysid in swarm.liveness.sysids:
                    acked.pop(sysid, None)
                    message = mavlink.MAVLink_command_long_message(
                        sysid, 1, command, 0, float(mavlink.MAVLINK_MSG_ID_HOME_POSITION), 0, 0, 0, 0, 0, 0
                    )
                    start = time.monotonic()
                    swarm.router.send_now(sysid, message)
                    sent += 1
                    while sysid not in acked and time.monotonic() - start < RTT_TIMEOUT_S:
                        if (now := swarm.clock.now()) >= next_tick:
                            self.tick(now)
                            next_tick = now + 1.0 / SETPOINT_STREAM_HZ
                        swarm.pump.once(0.002, gather=False)  # the round trip itself is timed
                    if sysid in acked:
                        rtts.append(acked[sysid] - start)
        finally:
            swarm.router.listeners.remove(on_ack)
        return latency_figures(rtts, sent)

    def relay_latency(self) -> LatencyFigures:
        """``python -m gcs.bench.probe PORT`` in a process of its own while this supervisor keeps pumping and streaming
        (no figures when the swarm leaves the probe no two sysids of its own)."""
        sysids = swarm_probe_sysids(self.swarm.plan)
        if sysids is None:
            return LatencyFigures()
        origin = self.swarm.plan.origin
        cmd = [sys.executable, "-m", "gcs.bench.probe", str(self.swarm.link.port), "--seconds", f"{PROBE_SECONDS:g}",
               "--anchor", f"{origin.lat_deg:.7f},{origin.lon_deg:.7f},{origin.alt_amsl_m:.2f}",
               "--sysids", f"{sysids[0]},{sysids[1]}"]  # fmt: skip
        probe = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + PROBE_SECONDS + PROBE_EXTRA_WALL_S
            while probe.poll() is None and time.monotonic() < deadline:
                self.keep_flying(0.1)
        finally:
            if probe.poll() is None:
                probe.kill()
            out, err = probe.communicate()
        if probe.returncode != 0:
            detail = (err.strip().splitlines() or ["no output"])[-1]
            raise SwarmError(f"relay probe failed (exit {probe.returncode}): {detail}")
        result = json.loads(out.strip().splitlines()[-1])
        return LatencyFigures(
            median_ms=_float(result.get("median_ms")),
            p95_ms=_float(result.get("p95_ms")),
            max_ms=_float(result.get("max_ms")),
            sent=int(result.get("sent", 0)),
            received=int(result.get("received", 0)),
        )

    def stop(self) -> None:
        """Stop streaming, disarm forcibly (no landing: nothing is measured any more), then shut everything down."""
        swarm = self.swarm
        try:
            self.session.streamer.stop()
            if swarm.liveness.sysids:
                armed = swarm.liveness.armed_sysids()
                if armed:
                    swarm.commands.force_disarm(armed)
                    swarm.pump.wait_until(lambda: not swarm.liveness.armed_sysids(armed), 3.0)
        except (SwarmError, OSError):
            pass  # shutdown below still terminates and reaps every process
        finally:
            swarm.shutdown(land_timeout_s=5.0)


def _float(value: Any) -> float:
    return float(value) if value is not None else math.nan


RUN_ERRORS = (SwarmError, SpawnError, FormationError, OSError, subprocess.SubprocessError, ValueError)


def run_paced(n: int, config: BenchConfig, say: Say, mode: PerProcess = 1) -> PacedFigures:
    flight = ScenarioFlight(n, config, lockstep=False, mode=mode)
    try:
        ready_s = flight.ready()
        say(f"  paced: {n} ready in {ready_s:.1f} s; arming and taking off")
        flight.take_off()
        say(f"  paced: circle r={flight.radius_m:.1f} m at {CIRCLE_RATE_RADPS:g} rad/s for {config.sim_seconds:g} s")
        before, after = flight.circle_window(config.sim_seconds)
        window = window_figures(before, after, float(os.sysconf("SC_CLK_TCK")))
        sizes, kind = drone_memory(flight.swarm)
        spreads = flight.samples.time_spreads_ms
        if swarm_probe_sysids(flight.swarm.plan) is None:
            say(f"  paced: rtf {window.rtf:.3f}; timing command round trips (the relay hop is not: {n} drones leave "
                "the probe no two sysids)")  # fmt: skip
        else:
            say(f"  paced: rtf {window.rtf:.3f}; timing command round trips and the relay hop")
        rtt = flight.command_round_trips()
        relay = flight.relay_latency()
        return PacedFigures(
            ready_s=ready_s,
            window=window,
            memory_mb_mean=float(np.mean(sizes)),
            memory_mb_max=max(sizes),
            memory_kind=kind,
            command_rtt=rtt,
            relay=relay,
            clock_skew_median_ms=percentile(spreads, 0.5),
            clock_skew_max_ms=max(spreads) if spreads else math.nan,
            clock_skew_drift_ms=spreads[-1] - spreads[0] if spreads else math.nan,
            clock_skew_samples=len(spreads),
            collisions=flight.collisions,
        )
    finally:
        flight.stop()


def run_lockstep(n: int, config: BenchConfig, say: Say, mode: PerProcess = 1) -> LockstepFigures:
    flight = ScenarioFlight(n, config, lockstep=True, mode=mode)
    try:
        ready_s = flight.ready()
        flight.take_off()
        before, after = flight.circle_window(config.sim_seconds)
        window = window_figures(before, after, float(os.sysconf("SC_CLK_TCK")))
        steps = flight.samples.step_spreads
        say(f"  lockstep: rtf {window.rtf:.2f} (as fast as possible)")
        return LockstepFigures(
            ready_s=ready_s,
            window=window,
            skew_max_steps=max(steps) if steps else math.nan,
            skew_over_one=sum(1 for s in steps if s > 1),
            skew_samples=len(steps),
            collisions=flight.collisions,
        )
    finally:
        flight.stop()


def bench_one(n: int, config: BenchConfig, say: Say, mode: PerProcess, bare: float, hosts: list[int]) -> BenchRow:
    """Both runs of one swarm size with one drones-per-process setting; ``bare`` is the bare JSBSim reference
    measured just before them, ``hosts`` the drones each process runs."""
    say(f"N={n}, drones per process {mode}: {len(hosts)} process(es) of {max(hosts)} drone(s) at most")
    paced: PacedFigures | None = None
    lock: LockstepFigures | None = None
    errors: list[str] = []
    try:
        paced = run_paced(n, config, say, mode)
    except RUN_ERRORS as exc:
        errors.append(f"paced: {exc}")
        say(f"  paced: failed: {exc}")
    try:
        lock = run_lockstep(n, config, say, mode)
    except RUN_ERRORS as exc:
        errors.append(f"lockstep: {exc}")
        say(f"  lockstep: failed: {exc}")
    return BenchRow(n_drones=n, circle_radius_m=circle_radius_m(n), relay_scope=config.relay_scope.text(),
                    bare_jsbsim_cpu_ms_per_sim_s=bare, paced=paced, lockstep=lock, errors=tuple(errors),
                    drones_per_process=mode, hosts=len(hosts), drones_per_host=max(hosts))  # fmt: skip


def bench_size(n: int, config: BenchConfig, say: Say) -> list[BenchRow]:
    """Every drones-per-process setting for one swarm size, side by side; a setting that would share the drones out
    exactly as one already run (``auto`` with no more drones than CPUs is one process per drone) is not run again."""
    bare = config.simulation.bare_plant_cpu_ms_per_sim_s()
    say(f"N={n}: bare JSBSim {bare:.2f} ms CPU per simulated second")
    rows: list[BenchRow] = []
    seen: list[list[int]] = []
    for mode in config.modes:
        sharing = config.simulation.drones_per_host(n, mode)
        if sharing in seen:
            say(f"N={n}, drones per process {mode}: the same processes as a setting already run; skipped")
            continue
        seen.append(sharing)
        rows.append(bench_one(n, config, say, mode, bare, sharing))
    return rows


def write_plot(rows: Sequence[Mapping[str, Any]], path: Path) -> None:
    """Real-time factors and CPU per drone against N, with bare JSBSim stepping as the floor (PNG, Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import ticker

    modes = list(dict.fromkeys(str(r.get("drones_per_process", 1)) for r in rows))

    def series(key: str, mode: str | None = None) -> tuple[list[int], list[float]]:
        chosen = [r for r in rows if mode is None or str(r.get("drones_per_process", 1)) == mode]
        pts = [(r["n_drones"], r[key]) for r in chosen if r.get(key) is not None]
        return [p[0] for p in pts], [float(p[1]) for p in pts]

    fig, (ax_rtf, ax_cpu) = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    for mode in modes:
        for key, label, marker in (("rtf_paced", "paced", "o"), ("rtf_unpaced", "lockstep", "s")):
            xs, ys = series(key, mode)
            ax_rtf.plot(xs, ys, marker=marker, label=f"{label}, {mode_label(mode)}")
    ax_rtf.axhline(1.0, color="grey", linewidth=0.8)
    ax_rtf.axhline(REAL_TIME_HELD, color="grey", linewidth=0.8, linestyle=":", label=f"{REAL_TIME_HELD:g} (held)")
    ax_rtf.set(xscale="log", yscale="log", xlabel="drones N", ylabel="simulated s per wall s", title="real-time factor")
    finite = [float(r[k]) for r in rows for k in ("rtf_paced", "rtf_unpaced") if r.get(k) is not None] or [1.0]
    ax_rtf.set_ylim(min(0.5, 0.8 * min(finite)), max(2.0, 1.25 * max(finite)))  # always shows 0.5, 1 and 2
    ax_rtf.legend(fontsize="small")
    for mode in modes:
        for key, label, marker in (
            ("cpu_ms_per_drone_sim_s", "drone, paced", "o"),
            ("cpu_ms_per_drone_sim_s_lockstep", "drone, lockstep", "s"),
            ("supervisor_cpu_ms_per_drone_sim_s", "supervisor, paced", "^"),
        ):
            xs, ys = series(key, mode)
            ax_cpu.plot(xs, ys, marker=marker, label=f"{label}, {mode_label(mode)}")
    xs, ys = series("bare_jsbsim_cpu_ms_per_sim_s")
    ax_cpu.plot(xs, ys, color="black", linestyle="--", label="bare JSBSim plant")
    ax_cpu.set(xscale="log", yscale="log", xlabel="drones N", ylabel="ms CPU per drone per simulated s",
               title="CPU per drone")  # fmt: skip
    ax_cpu.legend()
    counts = sorted({int(r["n_drones"]) for r in rows})
    for ax in (ax_rtf, ax_cpu):
        ax.grid(True, which="both", alpha=0.3)
        ax.set_xticks(counts, [str(n) for n in counts])
        ax.xaxis.set_minor_formatter(ticker.NullFormatter())
        ax.yaxis.set_major_locator(ticker.LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
        ax.yaxis.set_major_formatter(ticker.FormatStrFormatter("%g"))
        ax.yaxis.set_minor_formatter(ticker.NullFormatter())
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(config: BenchConfig, say: Say) -> tuple[dict[str, Any], bool]:
    """Bench every swarm size in turn; returns the JSON document and whether every run succeeded."""
    machine = machine_info(config.simulation.physics_rate_hz)
    machine["loadavg_before"] = list(os.getloadavg())
    rows: list[BenchRow] = []
    try:
        for n in config.drone_counts:
            rows += bench_size(n, config, say)
    finally:
        machine["loadavg_after"] = list(os.getloadavg())
        document = bench_document(rows, machine, config.sim_seconds, config.simulation.physics_rate_hz)
        say("")
        say(format_table(document["rows"]))
        largest = ", ".join(f"{mode_label(mode)}: {n or 'none'}" for mode, n in document["largest_n_real_time"].items())
        say(
            f"largest N that held real time (rtf >= {REAL_TIME_HELD:g}): {largest or 'none'}; load average "
            f"before {machine['loadavg_before'][0]:.2f}, after {machine['loadavg_after'][0]:.2f}"
        )
        if config.json_path is not None:
            config.json_path.parent.mkdir(parents=True, exist_ok=True)
            config.json_path.write_text(json.dumps(document, indent=2) + "\n")
            say(f"JSON in {config.json_path}")
        if config.plot_path is not None and rows:
            write_plot(document["rows"], config.plot_path)
            say(f"plot in {config.plot_path}")
    return document, all(not r.errors for r in rows)


# =================================================================================================== command line


def _drone_counts_arg(text: str) -> tuple[int, ...]:
    try:
        return parse_drone_counts(text)
    except BenchUsageError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--drones ")) from None


def _sim_seconds_arg(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(value) and 0.0 < value <= 3600.0):
        raise argparse.ArgumentTypeError(f"must be in (0, 3600] simulated seconds, got {text!r}")
    return value


def _configure(parser: argparse.ArgumentParser) -> None:
    default_counts = ",".join(map(str, DEFAULT_DRONE_COUNTS))
    parser.add_argument("--drones", type=_drone_counts_arg, default=DEFAULT_DRONE_COUNTS, metavar="N,N,...",
                        help=f"swarm sizes to bench, comma separated (default {default_counts})")  # fmt: skip
    parser.add_argument(
        "--sim-seconds",
        type=_sim_seconds_arg,
        default=DEFAULT_SIM_SECONDS,
        metavar="S",
        help=f"simulated seconds of circle flight measured per run (default {DEFAULT_SIM_SECONDS:g})",
    )
    parser.add_argument("--json", type=Path, default=None, metavar="FILE", help="write the results as JSON")
    parser.add_argument("--plot", type=Path, default=None, metavar="FILE", help="write the scaling plot (PNG)")
    parser.add_argument(
        "--first-instance",
        type=int,
        default=None,
        metavar="I",
        help=f"instance of the first drone (sysid = instance+1; default {DEFAULT_FIRST_INSTANCE}, or lower when the "
        "largest swarm would not fit above it)",
    )
    parser.add_argument("--seed", type=int, default=0, help="base random seed (the k-th drone, from 0, uses seed+k)")
    parser.add_argument("--relay-scope", type=scope_argument, default=DEFAULT_RELAY_SCOPE, metavar="SCOPE",
                        help=RELAY_SCOPE_HELP)  # fmt: skip
    parser.add_argument(
        "--drones-per-process",
        type=_modes_arg,
        default=DEFAULT_MODES,
        metavar="K|auto[,...]",
        help="drones per simulation process, each setting benched side by side (default 1,auto)",
    )


def _modes_arg(text: str) -> tuple[PerProcess, ...]:
    modes: list[PerProcess] = []
    for item in text.split(","):
        try:
            mode = parse_drones_per_process(item.strip())
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
        if mode in modes:
            raise argparse.ArgumentTypeError(f"lists {mode} twice")
        modes.append(mode)
    return tuple(modes)


def add_bench_parser(sub: Any) -> None:
    """Add ``bench`` to the ``swarm`` command's subparsers (``sub`` is what ``add_subparsers`` returned)."""
    bench = sub.add_parser("bench", help="measure how the swarm scales with N (real-time factor, CPU, latency)")
    _configure(bench)


def _interrupt(_signum: int, _frame: FrameType | None) -> NoReturn:
    raise KeyboardInterrupt


def _say(text: str) -> None:
    print(text, flush=True)


def run_bench(args: argparse.Namespace, simulation: Simulation) -> int:
    """``swarm bench``: 0 when every run succeeded, 1 when one failed, 2 for bad arguments, 130 when interrupted."""
    if args.first_instance is None:
        args.first_instance = default_first_instance(max(args.drones), simulation.max_instances)
    try:
        check_instances(args.first_instance, max(args.drones), simulation.max_instances)
    except BenchUsageError as exc:
        print(f"swarm bench: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    config = BenchConfig(simulation=simulation, drone_counts=tuple(args.drones), sim_seconds=args.sim_seconds,
                         first_instance=args.first_instance, seed=args.seed, json_path=args.json,
                         plot_path=args.plot, modes=tuple(args.drones_per_process),
                         relay_scope=args.relay_scope)  # fmt: skip
    previous = signal.signal(signal.SIGTERM, _interrupt)  # a terminated bench stops its drones like Ctrl-C
    try:
        _, ok = run(config, _say)
    except KeyboardInterrupt:
        print("swarm bench: interrupted; every drone stopped", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)
    return 0 if ok else EXIT_FAILED
