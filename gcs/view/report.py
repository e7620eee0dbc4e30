"""The flight report written after ``swarm fly MISSION --report DIR``: metrics, plots and a plain-text summary.

One call, ``write_report(recording, out_dir)``, turns a FlightRecording into files a person can open without our
tools: ``metrics.json`` (the numbers defined in gcs/record/metrics.py, for scripts and acceptance checks),
``trajectories.png``, ``altitude.png``, ``separation.png``, ``summary.txt`` and ``report.html``, a page that replays
the flight and holds everything else (gcs/view/report_page.py). Plots are drawn on matplotlib Figure
objects with the Agg canvas directly (no pyplot state, no display), so reports can be written from any thread or a
headless machine.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

from gcs.fleet.pace_monitor import SLOW_FRACTION
from gcs.record.metrics import (
    AIRBORNE_HEIGHT_M,
    FORMATION_SETTLED_RMS_M,
    TAKEOFF_TOLERANCE_M,
    FlightMetrics,
    compute_metrics,
    link_summary,
)
from gcs.record.recording import DroneSample, FlightRecording, StepRecord
from gcs.view.replay import replay_document
from gcs.view.report_page import write_report_page

if TYPE_CHECKING:  # matplotlib is imported when a report is drawn: every `swarm` command would wait for it otherwise
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

log = logging.getLogger(__name__)

METRICS_FILE = "metrics.json"
TRAJECTORIES_FILE = "trajectories.png"
ALTITUDE_FILE = "altitude.png"
SEPARATION_FILE = "separation.png"
SUMMARY_FILE = "summary.txt"

SEPARATION_GOAL_M = 1.0  # drawn on the separation plot: the swarm's minimum-separation requirement
MAX_LEGEND_DRONES = 12
SUMMARY_AVOIDANCE_STARTS = 20  # avoidance episodes listed in summary.txt; metrics.json lists all
_DPI = 110

Colour = tuple[float, float, float, float]

# When the three plots are drawn: ``failed`` draws them for a flight that broke something (it did not finish, an
# invariant was violated, a drone touched another) and leaves them out of one that did not. Drawing them costs a
# flight about three seconds (matplotlib's import and rendering), as much as a short lockstep flight itself: sweeps and
# falsification campaigns, which fly hundreds, ask for ``failed``; a person flying one mission gets them always.
PlotPolicy = Literal["always", "failed", "never"]
PLOT_POLICIES: tuple[PlotPolicy, ...] = ("always", "failed", "never")
PLOT_FILES = (TRAJECTORIES_FILE, ALTITUDE_FILE, SEPARATION_FILE)


def write_report(recording: FlightRecording, out_dir: str | Path, *, plots: PlotPolicy = "always",
                 failed: bool = False) -> Path:  # fmt: skip
    """Write every report file into ``out_dir`` (created if missing) and return that directory. ``failed``: the
    flight did not finish (for ``plots="failed"``; a violation or a contact counts as well, from the metrics)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    metrics = compute_metrics(recording)
    with (out / METRICS_FILE).open("w", encoding="utf-8") as f:
        json.dump(metrics.to_dict(), f, indent=2, allow_nan=False)
        f.write("\n")
    broke = failed or metrics.collisions > 0 or bool(metrics.violations)
    drawn = [out / name for name in PLOT_FILES] if plots == "always" or (plots == "failed" and broke) else []
    if drawn:
        tracks = _by_drone(recording.samples)
        colours = drone_colours(list(tracks))
        _save(_trajectories_figure(recording, tracks, colours), out / TRAJECTORIES_FILE)
        _save(_altitude_figure(recording, tracks, colours), out / ALTITUDE_FILE)
        _save(_separation_figure(recording, metrics), out / SEPARATION_FILE)
    else:  # none left from an earlier flight into the same folder (a sweep's run flown again)
        for name in PLOT_FILES:
            (out / name).unlink(missing_ok=True)
    summary = summary_text(metrics)
    (out / SUMMARY_FILE).write_text(summary, encoding="utf-8")
    write_report_page(replay_document(recording), out, title=recording.mission_name, summary=summary, plots=drawn)
    log.info("flight report written to %s", out)
    return out


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """``n`` and the noun agreeing with it: "1 drone", "2 drones", "0 drones" (``plural`` when not noun + "s")."""
    return f"{n} {noun if n == 1 else plural or noun + 's'}"


def drone_colours(sysids: Sequence[int]) -> dict[int, Colour]:
    """Distinct colours per drone: qualitative palettes while they last, then an evenly sampled colour map."""
    from matplotlib import colormaps

    n = len(sysids)
    if n <= 10:
        palette = colormaps["tab10"]
        return {sysid: palette(i) for i, sysid in enumerate(sysids)}
    if n <= 20:
        palette = colormaps["tab20"]
        return {sysid: palette(i) for i, sysid in enumerate(sysids)}
    cmap = colormaps["turbo"]
    return {sysid: cmap(x) for sysid, x in zip(sysids, np.linspace(0.05, 0.95, n), strict=True)}


# --- plots ------------------------------------------------------------------------------------------------------


def _by_drone(samples: Sequence[DroneSample]) -> dict[int, list[DroneSample]]:
    out: dict[int, list[DroneSample]] = {}
    for sample in sorted(samples, key=lambda s: (s.sysid, s.time_s)):
        out.setdefault(sample.sysid, []).append(sample)
    return out


def _new_figure(width_in: float, height_in: float) -> tuple[Figure, Axes]:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), layout="constrained")
    FigureCanvasAgg(fig)
    return fig, fig.add_subplot()


def _save(fig: Figure, path: Path) -> None:
    fig.savefig(path, dpi=_DPI)


def _no_data(ax: Axes) -> None:
    ax.text(0.5, 0.5, "no data recorded", transform=ax.transAxes, ha="center", va="center", color="grey")


def _legend_outside(ax: Axes, n_drones: int) -> None:
    """Beside the axes, so it never hides a trajectory; left out when there are too many drones to tell apart."""
    if 0 < n_drones <= MAX_LEGEND_DRONES:
        ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    elif n_drones:
        ax.text(
            1.01,
            1.0,
            f"{counted(n_drones, 'drone')},\none colour each\n(no legend)",
            transform=ax.transAxes,
            va="top",
            fontsize="small",
            color="dimgrey",
        )


def _last_slots(recording: FlightRecording, tracks: dict[int, list[DroneSample]]) -> tuple[str, list[DroneSample]]:
    """The last commanded slot of each drone in the last step that commanded any (name, samples holding the slot)."""
    for step in reversed(recording.steps):
        slots = []
        for samples in tracks.values():
            in_step = [s for s in samples if step.start_s <= s.time_s <= step.end_s and s.target_ned_m is not None]
            if in_step:
                slots.append(in_step[-1])
        if slots:
            return step.name, slots
    return "", []


def _trajectories_figure(
    recording: FlightRecording, tracks: dict[int, list[DroneSample]], colours: dict[int, Colour]
) -> Figure:
    fig, ax = _new_figure(9.0, 7.5)
    ax.set_title(f"{recording.mission_name}: trajectories, top-down (swarm frame)")
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    if not tracks:
        _no_data(ax)
        return fig
    step_name, slots = _last_slots(recording, tracks)
    if slots:
        ax.scatter(
            [s.target_ned_m[1] for s in slots if s.target_ned_m],
            [s.target_ned_m[0] for s in slots if s.target_ned_m],
            s=160,
            facecolors="none",
            edgecolors=[colours[s.sysid] for s in slots],
            alpha=0.35,
            linewidths=2.0,
            label=f"slots: {step_name}",
            zorder=1,
        )
    for sysid, samples in tracks.items():
        north = [s.pos_ned_m[0] for s in samples]
        east = [s.pos_ned_m[1] for s in samples]
        colour = colours[sysid]
        ax.plot(east, north, color=colour, linewidth=1.2, label=f"drone {sysid}", zorder=2)
        ax.plot(east[0], north[0], marker="o", color=colour, markersize=7, zorder=3)
        ax.plot(east[-1], north[-1], marker="s", color=colour, markersize=7, markeredgecolor="black", zorder=3)
    # proxy artists so the legend explains the markers once, not per drone
    ax.plot([], [], marker="o", linestyle="none", color="grey", label="start")
    ax.plot([], [], marker="s", linestyle="none", color="grey", markeredgecolor="black", label="end")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    _legend_outside(ax, len(tracks))
    return fig


def _step_lines(ax: Axes, steps: Sequence[StepRecord]) -> None:
    for step in steps:
        ax.axvline(step.start_s, color="grey", linestyle=":", linewidth=1.0)
        ax.text(
            step.start_s,
            0.99,
            f" {step.name}",
            transform=ax.get_xaxis_transform(),
            rotation=90,
            va="top",
            ha="left",
            fontsize="small",
            color="dimgrey",
            bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none", "pad": 1.0},
        )
    if steps:
        ax.axvline(steps[-1].end_s, color="grey", linestyle=":", linewidth=1.0)


def _altitude_figure(
    recording: FlightRecording, tracks: dict[int, list[DroneSample]], colours: dict[int, Colour]
) -> Figure:
    fig, ax = _new_figure(10.0, 5.0)
    ax.set_title(f"{recording.mission_name}: altitude above the swarm origin")
    ax.set_xlabel("time since mission start [s]")
    ax.set_ylabel("altitude [m]")
    if not tracks:
        _no_data(ax)
        return fig
    for sysid, samples in tracks.items():
        ax.plot(
            [s.time_s for s in samples],
            [-s.pos_ned_m[2] for s in samples],
            color=colours[sysid],
            linewidth=1.2,
            label=f"drone {sysid}",
        )
    for step in recording.steps:
        if step.kind == "takeoff" and step.target_alt_m is not None:
            ax.fill_between(
                [step.start_s, step.end_s],
                step.target_alt_m - TAKEOFF_TOLERANCE_M,
                step.target_alt_m + TAKEOFF_TOLERANCE_M,
                color="green",
                alpha=0.12,
                label=f"takeoff target ±{TAKEOFF_TOLERANCE_M:g} m",
            )
    _step_lines(ax, recording.steps)
    ax.set_ylim(bottom=min(0.0, ax.get_ylim()[0]))
    ax.grid(True, alpha=0.3)
    _legend_outside(ax, len(tracks))
    return fig


def _separation_figure(recording: FlightRecording, metrics: FlightMetrics) -> Figure:
    fig, ax = _new_figure(10.0, 5.0)
    ax.set_title(f"{recording.mission_name}: minimum separation between airborne drones")
    ax.set_xlabel("time since mission start [s]")
    ax.set_ylabel("minimum pairwise distance [m]")
    series = metrics.separation
    if not np.any(np.isfinite(series.min_separation_m)):
        ax.text(
            0.5,
            0.5,
            "never two drones airborne at once",
            transform=ax.transAxes,
            ha="center",
            va="center",
            color="grey",
        )
    ax.plot(series.time_s, series.min_separation_m, color="tab:blue", linewidth=1.3, label="min separation")
    ax.axhline(SEPARATION_GOAL_M, color="tab:orange", linestyle="--", label=f"required {SEPARATION_GOAL_M:g} m")
    ax.axhline(
        recording.collision_radius_m,
        color="tab:red",
        linestyle="--",
        label=f"contact distance {recording.collision_radius_m:g} m",
    )
    if metrics.min_separation_m is not None and metrics.min_separation_time_s is not None:
        a, b = metrics.min_separation_pair or (0, 0)
        ax.plot(
            metrics.min_separation_time_s,
            metrics.min_separation_m,
            marker="v",
            color="black",
            linestyle="none",
            clip_on=False,  # a minimum of 0 m sits on the axis
        )
        ax.annotate(
            f"{metrics.min_separation_m:.2f} m (drones {a}, {b})",
            (metrics.min_separation_time_s, metrics.min_separation_m),
            textcoords="offset points",
            xytext=(10, 2),
            fontsize="small",
            bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none", "pad": 1.0},
        )
    for k, event in enumerate(metrics.collision_events):
        ax.axvline(
            event.time_s,
            color="tab:red",
            alpha=0.6,
            linewidth=1.5,
            label="collision event" if k == 0 else None,
        )
    _step_lines(ax, recording.steps)
    ax.set_ylim(bottom=0.0)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    return fig


# --- summary ----------------------------------------------------------------------------------------------------


def _fmt(value: float | None, unit: str, decimals: int = 2) -> str:
    return "-" if value is None else f"{value:.{decimals}f} {unit}"


def summary_text(metrics: FlightMetrics) -> str:
    """The report in a few lines of plain text (also what ``swarm fly`` can print at the end)."""
    sysids = ", ".join(str(s) for s in metrics.sysids) or "none"
    lines = [
        f"Flight report: {metrics.mission_name}",
        f"drones: {metrics.n_drones} (reporting: {sysids})",
        f"duration: {metrics.duration_s:.1f} s",
        "MAVLink signing: "
        + (
            f"on (key {metrics.signing_key_id}; the drones drop unsigned messages)" if metrics.signing_key_id else "off"
        ),
        f"neighbours: {metrics.neighbours}",
    ]
    for name, counts in metrics.link_counters.items():
        link = link_summary(counts)
        lines.append(
            f"link model, {name}: {link['frames_lost']} of {counted(link['frames_offered'], 'frame')} lost "
            f"({100.0 * (link['loss_rate'] or 0.0):.1f} %), {link['frames_delayed']} delayed"
            + (f" (mean {link['mean_delay_ms']:.1f} ms)" if link["mean_delay_ms"] is not None else "")
            + (
                f"; lost {link['lost_range']} beyond range, {link['lost_path']} to path loss, {link['lost_model']} "
                f"to the link model; the neighbour tables took {counted(link['mesh_updates'], 'report')} "
                f"from the mesh, {link['relay_updates']} from the relay"
                + (f", {link['link_updates']} from other MAVLink links" if link.get("link_updates") else "")
                if "lost_range" in link
                else ""
            )
        )
    if metrics.requested_speed is not None and metrics.realtime_factor_min is not None:
        speed, low = metrics.requested_speed, metrics.realtime_factor_min
        behind = low < SLOW_FRACTION * speed
        lines.append(
            f"pace: {metrics.realtime_factor_mean:.2f}x real time on average, {low:.2f}x at the slowest, "
            f"{speed:g}x requested"
            + (" - BEHIND: the mission's timing ran ahead of the drones (see docs/benchmarks.md)" if behind else "")
        )
    lines.append("")

    if metrics.takeoff_time_per_drone_s:
        slowest = [k for k, v in metrics.takeoff_time_per_drone_s.items() if v == metrics.takeoff_time_s]
        takeoff = (
            "not every drone reached and held its altitude"
            if metrics.takeoff_time_s is None
            else f"{metrics.takeoff_time_s:.2f} s (slowest: drone {slowest[0]})"
        )
        lines.append(f"takeoff (all drones within {TAKEOFF_TOLERANCE_M:g} m of the target and holding): {takeoff}")
        per_drone = "  ".join(f"{k}: {_fmt(v, 's')}" for k, v in metrics.takeoff_time_per_drone_s.items())
        lines += [f"  per drone: {per_drone}", ""]

    lines.append(
        f"steps (in formation: swarm RMS error <= {FORMATION_SETTLED_RMS_M:g} m until the step ends, from the plan's "
        "arrival on; rms/max error over that settled part):"
    )
    header = (
        f"  {'#':>2}  {'name':<14} {'kind':<10} {'start':>8} {'end':>8} "
        f"{'to form.':>9} {'rms':>8} {'max err':>8} {'step rms':>9}"
    )
    lines.append(header)
    for step in metrics.steps:
        lines.append(
            f"  {step.index:>2}  {step.name:<14.14} {step.kind:<10.10} {step.start_s:>6.1f} s {step.end_s:>6.1f} s "
            f"{_fmt(step.time_to_formation_s, 's'):>9} {_fmt(step.formation_rms_m, 'm'):>8} "
            f"{_fmt(step.max_error_m, 'm'):>8} {_fmt(step.step_rms_m, 'm'):>9}"
        )
    if not metrics.steps:
        lines.append("  (no steps recorded)")
    lines.append("")

    if metrics.min_separation_m is None:
        lines.append(f"min separation: - (never two drones airborne, i.e. armed and > {AIRBORNE_HEIGHT_M:g} m up)")
    else:
        a, b = metrics.min_separation_pair or (0, 0)
        lines.append(
            f"min separation: {metrics.min_separation_m:.2f} m at {_fmt(metrics.min_separation_time_s, 's', 1)} "
            f"(drones {a} and {b}; contact distance {metrics.collision_radius_m:g} m)"
        )
    for sysid, attached in metrics.attached.items():
        where = (
            f"closest to a drone {attached.min_separation_m:.2f} m at {_fmt(attached.min_separation_time_s, 's', 1)} "
            f"(drone {attached.closest_drone})"
            if attached.min_separation_m is not None
            else "never there while a drone flew"
        )
        slot = (f"; its slot {attached.slot_rms_m:.2f} m RMS (at most {attached.max_slot_error_m:.2f} m) once the "
                "formations settled" if attached.slot_rms_m is not None and attached.max_slot_error_m is not None
                else "")  # fmt: skip
        lines.append(f"attached vehicle {sysid} ({attached.role} on {attached.link}): {where}{slot}")
    if metrics.invariants:
        lines.append(f"invariants: {len(metrics.invariants)} checked, {len(metrics.violations)} violated")
        lines.extend(f"  {v.line()}" for v in metrics.violations)
    lines.append(f"collisions: {metrics.collisions}")
    for event in metrics.collision_events:
        who = "swarm" if event.sysid is None else f"drone {event.sysid}"
        lines.append(f"  {event.time_s:7.1f} s  {who}: {event.text}")
    closest = metrics.avoidance_closest_approach_m
    lines.append(
        f"avoidance events: {metrics.avoidance_events}"
        + (f" (closest approach seen by a drone: {closest:.2f} m)" if closest is not None else "")
    )
    for event in metrics.avoidance_starts[:SUMMARY_AVOIDANCE_STARTS]:  # each says why: whom, how close, when
        lines.append(f"  {event.time_s:7.1f} s  drone {event.sysid}: {event.text}")
    if len(metrics.avoidance_starts) > SUMMARY_AVOIDANCE_STARTS:
        lines.append(f"  ... and {len(metrics.avoidance_starts) - SUMMARY_AVOIDANCE_STARTS} more (metrics.json: "
                     "avoidance_starts)")  # fmt: skip
    flown = "  ".join(f"{k}: {v:.1f} m" for k, v in metrics.distance_flown_m.items()) or "-"
    lines += [f"distance flown: {flown}", ""]
    if metrics.items_reached:
        lines.append("mission items reached (AUTO.MISSION):")
        for sysid in sorted({r.sysid for r in metrics.items_reached}):
            reached = [r for r in metrics.items_reached if r.sysid == sysid]
            seqs = " ".join(str(r.seq) for r in reached)
            lines.append(f"  drone {sysid}: {seqs} (last at {reached[-1].time_s:.1f} s)")
        lines.append("")
    lines += faults_text(metrics)
    return "\n".join(lines)


def faults_text(metrics: FlightMetrics) -> list[str]:
    """Faults injected, failsafes, losses and the loss policy, in the order a reader asks about them."""
    lines = []
    if metrics.faults:
        lines.append(f"faults injected: {len(metrics.faults)}")
        lines += [f"  {f.time_s:7.1f} s  drone {f.sysid}: {f.fault} ({f.result})" for f in metrics.faults]
    if metrics.failsafes:
        lines.append(f"failsafes: {len(metrics.failsafes)}")
        lines += [f"  {e.time_s:7.1f} s  drone {e.sysid}: {e.text}" for e in metrics.failsafes]
    regained = f", {len(metrics.regained)} more heard again" if metrics.regained else ""
    lines.append(f"drones lost: {len(metrics.losses)}{regained} (loss policy: {metrics.loss_policy})")
    for loss in metrics.losses:
        down = loss.down_ne_m
        where = "not seen on the ground" if down is None else f"down at {down[0]:.1f} m N, {down[1]:.1f} m E"
        lines.append(f"  {loss.time_s:7.1f} s  drone {loss.sysid}: {loss.cause}; {where}")
    for loss in metrics.regained:
        lines.append(f"  {loss.time_s:7.1f} s  drone {loss.sysid}: {loss.cause}; regained at {loss.regained_s:.1f} s")
    lines += [f"  {e.time_s:7.1f} s  swarm: {e.text}" for e in metrics.policy_events]
    if metrics.losses or metrics.regained:
        lines.append(
            "  (formation errors and separations count each lost drone only until its loss, and each drone "
            "heard again from its return)"
        )
    lines.append("")
    return lines
