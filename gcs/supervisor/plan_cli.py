"""``swarm plan upload|start|download``: QGroundControl plans on a running ``swarm up``, over its control channel.

The plan is read and checked here first, so a malformed file is one line and exit code 2 before anything is sent;
the supervisor then reads the same file (the control channel is loopback: both run on this machine) and uploads
each chosen drone its copy. A download comes back as the plan's text and is written here.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, Final

from gcs.missions.plan_flight import PlanUsageError, parse_offsets
from gcs.missions.qgc_plan import PlanFileError, load_plan
from gcs.supervisor.control import ControlClient

EXIT_USAGE: Final = 2
EXIT_FAILED: Final = 1


def add_plan_parser(sub: Any) -> None:
    """Add ``plan`` to the ``swarm`` command's subparsers (``sub`` is what ``add_subparsers`` returned)."""
    plan = sub.add_parser("plan", help="QGroundControl .plan files: upload to drones, start, download")
    verbs = plan.add_subparsers(dest="plan_command", required=True, parser_class=type(plan))
    upload = verbs.add_parser("upload", help="upload a .plan (mission and fence) to drones, each its own copy")
    upload.add_argument("file", type=Path, help="a QGroundControl .plan file")
    _add_drones_option(upload)
    upload.add_argument(
        "--offsets",
        default="spawn",
        metavar="spawn|none|'N,E N,E'",
        help="how each drone's copy is moved: by its spawn offset from the swarm origin (spawn, the default), "
        "not at all (none), or by N,E metres per chosen drone, in sysid order",
    )
    upload.add_argument("--start", action="store_true", help="start AUTO.MISSION once uploaded")
    start = verbs.add_parser("start", help="AUTO.MISSION on drones (arming those on the ground first)")
    _add_drones_option(start)
    download = verbs.add_parser("download", help="a drone's mission and fence, written as a .plan")
    download.add_argument("sysid", type=int, help="the drone's sysid")
    download.add_argument("file", type=Path, help="the .plan file to write")


def _add_drones_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--drones", default="all", metavar="all|1,3-5", help="sysids of the drones (default all)")


def run_plan(args: argparse.Namespace, client: ControlClient | None = None) -> int:
    """One ``swarm plan`` command; the exit code (2: a mistake in the file or the options, 1: the swarm failed)."""
    client = client or ControlClient()
    try:
        if args.plan_command == "upload":
            if not load_plan(args.file).items and args.start:
                raise PlanUsageError(f"{args.file}: the plan has no mission items to start (upload its fence alone "
                                     "without --start)")  # fmt: skip
            parse_offsets(args.offsets)
            request: dict[str, Any] = {"cmd": "plan_upload", "path": str(args.file.resolve()),
                                       "drones": args.drones, "offsets": args.offsets}  # fmt: skip
        elif args.plan_command == "start":
            request = {"cmd": "plan_start", "drones": args.drones}
        else:
            request = {"cmd": "plan_download", "sysid": args.sysid}
    except (PlanFileError, PlanUsageError) as exc:
        print(f"swarm: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    steps = [request]
    if args.plan_command == "upload" and args.start:
        steps.append({"cmd": "plan_start", "drones": args.drones})
    for step in steps:
        response = client.request(step)
        if not response.get("ok"):
            print(f"swarm: error: {response.get('error', 'failed')}", file=sys.stderr)
            return EXIT_USAGE if response.get("usage") else EXIT_FAILED
        if "result" in response:
            print(f"swarm: {response['result']}")
    if args.plan_command == "download":
        try:
            args.file.write_text(response["plan"])
        except OSError as exc:
            print(f"swarm: error: {args.file}: cannot write: {exc.strerror}", file=sys.stderr)
            return EXIT_FAILED
        print(f"swarm: sysid {args.sysid}: mission and fence written to {args.file}")
    return 0
