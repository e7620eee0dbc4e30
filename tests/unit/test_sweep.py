"""Scenario sweeps without flying: what runs (gcs/sweep/plan.py), the statistics (stats.py), the instance locks that
keep runs apart (instance_locks.py), resuming (sweep.py) and the summary's files (summary.py)."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from gcs.fleet.clock import FLIGHT_VERSION
from gcs.sweep.instance_locks import FIRST_SWEEP_INSTANCE, InstanceLocks
from gcs.sweep.plan import (
    LINK_LOSS,
    Axis,
    SweepError,
    SweepPlan,
    fly_command,
    link_loss_axis,
    parse_param,
    parse_seeds,
    parse_values,
)
from gcs.sweep.runs import RunResult
from gcs.sweep.stats import bootstrap_mean_ci, distribution, event_rate, run_metrics, summarise, wilson_ci
from gcs.sweep.summary import RUNS_CSV, SUMMARY_JSON, write_summary
from gcs.sweep.sweep import PLAN_FILE, prepare
from gcs.view.report import write_report
from tests.unit.test_report import synthetic_flight


def plan(tmp_path: Path, seeds: tuple[int, ...] = (1, 2), axes: tuple[Axis, ...] = ()) -> SweepPlan:
    return SweepPlan(mission=tmp_path / "m.toml", mission_sha256="ab" * 32, n_drones=4, seeds=seeds, axes=axes)


# ---- what runs -------------------------------------------------------------------------------------------------


def test_seeds_values_and_parameters_parse_as_written() -> None:
    assert parse_seeds("1-3,7,2") == (1, 2, 3, 7)
    assert parse_values("1.2,1.5,1.8", "x") == (1.2, 1.5, 1.8)
    assert parse_values("1:2:0.25", "x") == (1.0, 1.25, 1.5, 1.75, 2.0)
    assert parse_param("AVOID_MIN_DIST=1.2,1.5") == Axis("AVOID_MIN_DIST", (1.2, 1.5))
    assert link_loss_axis("0,0.2") == Axis(LINK_LOSS, (0.0, 0.2))


@pytest.mark.parametrize(
    ("call", "line"),
    [
        (lambda: parse_seeds("20-1"), "must be a range from low to high"),
        (lambda: parse_seeds("1-x"), "is not a seed or a range"),
        (lambda: parse_values("1,1", "--param A"), "lists a value twice"),
        (lambda: parse_values("2:1:0.5", "--param A"), "needs START <= STOP"),
        (lambda: parse_values("1,nan", "--param A"), "finite numbers"),
        (lambda: parse_param("avoid_min_dist=1"), "must be NAME=v1,v2"),
        (lambda: parse_param("AVOID_MIN_DIST"), "must be NAME=v1,v2"),
        (lambda: link_loss_axis("0,1"), "must be in [0, 1)"),
    ],
)
def test_a_bad_range_or_name_is_one_line(call: object, line: str) -> None:
    with pytest.raises(SweepError, match=line.replace("[", r"\[").replace(")", r"\)")) as caught:
        call()  # type: ignore[operator]
    assert "\n" not in str(caught.value)


def test_runs_are_the_product_of_settings_and_seeds_in_a_fixed_order(tmp_path: Path) -> None:
    axes = (Axis("AVOID_MIN_DIST", (1.2, 1.5)), Axis(LINK_LOSS, (0.0, 0.2)))
    sweep = plan(tmp_path, seeds=(3, 4, 5), axes=axes)
    runs = sweep.runs()
    assert sweep.n_runs == len(runs) == 12 and [r.index for r in runs] == list(range(12))
    assert runs[0].name == "AVOID_MIN_DIST=1.2+link_loss=0/seed-0003"
    assert runs[-1].name == "AVOID_MIN_DIST=1.5+link_loss=0.2/seed-0005"
    command = fly_command(sweep, runs[-1], first_instance=40, report=tmp_path / "r")
    assert command[:3] == ["fly", str(tmp_path / "m.toml"), "--lockstep"]
    assert command[command.index("--seed") + 1] == "5" and command[command.index("--first-instance") + 1] == "40"
    assert command[-4:] == ["--param", "AVOID_MIN_DIST=1.5", "--link-loss", "0.2"]
    with pytest.raises(SweepError, match="swept twice"):
        plan(tmp_path, axes=(Axis("A", (1.0,)), Axis("A", (2.0,))))


def test_a_folder_holding_another_sweep_is_refused_and_the_same_one_resumed(tmp_path: Path) -> None:
    out = tmp_path / "out"
    prepare(plan(tmp_path), out)
    assert json.loads((out / PLAN_FILE).read_text())["seeds"] == [1, 2]
    prepare(plan(tmp_path), out)  # the same sweep: resumed
    with pytest.raises(SweepError, match="holds another sweep"):
        prepare(plan(tmp_path, seeds=(1, 2, 3)), out)


def test_a_sweep_flown_by_code_that_flies_differently_is_refused_in_one_line(tmp_path: Path) -> None:
    # GIVEN a sweep's folder whose record says its runs were flown by another version of the flights (or none, as
    # every sweep recorded before the version was)
    out = tmp_path / "out"
    prepare(plan(tmp_path), out)
    record = json.loads((out / PLAN_FILE).read_text())
    assert record["flight_version"] == FLIGHT_VERSION
    for held in (FLIGHT_VERSION - 1, None):
        old = {k: v for k, v in record.items() if k != "flight_version"}
        (out / PLAN_FILE).write_text(json.dumps(old if held is None else {**old, "flight_version": held}))
        # WHEN the same sweep is resumed there THEN it is refused, in one line naming both versions
        with pytest.raises(SweepError, match="holds flights flown by code that flies differently") as caught:
            prepare(plan(tmp_path), out)
        assert "\n" not in str(caught.value) and f"this code flies version {FLIGHT_VERSION}" in str(caught.value)


# ---- statistics ------------------------------------------------------------------------------------------------


def test_intervals_wilson_and_bootstrap() -> None:
    low, high = wilson_ci(0, 20)
    assert low == 0.0 and 0.15 < high < 0.17  # 0 of 20 is not "never"
    low, high = wilson_ci(10, 20)
    assert abs((low + high) / 2 - 0.5) < 1e-9 and 0.29 < low < 0.30
    values = [1.0, 2.0, 3.0, 4.0, 10.0]
    assert bootstrap_mean_ci(values) == bootstrap_mean_ci(list(reversed(values)))  # the same runs, any order
    low, high = bootstrap_mean_ci(values)
    assert low < 4.0 < high
    d = distribution([1.0, None, 3.0])
    assert (d.n, d.mean, d.min, d.max) == (2, 2.0, 1.0, 3.0)
    assert distribution([None]).mean is None
    rate = event_rate([0.0, 2.0, 0.0, 0.0])
    assert (rate.runs_with, rate.per_100_flights) == (1, 50.0)


def test_a_runs_figures_come_from_its_metrics_json(tmp_path: Path) -> None:
    metrics = json.loads((write_report(synthetic_flight(), tmp_path) / "metrics.json").read_text())
    row = run_metrics(metrics)
    assert row["collisions"] == 1.0 and row["min_separation_m"] == metrics["min_separation_m"]
    assert row["circle:formation_rms_m"] == metrics["steps"][1]["formation_rms_m"]
    assert "takeoff:formation_rms_m" not in row  # a takeoff is no formation
    figures = summarise([row, row])
    assert figures["runs"] == 2 and figures["events"]["collisions"]["runs_with"] == 2
    # a run that broke an invariant counts it: the share of runs with a violation is a figure of its own
    assert row["violations"] == 0.0
    broken = run_metrics({**metrics, "violations": [{"name": "apart", "kind": "separation", "time_s": 3.0,
                                                     "sysids": [1, 2], "detail": "1 and 2 0.80 m apart"}]})  # fmt: skip
    assert summarise([row, broken])["events"]["violations"]["runs_with"] == 1


# ---- instances ---------------------------------------------------------------------------------------------------


def test_runs_side_by_side_get_disjoint_instances_and_free_them_when_done(tmp_path: Path) -> None:
    first, second = InstanceLocks(100, tmp_path), InstanceLocks(100, tmp_path)  # as two sweeps on one machine
    with first.block() as a, second.block() as b:
        assert a.first == FIRST_SWEEP_INSTANCE and b.first == FIRST_SWEEP_INSTANCE + 100
        assert len(a.fds) == 100
        stop = threading.Event()
        stop.set()
        with pytest.raises(InterruptedError), InstanceLocks(100, tmp_path).block(stop):
            pass  # every block of 100 taken: a third waits (here: is stopped while waiting)
    with second.block() as again:
        assert again.first == FIRST_SWEEP_INSTANCE  # freed


def test_a_reservation_keeps_new_holders_out_of_its_range_until_it_is_let_go(tmp_path: Path) -> None:
    # GIVEN a range of 10 reserved from the lowest instances (where a sweep's runs take their blocks first)
    small, wide = InstanceLocks(2, tmp_path), InstanceLocks(10, tmp_path)
    reservation = wide.reserve([FIRST_SWEEP_INSTANCE], set())
    assert reservation is not None and reservation.instances == range(FIRST_SWEEP_INSTANCE, FIRST_SWEEP_INSTANCE + 10)
    try:
        # THEN a sweep's next block lies above it, nobody else holds an instance inside it, but its reserver does
        with small.block() as run:
            assert run.first == FIRST_SWEEP_INSTANCE + 10
        assert small.try_hold(FIRST_SWEEP_INSTANCE + 4) is None
        mine = small.try_hold(FIRST_SWEEP_INSTANCE + 4, own=reservation)
        assert mine is not None and len(mine) == 2
        for handle in mine:
            handle.close()
        # AND a second reservation is made clear of it, or not at all
        assert wide.reserve([FIRST_SWEEP_INSTANCE, FIRST_SWEEP_INSTANCE + 5], set()) is None
        second = wide.reserve([FIRST_SWEEP_INSTANCE + 5, FIRST_SWEEP_INSTANCE + 10], set())
        assert second is not None and second.first == FIRST_SWEEP_INSTANCE + 10
        second.release()
    finally:
        reservation.release()
    # AND once let go, the range is anyone's again
    with small.block() as run:
        assert run.first == FIRST_SWEEP_INSTANCE


def test_the_reservation_of_a_process_that_died_holds_nothing_back(tmp_path: Path) -> None:
    # GIVEN a process that reserved a range and was killed (SIGKILL: it let nothing go)
    script = (f"from pathlib import Path; from gcs.sweep.instance_locks import InstanceLocks; "
              f"r = InstanceLocks(10, Path({str(tmp_path)!r})).reserve([{FIRST_SWEEP_INSTANCE}], set()); "
              f"print(r.first, flush=True); import time; time.sleep(60)")  # fmt: skip
    child = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout is not None and int(child.stdout.readline()) == FIRST_SWEEP_INSTANCE
        locks = InstanceLocks(2, tmp_path)
        assert locks.try_hold(FIRST_SWEEP_INSTANCE) is None  # alive: respected
    finally:
        child.kill()
        child.wait(10)
    # THEN its range is free at once, and its file is cleared away by the look that found it dead
    held = locks.try_hold(FIRST_SWEEP_INSTANCE)
    assert held is not None
    for handle in held:
        handle.close()
    assert locks.reserved() == [] and not list(tmp_path.glob("reserved-*"))


# ---- the summary ---------------------------------------------------------------------------------------------


def test_the_summary_has_every_setting_every_run_and_names_the_worst(tmp_path: Path) -> None:
    metrics = json.loads((write_report(synthetic_flight(), tmp_path / "r") / "metrics.json").read_text())
    sweep = plan(tmp_path, axes=(Axis("AVOID_MIN_DIST", (1.2, 1.5)),))
    results = []
    for run in sweep.runs():
        row = run_metrics(metrics)
        row["min_separation_m"] = 1.0 + run.index  # the first run is the worst
        failed = run.index == 3
        results.append(RunResult(index=run.index, name=run.name, setting=run.setting, seed=run.seed, ok=not failed,
                                 wall_s=10.0 + run.index, metrics={} if failed else row,
                                 error="swarm fly exited with 1: boom" if failed else None, command=()))  # fmt: skip
    out = tmp_path / "out"
    out.mkdir()
    lines = write_summary(sweep, results, out)
    summary = json.loads((out / SUMMARY_JSON).read_text())
    assert list(summary["settings"]) == ["AVOID_MIN_DIST=1.2", "AVOID_MIN_DIST=1.5"]
    assert summary["settings"]["AVOID_MIN_DIST=1.5"]["failed"] == 1
    assert summary["worst_runs"][0]["name"] == results[3].name  # failed first
    assert summary["slowest_runs"][0]["name"] == results[3].name
    with (out / RUNS_CSV).open() as f:
        rows = list(csv.DictReader(f))
    assert [r["seed"] for r in rows] == ["1", "2", "1", "2"] and rows[3]["ok"] == "False"
    assert any(line.startswith("AVOID_MIN_DIST=1.2") for line in lines)
    assert (out / "plots" / "min_separation_m.png").stat().st_size > 5000
