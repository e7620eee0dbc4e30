"""``swarm sweep``: its options, their checks (one line and exit code 2 before anything flies), and the run."""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any, Final

from gcs.fleet.harness import Simulation
from gcs.missions.mission_file import load_mission
from gcs.sweep.plan import SweepError, SweepPlan, file_sha256, link_loss_axis, parse_param, parse_seeds
from gcs.sweep.summary import write_summary
from gcs.sweep.sweep import Flyer, LocalFlyer, SweepInterrupted, default_jobs, run_sweep

DRONES_PER_CPU: Final = 10  # drones one run's process hosts (a hosted drone takes about a tenth of a CPU)
EXIT_RUNS_FAILED: Final = 1
EXIT_INTERRUPTED: Final = 130


def add_sweep_parser(sub: Any) -> None:
    sweep = sub.add_parser("sweep", help="fly a mission over many seeds and settings (locally or on Ray) with "
                           "statistics (docs/sweeps.md)")  # fmt: skip
    sweep.add_argument("mission", type=Path, help="mission file")
    sweep.add_argument("--seeds", required=True, help="seeds: 1-200, 1,5,9 or 1-10,20-30")
    sweep.add_argument("--param", action="append", default=[], metavar="NAME=V1,V2,...",
                       help="a drone parameter and its values (or START:STOP:STEP); repeatable, every combination "
                       "is flown")  # fmt: skip
    sweep.add_argument(
        "--link-loss",
        default=None,
        metavar="P1,P2,...",
        help="link loss probabilities to sweep (every link class, as swarm fly --link-loss)",
    )
    sweep.add_argument("--jobs", type=int, default=None,
                       help="runs side by side on this machine (default: as many as its CPUs hold)")  # fmt: skip
    sweep.add_argument("--out", type=Path, default=None, help="output folder (default sweeps/<mission>-<time>); "
                       "the same folder again resumes the sweep")  # fmt: skip
    sweep.add_argument(
        "--ray",
        default=None,
        metavar="auto|ADDRESS",
        help="fly the runs on a Ray cluster (pip install .[cluster]; docs/sweeps.md)",
    )
    sweep.add_argument("--drones-per-process", type=int, default=None, metavar="K",
                       help=f"drones each simulation process of a run hosts (default {DRONES_PER_CPU}); a run asks "
                       "one CPU per process")  # fmt: skip
    sweep.add_argument("--quantum", type=int, default=None, help="lockstep quantum of every run (swarm fly --quantum)")
    sweep.add_argument("--speed", type=float, default=None, metavar="F",
                       help="pace every run's lockstep clock at F times real time (swarm fly --speed; default: as "
                       "fast as the CPU allows); a run flies the same at any pace")  # fmt: skip
    sweep.add_argument("--airframe", default=None, help="airframe of every drone (swarm fly --airframe)")


def _plan(args: argparse.Namespace, simulation: Simulation) -> tuple[SweepPlan, int]:
    mission = load_mission(args.mission, max_obstacles=simulation.max_obstacles)
    if mission.swarm.attach:
        raise SweepError(f"{args.mission}: a mission with [[swarm.attach]] flies paced at speed 1 beside a real "
                         "vehicle; a sweep's runs are lockstep flights of simulated drones alone")  # fmt: skip
    n = mission.swarm.drones
    axes = [parse_param(p) for p in args.param]
    for axis in axes:
        for value in axis.values:
            try:
                simulation.parameter_value(axis.name, value)
            except ValueError as exc:
                raise SweepError(f"--param {axis.name}: {exc}") from None
    if args.link_loss is not None:
        axes.append(link_loss_axis(args.link_loss))
    per_process = args.drones_per_process if args.drones_per_process is not None else min(n, DRONES_PER_CPU)
    if per_process < 1:
        raise SweepError(f"--drones-per-process must be at least 1, got {per_process}")
    fly_args = ["--drones-per-process", str(per_process)]
    if args.quantum is not None:
        if args.quantum < 1:
            raise SweepError(f"--quantum must be at least 1, got {args.quantum}")
        fly_args += ["--quantum", str(args.quantum)]
    if args.speed is not None:
        if not (math.isfinite(args.speed) and args.speed > 0):
            raise SweepError(f"--speed must be a positive number, got {args.speed:g}")
        fly_args += ["--speed", f"{args.speed:g}"]
    if args.airframe is not None:
        try:
            simulation.contact_distance_m(args.airframe)
        except ValueError as exc:
            raise SweepError(f"--airframe: {exc}") from None
        fly_args += ["--airframe", args.airframe]
    plan = SweepPlan(mission=args.mission.resolve(), mission_sha256=file_sha256(args.mission), n_drones=n,
                     seeds=parse_seeds(args.seeds), axes=tuple(axes), fly_args=tuple(fly_args))  # fmt: skip
    return plan, per_process


def run_sweep_command(args: argparse.Namespace, simulation: Simulation, usable_cpus: int) -> int:
    """``swarm sweep``; SweepError (one line, exit code 2) for what is wrong before anything flies."""
    plan, per_process = _plan(args, simulation)
    if args.jobs is not None and args.jobs < 1:
        raise SweepError(f"--jobs must be at least 1, got {args.jobs}")
    if args.ray is not None and args.jobs is not None:
        raise SweepError("--jobs is for this machine; with --ray the cluster's CPUs decide")
    stamp = time.strftime("%Y%m%d-%H%M%S")
    out: Path = args.out or Path("sweeps") / f"{args.mission.stem}-{stamp}"

    def say(text: str) -> None:
        print(text, flush=True)

    flyer: Flyer
    if args.ray is not None:
        from gcs.sweep.cluster import RayFlyer

        flyer = RayFlyer(args.ray, per_process, say)
    else:
        jobs = args.jobs or default_jobs(usable_cpus, plan.n_drones, per_process)
        say(f"sweep: {jobs} run(s) at a time on this machine")
        flyer = LocalFlyer(jobs)
    try:
        outcome = run_sweep(plan, out, flyer, say)
    except SweepInterrupted as exc:
        print(f"swarm: sweep interrupted: {exc.complete} of {exc.total} runs complete in {out}; the same command "
              f"with --out {out} flies the rest", file=sys.stderr)  # fmt: skip
        return EXIT_INTERRUPTED
    finally:
        flyer.close()
    for line in write_summary(plan, outcome.results, out):
        say(line)
    failed = [r for r in outcome.results if not r.ok]
    say(f"sweep: {len(outcome.results)} runs ({outcome.skipped} from before), summary in {out}")
    if failed:
        print(f"swarm: {len(failed)} run(s) failed (see summary.txt); run the same command again to fly them again",
              file=sys.stderr)  # fmt: skip
        return EXIT_RUNS_FAILED
    return 0
