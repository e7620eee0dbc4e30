"""What the Python API hands its user: launch options, each drone's state, events, the flight's outcome.

Plain frozen dataclasses with units in their names, built from MAVLink telemetry only (gcs/fleet/telemetry.py): a
drone's state is what a ground station would know of a real PX4 vehicle, in the swarm frame (north, east, down metres
from the swarm origin), never simulation truth.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from gcs.fleet.attach import AttachSpec, parse_attach, role_of
from gcs.fleet.harness import MAX_DRONES
from gcs.fleet.links import LinkPlan, NeighbourPlan
from gcs.fleet.losses import LossPolicy
from gcs.flight.frames import Vec3
from gcs.flight.geodesy import DEFAULT_ORIGIN, GeoPoint
from gcs.invariants.spec import build_invariant, unique_names
from gcs.mavlink.transport import GCS_SYSID


@dataclass(frozen=True, slots=True, kw_only=True)
class LaunchOptions:
    """Everything ``launch`` needs, with the defaults of ``swarm up`` except ``lockstep`` (on: an API user's
    script is reproducible unless asked otherwise)."""

    drones: int
    layout: str = "grid"  # grid or line (gcs/fleet/harness.py LAYOUTS)
    spacing_m: float = 2.0
    origin: GeoPoint = DEFAULT_ORIGIN
    lockstep: bool = True
    speed: float | None = None  # paced: the speed factor (default 1); lockstep: a pace (default: as fast as it can)
    quantum: int = 1  # lockstep: physics steps every drone runs between waits
    seed: int = 0
    first_instance: int = 0
    airframe: str | None = None
    drones_per_process: int | Literal["auto"] = 1
    params: Mapping[str, float] = field(default_factory=dict)  # drone parameters set before anything flies
    links: LinkPlan = field(default_factory=LinkPlan)
    # How the drones hear each other: the supervisor's relay and/or the drone-to-drone mesh (docs/links.md)
    neighbours: NeighbourPlan = field(default_factory=NeighbourPlan)
    loss_policy: LossPolicy = LossPolicy.CONTINUE
    report_dir: Path | None = None  # write the flight report here at the end (None: no report)
    log_dir: Path | None = None  # each drone's log (None: a temporary directory)
    forward: tuple[str, int] | None = None  # forward all drone traffic to a ground station (QGroundControl)
    signing_key_file: Path | None = None
    behaviour: str | None = None  # an onboard behaviour every drone carries: "path/to/file.py:ClassName"
    ready_timeout_s: float = 60.0  # wall seconds for every drone to come up
    view: bool = False  # serve the live view (docs/view.md); its address is the session's ``view_url``
    view_port: int | None = None  # the live view's port (None: 8765 or the next free one; 0: any free port)
    # Vehicles the simulation does not run, as ``swarm up --attach`` takes them ("intruder=udpin:0.0.0.0:14560";
    # docs/external.md): attached before the drones start; a swarm with one runs paced at speed 1 (lockstep=False)
    attach: Sequence[str] = ()
    arm_external: bool = False  # the attached members are armed and taken off with the drones (--arm-external)
    gcs_sysid: int = GCS_SYSID  # the supervisor's own system id (another when a QGroundControl beside it uses 255)
    # Invariants checked at every tick once the drones are up, each as a mission's [[invariants]] table gives it
    # ({"kind": "separation", "min_m": 1.0}; docs/invariants.md); a predicate's file is read from the working folder
    invariants: Sequence[Mapping[str, Any]] = ()
    stop_on_violation: bool = False  # the first violation ends the flight (the call in progress raises SwarmError)

    def __post_init__(self) -> None:
        for name in ("report_dir", "log_dir", "signing_key_file"):  # a path may come as a string (launch's **options)
            value = getattr(self, name)
            if value is not None and not isinstance(value, Path):
                object.__setattr__(self, name, Path(value))
        if not 1 <= self.drones <= MAX_DRONES:
            raise ValueError(f"drones must be in 1..{MAX_DRONES}, got {self.drones}")
        if self.first_instance < 0 or self.first_instance + self.drones > MAX_DRONES:
            raise ValueError(f"first_instance must leave room for every sysid (instance + 1 <= {MAX_DRONES})")
        if self.speed is not None and not (math.isfinite(self.speed) and self.speed > 0):
            raise ValueError(f"speed must be a positive number, got {self.speed!r}")
        if self.quantum < 1:
            raise ValueError(f"quantum must be at least 1, got {self.quantum}")
        if self.view_port is not None and not self.view:
            raise ValueError("view_port needs view=True")
        if isinstance(self.attach, str):
            raise ValueError("attach takes a list of [ROLE=]URL strings, e.g. attach=['intruder=udpin:0.0.0.0:14560']")
        drones_sysids = range(self.first_instance + 1, self.first_instance + self.drones + 1)
        if not 1 <= self.gcs_sysid <= GCS_SYSID or self.gcs_sysid in drones_sysids:
            raise ValueError(f"gcs_sysid must be in 1..{GCS_SYSID} and no drone's, got {self.gcs_sysid}")
        if isinstance(self.invariants, Mapping) or not all(isinstance(i, Mapping) for i in self.invariants):
            raise ValueError("invariants takes a list of tables, e.g. invariants=[{'kind': 'separation', 'min_m': 1}]")
        unique_names([build_invariant(i, base=Path.cwd(), drone_count=self.drones) for i in self.invariants])
        specs = self.attach_specs()  # AttachError: a ValueError of one line
        if specs and (self.lockstep or (self.speed is not None and self.speed != 1.0)):
            raise ValueError("attach: a swarm with an attached vehicle runs paced at speed 1 (the real world keeps "
                             "wall time): pass lockstep=False")  # fmt: skip

    def attach_specs(self) -> list[AttachSpec]:
        """``attach`` as the swarm takes it (AttachError, a ValueError of one line, for a bad one)."""
        return [parse_attach(text, arm=self.arm_external and role_of(text) == "member") for text in self.attach]


@dataclass(frozen=True, slots=True, kw_only=True)
class DroneState:
    """One drone as its telemetry reports it, at ``time_s`` on the swarm's clock (simulated seconds)."""

    sysid: int
    time_s: float
    pos_ned_m: Vec3  # swarm frame; NaN until the drone has reported a position and its home
    vel_ned_mps: Vec3
    armed: bool
    mode: str  # PX4's name: OFFBOARD, AUTO.LOITER, AUTO.LAND, ...
    in_air: bool  # EXTENDED_SYS_STATE: not on the ground
    battery_remaining: float  # 0..1, NaN unknown
    link_age_s: float  # since anything was last heard from it
    lost: bool  # the swarm has lost it (process ended, crashed, or silent): see ``Event`` DroneLost
    failsafe: str | None  # its warning while it reports MAV_STATE_CRITICAL (a failsafe in force)

    @property
    def alt_m(self) -> float:
        """Altitude above the swarm origin."""
        return -self.pos_ned_m[2]


@dataclass(frozen=True, slots=True, kw_only=True)
class Event:
    """Something that happened, as the supervisor would print it: ``kind`` is ``statustext`` (a drone's warning or
    information text), ``lost`` (the swarm lost a drone), ``regained`` (a silent drone heard again), ``failsafe`` (a
    drone entered a failsafe) or ``policy`` (what the swarm did about a loss or a return)."""

    kind: Literal["statustext", "lost", "regained", "failsafe", "policy"]
    time_s: float
    sysid: int | None  # None: the whole swarm
    text: str
    severity: int | None = None  # MAV_SEVERITY of a statustext


@dataclass(frozen=True, slots=True, kw_only=True)
class FlightResult:
    """The outcome of a session: where the report went (None without ``report_dir``) and its metrics (the content
    of metrics.json: docs/missions.md lists every figure)."""

    report_dir: Path | None
    metrics: dict[str, Any]


class ControllerError(RuntimeError):
    """The user's controller raised: it was stopped and every drone holds where it is (the cause is chained)."""
