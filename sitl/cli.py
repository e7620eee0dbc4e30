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
from typing import TYPE_CHECKING, NoReturn

from sitl.dynamics.airframe import DEFAULT_AIRFRAME, AirframeError, load_airframe
from sitl.dynamics.geodesy import geo_from_ned
from sitl.dynamics.plant import DEFAULT_HOME, GeoPoint
from sitl.dynamics.wind import WindConfig
from sitl.process.mavlink_io import LinkConfig, LinkError
from sitl.process.ports import GCS_REMOTE_PORT, MAX_INSTANCE, instance_ports
from sitl.process.specs import DroneSpec, ProcessSpec
from sitl.protocol.signing import SigningKeyError, load_key
from sitl.world.linkmodel import LinkProfile, link_profile
from sitl.world.mesh import MeshSettings, mesh_problem
from sitl.world.shared import WorldError
from swarmcommon.datagrams import parse_host_port
from swarmcommon.links import DEFAULT_MESH_EXPONENT, LINK_KEYS
from swarmcommon.process_end import ending

EXIT_USAGE = 2
SPEED_ENV = "PX4_SIM_SPEED_FACTOR"

if TYPE_CHECKING:
    from sitl.onboard.loader import LoadedBehaviour


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


def _links(args: argparse.Namespace, i: int) -> tuple[LinkConfig, ...]:
    """Instance i's links on its ports (sitl/process/ports.py): PX4 SITL's for i < 40 (API 14580+i -> 14540+i, ground
    station 18570+i -> 14550), API 16000+i -> 15000+i from 40 on."""
    if args.no_mavlink:
        return ()
    ports = instance_ports(i)
    links = [
        LinkConfig(
            name="API",
            bind=(args.host, _port(args.api_port, ports.api_bind, "--api-port")),
            remote=_address(args.api_remote or f"127.0.0.1:{ports.api_remote}", "--api-remote"),
        )
    ]
    if not args.no_gcs:
        links.append(
            LinkConfig(
                name="GCS",
                bind=(args.host, _port(args.gcs_port, ports.gcs_bind, "--gcs-port")),
                remote=_address(args.gcs_remote, "--gcs-remote"),
            )
        )
    return tuple(links)


def parse_instances(text: str) -> list[int]:
    """``0-24``, ``3`` or ``0-3,8,10-11``: instance numbers, each in 0..MAX_INSTANCE, in order, without repeats."""
    out: list[int] = []
    for part in text.split(","):
        low, sep, high = part.strip().partition("-")
        try:
            first, last = int(low), int(high) if sep else int(low)
        except ValueError:
            raise UsageError(f"--instances must look like 0-24 or 0-3,8, got {text!r}") from None
        if not 0 <= first <= last <= MAX_INSTANCE:
            raise UsageError(f"--instances must be ranges within 0..{MAX_INSTANCE}, low to high, got {text!r}")
        out.extend(range(first, last + 1))
    if len(set(out)) != len(out):
        raise UsageError(f"--instances names an instance twice: {text!r}")
    return out


def _home(text: str) -> GeoPoint:
    lat, lon, alt = _float_list(text, 3, "--home")
    if not (-90 < lat < 90 and -180 <= lon <= 180):
        raise UsageError(f"--home latitude/longitude out of range: {text!r}")
    return GeoPoint(lat_deg=lat, lon_deg=lon, alt_amsl_m=alt)


def _homes(args: argparse.Namespace, count: int) -> list[GeoPoint]:
    """One home per drone: as many ``--home`` as drones, or one (default PX4's), from which the drones stand in a
    line eastwards ``--spacing`` apart, as PX4's multi-vehicle SITL lines its vehicles up."""
    given = [_home(text) for text in args.home or []]
    if len(given) == count:
        return given
    if len(given) > 1:
        raise UsageError(f"give one --home, or one per instance ({count}), not {len(given)}")
    if not (math.isfinite(args.spacing) and args.spacing > 0):
        raise UsageError(f"--spacing must be a positive number of metres, got {args.spacing}")
    first = given[0] if given else DEFAULT_HOME
    return [geo_from_ned((0.0, k * args.spacing, 0.0), first) for k in range(count)]


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="sitl", description="Run one simulated quadrotor (JSBSim + PX4-style autopilot).")
    parser.add_argument("--instance", type=int, default=None, help="instance number i >= 0 (MAVLink sysid i+1)")
    parser.add_argument(
        "--instances",
        default=None,
        help="host several drones in this process, e.g. 0-24 or 0-3,8 (each its own sysid, ports, seed, log)",
    )
    parser.add_argument("--airframe", default=DEFAULT_AIRFRAME, help="airframe name in airframes/ or a .toml path")
    parser.add_argument(
        "--speed", default=None, help=f"simulation speed factor (default: ${SPEED_ENV} or 1.0; 0 = unpaced)"
    )
    parser.add_argument(
        "--seed", type=int, default=None, help="random seed of the first instance, +1 per instance (default: instance)"
    )
    parser.add_argument(
        "--home",
        action="append",
        default=None,
        help="home as LAT,LON,ALT_AMSL (default: PX4 SITL home); once, or once per instance",
    )
    parser.add_argument(
        "--spacing", type=float, default=2.0, help="with several instances and one home: metres between them (east)"
    )
    parser.add_argument("--wind", default="0,0,0", help="steady wind N,E,D in m/s (the direction it blows to)")
    parser.add_argument("--gust", type=float, default=0.0, help="gust RMS intensity in m/s")
    parser.add_argument("--host", default="127.0.0.1", help="address the MAVLink links bind (default loopback)")
    parser.add_argument("--api-port", type=int, default=None, help="API link UDP port (default 14580+instance; "
                        "16000+instance from instance 40 on)")  # fmt: skip
    parser.add_argument(
        "--api-remote",
        default=None,
        help="HOST:PORT the API link streams to (default 127.0.0.1:14540+instance; 15000+instance from instance 40 on)",
    )
    parser.add_argument("--gcs-port", type=int, default=None, help="ground-station link port (default 18570+instance)")
    parser.add_argument("--gcs-remote", default=f"127.0.0.1:{GCS_REMOTE_PORT}", help="HOST:PORT of the ground station")
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
        "--link",
        action="append",
        default=None,
        metavar="CLASS:KEY=VALUE[,...]",
        help="impair a link class (gcs, api, neighbour or all) with the link model; repeatable, later keys win; "
        f"keys: {', '.join(LINK_KEYS)} (docs/links.md)",
    )
    parser.add_argument(
        "--mesh-range-m",
        type=float,
        default=None,
        metavar="M",
        help="broadcast position reports to the other drones over the simulated drone-to-drone mesh, heard up to "
        "this range (needs --world; docs/links.md)",
    )
    parser.add_argument(
        "--mesh-exponent",
        type=float,
        default=None,
        metavar="X",
        help=f"mesh path loss: a report is lost with probability (distance / range)^X "
        f"(default {DEFAULT_MESH_EXPONENT:g})",
    )
    parser.add_argument(
        "--behaviour",
        default=None,
        metavar="FILE.py:CLASS",
        help="an onboard behaviour every drone runs, from BHV_EN = 1 on (docs/onboard.md)",
    )
    parser.add_argument(
        "--camera-frames",
        type=Path,
        default=None,
        help="save every camera frame as PNG in this directory (drone-<instance>/ in it with several instances)",
    )
    parser.add_argument(
        "--camera-instances", default=None, help="with several instances: whose frames to save (default all)"
    )
    parser.add_argument(
        "--log-dir", type=Path, default=None, help="each drone's output in drone-<instance>.log here (default stdout)"
    )
    parser.add_argument(
        "--signing-key",
        default=None,
        help="MAVLink 2 signing key file: 64 hex digits, or a one-line passphrase (key = its SHA-256, as MAVProxy "
        "and QGroundControl derive it); every message sent is signed",
    )
    parser.add_argument(
        "--signing-required",
        action="store_true",
        help="set MAV_SIGN_CFG = 2: drop unsigned or wrongly signed messages (except HEARTBEAT, RADIO_STATUS, "
        "ADSB_VEHICLE, COLLISION)",
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
    instances = _instances(args)
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise UsageError(f"--duration must be a positive number of seconds, got {args.duration}")
    if not (math.isfinite(args.gust) and args.gust >= 0):
        raise UsageError(f"--gust must be >= 0, got {args.gust}")
    if not 1 <= args.lockstep_quantum <= 400:
        raise UsageError(f"--lockstep-quantum must be in 1..400 steps, got {args.lockstep_quantum}")
    if args.lockstep and args.world is None:
        raise UsageError("--lockstep needs --world (the swarm's shared world carries the common clock)")
    if args.demo and len(instances) > 1:
        raise UsageError("--demo flies one drone: give --instance, not several --instances")
    wind = _float_list(args.wind, 3, "--wind")
    links = _link_profile(args.link or [])
    mesh = _mesh(args)
    behaviour = _behaviour(args.behaviour)
    speed = _speed_factor(args.speed)
    homes = _homes(args, len(instances))
    cameras = set(parse_instances(args.camera_instances)) if args.camera_instances else set(instances)
    airframe = load_airframe(args.airframe)
    signing_key = _signing_key(args.signing_key)
    if args.log_dir is not None:
        try:
            args.log_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UsageError(f"--log-dir {args.log_dir}: {exc.strerror}") from None
    first_seed = args.seed if args.seed is not None else instances[0]
    specs = [
        DroneSpec(
            instance=i,
            seed=first_seed + (i - instances[0]),
            home=home,
            links=_links(args, i),
            camera_frames=_camera_dir(args.camera_frames, i, len(instances)) if i in cameras else None,
            log_path=args.log_dir / f"drone-{i}.log" if args.log_dir is not None else None,
        )
        for i, home in zip(instances, homes, strict=True)
    ]
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, format="%(name)s: %(message)s")

    from sitl.process.app import run  # heavy imports (jsbsim) only after the arguments are known to be good

    return run(
        specs,
        ProcessSpec(
            airframe=airframe,
            speed_factor=speed,
            wind=WindConfig(steady_ned_mps=(wind[0], wind[1], wind[2]), gust_rms_mps=args.gust),
            duration_s=args.duration,
            demo=args.demo,
            world_name=args.world,
            lockstep=args.lockstep,
            lockstep_quantum=args.lockstep_quantum,
            signing_key=signing_key,
            signing_required=args.signing_required,
            links=links,
            mesh=mesh,
            behaviour=behaviour,
        ),
    )


def _instances(args: argparse.Namespace) -> list[int]:
    if args.instances is not None:
        if args.instance is not None:
            raise UsageError("give --instance or --instances, not both")
        instances = parse_instances(args.instances)
        if len(instances) > 1:
            for option in ("api_port", "gcs_port", "api_remote"):
                if getattr(args, option) is not None:
                    flag = "--" + option.replace("_", "-")
                    raise UsageError(f"{flag} is one drone's: with several --instances the ports follow each instance")
        return instances
    instance = 0 if args.instance is None else args.instance
    if not 0 <= instance <= MAX_INSTANCE:
        raise UsageError(f"--instance must be in 0..{MAX_INSTANCE}, got {instance}")
    return [instance]


def _signing_key(path: str | None) -> bytes | None:
    if path is None:
        return None
    try:
        return load_key(path)
    except SigningKeyError as exc:
        raise UsageError(str(exc)) from None


def _link_profile(options: list[str]) -> LinkProfile:
    try:
        return link_profile(options)
    except ValueError as exc:
        raise UsageError(f"--link: {exc}") from None


def _behaviour(spec: str | None) -> LoadedBehaviour | None:
    """The onboard behaviour, loaded and checked before any drone starts (one line if it cannot be)."""
    if spec is None:
        return None
    from sitl.onboard.loader import BehaviourError, load_behaviour  # imports the simulation: only when asked

    try:
        return load_behaviour(spec)
    except BehaviourError as exc:
        raise UsageError(f"--behaviour {exc}") from None


def _mesh(args: argparse.Namespace) -> MeshSettings | None:
    if args.mesh_range_m is None:
        if args.mesh_exponent is not None:
            raise UsageError("--mesh-exponent needs --mesh-range-m (the mesh is off without a range)")
        return None
    if args.world is None:
        raise UsageError("--mesh-range-m needs --world (the mesh's medium is in the swarm's shared world)")
    exponent = DEFAULT_MESH_EXPONENT if args.mesh_exponent is None else args.mesh_exponent
    problem = mesh_problem(args.mesh_range_m, exponent)
    if problem is not None:
        key, _, rest = problem.partition(" ")  # "range_m must be > 0, got -1" -> "--mesh-range-m must be > 0, ..."
        raise UsageError(f"--mesh-{key.replace('_', '-')} {rest}")
    return MeshSettings(range_m=args.mesh_range_m, exponent=exponent)


def _camera_dir(root: Path | None, instance: int, count: int) -> Path | None:
    if root is None:
        return None
    return root if count == 1 else root / f"drone-{instance}"


def entry() -> int:
    """The ``sitl`` command (pyproject.toml's script, ``python -m sitl.cli``): ``main`` on the command
    line, ended without the interpreter's last garbage collection (swarmcommon/process_end.py)."""
    return ending(main)


if __name__ == "__main__":
    sys.exit(entry())
