"""``sitl``: run one simulated drone as a process.

The command line only parses and validates arguments, then calls ``run(...)``; tests call the same entry point.
User mistakes end with one line on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import NoReturn

from sitl.airframe import DEFAULT_AIRFRAME, AirframeError, load_airframe
from sitl.dynamics.plant import DEFAULT_HOME, GeoPoint
from sitl.mavlink_io import LinkConfig, LinkError, parse_host_port
from sitl.wind import WindConfig
from sitl.world import WorldError

EXIT_USAGE = 2
SPEED_ENV = "PX4_SIM_SPEED_FACTOR"


class UsageError(Exception):
    """A bad argument or input file, reported as one line with exit code 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        raise UsageError(message)


def _float_list(text: str, count: int, what: str) -> tuple[float, ...]:
    parts = text.split(",")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        raise UsageError(f"{what} must be {count} comma-separated numbers, got {text!r}") from None
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise UsageError(f"{what} must be {count} comma-separated finite numbers, got {text!r}")
    return values


def _speed_factor(arg: str | None) -> float:
    source, text = ("--speed", arg) if arg is not None else (SPEED_ENV, os.environ.get(SPEED_ENV))
    if text is None or text == "":
        return 1.0
    try:
        value = float(text)
    except ValueError:
        raise UsageError(f"{source} must be a number, got {text!r}") from None
    if not math.isfinite(value) or value < 0:
        raise UsageError(f"{source} must be a finite number >= 0 (0 = as fast as possible), got {text!r}")
    return value


def _address(text: str, what: str) -> tuple[str, int]:
    address = parse_host_port(text)
    if address is None:
        raise UsageError(f"{what} must be HOST:PORT with a port in 1..65535, got {text!r}")
    return address


def _port(value: int | None, default: int, what: str) -> int:
    port = default if value is None else value
    if not 0 <= port < 65536:
        raise UsageError(f"{what} must be in 0..65535, got {port}")
    return port


def _links(args: argparse.Namespace) -> list[LinkConfig]:
    """PX4 SITL's port convention for instance i: API 14580+i -> 14540+i, ground station 18570+i -> 14550."""
    if args.no_mavlink:
        return []
    i = args.instance
    links = [
        LinkConfig(
            name="API",
            bind=(args.host, _port(args.api_port, 14580 + i, "--api-port")),
            remote=_address(args.api_remote or f"127.0.0.1:{14540 + i}", "--api-remote"),
        )
    ]
    if not args.no_gcs:
        links.append(
            LinkConfig(
                name="GCS",
                bind=(args.host, _port(args.gcs_port, 18570 + i, "--gcs-port")),
                remote=_address(args.gcs_remote, "--gcs-remote"),
            )
        )
    return links


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="sitl", description="Run one simulated quadrotor (JSBSim + PX4-style autopilot).")
    parser.add_argument("--instance", type=int, default=0, help="instance number i >= 0 (MAVLink sysid i+1)")
    parser.add_argument("--airframe", default=DEFAULT_AIRFRAME, help="airframe name in airframes/ or a .toml path")
    parser.add_argument(
        "--speed", default=None, help=f"simulation speed factor (default: ${SPEED_ENV} or 1.0; 0 = unpaced)"
    )
    parser.add_argument("--seed", type=int, default=None, help="random seed (default: the instance number)")
    parser.add_argument("--home", default=None, help="home as LAT,LON,ALT_AMSL (default: PX4 SITL home)")
    parser.add_argument("--wind", default="0,0,0", help="steady wind N,E,D in m/s (the direction it blows to)")
    parser.add_argument("--gust", type=float, default=0.0, help="gust RMS intensity in m/s")
    parser.add_argument("--host", default="127.0.0.1", help="address the MAVLink links bind (default loopback)")
    parser.add_argument("--api-port", type=int, default=None, help="API link UDP port (default 14580+instance)")
    parser.add_argument(
        "--api-remote", default=None, help="HOST:PORT the API link streams to (default 127.0.0.1:14540+instance)"
    )
    parser.add_argument("--gcs-port", type=int, default=None, help="ground-station link port (default 18570+instance)")
    parser.add_argument("--gcs-remote", default="127.0.0.1:14550", help="HOST:PORT of the ground station")
    parser.add_argument("--no-gcs", action="store_true", help="no ground-station link")
    parser.add_argument("--no-mavlink", action="store_true", help="no MAVLink links at all (e.g. for --demo)")
    parser.add_argument("--world", default=None, help="name of the swarm's shared-world table (set by swarm)")
    parser.add_argument(
        "--lockstep", action="store_true", help="advance time together with the swarm's other drones (needs --world)"
    )
    parser.add_argument(
        "--lockstep-quantum", type=int, default=1, help="lockstep: steps run between waits (skew bound; default 1)"
    )
    parser.add_argument(
        "--camera-frames", type=Path, default=None, help="save every camera frame as PNG in this directory"
    )
    parser.add_argument("--duration", type=float, default=None, help="exit after this many simulated seconds")
    parser.add_argument("--demo", action="store_true", help="take off to 3 m, hover, land and exit, printing progress")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    try:
        return _main(argv)
    except (UsageError, AirframeError) as exc:
        print(f"sitl: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except (LinkError, WorldError) as exc:
        print(f"sitl: error: {exc}", file=sys.stderr)
        return 1


def _main(argv: Sequence[str] | None) -> int:
    args = build_parser().parse_args(argv)
    if args.instance < 0 or args.instance > 254:
        raise UsageError(f"--instance must be in 0..254, got {args.instance}")
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise UsageError(f"--duration must be a positive number of seconds, got {args.duration}")
    if not (math.isfinite(args.gust) and args.gust >= 0):
        raise UsageError(f"--gust must be >= 0, got {args.gust}")
    home = DEFAULT_HOME
    if args.home is not None:
        lat, lon, alt = _float_list(args.home, 3, "--home")
        if not (-90 < lat < 90 and -180 <= lon <= 180):
            raise UsageError(f"--home latitude/longitude out of range: {args.home!r}")
        home = GeoPoint(lat_deg=lat, lon_deg=lon, alt_amsl_m=alt)
    if not 1 <= args.lockstep_quantum <= 400:
        raise UsageError(f"--lockstep-quantum must be in 1..400 steps, got {args.lockstep_quantum}")
    if args.lockstep and args.world is None:
        raise UsageError("--lockstep needs --world (the swarm's shared world carries the common clock)")
    wind = _float_list(args.wind, 3, "--wind")
    speed = _speed_factor(args.speed)
    links = _links(args)
    airframe = load_airframe(args.airframe)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, format="%(name)s: %(message)s")

    from sitl.app import run  # heavy imports (jsbsim) only after the arguments are known to be good

    return run(
        instance=args.instance,
        airframe=airframe,
        seed=args.seed if args.seed is not None else args.instance,
        speed_factor=speed,
        home=home,
        wind=WindConfig(steady_ned_mps=(wind[0], wind[1], wind[2]), gust_rms_mps=args.gust),
        duration_s=args.duration,
        demo=args.demo,
        links=links,
        world_name=args.world,
        lockstep=args.lockstep,
        lockstep_quantum=args.lockstep_quantum,
        camera_frames=args.camera_frames,
    )


if __name__ == "__main__":
    sys.exit(main())
