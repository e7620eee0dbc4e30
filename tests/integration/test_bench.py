"""``swarm bench`` for real: N = 1 and 2 for a few simulated seconds, paced and in lockstep; and bench/wakeups.py (the
machine's price of a wake-up), which forks flights of its own and must reap them.

Policy: loopback only; two leased instances (tests/integration/instances.py); the bench runs as its own process
(``python -m gcs.cli bench``) and must leave no drone behind. What is checked is the shape of the result and that
every figure was actually measured (finite, positive, consistent with the others); the figures themselves depend on
the machine and are not asserted.
"""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from gcs.bench.scaling import CPU_KEYS, CPU_PARTS
from tests.integration.instances import Leases

pytestmark = [pytest.mark.sim_only, pytest.mark.timeout(330)]

REPO = Path(__file__).resolve().parents[2]
WAKEUPS = REPO / "bench" / "wakeups.py"
WAKEUP_ROW = re.compile(r"^(\d+ process(?:es)?, [a-z ,0-9]+?) +([\d.]+) +([\d.]+) +([\d.]+) +([\d.]+)", re.MULTILINE)
SIM_SECONDS = 3.0
POSITIVE = (
    "ready_s",
    "rtf_paced",
    "rtf_unpaced",
    "cpu_ms_per_drone_sim_s",
    "bare_jsbsim_cpu_ms_per_sim_s",
    "supervisor_cpu_ms_per_drone_sim_s",
    "cpu_ms_per_drone_sim_s_lockstep",
    "memory_mb_per_drone",
    "cmd_rtt_median_ms",
    "relay_median_ms",
    "sim_s_paced",
    "wall_s_paced",
    "sim_s_unpaced",
    "wall_s_unpaced",
    *(f"{part}_ms_per_drone_sim_s" for part in CPU_PARTS),
    *(f"{key}_x_bare" for key in CPU_KEYS),
)


def sitl_processes_of(instances: set[int]) -> list[int]:
    """PIDs of any running ``sitl`` with one of these instance numbers (only this test uses them)."""
    found = []
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            argv = Path(entry.path, "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"sitl.cli" in argv and b"--instance" in argv:
            index = argv.index(b"--instance") + 1
            if index < len(argv) and argv[index].isdigit() and int(argv[index]) in instances:
                found.append(int(entry.name))
    return found


def test_bench_measures_every_figure_for_each_swarm_size_and_leaves_nothing_behind(
    tmp_path: Path, instances: Leases
) -> None:
    json_path, plot_path = tmp_path / "bench.json", tmp_path / "bench.png"
    first = instances(2)
    # GIVEN no drone of ours running WHEN the bench runs N = 2 for a few simulated seconds, each drone in its own
    # process and both hosted by one
    assert sitl_processes_of({first, first + 1}) == []
    cmd = [sys.executable, "-m", "gcs.cli", "bench", "--drones", "2", "--drones-per-process", "1,2",
           "--sim-seconds", str(SIM_SECONDS), "--first-instance", str(first), "--json", str(json_path),
           "--plot", str(plot_path)]  # fmt: skip
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=310)
    # THEN it succeeds, prints one table row per setting, and every drone it started is gone
    assert result.returncode == 0, result.stdout + result.stderr
    assert sitl_processes_of({first, first + 1}) == []
    lines = result.stdout.splitlines()
    header = next(i for i, line in enumerate(lines) if line.split()[:4] == ["N", "hosts", "per", "host"])
    assert [line.split()[:3] for line in lines[header + 1 : header + 3]] == [["2", "2", "1"], ["2", "1", "2"]], (
        result.stdout
    )
    assert "largest N that held real time" in result.stdout
    assert plot_path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # and the JSON holds one row per setting, as run, with the machine it ran on
    doc: dict[str, Any] = json.loads(json_path.read_text())
    assert {"rows", "machine", "largest_n_real_time", "sim_seconds"} <= doc.keys()
    assert doc["machine"]["logical_cpus"] >= 1 and len(doc["machine"]["loadavg_after"]) == 3
    assert doc["machine"]["numba"] and doc["machine"]["numpy"]  # the versions the drones' kernels ran on
    rows = doc["rows"]
    assert [(r["n_drones"], r["drones_per_process"], r["hosts"]) for r in rows] == [(2, 1, 2), (2, 2, 1)]
    for row in rows:
        n = row["n_drones"]
        assert row["errors"] == [], row["errors"]
        for key in POSITIVE:
            value = row[key]
            assert isinstance(value, float) and math.isfinite(value) and value > 0, (n, key, value)
        assert isinstance(row["held_real_time"], bool)
        # the split shares out the measured total; ratios are to the bare plant measured in the same run
        parts = sum(row[f"{part}_ms_per_drone_sim_s"] for part in CPU_PARTS)
        assert parts == pytest.approx(row["cpu_ms_per_drone_sim_s"], rel=1e-9)
        bare = row["bare_jsbsim_cpu_ms_per_sim_s"]
        assert row["cpu_ms_per_drone_sim_s_x_bare"] == pytest.approx(row["cpu_ms_per_drone_sim_s"] / bare)
        assert row["cpu_ms_per_drone_sim_s"] > bare  # a whole drone costs more than its plant alone
        # paced: the window is SIM_SECONDS of the supervisor's clock, which the drones' own clocks follow
        assert row["wall_s_paced"] == pytest.approx(SIM_SECONDS, rel=0.1)
        assert row["rtf_paced"] == pytest.approx(row["sim_s_paced"] / row["wall_s_paced"])
        assert row["memory_kind"] in ("pss", "rss") and 5.0 < row["memory_mb_per_drone"] < 2000.0
        # every command was answered, the relay probe got (nearly) every report back
        assert row["cmd_rtt_received"] == row["cmd_rtt_sent"] >= 20
        assert row["cmd_rtt_median_ms"] <= row["cmd_rtt_p95_ms"] <= row["cmd_rtt_max_ms"]
        assert row["relay_sent"] >= 25 and row["relay_received"] >= row["relay_sent"] - 1
        assert row["relay_median_ms"] <= row["relay_p95_ms"] <= row["relay_max_ms"]
        assert row["clock_skew_samples"] > 0 and row["clock_skew_max_ms"] >= 0
        # lockstep: the same simulated window, no drone ever more than one step ahead of another
        assert row["sim_s_unpaced"] == pytest.approx(SIM_SECONDS, abs=0.1)
        assert row["lockstep_skew_samples"] > 0
        assert row["lockstep_skew_max_steps"] <= 1 and row["lockstep_skew_over_one"] == 0
        assert row["collisions_paced"] == 0 and row["collisions_lockstep"] == 0
        assert row["relay_scope"] == "reach" and row["circle_radius_m"] == 3.0
    assert doc["largest_n_real_time"].keys() == {"1", "2"}
    assert all(n in (None, 2) for n in doc["largest_n_real_time"].values())


def test_bad_arguments_are_one_line_and_spawn_nothing() -> None:
    result = subprocess.run([sys.executable, "-m", "gcs.cli", "bench", "--drones", "1,1"],
                            capture_output=True, text=True, timeout=60)  # fmt: skip
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == ["swarm: error: argument --drones: lists 1 twice"]
    assert result.stdout == ""


def _wakeup_processes() -> list[int]:
    """PIDs of any process running bench/wakeups.py (its forked flights carry the same command line)."""
    found = []
    for entry in os.scandir("/proc"):
        try:
            argv = Path(entry.path, "cmdline").read_bytes().split(b"\0") if entry.name.isdigit() else []
        except OSError:
            continue
        if str(WAKEUPS).encode() in argv:
            found.append(int(entry.name))
    return found


def test_the_wakeup_bench_measures_every_run_and_reaps_its_flights() -> None:
    result = subprocess.run([sys.executable, str(WAKEUPS), "--sim-seconds", "0.5", "--crowd", "2"],
                            capture_output=True, text=True, timeout=120, cwd=REPO)  # fmt: skip
    assert result.returncode == 0, result.stderr
    rows = [m.groups() for m in WAKEUP_ROW.finditer(result.stdout)]
    # one process unpaced and at 4 wake intervals; the crowd of 2 at 2 wake intervals and unpaced
    assert [label for label, *_ in rows] == [
        "1 process, unpaced",
        *(f"1 process, paced, wake every {w} steps" for w in (2, 8, 32, 125)),
        *(f"2 processes, paced, wake every {w} steps" for w in (8, 32)),
        "2 processes, unpaced",
    ]
    for label, *figures in rows:
        mean, low, high, wakes = (float(v) for v in figures)
        assert 0 < low <= mean <= high
        assert (wakes == 0) == label.endswith("unpaced")
    assert _wakeup_processes() == []


def test_the_wakeup_bench_refuses_a_bad_crowd_in_one_line() -> None:
    result = subprocess.run([sys.executable, str(WAKEUPS), "--crowd", "1,x"],
                            capture_output=True, text=True, timeout=60, cwd=REPO)  # fmt: skip
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == ["wakeups.py: error: argument --crowd: expected process counts like "
                                                  "9,30, got '1,x'"]  # fmt: skip
