"""``swarm bench``'s pure parts: arguments, statistics, window arithmetic, the table and the JSON rows."""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path

import numpy as np
import pytest

from gcs.bench.probe import PROBE_SYSIDS, latency_stats, probe_sysids
from gcs.bench.scaling import (
    CPU_KEYS,
    CPU_PARTS,
    BenchRow,
    BenchUsageError,
    DroneCounters,
    LatencyFigures,
    LockstepFigures,
    PacedFigures,
    Snapshot,
    WindowFigures,
    add_bench_parser,
    bench_document,
    check_instances,
    circle_limits,
    circle_radius_m,
    consistent_read,
    default_first_instance,
    format_table,
    largest_real_time,
    latency_figures,
    memory_kb,
    parse_drone_counts,
    percentile,
    proc_stat_cpu_ticks,
    row_json,
    run_bench,
    spread,
    swarm_probe_sysids,
    window_figures,
    write_plot,
)
from gcs.cli import main as swarm_main
from gcs.command.streamer import DEFAULT_LIMITS
from gcs.composition import SITL
from gcs.fleet.harness import SpawnPlan, grid_layout
from gcs.flight.formation import CircleSpec, FormationEngine, FormationError, slots_at
from sitl.harness.simulation import bare_plant_cpu_ms_per_sim_s

RATE_HZ = SITL.physics_rate_hz
REQUIRED_ROW_KEYS = {
    "n_drones",
    "rtf_paced",
    "rtf_unpaced",
    "cpu_ms_per_drone_sim_s",
    "bare_jsbsim_cpu_ms_per_sim_s",
    "ready_s",
    "held_real_time",
    "supervisor_cpu_ms_per_drone_sim_s",
    "memory_mb_per_drone",
    "cmd_rtt_median_ms",
    "cmd_rtt_p95_ms",
    "relay_median_ms",
    "relay_p95_ms",
    "clock_skew_max_ms",
    "lockstep_skew_max_steps",
    *(f"{part}_ms_per_drone_sim_s" for part in CPU_PARTS),
    *(f"{key}_x_bare" for key in CPU_KEYS),
}


# ------------------------------------------------------------------------------------------------ arguments


def test_drone_counts_are_parsed_distinct_and_run_smallest_first() -> None:
    assert parse_drone_counts("9, 1,3") == (1, 3, 9)
    assert parse_drone_counts("100") == (100,)
    assert parse_drone_counts("254") == (254,)


@pytest.mark.parametrize(
    ("text", "complaint"),
    [("0", "1..254"), ("255", "1..254"), ("1,x", "whole numbers"), ("3,3", "twice"), ("", "whole numbers")],
)
def test_bad_drone_counts_say_what_is_wrong(text: str, complaint: str) -> None:
    with pytest.raises(BenchUsageError, match=complaint):
        parse_drone_counts(text)


def test_instances_must_fit_the_sysids_below_the_ground_stations() -> None:
    limit = SITL.max_instances
    check_instances(100, 100, limit)  # sysids 101..200
    check_instances(200, 50, limit)  # over the probe's usual sysids: it moves aside
    check_instances(0, 254, limit)  # sysids 1..254
    with pytest.raises(BenchUsageError, match=r"must lie in 0\.\.253"):
        check_instances(1, 254, limit)
    with pytest.raises(BenchUsageError, match="must lie in"):
        check_instances(250, 10, limit)
    with pytest.raises(BenchUsageError, match="must lie in"):
        check_instances(-1, 1, limit)


def test_the_relay_probe_takes_two_sysids_no_drone_has() -> None:
    assert probe_sysids(range(101, 201)) == PROBE_SYSIDS  # clear of the swarm: its usual pair
    assert probe_sysids(range(201, 251)) == (254, 253)  # the swarm flies 240: the highest free pair
    assert probe_sysids(range(1, 253)) == (254, 253)
    assert probe_sysids(range(3, 255)) == (2, 1)
    assert probe_sysids(range(1, 254)) is None  # 253 drones leave one sysid: the relay hop is not timed
    assert probe_sysids(range(1, 255)) is None
    plan = SpawnPlan(n_drones=50, first_instance=200)
    assert swarm_probe_sysids(plan) == (254, 253)


def test_the_subcommand_parses_like_the_standalone_command() -> None:
    # GIVEN a parser built the way ``swarm`` builds its subcommands
    parser = argparse.ArgumentParser(prog="swarm")
    add_bench_parser(parser.add_subparsers(dest="command", required=True))
    # WHEN bench is given its options THEN they arrive parsed and checked
    args = parser.parse_args(["bench", "--drones", "3,1", "--sim-seconds", "4", "--json", "out.json"])
    assert args.command == "bench" and args.drones == (1, 3) and args.sim_seconds == 4.0
    assert args.json == Path("out.json") and args.plot is None and args.first_instance is None  # chosen by size
    defaults = parser.parse_args(["bench"])
    assert defaults.drones == (1, 3, 9, 20, 50, 100) and defaults.sim_seconds > 0


@pytest.mark.parametrize("argv", [["--drones", "0"], ["--sim-seconds", "-1"], ["--sim-seconds", "nan"], ["--bogus"]])
def test_bad_arguments_end_with_one_error_line_and_exit_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert swarm_main(["bench", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("swarm: error:"), err


def test_instances_beyond_the_sysids_are_refused_before_anything_is_spawned(capsys: pytest.CaptureFixture[str]) -> None:
    args = argparse.Namespace(drones=(1, 254), first_instance=1, sim_seconds=1.0, seed=0, json=None, plot=None)
    assert run_bench(args, SITL) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "needs instances up to 254; they must lie in 0..253" in err[0], err


def test_the_first_instance_is_100_unless_the_largest_swarm_needs_room_below_it() -> None:
    assert default_first_instance(100, SITL.max_instances) == 100
    assert default_first_instance(154, SITL.max_instances) == 100  # instances 100..253
    assert default_first_instance(200, SITL.max_instances) == 54  # instances 54..253: sysids 55..254
    assert default_first_instance(254, SITL.max_instances) == 0
    check_instances(default_first_instance(254, SITL.max_instances), 254, SITL.max_instances)  # fits


# ------------------------------------------------------------------------------------------------ statistics


def test_percentiles_are_nearest_rank_the_smallest_value_with_q_of_the_samples_at_or_below_it() -> None:
    values = [float(v) for v in range(137, 0, -1)]  # 1..137, any order
    assert percentile(values, 0.5) == 69.0  # 69 of 137 samples (50.4 %) at or below; 68 would be 49.6 %
    assert percentile(values, 0.95) == 131.0  # ceil(0.95 * 137) = 131
    assert percentile([float(i) for i in range(1, 101)], 0.95) == 95.0
    assert percentile([5.0], 0.95) == 5.0 and math.isnan(percentile([], 0.5))


def test_latency_figures_are_in_milliseconds_with_what_was_lost() -> None:
    # the relay probe's summary of the same hops agrees where its rounding and nearest rank coincide
    hops_s = [i * 1e-3 for i in range(1, 101)]
    ours, probe = latency_figures(hops_s, sent=102), latency_stats(hops_s, sent=102)
    assert (ours.median_ms, ours.p95_ms, ours.max_ms) == pytest.approx((probe.median_ms, probe.p95_ms, probe.max_ms))
    assert (ours.sent, ours.received) == (102, 100)
    nothing = latency_figures([], sent=3)
    assert math.isnan(nothing.median_ms) and nothing.received == 0


def test_spread_ignores_rows_that_are_not_finite() -> None:
    assert spread([3.0, 1.0, math.inf, 2.5]) == 2.0
    assert math.isnan(spread([math.inf, math.nan]))


def test_a_consistent_read_waits_for_two_equal_reads_and_gives_up_on_a_moving_column() -> None:
    reads = iter([np.array([5.0, 7.0]), np.array([6.0, 7.0]), np.array([6.0, 7.0])])  # torn first, then stable
    got = consistent_read(lambda: next(reads))
    assert got is not None and got.tolist() == [6.0, 7.0]
    counter = iter(range(100))
    assert consistent_read(lambda: np.array([float(next(counter))]), tries=4) is None


# ------------------------------------------------------------------------------------------------ scenario geometry


@pytest.mark.parametrize("n", [1, 2, 3, 9, 20, 50, 100])
def test_circle_neighbours_are_at_least_2_m_apart_and_the_radius_at_least_3_m(n: int) -> None:
    radius = circle_radius_m(n)
    assert radius >= 3.0
    if n > 1:
        chord = 2.0 * radius * math.sin(math.pi / n)
        assert chord >= 2.0 - 1e-9
        assert radius == 3.0 or chord == pytest.approx(2.0)  # no larger than needed


@pytest.mark.parametrize("n", [9, 50, 100])
def test_the_rotating_circle_fits_the_limits_the_bench_streams_it_with(n: int) -> None:
    # GIVEN the spawn grid at 2 m and the bench's circle at 0.2 rad/s
    radius = circle_radius_m(n)
    spec = CircleSpec(radius_m=radius, alt_m=3.0, angular_rate_radps=0.2)
    start = {i + 1: (north, east, -3.0) for i, (north, east) in enumerate(grid_layout(n, 2.0))}
    # WHEN the engine plans it with the bench's limits THEN it is accepted and every slot is reached
    engine = FormationEngine(circle_limits(radius, 0.2))
    engine.command(spec, 0.0, start)
    assert engine.targets(1e4).keys() == start.keys()
    assert slots_at(spec, 0.0, n).shape == (n, 3)
    # and a circle whose rim outruns the default 1.5 m/s is refused with the defaults (why the limits are raised)
    if 0.2 * radius > DEFAULT_LIMITS.max_speed_mps:
        with pytest.raises(FormationError):
            FormationEngine(DEFAULT_LIMITS).command(spec, 0.0, start)
    else:
        assert circle_limits(radius, 0.2) == DEFAULT_LIMITS


# ------------------------------------------------------------------------------------------------ /proc parsing


def test_cpu_ticks_are_utime_plus_stime_even_with_odd_process_names() -> None:
    fields = ["S", "1", "2", "3", "0", "-1", "4194560", "10", "0", "0", "0", "1234", "56", "0", "0"]
    assert proc_stat_cpu_ticks(f"4242 (we ird) name)) {' '.join(fields)} 20 0") == 1290


def test_cpu_ticks_of_this_process_agree_with_the_kernel_counters() -> None:
    end = time.process_time() + 0.05
    while time.process_time() < end:  # burn a little CPU so the counters are not zero
        pass
    ticks = proc_stat_cpu_ticks(Path("/proc/self/stat").read_text())
    times = os.times()
    assert ticks / os.sysconf("SC_CLK_TCK") == pytest.approx(times.user + times.system, abs=0.03)


def test_memory_prefers_pss_and_falls_back_to_rss() -> None:
    rollup = "55d0-7ffe ---p 00000000 00:00 0 [rollup]\nRss:  52000 kB\nPss:  41000 kB\nPss_Anon: 30000 kB\n"
    status = "Name:\tsitl\nVmRSS:\t  52000 kB\n"
    assert memory_kb(rollup, status) == (41000.0, "pss")
    assert memory_kb(None, status) == (52000.0, "rss")
    kb, kind = memory_kb(None, None)
    assert math.isnan(kb) and kind == ""
    real_kb, real_kind = memory_kb(Path("/proc/self/smaps_rollup").read_text(), None)
    assert real_kind == "pss" and real_kb > 1000


# ------------------------------------------------------------------------------------------------ window figures


def _sample(parts: tuple[float, float, float, float], t: float) -> DroneCounters:
    return DroneCounters(parts_s=parts, sim_time_s=t)


@pytest.mark.parametrize("hosted", [False, True], ids=["process-per-drone", "one-host"])
def test_window_figures_share_the_measured_cpu_out_by_the_drones_own_counters(hosted: bool) -> None:
    # GIVEN two drones over 10 wall seconds: one advanced 10.0 s of simulation, the slower 9.8 s; 0.8 s of CPU
    # in all, 0.4 s in each drone's own process, or all of it in the one process that hosts both
    ticks_before, ticks_after = ((3000,), (3080,)) if hosted else ((1000, 2000), (1040, 2040))
    before = Snapshot(wall_s=100.0, supervisor_cpu_s=1.0, process_cpu_ticks=ticks_before, drones=(
        _sample((1.0, 2.0, 0.5, 0.5), 50.0),
        _sample((1.0, 2.0, 0.5, 0.5), 49.9),
    ))  # fmt: skip
    after = Snapshot(wall_s=110.0, supervisor_cpu_s=1.4, process_cpu_ticks=ticks_after, drones=(
        _sample((1.05, 2.20, 0.55, 0.10 + 0.5), 60.0),  # parts 0.05/0.20/0.05/0.10 s
        _sample((1.05, 2.20, 0.55, 0.10 + 0.5), 59.7),
    ))  # fmt: skip
    fig = window_figures(before, after, clk_tck=100.0)
    # THEN the real-time factor follows the slowest clock: (59.7 - 49.9) / 10
    assert fig.sim_s == pytest.approx(9.8) and fig.wall_s == 10.0 and fig.rtf == pytest.approx(0.98)
    # and CPU per drone per simulated second is the total over the drones' own simulated time: 0.8 s / 19.8 s
    cpu_ms = 800.0 / 19.8
    assert fig.cpu_ms_per_drone_sim_s == pytest.approx(cpu_ms)
    # and the parts (0.1, 0.4, 0.1, 0.2 s in all) share that total in proportion, summing to it exactly
    assert fig.parts_ms_per_drone_sim_s == pytest.approx((cpu_ms / 8, cpu_ms / 2, cpu_ms / 8, cpu_ms / 4))
    assert sum(fig.parts_ms_per_drone_sim_s) == pytest.approx(cpu_ms)
    assert fig.parts_coverage == pytest.approx(0.8 / 0.8)
    # and the supervisor's 0.4 s is spread over 2 drones and the slowest clock's 9.8 s
    assert fig.supervisor_cpu_ms_per_drone_sim_s == pytest.approx(400.0 / (2 * 9.8))


def test_window_figures_refuse_snapshots_of_different_swarms() -> None:
    one = Snapshot(wall_s=0.0, supervisor_cpu_s=0.0, drones=(_sample((0.0,) * 4, 0.0),), process_cpu_ticks=(0,))
    with pytest.raises(ValueError, match="same"):
        window_figures(one, Snapshot(wall_s=1.0, supervisor_cpu_s=0.0, drones=(), process_cpu_ticks=(0,)), 100.0)
    with pytest.raises(ValueError, match="same processes"):
        window_figures(one, Snapshot(wall_s=1.0, supervisor_cpu_s=0.0, drones=one.drones, process_cpu_ticks=()), 100.0)


# ------------------------------------------------------------------------------------------------ rows, table, JSON


def _window(rtf: float, cpu_ms: float) -> WindowFigures:
    return WindowFigures(sim_s=10.0 * rtf, wall_s=10.0, rtf=rtf, cpu_ms_per_drone_sim_s=cpu_ms,
                         parts_ms_per_drone_sim_s=(cpu_ms * 0.3, cpu_ms * 0.5, cpu_ms * 0.1, cpu_ms * 0.1),
                         parts_coverage=0.95, supervisor_cpu_ms_per_drone_sim_s=2.0)  # fmt: skip


def _row(n: int, rtf_paced: float, *, lockstep: bool = True, mode: int | str = 1) -> BenchRow:
    paced = PacedFigures(ready_s=6.0, window=_window(rtf_paced, 30.0), memory_mb_mean=50.0,
                         memory_mb_max=52.0, memory_kind="pss",
                         command_rtt=LatencyFigures(median_ms=0.4, p95_ms=1.5, max_ms=2.0, sent=20, received=20),
                         relay=LatencyFigures(median_ms=0.3, p95_ms=0.9, max_ms=1.0, sent=30, received=30),
                         clock_skew_median_ms=20.0, clock_skew_max_ms=30.0, clock_skew_drift_ms=0.0,
                         clock_skew_samples=100, collisions=0)  # fmt: skip
    lock = LockstepFigures(ready_s=1.0, window=_window(4.0, 35.0), skew_max_steps=1.0,
                           skew_over_one=0, skew_samples=80, collisions=0)  # fmt: skip
    hosts = n if mode == 1 else 2
    return BenchRow(n_drones=n, circle_radius_m=3.0, relay_scope="reach", bare_jsbsim_cpu_ms_per_sim_s=3.0,
                    paced=paced, lockstep=lock if lockstep else None, drones_per_process=mode,  # type: ignore[arg-type]
                    hosts=hosts, drones_per_host=-(-n // hosts))  # fmt: skip


def test_a_row_holds_every_figure_and_each_cpu_figure_as_a_multiple_of_bare_jsbsim() -> None:
    out = row_json(_row(9, 0.99), RATE_HZ)
    assert out.keys() >= REQUIRED_ROW_KEYS
    assert out["n_drones"] == 9 and out["held_real_time"] is True
    assert out["cpu_ms_per_drone_sim_s_x_bare"] == pytest.approx(10.0)
    assert out["control_ms_per_drone_sim_s_x_bare"] == pytest.approx(5.0)
    assert out["cpu_ms_per_drone_sim_s_lockstep_x_bare"] == pytest.approx(35.0 / 3.0)
    json.dumps(out, allow_nan=False)


def test_a_missing_run_is_null_in_json_and_a_dash_in_the_table() -> None:
    # GIVEN a row whose lockstep run failed
    row = BenchRow(n_drones=3, circle_radius_m=3.0, relay_scope="reach", bare_jsbsim_cpu_ms_per_sim_s=3.0,
                   paced=_row(3, 0.9).paced, errors=("lockstep: stalled",))  # fmt: skip
    out = row_json(row, RATE_HZ)
    # THEN its figures are null (valid JSON), the error is kept, and the table shows '-'
    assert out["rtf_unpaced"] is None and out["cpu_ms_per_drone_sim_s_lockstep_x_bare"] is None
    assert out["errors"] == ["lockstep: stalled"] and out["held_real_time"] is False
    json.dumps(out, allow_nan=False)
    table = format_table([out]).splitlines()
    assert len(table) == 2 and table[0].split()[0] == "N"
    cells = table[1].split()
    assert cells[0] == "3" and "-" in cells and cells[-1] == "no"


def test_the_document_names_the_largest_swarm_that_held_real_time_in_each_mode() -> None:
    rows = [_row(1, 1.0), _row(3, 0.99), _row(9, 0.97), _row(9, 0.99, mode="auto"), _row(20, 0.5),
            _row(20, 0.97, mode="auto")]  # fmt: skip
    doc = bench_document(rows, {"logical_cpus": 2}, sim_seconds=10.0, physics_rate_hz=SITL.physics_rate_hz)
    assert [(r["n_drones"], r["drones_per_process"]) for r in doc["rows"]] == [
        (1, 1), (3, 1), (9, 1), (9, "auto"), (20, 1), (20, "auto")
    ]  # fmt: skip
    assert doc["largest_n_real_time"] == {"1": 3, "auto": 9} and doc["machine"] == {"logical_cpus": 2}
    assert largest_real_time([row_json(_row(1, 0.5), RATE_HZ)]) is None
    table = format_table(doc["rows"]).splitlines()
    assert len(table) == 7 and table[0].split()[:4] == ["N", "hosts", "per", "host"]
    assert table[4].split()[:3] == ["9", "2", "5"]  # nine drones hosted by two processes, five at most in one


def test_the_plot_is_a_png_even_with_missing_figures(tmp_path: Path) -> None:
    rows = [row_json(_row(1, 1.0), RATE_HZ), row_json(_row(3, 0.99, lockstep=False), RATE_HZ)]
    path = tmp_path / "plots" / "scaling.png"
    write_plot(rows, path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bare_jsbsim_stepping_costs_a_few_ms_of_cpu_per_simulated_second() -> None:
    ms = bare_plant_cpu_ms_per_sim_s(sim_seconds=2.0, repeats=1)
    assert 0.1 < ms < 100.0  # 3.7 ms on the 2-core development machine (docs/benchmarks.md)
