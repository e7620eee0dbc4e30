"""A sweep's summary: per setting, every metric's distribution with 95 % intervals, as a table on the terminal,
summary.json, summary.txt, runs.csv (and runs.parquet with pyarrow), and plots of each metric against the swept
values; then the worst and the slowest runs by name, so their reports can be opened.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

from gcs.sweep.plan import SweepPlan, setting_key
from gcs.sweep.runs import RunResult
from gcs.sweep.stats import metric_names, summarise

if TYPE_CHECKING:
    from matplotlib.axes import Axes

SUMMARY_JSON: Final = "summary.json"
SUMMARY_TXT: Final = "summary.txt"
RUNS_CSV: Final = "runs.csv"
RUNS_PARQUET: Final = "runs.parquet"
PLOTS_DIR: Final = "plots"
NAMED_RUNS: Final = 3  # worst and slowest runs named in the summary


def _fmt(value: float | None, digits: int = 2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _mean_ci(figure: dict[str, Any], digits: int = 2) -> str:
    low, high = figure["ci95"]
    return (
        "-" if figure["mean"] is None else f"{_fmt(figure['mean'], digits)} [{_fmt(low, digits)}, {_fmt(high, digits)}]"
    )


def step_columns(names: Sequence[str]) -> list[str]:
    """The step metrics the table shows: those of the last formation-like step (the one a mission builds up to)."""
    steps = [n for n in names if ":" in n]
    if not steps:
        return []
    last = steps[-1].split(":")[0]
    return [n for n in steps if n.split(":")[0] == last]


def summary_table(plan: SweepPlan, per_setting: dict[str, dict[str, Any]]) -> list[str]:
    """The terminal table: one row per setting."""
    names = next(iter(per_setting.values()))["metric_names"] if per_setting else []
    steps = step_columns(names)
    header = ["setting", "runs", "collisions/100 [95% CI]", "runs w/ collision", "min sep m [95% CI]",
              *(f"{s} [95% CI]" for s in steps), "failsafes/100", "losses/100"]  # fmt: skip
    rows = [header]
    for key, figures in per_setting.items():
        collisions = figures["events"]["collisions"]
        rows.append([
            key, f"{figures['runs']} ({figures['failed']} failed)" if figures["failed"] else str(figures["runs"]),
            f"{_fmt(collisions['per_100_flights'], 1)} [{_fmt(collisions['per_100_flights_ci95'][0], 1)}, "
            f"{_fmt(collisions['per_100_flights_ci95'][1], 1)}]",
            f"{collisions['runs_with']}/{collisions['runs']}",
            _mean_ci(figures["metrics"]["min_separation_m"]),
            *(_mean_ci(figures["metrics"][s]) for s in steps),
            _fmt(figures["events"]["failsafes"]["per_100_flights"], 1),
            _fmt(figures["events"]["losses"]["per_100_flights"], 1),
        ])  # fmt: skip
    widths = [max(len(r[k]) for r in rows) for k in range(len(header))]
    return ["  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip() for row in rows]


def _row(result: RunResult, axes: Sequence[str], names: Sequence[str]) -> dict[str, Any]:
    setting = dict(result.setting)
    return {"run": result.index, "name": result.name, **{a: setting.get(a) for a in axes}, "seed": result.seed,
            "ok": result.ok, "wall_s": round(result.wall_s, 3), **{n: result.metrics.get(n) for n in names},
            "error": result.error or ""}  # fmt: skip


def worst_runs(results: Sequence[RunResult]) -> list[RunResult]:
    """The runs a user should look at first: failed ones, then most collisions, then the smallest separation."""

    def badness(r: RunResult) -> tuple[float, float, float]:
        sep = r.metrics.get("min_separation_m")
        return (0.0 if r.ok else -1.0, -(r.metrics.get("collisions") or 0.0), math.inf if sep is None else sep)

    return sorted(results, key=badness)[:NAMED_RUNS]


def write_summary(plan: SweepPlan, results: Sequence[RunResult], out: Path) -> list[str]:
    """Every summary file under ``out``; the lines for the terminal (the table and the runs to look at)."""
    ordered = sorted(results, key=lambda r: r.index)
    ok = [r for r in ordered if r.ok]
    names = metric_names([r.metrics for r in ok])
    axes = [a.name for a in plan.axes]
    per_setting: dict[str, dict[str, Any]] = {}
    for setting in plan.settings():
        key = setting_key(setting)
        mine = [r for r in ordered if r.setting == setting]
        figures = summarise([r.metrics for r in mine if r.ok])
        per_setting[key] = {"setting": dict(setting), **figures, "failed": sum(not r.ok for r in mine),
                            "metric_names": names}  # fmt: skip
    slowest = sorted(ordered, key=lambda r: -r.wall_s)[:NAMED_RUNS]
    worst = worst_runs(ordered)
    summary = {
        "plan": plan.to_json(),
        "runs": len(ordered),
        "failed": [r.name for r in ordered if not r.ok],
        "settings": {k: {x: v for x, v in f.items() if x != "metric_names"} for k, f in per_setting.items()},
        "worst_runs": [{"name": r.name, "collisions": r.metrics.get("collisions"),
                        "min_separation_m": r.metrics.get("min_separation_m"), "error": r.error} for r in worst],
        "slowest_runs": [{"name": r.name, "wall_s": round(r.wall_s, 2)} for r in slowest],
    }  # fmt: skip
    (out / SUMMARY_JSON).write_text(json.dumps(summary, indent=1, allow_nan=False) + "\n")
    rows = [_row(r, axes, names) for r in ordered]
    columns = ["run", "name", *axes, "seed", "ok", "wall_s", *names, "error"]
    with (out / RUNS_CSV).open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    parquet = _write_parquet(rows, columns, out / RUNS_PARQUET)
    _plots(plan, per_setting, ordered, names, out / PLOTS_DIR)
    lines = summary_table(plan, per_setting)
    lines.append("")
    lines.append("worst runs (reports under runs/NAME/report):")
    lines += [f"  {r.name}: " + (r.error or f"collisions {_fmt(r.metrics.get('collisions'), 0)}, min separation "
                                 f"{_fmt(r.metrics.get('min_separation_m'))} m") for r in worst]  # fmt: skip
    lines.append("slowest runs: " + ", ".join(f"{r.name} ({r.wall_s:.0f} s)" for r in slowest))
    if not parquet:
        lines.append(f"({RUNS_PARQUET} not written: pip install pyarrow, or the [cluster] extra)")
    (out / SUMMARY_TXT).write_text("\n".join(lines) + "\n")
    return lines


def _write_parquet(rows: list[dict[str, Any]], columns: list[str], path: Path) -> bool:
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return False
    table = pa.table({c: [row.get(c) for row in rows] for c in columns})
    pq.write_table(table, path)
    return True


def _plots(plan: SweepPlan, per_setting: dict[str, dict[str, Any]], results: Sequence[RunResult],
           names: Sequence[str], out: Path) -> None:  # fmt: skip
    """Each metric against the first swept axis: the mean with its 95 % interval, each run as a dot; one line per
    value of the other axes. Nothing swept: one point per metric."""
    from matplotlib.figure import Figure

    out.mkdir(exist_ok=True)
    x_axis = plan.axes[0].name if plan.axes else None
    groups: dict[str, list[tuple[float, dict[str, Any], list[RunResult]]]] = {}
    for key, figures in per_setting.items():
        setting = figures["setting"]
        others = "+".join(f"{a}={v:g}" for a, v in setting.items() if a != x_axis) or "all runs"
        runs = [r for r in results if r.ok and setting_key(r.setting) == key]
        groups.setdefault(others, []).append((setting.get(x_axis, 0.0) if x_axis else 0.0, figures, runs))
    for name in names:
        fig = Figure(figsize=(6.4, 4.0), dpi=110)
        ax: Axes = fig.add_subplot()
        for label, points in groups.items():
            points.sort(key=lambda p: p[0])
            xs = [p[0] for p in points]
            figure = [p[1]["metrics"].get(name) or {"mean": None, "ci95": [None, None]} for p in points]
            means = [f["mean"] if f["mean"] is not None else math.nan for f in figure]
            low = [m - f["ci95"][0] if f["mean"] is not None else 0.0 for m, f in zip(means, figure, strict=True)]
            high = [f["ci95"][1] - m if f["mean"] is not None else 0.0 for m, f in zip(means, figure, strict=True)]
            line = ax.errorbar(xs, means, yerr=[low, high], marker="o", capsize=4, label=label)
            dots = [(p[0], float(v)) for p in points for r in p[2] if (v := r.metrics.get(name)) is not None]
            ax.scatter([d[0] for d in dots], [d[1] for d in dots], s=8, alpha=0.3, color=line[0].get_color())
        ax.set_xlabel(x_axis or "")
        ax.set_ylabel(name)
        ax.set_title(f"{name}: mean and 95 % interval, each run a dot")
        ax.grid(alpha=0.3)
        if len(groups) > 1:
            ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(out / f"{name.replace(':', '-').replace('#', '-')}.png")
