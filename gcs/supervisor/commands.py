"""The control channel's language: a JSON command of ``swarm up``'s control channel decoded into a request.

``swarm takeoff --alt 5`` sends ``{"cmd": "takeoff", "alt_m": 5}``; the station (gcs/supervisor/station.py) decodes it
here and starts the request. The CLI decodes what it is about to send with the same function first, so that a
mistake is one line before anything is sent (``decode(command, None)``: without a swarm, what needs one is checked by
the station). Keys every earlier version took keep working: ``alt`` for a takeoff's ``alt_m``, a fault's ``kind``
``crash`` for a kill.

A decoder raises ``FieldError`` naming the JSON key (the CLI words it as its flag), ``ValueError`` for anything else
the user must fix; both are answered as usage errors (exit code 2).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Final, TypeVar

from gcs.fleet.attach import DEFAULT_KEEP_IN_M, DEFAULT_MAX_DISTANCE_M, parse_attach
from gcs.fleet.faults import CRASH, fault_request
from gcs.fleet.swarm import Swarm, SwarmError
from gcs.flight.formation import FieldError
from gcs.missions.mission_file import build_flock, build_follow, build_follow_attached, build_formation
from gcs.missions.plan_flight import (
    PlanUsageError,
    copy_offsets,
    nothing_to_start,
    parse_drones,
    parse_offsets,
    spawn_offsets,
)
from gcs.missions.qgc_plan import load_plan
from gcs.supervisor import requests as rq

Command = Mapping[str, Any]
C = TypeVar("C", bound=Command)
Decoder = Callable[[Command, "Swarm | None"], rq.Request]


def _number(command: Command, key: str) -> float:
    """A number under ``key``; FieldError names the key when it is missing or not a number."""
    value = command.get(key)
    if value is None:
        raise FieldError(key, "missing")
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise FieldError(key, f"must be a number, got {value!r}")
    return float(value)


def _numbers(command: Command, *keys: str, **aliases: str) -> dict[str, float]:
    """The numbers among ``keys`` the command gives (an older name in ``aliases``: new=old), for a request's
    arguments: what is not given keeps the request's own default."""
    out = {key: _number(command, key) for key in keys if command.get(key) is not None}
    for key, old in aliases.items():
        if key not in out and command.get(old) is not None:
            out[key] = _number(command, old)
    return out


def _fields(command: Command) -> dict[str, Any]:
    fields = command.get("fields", {})
    if not isinstance(fields, Mapping):
        raise FieldError("fields", f"must be a table of a spec's fields, got {fields!r}")
    return dict(fields)


def _flag(command: Command, key: str) -> bool:
    value = command.get(key, False)
    if not isinstance(value, bool):
        raise FieldError(key, f"must be true or false, got {value!r}")
    return value


class NeedsTheSwarm(ValueError):
    """A command checked as far as it can be without the running swarm: what is left (which drones, their offsets)
    only the station can decode."""


def _swarm(swarm: Swarm | None) -> Swarm:
    if swarm is None:
        raise NeedsTheSwarm("this command needs the running swarm")
    return swarm


def _takeoff(c: Command, _swarm: Swarm | None) -> rq.Request:
    return rq.Takeoff(**_numbers(c, "alt_m", "timeout_s", alt_m="alt"))


def _formation(c: Command, _swarm: Swarm | None) -> rq.Request:
    """A formation's shape and its fields, as a mission file gives them; a grid without rows and columns is made as
    square as the surviving drones allow when it is flown."""
    shape, fields = c.get("shape"), _fields(c)
    if shape == "grid" and not fields.get("rows"):
        fields = {k: v for k, v in fields.items() if k not in ("rows", "cols")}
        build_formation("grid", {**fields, "rows": 1, "cols": 1})  # the other fields' checks
        return rq.FlyFormation(formation=rq.SquareGrid(**fields))
    return rq.FlyFormation(formation=build_formation(str(shape), fields))


def _goto(c: Command, _swarm: Swarm | None) -> rq.Request:
    return rq.Goto(north_m=_number(c, "north_m"), east_m=_number(c, "east_m"), **_numbers(c, "alt_m"))


def _behaviour(c: Command, _swarm: Swarm | None) -> rq.Request:
    action = c.get("action")
    if action not in ("start", "stop"):
        raise FieldError("action", f"behaviour must be start or stop, got {action!r}")
    return rq.Behaviours(run=action == "start")


def _fault(c: Command, _swarm: Swarm | None) -> rq.Request:
    """A fault by name (``crash``: a kill), with a motor fault's rotor or a link fault's time (FaultError)."""
    fault = fault_request(c.get("kind"), c.get("motor"), c.get("for_s"))
    if fault.kind == CRASH:
        return rq.Kill(sysid=c.get("sysid"))  # type: ignore[arg-type]  # the request checks the sysid
    return rq.InjectFault(sysid=c.get("sysid"), fault=fault)  # type: ignore[arg-type]


def _attach(c: Command, _swarm: Swarm | None) -> rq.Request:
    key = c.get("signing_key")
    given = _numbers(c, "max_distance_m", "keep_in_m")
    spec = parse_attach(str(c.get("url")), max_distance_m=given.get("max_distance_m", DEFAULT_MAX_DISTANCE_M),
                        keep_in_m=given.get("keep_in_m", DEFAULT_KEEP_IN_M),
                        signing_key_file=None if key is None else Path(str(key)))  # fmt: skip
    return rq.Attach(spec=spec)


def _chosen(c: Command, swarm: Swarm) -> list[int]:
    """The drones a plan command names (sysids, "all"), the lost ones left out."""
    chosen = parse_drones(str(c.get("drones", "all")), swarm.liveness.sysids)
    chosen = [s for s in chosen if s not in swarm.liveness.losses]
    if not chosen:
        raise SwarmError("every chosen drone is lost")
    return chosen


def _plan_upload(c: Command, swarm: Swarm | None) -> rq.Request:
    """``swarm plan upload``: each chosen drone its copy of a QGroundControl plan, moved by an offset
    (gcs/missions/plan_flight.py). The file and the offsets are checked before the swarm is needed; ``start``: the
    upload is to be started (``swarm plan upload --start`` sends ``plan_start`` next), so a plan without mission
    items is refused."""
    path = Path(str(c.get("path")))
    plan = load_plan(path)
    problem = nothing_to_start(plan, path) if _flag(c, "start") else None
    if problem is not None:
        raise PlanUsageError(f"{problem} (upload its fence alone without --start)")
    wanted = parse_offsets(str(c.get("offsets", "spawn")))
    flying = _swarm(swarm)
    offsets = copy_offsets(spawn_offsets(flying), _chosen(c, flying), wanted)
    return rq.PlanUpload(plan=plan, offsets=offsets)


def _plan_start(c: Command, swarm: Swarm | None) -> rq.Request:
    return rq.PlanStart(sysids=tuple(_chosen(c, _swarm(swarm))))


def _land(c: Command, _swarm: Swarm | None) -> rq.Request:
    return rq.Land(**_numbers(c, "timeout_s"))


def _rtl(c: Command, _swarm: Swarm | None) -> rq.Request:
    return rq.ReturnToLaunch(**_numbers(c, "timeout_s"))


DECODERS: Final[Mapping[str, Decoder]] = {
    "takeoff": _takeoff,
    "formation": _formation,
    "flock": lambda c, _s: rq.Flock(spec=build_flock(_fields(c)), onboard=_flag(c, "onboard")),
    "follow": lambda c, _s: rq.Follow(spec=build_follow(_fields(c)), onboard=_flag(c, "onboard")),
    "follow_attached": lambda c, _s: rq.FollowAttached(spec=build_follow_attached(_fields(c))),
    "goto": _goto,
    "pause": lambda _c, _s: rq.Pause(),
    "land": _land,
    "rtl": _rtl,
    "behaviour": _behaviour,
    "fault": _fault,
    "kill": lambda c, _s: rq.Kill(sysid=c.get("sysid")),  # type: ignore[arg-type]
    "plan_upload": _plan_upload,
    "plan_start": _plan_start,
    "plan_download": lambda c, _s: rq.PlanDownload(sysid=c.get("sysid")),  # type: ignore[arg-type]
    "param": lambda c, _s: rq.SetParam(name=str(c.get("name")), value=_number(c, "value")),
    "attach": _attach,
    "detach": lambda c, _s: rq.Detach(sysid=c.get("sysid")),  # type: ignore[arg-type]
    "require": lambda c, _s: rq.Require(invariants=(_fields(c),), base=Path(str(c.get("cwd", ".")))),
}
"""Every verb the control channel offers, by its ``cmd``; the station answers ``ping``, ``status`` and ``down``
itself (they ask nothing of the drones)."""


def decode(command: Command, swarm: Swarm | None) -> rq.Request:
    """The request a control command makes (FieldError, ValueError: the user's mistake, in one line)."""
    decoder = DECODERS.get(str(command.get("cmd")))
    if decoder is None:
        raise ValueError(f"unknown command {command.get('cmd')!r}")
    return decoder(command, swarm)


def check(command: C, names: Mapping[str, str]) -> C:
    """``command`` decoded as the station will decode it, as far as that can be done without the running swarm, so
    that a front-end says a mistake in one line before anything is sent (ValueError); ``names``: how the front-end
    names a field (its flag), for a field's mistake (``argument --alt: ...``)."""
    try:
        decode(command, None)
    except NeedsTheSwarm:
        pass  # the rest is the station's to decode
    except FieldError as exc:
        raise ValueError(f"argument {names.get(exc.field, exc.field)}: {exc.problem}") from None
    return command
