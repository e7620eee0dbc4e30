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

from gcs.supervisor.commands import check
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


def plan_commands(args: argparse.Namespace) -> list[dict[str, Any]]:
    """The control channel's commands for one ``swarm plan`` command, each checked as the supervisor will decode it
    (gcs/supervisor/commands.py ``check``; ValueError: one line), so that a mistake in the file or the options is
    said before anything is sent."""
    if args.plan_command == "upload":
        upload: dict[str, Any] = {"cmd": "plan_upload", "path": str(args.file), "drones": args.drones,
                                  "offsets": args.offsets, "start": args.start}  # fmt: skip
        check(upload, {})  # the file as the user named it, in their words
        commands = [{**upload, "path": str(args.file.resolve())}]  # the supervisor's cwd may differ
        if not args.start:
            return commands
        return [*commands, check({"cmd": "plan_start", "drones": args.drones}, {})]
    if args.plan_command == "start":
        return [check({"cmd": "plan_start", "drones": args.drones}, {})]
    return [check({"cmd": "plan_download", "sysid": args.sysid}, {})]


def run_plan(args: argparse.Namespace, client: ControlClient | None = None) -> int:
    """One ``swarm plan`` command; the exit code (2: a mistake in the file or the options, 1: the swarm failed)."""
    client = client or ControlClient()
    try:
        steps = plan_commands(args)
    except ValueError as exc:
        print(f"swarm: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
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
