"""What a user can ask of the swarm: one frozen request type per verb, with its fields, units, defaults and checks.

Every front-end is a decoder into these types: the CLI's arguments and the control channel's JSON
(gcs/supervisor/commands.py), a mission file's steps (gcs/supervisor/mission_runner.py), the Python API
(gcs/api/engine.py and its two faces). ``gcs.supervisor.verbs.start`` carries a request out, whichever front-end made
it, so a default or a check written here holds for all of them; tests/unit/test_requests.py drives every front-end's
decoder to these types.

A request checks what it can know alone (a finite number, a positive time, an altitude in range) when it is made and
raises ``FieldError`` (a ValueError of one line naming the field, which each front-end words in its own terms: a flag,
a JSON key, ``FILE:LINE: steps[2].alt_m``). What needs the swarm (a sysid that exists, a formation with enough
slots) is checked when the request is started, by its verb.

Adding a verb: a request type here (its ``verb`` name, fields with units, defaults, ``__post_init__`` checks), its
function in verbs.py with its row in ``VERBS``, and a decoder in each front-end that offers it (docs/architecture.md,
"Adding a verb").
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from gcs.command.procedures import check_takeoff_alt
from gcs.fleet.attach import AttachSpec
from gcs.fleet.faults import CRASH, FaultRequest
from gcs.fleet.swarm import ARM_TIMEOUT_S
from gcs.flight.behaviours import Behaviour, FlockSpec, FollowAttachedSpec, FollowSpec
from gcs.flight.formation import FieldError, Formation, not_a_sysid
from gcs.invariants.spec import Invariant
from gcs.missions.mission_file import (
    LAND_TIMEOUT_S,
    RTL_TIMEOUT_S,
    SHAPE_NAMES,
    SWAP_ACCEL_MPS2,
    SWAP_TIMEOUT_S,
    SWAP_TOLERANCE_M,
    TAKEOFF_ALT_M,
    TAKEOFF_TIMEOUT_S,
)
from gcs.missions.plan_flight import Offset, Uploaded
from gcs.missions.qgc_plan import QgcPlan


def _finite(name: str, value: float) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise FieldError(name, f"must be a finite number, got {value!r}")


def _positive_time(name: str, value: float) -> None:
    """A time limit: a positive number of seconds (infinity: no limit)."""
    if isinstance(value, bool) or not isinstance(value, int | float) or math.isnan(value) or value <= 0:
        raise FieldError(name, f"must be a positive number of seconds, got {value!r}")


def _sysid(name: str, value: int) -> None:
    problem = not_a_sysid(value)
    if problem is not None:
        raise FieldError(name, problem)


@dataclass(frozen=True, slots=True, kw_only=True)
class Arm:
    """Arm every surviving drone on the ground (after its pre-arm checks); a mission does it before its first step."""

    verb: ClassVar[str] = "arm"
    timeout_s: float = ARM_TIMEOUT_S

    def __post_init__(self) -> None:
        _positive_time("timeout_s", self.timeout_s)


@dataclass(frozen=True, slots=True, kw_only=True)
class Takeoff:
    """Arm (unless armed) and climb to ``alt_m`` above home; done when every drone holds it."""

    verb: ClassVar[str] = "takeoff"
    alt_m: float = TAKEOFF_ALT_M
    timeout_s: float = TAKEOFF_TIMEOUT_S

    def __post_init__(self) -> None:
        try:
            check_takeoff_alt(self.alt_m)
        except (ValueError, TypeError) as exc:
            raise FieldError("alt_m", str(exc)) from None  # one check for every front-end, a mission file's too
        _positive_time("timeout_s", self.timeout_s)


@dataclass(frozen=True, slots=True, kw_only=True)
class SquareGrid:
    """A grid as square as the surviving drones allow, its rows and columns counted when it is flown (``swarm
    formation grid`` without ``--rows``)."""

    spacing_m: float
    alt_m: float
    heading_deg: float = 0.0

    def fields(self, drone_count: int) -> dict[str, Any]:
        """A mission file's grid fields for ``drone_count`` drones."""
        cols = max(1, math.ceil(math.sqrt(drone_count)))
        return {"spacing_m": self.spacing_m, "alt_m": self.alt_m, "heading_deg": self.heading_deg, "cols": cols,
                "rows": math.ceil(drone_count / cols)}  # fmt: skip


@dataclass(frozen=True, slots=True, kw_only=True)
class FlyFormation:
    """Fly a formation from where the drones are (a synchronised, collision-aware transition), until the next verb."""

    verb: ClassVar[str] = "formation"
    formation: Formation | SquareGrid

    def __post_init__(self) -> None:
        if type(self.formation) not in SHAPE_NAMES and not isinstance(self.formation, SquareGrid):
            raise TypeError(f"not a formation: {self.formation!r} (GridSpec, CircleSpec, LineSpec or VSpec)")

    @property
    def shape(self) -> str:
        return "grid" if isinstance(self.formation, SquareGrid) else SHAPE_NAMES[type(self.formation)]


@dataclass(frozen=True, slots=True, kw_only=True)
class Goto:
    """Move the formation being flown so that its centre is at north/east (and ``alt_m``), keeping its shape."""

    verb: ClassVar[str] = "goto"
    north_m: float
    east_m: float
    alt_m: float | None = None

    def __post_init__(self) -> None:
        _finite("north_m", self.north_m)
        _finite("east_m", self.east_m)
        if self.alt_m is not None:
            _finite("alt_m", self.alt_m)


@dataclass(frozen=True, slots=True, kw_only=True)
class Flock:
    """Reynolds flocking, computed by the ground station or (``onboard``) by every drone itself."""

    verb: ClassVar[str] = "flock"
    spec: FlockSpec
    onboard: bool = False


@dataclass(frozen=True, slots=True, kw_only=True)
class Follow:
    """Leader-follower along the leader's path; done when the leader has flown it."""

    verb: ClassVar[str] = "follow"
    spec: FollowSpec
    onboard: bool = False


@dataclass(frozen=True, slots=True, kw_only=True)
class FollowAttached:
    """Every drone holds its offset from an attached leader that flies itself, for the spec's ``duration_s``."""

    verb: ClassVar[str] = "follow_attached"
    spec: FollowAttachedSpec


@dataclass(frozen=True, slots=True, kw_only=True)
class Swap:
    """Every drone straight through the centre to the opposite point; done when each is within ``tolerance_m``."""

    verb: ClassVar[str] = "swap"
    speed_mps: float
    accel_mps2: float = SWAP_ACCEL_MPS2
    tolerance_m: float = SWAP_TOLERANCE_M
    timeout_s: float = SWAP_TIMEOUT_S

    def __post_init__(self) -> None:
        for name in ("speed_mps", "accel_mps2", "tolerance_m"):
            value = getattr(self, name)
            _finite(name, value)
            if value <= 0:
                raise FieldError(name, f"must be a positive number, got {value!r}")
        _positive_time("timeout_s", self.timeout_s)


@dataclass(frozen=True, slots=True, kw_only=True)
class Hold:
    """Fly on as now for ``duration_s`` simulated seconds."""

    verb: ClassVar[str] = "hold"
    duration_s: float

    def __post_init__(self) -> None:
        value = self.duration_s
        if isinstance(value, bool) or not isinstance(value, int | float) or not (math.isfinite(value) and value >= 0):
            raise FieldError("duration_s", f"must be a finite number of seconds >= 0, got {value!r}")


@dataclass(frozen=True, slots=True, kw_only=True)
class Pause:
    """Every drone holds where it is in PX4 Hold (AUTO.LOITER), the ground station's setpoints stopped, until the
    next verb: QGroundControl's Pause, MAVSDK's ``action.hold()``."""

    verb: ClassVar[str] = "pause"


@dataclass(frozen=True, slots=True, kw_only=True)
class Land:
    """Land every drone still armed where it is (clear of wrecks); done when all have landed and disarmed."""

    verb: ClassVar[str] = "land"
    timeout_s: float = LAND_TIMEOUT_S

    def __post_init__(self) -> None:
        _positive_time("timeout_s", self.timeout_s)


@dataclass(frozen=True, slots=True, kw_only=True)
class ReturnToLaunch:
    """Every drone still armed returns to its launch point and lands; done when all have disarmed."""

    verb: ClassVar[str] = "rtl"
    timeout_s: float = RTL_TIMEOUT_S

    def __post_init__(self) -> None:
        _positive_time("timeout_s", self.timeout_s)


@dataclass(frozen=True, slots=True, kw_only=True)
class Behaviours:
    """Every drone's onboard behaviour on (``run``: BHV_EN = 1) or off (BHV_EN = 0, then Hold)."""

    verb: ClassVar[str] = "behaviour"
    run: bool

    def __post_init__(self) -> None:
        if not isinstance(self.run, bool):
            raise FieldError("run", f"must be true or false, got {self.run!r}")


@dataclass(frozen=True, slots=True, kw_only=True)
class InjectFault:
    """A fault in one drone: PX4's MAV_CMD_INJECT_FAILURE, or (kind ``crash``) the end of its flight software."""

    verb: ClassVar[str] = "fault"
    sysid: int
    fault: FaultRequest

    def __post_init__(self) -> None:
        _sysid("sysid", self.sysid)


@dataclass(frozen=True, slots=True, kw_only=True)
class Kill:
    """End one drone's flight software, as a crash would (a fault of kind ``crash``)."""

    verb: ClassVar[str] = "kill"
    sysid: int

    def __post_init__(self) -> None:
        _sysid("sysid", self.sysid)

    @property
    def fault(self) -> FaultRequest:
        return FaultRequest(kind=CRASH)


@dataclass(frozen=True, slots=True, kw_only=True)
class PlanUpload:
    """A QGroundControl plan's copy to each drone named, moved by its offset (north, east metres)."""

    verb: ClassVar[str] = "plan_upload"
    plan: QgcPlan
    offsets: Mapping[int, Offset]
    hold_first: bool = False  # every drone in the air waits in Hold while the transfer is served


@dataclass(frozen=True, slots=True, kw_only=True)
class PlanStart:
    """AUTO.MISSION on the drones named; with what was ``uploaded``, done when every one has finished it."""

    verb: ClassVar[str] = "plan_start"
    sysids: tuple[int, ...]
    uploaded: Uploaded | None = None
    timeout_s: float = math.inf

    def __post_init__(self) -> None:
        _positive_time("timeout_s", self.timeout_s)


@dataclass(frozen=True, slots=True, kw_only=True)
class PlanDownload:
    """One drone's mission and fence, as a QGroundControl plan."""

    verb: ClassVar[str] = "plan_download"
    sysid: int

    def __post_init__(self) -> None:
        _sysid("sysid", self.sysid)


@dataclass(frozen=True, slots=True, kw_only=True)
class SetParam:
    """A drone parameter on the drones named (every drone: None), each confirmed by its PARAM_VALUE echo."""

    verb: ClassVar[str] = "param"
    name: str
    value: float
    sysids: tuple[int, ...] | None = None

    def __post_init__(self) -> None:
        _finite("value", self.value)
        for sysid in self.sysids or ():
            _sysid("sysids", sysid)


@dataclass(frozen=True, slots=True, kw_only=True)
class Control:
    """A user's controller flies the swarm: the streamer asks it for setpoints every tick."""

    verb: ClassVar[str] = "control"
    controller: Behaviour


@dataclass(frozen=True, slots=True, kw_only=True)
class Attach:
    """Attach the vehicles heard on a link the simulation does not run (docs/external.md)."""

    verb: ClassVar[str] = "attach"
    spec: AttachSpec


@dataclass(frozen=True, slots=True, kw_only=True)
class Detach:
    """Let an attached vehicle go; it is told nothing."""

    verb: ClassVar[str] = "detach"
    sysid: int

    def __post_init__(self) -> None:
        _sysid("sysid", self.sysid)


@dataclass(frozen=True, slots=True, kw_only=True)
class Require:
    """Check invariants (each as a mission's ``[[invariants]]`` table, or built from one already: a mission file's,
    checked with its line when the file was read) at every tick from now on; ``base``: where a predicate's file is
    read from; ``stop``: the first violation ends the flight."""

    verb: ClassVar[str] = "require"
    invariants: tuple[Mapping[str, Any] | Invariant, ...]
    base: Path = field(default_factory=Path.cwd)
    stop: bool = False


Request = (
    Arm | Takeoff | FlyFormation | Goto | Flock | Follow | FollowAttached | Swap | Hold | Pause | Land
    | ReturnToLaunch | Behaviours | InjectFault | Kill | PlanUpload | PlanStart | PlanDownload | SetParam | Control
    | Attach | Detach | Require
)  # fmt: skip
