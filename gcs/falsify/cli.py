"""``swarm falsify``: its options, their checks (one line and exit code 2 before anything flies), and the search."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any, Final

from gcs.falsify.space import FalsifyError
from gcs.invariants.monitor import EXIT_VIOLATED
from gcs.sweep.cli import DRONES_PER_CPU, EXIT_INTERRUPTED
from gcs.sweep.sweep import Flyer, LocalFlyer, default_jobs

MAX_BUDGET: Final = 10_000
MAX_RAY_SHRINKS: Final = 8  # failures shrunk side by side on a cluster (each shrinking is one flight at a time)


def add_falsify_parser(sub: Any) -> None:
    falsify = sub.add_parser("falsify", help="search a mission's [falsify] space for flights that break its "
                             "invariants, each shrunk to a minimal mission file (docs/falsify.md)")  # fmt: skip
    falsify.add_argument("mission", type=Path, help="a mission file with [[invariants]] and a [falsify] table")
    falsify.add_argument("--budget", type=int, default=40, help="flights to search (default 40)")
    falsify.add_argument("--shrink-budget", type=int, default=40,
                         help="flights to shrink what was found, counted apart (default 40)")  # fmt: skip
    falsify.add_argument("--seed", type=int, default=0, help="the campaign's seed: the same seed, the same search")
    falsify.add_argument(
        "--jobs",
        type=int,
        default=None,
        help="flights side by side on this machine (default: as many as it has CPUs for)",
    )
    falsify.add_argument(
        "--ray",
        default=None,
        metavar="ADDRESS",
        help="fly on a Ray cluster (auto: the one this machine belongs to), as swarm sweep --ray",
    )
    falsify.add_argument("--time", type=float, default=None, metavar="S", help="stop searching after S wall seconds")
    falsify.add_argument("--out", type=Path, default=None,
                         help="the campaign's folder (default falsify/<mission>-<seed>); again: resume")  # fmt: skip
    falsify.add_argument(
        "--emit-tests",
        type=Path,
        default=None,
        metavar="DIR",
        help="write each minimal mission file and a pytest regression test for it into DIR",
    )


def run_falsify(args: argparse.Namespace, usable_cpus: int) -> int:
    """``swarm falsify``; 0 when nothing broke, EXIT_VIOLATED (3) when a failure was found. Bad input raises
    FalsifyError or MissionFileError (one line: the swarm command's exit code 2) before anything flies."""
    problem = _problem(args)
    if problem is not None:
        raise FalsifyError(problem)
    try:
        import hypothesis  # noqa: F401
        import tomli_w  # noqa: F401
    except ImportError:
        raise FalsifyError("swarm falsify needs hypothesis and tomli-w: pip install 'swarmsitl[falsify]'") from None
    from gcs.falsify.campaign import Campaign
    from gcs.missions.mission_file import load_mission

    mission = load_mission(args.mission)
    if not mission.invariants:
        raise FalsifyError(f"{args.mission}: no [[invariants]]: nothing a flight could break")
    out = args.out or Path("falsify") / f"{args.mission.stem}-{args.seed}"
    per_process = min(mission.swarm.drones, DRONES_PER_CPU)
    flyer: Flyer
    if args.ray is not None:
        from gcs.sweep.cluster import RayFlyer

        flyer = RayFlyer(args.ray, per_process, print)
        jobs = args.jobs or MAX_RAY_SHRINKS
    else:
        jobs = args.jobs or default_jobs(usable_cpus, mission.swarm.drones, per_process)
        flyer = LocalFlyer(jobs)
        print(f"falsify: {jobs} flight(s) at a time on this machine")
    campaign = Campaign(args.mission, out, budget=args.budget, shrink_budget=args.shrink_budget, seed=args.seed,
                        time_s=args.time, flyer=flyer, jobs=jobs, say=print,
                        fly_args=("--drones-per-process", str(per_process)))  # fmt: skip
    started = time.monotonic()
    try:
        result = campaign.run()
    except KeyboardInterrupt:
        print(f"swarm: falsify interrupted; what was flown is kept in {out}: the same command resumes",
              file=sys.stderr)  # fmt: skip
        return EXIT_INTERRUPTED
    finally:
        flyer.close()
    print((out / "summary.txt").read_text().rstrip())
    print(f"swarm: falsify took {time.monotonic() - started:.0f} s; summary in {out / 'summary.txt'}")
    if args.emit_tests is not None:
        for test in campaign.emit_tests(args.emit_tests):
            print(f"swarm: regression test {test}")
    return EXIT_VIOLATED if result.failures else 0


def _problem(args: argparse.Namespace) -> str | None:
    if not 1 <= args.budget <= MAX_BUDGET:
        return f"--budget must be in 1..{MAX_BUDGET} flights, got {args.budget}"
    if not 0 <= args.shrink_budget <= MAX_BUDGET:
        return f"--shrink-budget must be in 0..{MAX_BUDGET} flights, got {args.shrink_budget}"
    if args.jobs is not None and args.jobs < 1:
        return f"--jobs must be at least 1, got {args.jobs}"
    if args.ray is not None and args.jobs is not None:
        return "--jobs is for this machine; with --ray the cluster's CPUs decide"
    if args.time is not None and not args.time > 0:
        return f"--time must be a positive number of seconds, got {args.time}"
    if not args.mission.is_file():
        return f"{args.mission}: no such mission file"
    return None
