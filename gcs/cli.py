"""``swarm``: the ground-station command line.

The supervisor (spawning drones, formations, neighbour relay, missions) is being built; for now the command lists
its planned sub-commands and refuses to pretend it can run them.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

PLANNED = (
    ("up -n N", "spawn N sitl drones and supervise them"),
    ("status", "table of every drone: mode, armed, position, battery, link age"),
    ("takeoff [--alt M]", "all drones take off"),
    ("formation grid|circle|line|v", "fly a formation"),
    ("goto", "move the formation"),
    ("land | rtl", "land where they are, or return to launch"),
    ("down", "land, disarm and stop every drone"),
    ("fly MISSION", "run a mission file end to end and write a flight report"),
)


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if args and args[0] not in ("-h", "--help"):
        print(
            f"swarm: error: '{args[0]}' is not available yet; run 'swarm --help' for the plan",
            file=sys.stderr,
        )
        return 2
    print("usage: swarm COMMAND [options]   (ground station; not yet implemented)\n\nplanned commands:")
    for command, text in PLANNED:
        print(f"  swarm {command:<30} {text}")
    print("\nToday, fly one drone with:  sitl --demo")
    return 0


if __name__ == "__main__":
    sys.exit(main())
