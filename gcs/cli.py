"""``swarm``: the ground-station command line.

``swarm up`` runs the supervisor in the foreground; the other commands talk to it over the local control channel.
Argument parsing only; the work is in gcs/supervisor/station.py and gcs/fleet/swarm.py. Mistakes end with one line on
stderr and a non-zero exit code.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import math
import os
import signal
import sys
import threading
import time
import tomllib
from collections.abc import Callable, Sequence
from pathlib import Path
from types import FrameType
from typing import Any, Literal, NoReturn

from gcs.bench.scaling import add_bench_parser, run_bench
from gcs.composition import SITL
from gcs.falsify.cli import add_falsify_parser, run_falsify
from gcs.falsify.space import FalsifyError
from gcs.fleet.attach import (
    DEFAULT_KEEP_IN_M,
    DEFAULT_MAX_DISTANCE_M,
    AttachError,
    AttachSpec,
    find_home,
    parse_attach,
    role_of,
)
from gcs.fleet.faults import CRASH, FAULT_NAMES
from gcs.fleet.harness import (
    LAYOUTS,
    MAX_DRONES,
    MAX_QUANTUM,
    Simulation,
    SpawnError,
    SpawnPlan,
    parse_drones_per_process,
)
from gcs.fleet.links import LINK_OPTIONS, NEIGHBOUR_MODES, LinkPlan, NeighbourPlan, parse_link_value, parse_mesh_value
from gcs.fleet.losses import LOSS_POLICIES, LossPolicy
from gcs.fleet.relay import RELAY_SCOPE_HELP, scope_argument
from gcs.fleet.swarm import Swarm, SwarmError
from gcs.flight.geodesy import DEFAULT_ORIGIN, GeoPoint
from gcs.flight.onboard import absolute_spec
from gcs.invariants.monitor import EXIT_VIOLATED, Violation
from gcs.mavlink.signing import SigningKeyError, load_key
from gcs.mavlink.transport import GCS_SYSID
from gcs.missions.mission_file import (
    FLIGHT_ALT_M,
    TAKEOFF_ALT_M,
    MissionFileError,
    MissionSpec,
    flown_onboard,
    load_mission,
)
from gcs.supervisor.commands import DECODERS, check
from gcs.supervisor.control import ControlClient, ControlError, ControlServer
from gcs.supervisor.mission_runner import MissionRunner
from gcs.supervisor.plan_cli import add_plan_parser, run_plan
from gcs.supervisor.session import InvariantViolated
from gcs.supervisor.station import Station, format_status
from gcs.supervisor.verbs import attach_all
from gcs.sweep.cli import add_sweep_parser, run_sweep_command
from gcs.sweep.plan import SweepError
from gcs.view.report import PLOT_POLICIES
from gcs.view.server import DEFAULT_PORT as DEFAULT_VIEW_PORT
from gcs.view.server import ViewError, ViewServer, serve_view
from swarmcommon.cpus import usable_cpus
from swarmcommon.datagrams import parse_host_port
from swarmcommon.process_end import ending

EXIT_USAGE = 2
DEFAULT_MISSION = Path(__file__).resolve().parent.parent / "missions" / "grid_to_circle.toml"
EXIT_FAILED = 1
ALT_HELP = f"altitude in metres (default {FLIGHT_ALT_M:g})"  # swarm formation, flock and follow


class UsageError(Exception):
    pass


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        raise UsageError(message)


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return value


def _nonneg(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"must be a number >= 0, got {text!r}")
    return value


def _pairs(text: str) -> list[list[float]]:
    """'10,0 10,10' or '10,0;10,10' -> [[10, 0], [10, 10]] (a value starting with '-' needs --option=VALUE)."""
    pairs = []
    for item in text.replace(";", " ").split():
        try:
            a, b = (float(v) for v in item.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be pairs like '10,0 10,10', got {item!r}") from None
        if not (math.isfinite(a) and math.isfinite(b)):
            raise argparse.ArgumentTypeError(f"must be finite numbers, got {item!r}")
        pairs.append([a, b])
    if not pairs:
        raise argparse.ArgumentTypeError("needs at least one pair like '10,0'")
    return pairs


def _sysid(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a drone's sysid (a whole number), got {text!r}") from None
    if not 1 <= value <= 255:
        raise argparse.ArgumentTypeError(f"must be a sysid in 1..255, got {text!r}")
    return value


def _v_angle(text: str) -> float:
    value = _positive(text)
    if value > 180.0:
        raise argparse.ArgumentTypeError(f"must be in (0, 180] degrees, got {text!r}")
    return value


ORIGIN_ATTACHED = "attached"  # --origin attached: the first attached vehicle's home
ORIGIN_HELP = (
    "swarm origin LAT,LON,ALT_AMSL, or 'attached': the home of the first vehicle on the first --attach link "
    "(docs/external.md); south or west, join it with '=': --origin=-33.86,151.21,10"
)


def _origin(text: str) -> GeoPoint | str:
    if text == ORIGIN_ATTACHED:
        return text
    try:
        lat, lon, alt = (float(p) for p in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be LAT,LON,ALT or {ORIGIN_ATTACHED}, got {text!r}") from None
    if not (-90 < lat < 90 and -180 <= lon <= 180 and math.isfinite(alt)):
        raise argparse.ArgumentTypeError(f"out of range: {text!r}")
    return GeoPoint(lat_deg=lat, lon_deg=lon, alt_amsl_m=alt)


def _resolve_origin(origin: GeoPoint | str, attach: tuple[AttachSpec, ...], gcs_sysid: int) -> GeoPoint:
    """``--origin``: a point, or (``attached``) the home of the first vehicle heard on the first --attach link,
    said in one line; UsageError (one line) when there is no link or nothing comes."""
    if isinstance(origin, GeoPoint):
        return origin
    if not attach:
        raise UsageError("--origin attached needs an attached vehicle (--attach or [[swarm.attach]])")
    try:
        sysid, home = find_home(attach[0], gcs_sysid)
    except AttachError as exc:
        raise UsageError(str(exc)) from None
    _say(f"swarm: origin at attached vehicle {sysid}'s home ({home.lat_deg:.7f}, {home.lon_deg:.7f}, "
         f"{home.alt_amsl_m:.2f} m)")  # fmt: skip
    return home


def _address(text: str) -> tuple[str, int]:
    address = parse_host_port(text)
    if address is None:
        raise argparse.ArgumentTypeError(f"must be HOST:PORT with a port in 1..65535, got {text!r}")
    return address


def _add_forward_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--forward", type=_address, default=("127.0.0.1", 14550),
                        help="HOST:PORT to forward all drone traffic to, for QGroundControl/MAVProxy (default "
                        "127.0.0.1:14550)")  # fmt: skip
    parser.add_argument("--no-forward", action="store_true", help="do not forward drone traffic to a ground station")


def _add_signing_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--signing-key", type=Path, default=None, metavar="FILE",
                        help="MAVLink 2 signing key file (64 hex digits, or a one-line passphrase as MAVProxy and "
                        "QGroundControl take it): the supervisor signs what it sends, the drones sign theirs and "
                        "drop unsigned messages")  # fmt: skip


def _add_attach_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--attach", action="append", default=[], metavar="[ROLE=]URL",
                        help="attach a MAVLink vehicle the simulation does not run (a real drone, another SITL) "
                        "heard on URL (udpin:0.0.0.0:14560, tcp:HOST:PORT, /dev/ttyUSB0,57600 or the MAVSDK "
                        "spellings): a member flies in the swarm's formations, a leader is followed, an intruder "
                        "is only seen, avoided and counted (repeatable; roles member (default), leader, intruder; "
                        "docs/external.md)")  # fmt: skip
    parser.add_argument("--gcs-sysid", type=_sysid, default=GCS_SYSID, metavar="N",
                        help=f"the supervisor's own MAVLink system id (default {GCS_SYSID}; another when a "
                        "QGroundControl beside it uses that one)")  # fmt: skip
    parser.add_argument("--attach-signing-key", type=Path, default=None, metavar="FILE",
                        help="the --attach links are MAVLink 2 signed with this key (their vehicles' frames must be "
                        "signed with it)")  # fmt: skip
    parser.add_argument("--attach-max-distance", type=_positive, default=DEFAULT_MAX_DISTANCE_M, metavar="M",
                        help="refuse an attached vehicle farther than M metres from the swarm's origin (default "
                        f"{DEFAULT_MAX_DISTANCE_M:g})")  # fmt: skip
    parser.add_argument("--arm-external", action="store_true",
                        help="the swarm arms and takes off the --attach members with its drones (else their pilot "
                        "flies them up and they join once in the air)")  # fmt: skip
    parser.add_argument("--attach-keep-in", type=_positive, default=DEFAULT_KEEP_IN_M, metavar="M",
                        help="no setpoint is sent to an --attach member farther than M metres from the origin or "
                        f"higher above it (default {DEFAULT_KEEP_IN_M:g}): it is put in Hold instead")  # fmt: skip


def _attach_specs(args: argparse.Namespace, from_mission: tuple[AttachSpec, ...] = ()) -> tuple[AttachSpec, ...]:
    """``--attach`` (after the mission's [[swarm.attach]]), each checked (that a swarm with one runs paced at speed 1
    is the attach's own check, before any drone starts: gcs/fleet/attachments.py)."""
    try:
        specs = (
            *from_mission,
            *(
                parse_attach(
                    text,
                    max_distance_m=args.attach_max_distance,
                    signing_key_file=args.attach_signing_key,
                    arm=args.arm_external and role_of(text) == "member",
                    keep_in_m=args.attach_keep_in,
                )
                for text in args.attach
            ),
        )
    except AttachError as exc:
        raise UsageError(str(exc)) from None
    return specs


def _add_view_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("live view (docs/view.md)")
    group.add_argument("--view-port", type=int, default=None, metavar="PORT",
                       help=f"serve the live view on 127.0.0.1:PORT (default: {DEFAULT_VIEW_PORT} or the next free "
                       "port)")  # fmt: skip
    group.add_argument("--no-view", action="store_true", help="do not serve the live view")


def _start_view(args: argparse.Namespace) -> ViewServer | None:
    """The live view's server, started before anything flies (its address said); a port that cannot be had is one
    line, exit code 2."""
    if args.no_view:
        if args.view_port is not None:
            raise UsageError("--view-port and --no-view contradict each other")
        return None
    try:
        server = serve_view(args.view_port)
    except ViewError as exc:
        raise UsageError(str(exc)) from None
    _say(f"swarm: live view on {server.url}")
    return server


def _signing_key_file(args: argparse.Namespace) -> Path | None:
    """The key file, checked now so a bad one is one line before anything starts (absolute: drones start
    elsewhere)."""
    if args.signing_key is None:
        return None
    try:
        load_key(args.signing_key)
    except SigningKeyError as exc:
        raise UsageError(str(exc)) from None
    return Path(args.signing_key).resolve()


def _add_timing_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--speed", type=_positive, default=None, help="speed factor (default 1; with --lockstep: as fast as possible)"
    )
    parser.add_argument(
        "--lockstep", action="store_true", help="all drones advance simulated time together (one shared clock)"
    )
    parser.add_argument(
        "--camera-frames",
        type=_drone_numbers,
        default=frozenset(),
        metavar="N[,N...]",
        help="save these drones' camera frames as PNG (swarm fly: REPORT/camera/; swarm up: ./camera-frames/)",
    )
    parser.add_argument(
        "--quantum",
        type=int,
        default=None,
        help="lockstep: physics steps every drone runs between waits, i.e. the clock skew bound (default: a "
        "mission's [swarm] quantum, else 1)",
    )
    parser.add_argument(
        "--drones-per-process",
        type=drones_per_process_arg,
        default=1,
        metavar="K|auto",
        help="drones each simulation process runs (default 1: one process per drone; auto: one process per CPU)",
    )


def _add_link_options(parser: argparse.ArgumentParser) -> None:
    """The link model's settings for every link class (over a mission's ``[swarm.links]``; docs/links.md)."""
    group = parser.add_argument_group("link model (every link class: ground station, API, neighbour)")
    helps = {
        "loss": ("P", "probability a frame is lost (0..1) while the channel is good"),
        "latency_ms": ("MS", "one-way delay of every frame"),
        "jitter_ms": ("MS", "standard deviation of the delay's random part (a normal, truncated at 0 delay)"),
        "burst_good_s": ("S", "burst outages: mean time between them (exponential)"),
        "burst_bad_s": ("S", "burst outages: mean length (exponential)"),
        "burst_loss": ("P", "probability a frame is lost during an outage (default 1)"),
        "bandwidth_bps": ("BPS", "air rate cap in bit/s: frames queue behind each other (docs/links.md)"),
    }
    for option, key in LINK_OPTIONS.items():
        metavar, text = helps[key]
        group.add_argument(option, type=_link_value(key), default=None, metavar=metavar, help=text)


def _add_neighbour_options(parser: argparse.ArgumentParser) -> None:
    """How neighbours' positions travel (over a mission's ``[swarm] neighbours`` and ``[swarm.mesh]``)."""
    group = parser.add_argument_group('neighbour positions (docs/links.md, "Mesh")')
    group.add_argument("--neighbours", choices=NEIGHBOUR_MODES, default=None,
                       help="relay: the supervisor forwards each drone's position to the others (default); mesh: the "
                       "drones hear each other directly over a simulated radio, no relay; both")  # fmt: skip
    group.add_argument("--relay-scope", type=scope_argument, default=None, metavar="SCOPE", help=RELAY_SCOPE_HELP)
    group.add_argument("--mesh-range-m", type=_mesh_value("range_m"), default=None, metavar="M",
                       help="mesh radio range in metres (default 15): nothing heard beyond it, a report lost with "
                       "probability (distance / range)^4 within it")  # fmt: skip


def _mesh_value(key: str) -> Callable[[str], float]:
    return _option_value(parse_mesh_value, key)


def _option_value(parse_value: Callable[[str, str], float], key: str) -> Callable[[str], float]:
    """An argparse type for ``key``: ``parse_value``'s one-line ValueError becomes argparse's own error."""

    def parse(text: str) -> float:
        try:
            return parse_value(key, text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    return parse


def _behaviour(spec: str | None, simulation: Simulation) -> str | None:
    """``--behaviour FILE.py:CLASS``, made absolute (the drones start elsewhere) and loaded as the drones will load
    it: a mistake is one line before anything starts."""
    if spec is None:
        return None
    absolute = absolute_spec(spec, Path.cwd())
    try:
        simulation.check_behaviour(absolute)
    except ValueError as exc:
        raise UsageError(f"--behaviour {exc}") from None
    return absolute


def _neighbour_plan(args: argparse.Namespace, base: NeighbourPlan) -> NeighbourPlan:
    """``base`` (a mission's, or the relay alone) with ``--neighbours`` and ``--mesh-range-m`` over it."""
    plan = base.with_mode(args.neighbours) if args.neighbours is not None else base
    if args.relay_scope is not None:
        if not plan.relay:
            raise UsageError("--relay-scope needs the relay: --neighbours relay or both (or a mission that has it)")
        plan = dataclasses.replace(plan, relay_scope=args.relay_scope)
    if args.mesh_range_m is not None:
        if plan.mesh is None:
            raise UsageError("--mesh-range-m needs the mesh: --neighbours mesh or both (or a mission that has it)")
        plan = dataclasses.replace(plan, mesh=dataclasses.replace(plan.mesh, range_m=args.mesh_range_m))
    return plan


def _link_value(key: str) -> Callable[[str], float]:
    return _option_value(parse_link_value, key)


def _link_plan(args: argparse.Namespace, base: LinkPlan) -> LinkPlan:
    """``base`` (a mission's links, or perfect ones) with the ``--link-*`` options given set for every class."""
    given = {key: getattr(args, option[2:].replace("-", "_")) for option, key in LINK_OPTIONS.items()}
    values = {key: value for key, value in given.items() if value is not None}
    try:
        return base.overridden(values)
    except ValueError as exc:
        raise UsageError(f"--link-* options: {exc}") from None


def drones_per_process_arg(text: str) -> int | Literal["auto"]:
    """``--drones-per-process``: a count of at least 1, or ``auto``."""
    try:
        return parse_drones_per_process(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _drone_numbers(text: str) -> frozenset[int]:
    try:
        numbers = frozenset(int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be drone numbers like 1,3, got {text!r}") from None
    if not numbers or min(numbers) < 1:
        raise argparse.ArgumentTypeError(f"drone numbers start at 1, got {text!r}")
    return numbers


def _camera_drones(args: argparse.Namespace, n_drones: int) -> frozenset[int]:
    numbers: frozenset[int] = args.camera_frames
    if numbers and max(numbers) > n_drones:
        raise UsageError(f"--camera-frames: drone numbers go from 1 to {n_drones}, got {max(numbers)}")
    return numbers


def _speed(args: argparse.Namespace) -> float:
    """The speed factor; 0 (as fast as the CPU allows) only in lockstep."""
    if args.speed is not None:
        return float(args.speed)
    return 0.0 if args.lockstep else 1.0


def _quantum(args: argparse.Namespace, default: int | None = None) -> int:
    """``--quantum``, else ``default`` (a mission's), else 1."""
    if args.quantum is None:
        return default or 1
    if not 1 <= args.quantum <= MAX_QUANTUM:
        raise UsageError(f"--quantum must be in 1..{MAX_QUANTUM} physics steps, got {args.quantum}")
    return int(args.quantum)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="swarm", description="Ground station for a swarm of simulated PX4-like drones.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    up = sub.add_parser("up", help="spawn N drones and supervise them (foreground; Ctrl-C lands and stops them)")
    up.add_argument("-n", "--drones", type=int, required=True, help=f"number of drones (1..{MAX_DRONES})")
    up.add_argument("--spacing", type=_positive, default=2.0, help="spawn spacing in metres (default 2)")
    up.add_argument("--layout", choices=sorted(LAYOUTS), default="grid", help="spawn layout (default grid)")
    _add_timing_options(up)
    _add_link_options(up)
    _add_neighbour_options(up)
    up.add_argument("--behaviour", default=None, metavar="FILE.py:CLASS",
                    help="an onboard behaviour every drone carries; 'swarm behaviour start' (or BHV_EN = 1 by "
                    "PARAM_SET) runs it (docs/onboard.md)")  # fmt: skip
    up.add_argument("--first-instance", type=int, default=0, help="instance of the first drone (sysid = instance+1)")
    up.add_argument("--origin", type=_origin, default=DEFAULT_ORIGIN, help=ORIGIN_HELP)
    up.add_argument("--airframe", default=None, help="airframe name or .toml path for every drone")
    up.add_argument("--seed", type=int, default=0, help="base random seed (the k-th drone, from 0, uses seed+k)")
    up.add_argument("--logs", type=Path, default=None, help="directory for each drone's log (default: none)")
    up.add_argument(
        "--report",
        type=Path,
        default=None,
        help="record the session and write a flight report (as swarm fly's) into this directory at the end",
    )
    up.add_argument("--loss-policy", choices=LOSS_POLICIES, default=LossPolicy.CONTINUE.value,
                    help="what the others do when a drone is lost: continue (re-plan over the survivors; default), "
                    "hold, land, or abort (every drone returns to launch and lands)")  # fmt: skip
    _add_forward_options(up)
    _add_signing_option(up)
    _add_attach_option(up)
    _add_view_options(up)
    fly = sub.add_parser("fly", help="run a mission file end to end and write a flight report")
    fly.add_argument(
        "mission", type=Path, nargs="?", default=DEFAULT_MISSION, help=f"mission file (default {DEFAULT_MISSION})"
    )
    fly.add_argument("--report", type=Path, default=None, help="report directory (default reports/<mission>-<time>)")
    fly.add_argument("--plots", choices=PLOT_POLICIES, default="always",
                     help="when the report draws its three plots: always (default), failed (only for a flight that "
                     "broke something: a contact, a violated invariant, a mission that did not finish; what sweeps "
                     "and falsification campaigns ask for, it saves each flight about 3 s), or never")  # fmt: skip
    fly.add_argument("--stop-on-violation", action="store_true",
                     help="end the flight at the first violation of one of the mission's invariants "
                     "(docs/invariants.md; the drones land, the report is written, exit code 3)")  # fmt: skip
    _add_timing_options(fly)
    _add_link_options(fly)
    _add_neighbour_options(fly)
    fly.add_argument("--behaviour", default=None, metavar="FILE.py:CLASS",
                     help="the onboard behaviour every drone carries (instead of the mission's [swarm] behaviour); "
                     "a mission's behaviour steps run it (docs/onboard.md)")  # fmt: skip
    fly.add_argument("--onboard", action="store_true",
                     help="every flock and follow step flown by the drones themselves (the shipped onboard "
                     "behaviours, docs/onboard.md) instead of the ground station")  # fmt: skip
    fly.add_argument("--first-instance", type=int, default=0, help="instance of the first drone")
    fly.add_argument("--origin", type=_origin, default=DEFAULT_ORIGIN, help=ORIGIN_HELP)
    fly.add_argument("--airframe", default=None, help="airframe name or .toml path for every drone")
    fly.add_argument("--seed", type=int, default=None,
                     help="base random seed (the k-th drone, from 0, uses seed+k; default: the mission's [swarm] "
                     "seed, else 0)")  # fmt: skip
    fly.add_argument("--param", action="append", default=[], type=_param_setting, metavar="NAME=VALUE",
                     help="set a drone parameter on every drone before arming, over the mission's [swarm] params "
                     "(repeatable; docs/parameters.md)")  # fmt: skip
    _add_forward_options(fly)
    _add_signing_option(fly)
    _add_attach_option(fly)
    _add_view_options(fly)
    add_bench_parser(sub)
    add_sweep_parser(sub)
    add_falsify_parser(sub)
    sub.add_parser("status", help="table of every drone")
    takeoff = sub.add_parser("takeoff", help="arm and take off every drone")
    takeoff.add_argument("--alt", type=_positive, default=TAKEOFF_ALT_M,
                         help=f"altitude above home in metres (default {TAKEOFF_ALT_M:g})")  # fmt: skip
    formation = sub.add_parser("formation", help="fly a formation (OFFBOARD): grid, circle, line or v")
    formation.add_argument("shape", choices=("grid", "circle", "line", "v"))
    formation.add_argument("--alt", type=_positive, default=FLIGHT_ALT_M, help=ALT_HELP)
    formation.add_argument("--spacing", type=_positive, default=2.0, help="spacing in metres (grid, line, v)")
    formation.add_argument("--rows", type=int, default=None, help="grid rows (default: a square-ish grid)")
    formation.add_argument("--cols", type=int, default=None, help="grid columns")
    formation.add_argument("--radius", type=_positive, default=3.0, help="circle radius in metres (default 3)")
    formation.add_argument("--rate", type=float, default=0.0, help="circle rotation in rad/s (default 0)")
    formation.add_argument("--osc", type=float, default=0.0, help="circle altitude wave amplitude in metres")
    formation.add_argument("--angle", type=float, default=90.0, help="V opening angle in degrees (default 90)")
    formation.add_argument("--heading", type=float, default=0.0, help="heading of the formation in degrees")
    flock = sub.add_parser(
        "flock", help="Reynolds flocking (OFFBOARD) towards migration points; until the next command"
    )
    flock.add_argument("--alt", type=_positive, default=FLIGHT_ALT_M, help=ALT_HELP)
    flock.add_argument(
        "--goals",
        type=_pairs,
        default=None,
        metavar="'N,E N,E'",
        help="migration points (north,east metres), visited in turn (default: none, just flock)",
    )
    flock.add_argument("--speed", type=_positive, default=None, help="maximum speed in m/s (default 1.5)")
    flock.add_argument("--accel", type=_positive, default=None, help="maximum acceleration in m/s^2 (default 1.5)")
    flock.add_argument("--radius", type=_positive, default=None, help="neighbour radius in metres (default 6)")
    flock.add_argument("--separation", type=_positive, default=None, help="separation radius in metres (default 2.5)")
    flock.add_argument("--w-separation", type=_positive, default=None, help="separation weight in m/s^2 (default 3)")
    flock.add_argument("--w-alignment", type=_nonneg, default=None, help="alignment weight in 1/s (default 1)")
    flock.add_argument("--w-cohesion", type=_nonneg, default=None, help="cohesion weight in 1/s^2 (default 0.05)")
    flock.add_argument("--w-migration", type=_nonneg, default=None, help="migration weight in 1/s (default 0.8)")
    follow = sub.add_parser("follow", help="leader-follower (OFFBOARD): the leader flies waypoints, the others follow; "
                            "or (--attached) the drones follow an attached leader that flies itself")  # fmt: skip
    led = follow.add_mutually_exclusive_group(required=True)
    led.add_argument("--waypoints", type=_pairs, metavar="'N,E N,E'",
                     help="the leader's waypoints, north,east metres in the swarm frame")  # fmt: skip
    led.add_argument(
        "--attached",
        action="store_true",
        help="follow the vehicle attached as leader (docs/external.md) until the next command",
    )
    follow.add_argument("--max-turn-rate", type=_positive, default=None, metavar="DEG_S",
                        help="--attached: how fast the followers' offsets may turn with the leader's course "
                        "(default 17 deg/s)")  # fmt: skip
    follow.add_argument("--leader", type=int, default=None, help="sysid of the leader (default: the lowest)")
    follow.add_argument("--alt", type=_positive, default=FLIGHT_ALT_M, help=ALT_HELP)
    follow.add_argument("--speed", type=_positive, default=None, help="leader's cruise speed in m/s (default 1.5)")
    follow.add_argument("--spacing", type=_positive, default=None, help="V spacing in metres (default 2.5)")
    follow.add_argument("--angle", type=_v_angle, default=None, help="V opening angle in degrees (default 90)")
    follow.add_argument("--offsets", type=_pairs, default=None, metavar="'F,R F,R'",
                        help="followers' offsets (forward,right metres from the leader) instead of the V")  # fmt: skip
    follow.add_argument("--turn-radius", type=_positive, default=None, help="leader's corner radius (default 3)")
    goto = sub.add_parser("goto", help="move the current formation's centre")
    goto.add_argument("north", type=float, help="metres north of the swarm origin")
    goto.add_argument("east", type=float, help="metres east of the swarm origin")
    goto.add_argument("--alt", type=_positive, default=None, help="new altitude in metres")
    fault = sub.add_parser("fault", help="inject a fault into one drone (MAV_CMD_INJECT_FAILURE, or crash: SIGKILL)")
    fault.add_argument("sysid", type=_sysid, help="the drone's sysid")
    fault.add_argument("kind", choices=FAULT_NAMES, metavar="KIND", help=f"one of: {', '.join(FAULT_NAMES)}")
    fault.add_argument("--motor", type=int, default=None, help="motor fault: the rotor, 1-based (default 1; 0 = all)")
    fault.add_argument(
        "--for",
        dest="for_s",
        type=float,
        default=None,
        metavar="S",
        help="link fault: the links come back after S simulated seconds (default: silent for good)",
    )
    kill = sub.add_parser("kill", help="kill one drone's process with SIGKILL (a crash of its flight software)")
    kill.add_argument("sysid", type=_sysid, help="the drone's sysid")
    behaviour = sub.add_parser(
        "behaviour", help="every drone's onboard behaviour (swarm up --behaviour): start or stop"
    )
    behaviour.add_argument("action", choices=("start", "stop"), help="start: BHV_EN = 1; stop: BHV_EN = 0, then Hold")
    attach = sub.add_parser("attach", help="attach a MAVLink vehicle to the running swarm (docs/external.md)")
    attach.add_argument("url", metavar="[ROLE=]URL", help="as swarm up --attach takes it")
    attach.add_argument("--max-distance", type=_positive, default=DEFAULT_MAX_DISTANCE_M, metavar="M",
                        help=f"refuse it farther than M metres from the swarm's origin (default "
                        f"{DEFAULT_MAX_DISTANCE_M:g})")  # fmt: skip
    attach.add_argument(
        "--signing-key",
        type=Path,
        default=None,
        metavar="FILE",
        help="the link is MAVLink 2 signed with this key (as swarm up --attach-signing-key)",
    )
    attach.add_argument("--keep-in", type=_positive, default=DEFAULT_KEEP_IN_M, metavar="M",
                        help=f"a member: no setpoint farther than M metres from the origin or higher above it "
                        f"(default {DEFAULT_KEEP_IN_M:g})")  # fmt: skip
    require = sub.add_parser("require", help="check an invariant at every tick from now on (docs/invariants.md)")
    require.add_argument("kind", help="separation, contact, altitude, fence, connected, formation, answered, "
                         "no_failsafe or predicate")  # fmt: skip
    require.add_argument("fields", nargs="*", metavar="FIELD=VALUE",
                         help="its fields as a mission's [[invariants]] table gives them (min_m=1.0 "
                         "form=eventually after=loss within_s=10 drones=[1,2] name=sep)")  # fmt: skip
    detach = sub.add_parser("detach", help="let an attached vehicle go (it is told nothing)")
    detach.add_argument("sysid", type=_sysid, help="the attached vehicle's sysid")
    sub.add_parser("pause", help="every drone holds where it is (PX4 Hold) until the next command")
    sub.add_parser("land", help="land every drone where it is")
    sub.add_parser("rtl", help="every drone returns to its launch point and lands")
    sub.add_parser("down", help="land, disarm and stop every drone, then the supervisor")
    add_plan_parser(sub)
    return parser


class _Stop:
    def __init__(self) -> None:
        self.stopped = False

    def __call__(self, _signum: int, _frame: FrameType | None) -> None:
        self.stopped = True


class _Interrupted(KeyboardInterrupt):
    """Ctrl-C for a signal (SIGTERM, SIGHUP), raised by ``_interrupt``: it names the signal, to be raised again."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _interrupt(signum: int, _frame: FrameType | None) -> NoReturn:
    raise _Interrupted(signum)


class _RaiseLostInterrupts:
    """``sys.unraisablehook`` while ``_interrupt`` handles signals: an interrupt the interpreter could only print is
    sent to the main thread again; anything else goes to the hook this one replaced.

    Python runs a handler in the main thread between two bytecodes of whatever runs there, and what a handler raises
    inside a callback the interpreter calls from C is printed and dropped: an ``os.register_at_fork`` hook (logging's
    runs around the fork of the drone factory, which has a ``preexec_fn``), a ``__del__``, a weakref callback. A
    sweep's run that got its SIGTERM (its parent died) while the factory was forked printed "Exception ignored in:
    <function _releaseLock>" and flew on to its end. Sent again from a thread of its own, the signal is handled once
    the main thread is out of that callback, and raised where it can end the flight."""

    def __init__(self, previous: Callable[[sys.UnraisableHookArgs], object]) -> None:
        self.previous = previous

    def __call__(self, unraisable: sys.UnraisableHookArgs) -> None:
        lost = unraisable.exc_value
        if not isinstance(lost, _Interrupted):
            self.previous(unraisable)
            return
        main = threading.main_thread().ident
        assert main is not None
        threading.Thread(target=_send_again, args=(main, lost.signum), daemon=True).start()


RESEND_AFTER_S = 0.05


def _send_again(thread_id: int, signum: int) -> None:
    """A lost interrupt's signal to the main thread, a moment later: sent at once, it could come while the main thread
    is still in the callback, or in the hook itself (starting this thread), and be lost there too."""
    time.sleep(RESEND_AFTER_S)
    with contextlib.suppress(ProcessLookupError):  # the main thread has ended meanwhile
        signal.pthread_kill(thread_id, signum)


def _interrupt_on(signals: Sequence[int]) -> None:
    """``signals`` interrupt the main thread as Ctrl-C does (``_Interrupted``), and none is lost
    (``_RaiseLostInterrupts``)."""
    for sig in signals:
        signal.signal(sig, _interrupt)
    if not isinstance(sys.unraisablehook, _RaiseLostInterrupts):
        sys.unraisablehook = _RaiseLostInterrupts(sys.unraisablehook)


def _say(text: str) -> None:
    print(text, flush=True)


def _check_first_instance(first_instance: int, drones: int, gcs_sysid: int = GCS_SYSID) -> None:
    if first_instance < 0 or first_instance + drones > MAX_DRONES:
        raise UsageError(
            f"--first-instance {first_instance} with {drones} drones: every sysid (instance + 1) must lie in "
            f"1..{MAX_DRONES} (255 is the ground station's)"
        )
    if first_instance < gcs_sysid <= first_instance + drones:
        raise UsageError(
            f"--gcs-sysid {gcs_sysid} is a drone's (sysids {first_instance + 1}..{first_instance + drones})"
        )


def run_up(args: argparse.Namespace, simulation: Simulation) -> int:
    if not 1 <= args.drones <= MAX_DRONES:
        raise UsageError(f"-n must be in 1..{MAX_DRONES}, got {args.drones}")
    _check_first_instance(args.first_instance, args.drones, args.gcs_sysid)
    contact = 0.0
    if args.report is not None:  # the report's contact distance (a bad airframe is named by the drones otherwise)
        try:
            contact = simulation.contact_distance_m(args.airframe)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    neighbours = _neighbour_plan(args, NeighbourPlan())
    attach = _attach_specs(args)
    plan = SpawnPlan(
        n_drones=args.drones,
        spacing_m=args.spacing,
        layout=args.layout,
        origin=_resolve_origin(args.origin, attach, args.gcs_sysid),
        speed_factor=_speed(args),
        lockstep=args.lockstep,
        lockstep_quantum=_quantum(args),
        first_instance=args.first_instance,
        airframe=args.airframe,
        seed=args.seed,
        log_dir=args.logs,
        camera_drones=_camera_drones(args, args.drones),
        camera_dir=Path("camera-frames"),
        drones_per_process=args.drones_per_process,
        signing_key_file=_signing_key_file(args),
        links=_link_plan(args, LinkPlan()),
        behaviour=_behaviour(args.behaviour, simulation),
        mesh=neighbours.mesh,
        gcs_sysid=args.gcs_sysid,
    )
    view = _start_view(args)
    stop = _Stop()
    signals = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    _interrupt_on(signals)  # while the drones start, a signal ends the start-up at once (and stops what started)
    swarm = Swarm(plan, simulation.harness(plan), forward=None if args.no_forward else args.forward,
                  relay=neighbours.relayed)  # fmt: skip
    station = Station(swarm, _say, LossPolicy(args.loss_policy), report_dir=args.report, contact_distance_m=contact)
    try:
        attach_all(station.session, attach)
    except AttachError as exc:
        station.session.discard()
        if view is not None:
            view.stop()
        raise UsageError(str(exc)) from None
    if view is not None:
        station.serve(view)
    server: ControlServer | None = None
    try:
        swarm.up()
        for sig in signals:  # from here on the loop notices the flag and lands the swarm in order
            signal.signal(sig, stop)
        server = ControlServer(station.handle)
        _say(
            f"swarm: {plan.n_drones} drones up (sysid {swarm.liveness.sysids[0]}..{swarm.liveness.sysids[-1]}); "
            f"MAVLink on udp 127.0.0.1:{swarm.link.port}; "
            f"control channel on 127.0.0.1:{server.port}; Ctrl-C or 'swarm down' to stop"
        )
        _loop(swarm, station, server, stop)
    except (SpawnError, ControlError) as exc:
        print(f"swarm: error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        print("swarm: interrupted while starting the drones", file=sys.stderr)
        return 130
    finally:
        for sig in signals:  # a second Ctrl-C must not cut the shutdown short
            signal.signal(sig, stop)
        if server is not None:
            server.close()
        _say("swarm: landing and stopping every drone")
        station.end_session()
        swarm.shutdown()
        _say("swarm: all drone processes stopped")
        report = station.write_report()
        if report is not None:
            _say(f"swarm: report in {report}")
        if view is not None:
            view.stop()
    return 0


def _loop(swarm: Swarm, station: Station, server: ControlServer, stop: _Stop) -> None:
    while not (stop.stopped or station.stop_requested):
        swarm.pump.once(0.02)
        station.tick()
        server.poll()
        station.watch()


def _param_setting(text: str) -> tuple[str, float]:
    """``NAME=VALUE`` for ``--param``."""
    name, equals, value = text.partition("=")
    try:
        number = float(value)
    except ValueError:
        number = math.nan
    if not equals or not name or not math.isfinite(number):
        raise argparse.ArgumentTypeError(f"{text!r} is not NAME=VALUE with a number, e.g. AVOID_MIN_DIST=1.5")
    return name.strip(), number


def _checked_params(mission: MissionSpec, given: list[tuple[str, float]], simulation: Simulation,
                    behaviour: str | None) -> tuple[tuple[str, int | float], ...]:  # fmt: skip
    """The mission's [swarm] params with ``--param`` over them, each checked against the drones' own table (one
    line before anything starts, instead of a PARAM_SET nobody answers). With an onboard behaviour, names the
    drones' table does not know may be the behaviour's: they go through."""
    merged: dict[str, int | float] = dict(mission.swarm.params)
    merged.update(given)
    for name, value in merged.items():
        try:  # typed as the drone's parameter: AVOID_MIN_DIST = 1 goes out as REAL32 1.0, not INT32 1
            merged[name] = simulation.parameter_value(name, float(value))
        except ValueError as exc:
            if behaviour is None or "is not a parameter" not in str(exc):
                where = "--param" if any(n == name for n, _ in given) else f"{mission.path}: swarm.params"
                raise UsageError(f"{where}: {exc}") from None
    return tuple(merged.items())


def run_fly(args: argparse.Namespace, simulation: Simulation) -> int:
    mission = load_mission(args.mission, max_obstacles=simulation.max_obstacles)
    if args.onboard:
        mission = flown_onboard(mission)
    try:  # a bad airframe is one line before anything starts (the runner needs its size for the report)
        simulation.contact_distance_m(args.airframe)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    _check_first_instance(args.first_instance, mission.swarm.drones, args.gcs_sysid)
    links = _link_plan(args, mission.swarm.links)
    params = _checked_params(mission, args.param, simulation, behaviour=args.behaviour or mission.swarm.behaviour)
    neighbours = _neighbour_plan(args, NeighbourPlan(relay=mission.swarm.relay, mesh=mission.swarm.mesh,
                                                     relay_scope=mission.swarm.relay_scope))  # fmt: skip
    behaviour = _behaviour(args.behaviour, simulation) if args.behaviour is not None else mission.swarm.behaviour
    if behaviour is not None and args.behaviour is None:
        try:  # the mission's own: checked as the drones will load it, and named by the mission file
            simulation.check_behaviour(behaviour)
        except ValueError as exc:
            raise UsageError(f"{args.mission}: swarm.behaviour: {exc}") from None
    mission = dataclasses.replace(
        mission,
        swarm=dataclasses.replace(
            mission.swarm,
            relay=neighbours.relay,
            relay_scope=neighbours.relay_scope,
            mesh=neighbours.mesh,
            behaviour=behaviour,
            params=params,
        ),
    )
    report = args.report or Path("reports") / f"{mission.name}-{time.strftime('%Y%m%d-%H%M%S')}"
    attach = _attach_specs(args, mission.swarm.attach)
    origin = _resolve_origin(args.origin, attach, args.gcs_sysid)
    runner = MissionRunner(mission, simulation, speed_factor=_speed(args), origin=origin,
                           first_instance=args.first_instance, report_dir=report, say=_say, airframe=args.airframe,
                           seed=args.seed if args.seed is not None else mission.swarm.seed or 0,
                           forward=None if args.no_forward else args.forward, lockstep=args.lockstep,
                           lockstep_quantum=_quantum(args, mission.swarm.quantum),
                           camera_drones=_camera_drones(args, mission.swarm.drones),
                           drones_per_process=args.drones_per_process, links=links,
                           signing_key_file=_signing_key_file(args), view=_start_view(args),
                           attach=attach, gcs_sysid=args.gcs_sysid,
                           stop_on_violation=args.stop_on_violation, plots=args.plots)  # fmt: skip
    view = runner.view
    _interrupt_on([signal.SIGTERM])  # a terminated run lands and stops its drones like Ctrl-C
    try:
        out = runner.run()
    except AttachError as exc:
        if view is not None:
            view.stop()
        raise UsageError(str(exc)) from None
    except (SwarmError, SpawnError) as exc:
        print(f"swarm: error: {exc}", file=sys.stderr)
        print(f"swarm: report (partial) in {report}", file=sys.stderr)
        violated = runner.session.recording.violations
        if violated and not isinstance(exc, InvariantViolated):  # broken before the step failed: that comes first
            print(f"swarm: error: {_violated_line(violated)}", file=sys.stderr)
        return EXIT_VIOLATED if violated or isinstance(exc, InvariantViolated) else EXIT_FAILED
    except KeyboardInterrupt:
        print(f"swarm: interrupted; drones landed and stopped; partial report in {report}", file=sys.stderr)
        return 130
    finally:
        if view is not None:
            view.stop()
    _say(f"swarm: report in {out}")
    violated = runner.session.recording.violations
    if violated:  # the flight flew, and broke what it was to hold (summary.txt names each)
        print(f"swarm: error: {_violated_line(violated)}", file=sys.stderr)
        return EXIT_VIOLATED
    return 0


def _violated_line(violated: Sequence[Violation]) -> str:
    first = min(violated, key=lambda v: v.time_s)
    return f"{len(violated)} invariant(s) violated, first {first.line()}"


def _formation_fields(args: argparse.Namespace) -> dict[str, Any]:
    if args.shape == "circle":
        return {"radius_m": args.radius, "alt_m": args.alt, "angular_rate_radps": args.rate, "alt_osc_amp_m": args.osc}
    fields: dict[str, Any] = {"spacing_m": args.spacing, "alt_m": args.alt, "heading_deg": args.heading}
    if args.shape == "v":
        fields["angle_deg"] = args.angle
    if args.shape == "grid":
        if (args.rows is None) != (args.cols is None):
            raise UsageError("give both --rows and --cols, or neither")
        fields["rows"] = args.rows if args.rows is not None else 0
        fields["cols"] = args.cols if args.cols is not None else 0
    return fields


def _given(args: argparse.Namespace, names: dict[str, str]) -> dict[str, Any]:
    """Spec fields for the options the user gave (the spec's defaults stand for the others)."""
    return {field: getattr(args, option) for option, field in names.items() if getattr(args, option) is not None}


_FLOCK_OPTIONS = {
    "alt": "alt_m",
    "goals": "migration_ne_m",
    "speed": "max_speed_mps",
    "accel": "max_accel_mps2",
    "radius": "neighbour_radius_m",
    "separation": "separation_radius_m",
    "w_separation": "separation_weight_mps2",
    "w_alignment": "alignment_weight_per_s",
    "w_cohesion": "cohesion_weight_per_s2",
    "w_migration": "migration_weight_per_s",
}
_FOLLOW_OPTIONS = {
    "waypoints": "waypoints_ne_m",
    "leader": "leader_sysid",
    "alt": "alt_m",
    "speed": "speed_mps",
    "spacing": "spacing_m",
    "angle": "angle_deg",
    "offsets": "offsets_fr_m",
    "turn_radius": "turn_radius_m",
}


_FOLLOW_ATTACHED_OPTIONS = {
    "leader": "leader_sysid",
    "alt": "alt_m",
    "spacing": "spacing_m",
    "angle": "angle_deg",
    "offsets": "offsets_fr_m",
    "max_turn_rate": "max_turn_rate_degps",
}
UNTIL_NEXT_COMMAND_S = 86400.0  # swarm follow --attached: flown until the next command (a day at most)


def _behaviour_fields(args: argparse.Namespace) -> dict[str, Any]:
    """A flock's or a follow's fields, as a mission file names them, for the options the user gave."""
    attached = args.command == "follow" and args.attached
    if not attached and args.command == "follow" and args.max_turn_rate is not None:
        raise UsageError("argument --max-turn-rate: only with --attached")
    if attached and (args.speed is not None or args.turn_radius is not None):
        raise UsageError("argument --speed, --turn-radius: not with --attached (the leader flies itself)")
    fields = _given(args, _OPTIONS[_command_name(args)])
    if attached:
        fields["duration_s"] = UNTIL_NEXT_COMMAND_S
    return fields


_OPTIONS: dict[str, dict[str, str]] = {
    "flock": _FLOCK_OPTIONS,
    "follow": _FOLLOW_OPTIONS,
    "follow_attached": _FOLLOW_ATTACHED_OPTIONS,
    "formation": {"alt": "alt_m", "spacing": "spacing_m", "rows": "rows", "cols": "cols", "radius": "radius_m",
                  "rate": "angular_rate_radps", "osc": "alt_osc_amp_m", "angle": "angle_deg",
                  "heading": "heading_deg"},
    "takeoff": {"alt": "alt_m"},
    "goto": {"north": "north_m", "east": "east_m", "alt": "alt_m"},
    "attach": {"max_distance": "max_distance_m", "keep_in": "keep_in_m", "signing_key": "signing_key"},
}  # fmt: skip
"""Per command, each option's field: what the control channel's JSON and a mission file call it."""
_POSITIONALS = frozenset({"north", "east"})  # ``swarm goto NORTH EAST``: named without dashes, as argparse names them


def _command_name(args: argparse.Namespace) -> str:
    """The control channel's command for the CLI's: ``swarm follow --attached`` is ``follow_attached``, ``swarm kill``
    a fault of kind crash."""
    if args.command == "follow" and args.attached:
        return "follow_attached"
    return "fault" if args.command == "kill" else str(args.command)


def _checked(command: dict[str, Any]) -> dict[str, Any]:
    """A command decoded as the supervisor will decode it, so that a mistake is one line before anything is sent; a
    field's mistake names the option that gave it."""
    flags = {field: option if option in _POSITIONALS else "--" + option.replace("_", "-")
             for option, field in _OPTIONS.get(command["cmd"], {}).items()}  # fmt: skip
    try:
        return check(command, flags)
    except ValueError as exc:  # AttachError, FaultError: already in the user's terms
        raise UsageError(str(exc)) from None


def _toml_fields(pairs: Sequence[str]) -> dict[str, Any]:
    """``FIELD=VALUE`` words as a TOML table reads them (numbers, lists, booleans; anything else a string)."""
    out: dict[str, Any] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.isidentifier():
            raise UsageError(f"argument FIELD=VALUE: expected field=value, got {pair!r}")
        try:
            out[key] = tomllib.loads(f"v = {value}")["v"]
        except tomllib.TOMLDecodeError:
            out[key] = value
    return out


def client_command(args: argparse.Namespace) -> dict[str, Any]:
    """The control channel's JSON command for ``swarm COMMAND ...`` (gcs/supervisor/commands.py decodes it),
    checked as the supervisor will check it."""
    name = _command_name(args)
    command: dict[str, Any] = {"cmd": name}
    if name not in DECODERS:  # the session's own: status, down
        return command
    if name in ("takeoff", "goto"):
        command.update(_given(args, _OPTIONS[name]))
    elif name == "formation":
        command.update(shape=args.shape, fields=_formation_fields(args))
    elif name in ("flock", "follow", "follow_attached"):
        command["fields"] = _behaviour_fields(args)
    elif name == "behaviour":
        command["action"] = args.action
    elif name == "attach":
        key = None if args.signing_key is None else str(args.signing_key.resolve())  # the supervisor's cwd may differ
        command.update(url=args.url, max_distance_m=args.max_distance, keep_in_m=args.keep_in, signing_key=key)
    elif name == "detach":
        command["sysid"] = args.sysid
    elif name == "require":
        command.update(fields={"kind": args.kind, **_toml_fields(args.fields)}, cwd=os.getcwd())
    elif name == "fault":
        command.update(sysid=args.sysid, kind=CRASH if args.command == "kill" else args.kind,
                       motor=getattr(args, "motor", None), for_s=getattr(args, "for_s", None))  # fmt: skip
    return _checked(command)


def run_client(args: argparse.Namespace) -> int:
    request = client_command(args)
    response = ControlClient().request(request)
    if not response.get("ok"):
        print(f"swarm: error: {response.get('error', 'failed')}", file=sys.stderr)
        return EXIT_USAGE if response.get("usage") else EXIT_FAILED
    if args.command == "status":
        print(format_status(response["drones"]))
    elif args.command in ("fault", "kill"):
        print(f"swarm: drone {args.sysid}: {response.get('result', 'done')}")
    elif request["cmd"] in ("behaviour", "attach", "detach", "require", "follow_attached", "pause"):
        print(f"swarm: {response.get('result', 'done')}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """The ``swarm`` entry point and the composition root's user: the simulated drones come from ``SITL``."""
    try:
        args = build_parser().parse_args(argv)
        if args.command == "up":
            return run_up(args, SITL)
        if args.command == "fly":
            return run_fly(args, SITL)
        if args.command == "bench":
            return run_bench(args, SITL)
        if args.command == "plan":
            return run_plan(args)
        if args.command == "falsify":
            return run_falsify(args, usable_cpus())
        if args.command == "sweep":
            return run_sweep_command(args, SITL, usable_cpus())
        return run_client(args)
    except (UsageError, MissionFileError, SweepError, FalsifyError) as exc:
        print(f"swarm: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except ControlError as exc:
        print(f"swarm: error: {exc}", file=sys.stderr)
        return EXIT_FAILED


def entry() -> int:
    """The ``swarm`` command (pyproject.toml's script, ``python -m gcs.cli``): ``main`` on the command
    line, ended without the interpreter's last garbage collection (swarmcommon/process_end.py)."""
    return ending(main)


if __name__ == "__main__":
    sys.exit(entry())
