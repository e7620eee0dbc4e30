"""What a flight records, in one place: the data model the mission runner fills and the flight report reads.

Positions are in the swarm frame: local NED in metres around the swarm's geographic origin (see gcs/flight/frames.py),
the frame formations are defined in. Times are seconds since the mission started (the supervisor's clock).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from gcs.fleet.losses import DroneLoss
from gcs.invariants.monitor import Violation

Vec3 = tuple[float, float, float]


@dataclass(frozen=True, slots=True, kw_only=True)
class DroneSample:
    """One drone's reported state (from its MAVLink telemetry) at one instant."""

    time_s: float
    sysid: int
    pos_ned_m: Vec3  # swarm frame
    vel_ned_mps: Vec3
    armed: bool
    mode: str  # PX4 mode name, e.g. "OFFBOARD"
    target_ned_m: Vec3 | None = None  # the formation slot commanded at that instant (swarm frame), if any


@dataclass(frozen=True, slots=True, kw_only=True)
class StepRecord:
    """One mission step (takeoff, a formation, land ...) with its time span."""

    index: int
    name: str  # e.g. "circle"
    kind: str  # "takeoff", "formation", "land", "hold", ...
    start_s: float
    end_s: float
    target_alt_m: float | None = None  # for takeoff: the altitude climbed to above home (MIS_TAKEOFF_ALT at least)
    arrival_s: float | None = None  # for a formation: when its planned transition puts every setpoint on its slot


@dataclass(frozen=True, slots=True, kw_only=True)
class EventRecord:
    time_s: float
    sysid: int | None  # None: swarm-wide
    text: str  # e.g. a STATUSTEXT: "Collision with drone 3", "Avoidance: ..."


@dataclass(frozen=True, slots=True, kw_only=True)
class FaultRecord:
    """A fault the mission injected: when it was ordered, into which drone, and the drone's answer."""

    time_s: float
    sysid: int
    fault: str  # "motor 1 off", "gps", "crash", ...
    result: str  # "accepted", "denied", "process 1234 killed", "not injected: drone already lost"


@dataclass(frozen=True, slots=True, kw_only=True)
class ItemReached:
    """A drone's MISSION_ITEM_REACHED: it reached item ``seq`` of its mission (a plan flown in AUTO.MISSION)."""

    time_s: float
    sysid: int
    seq: int


@dataclass(frozen=True, slots=True, kw_only=True)
class ObstacleShape:
    """A static obstacle as the live view and the report page draw it (swarm frame)."""

    kind: str  # cylinder (standing on the ground) or sphere
    north_m: float
    east_m: float
    radius_m: float
    height_m: float  # cylinder: its height; sphere: its centre's altitude


@dataclass(slots=True)
class FlightRecording:
    mission_name: str
    n_drones: int
    collision_radius_m: float  # centre distance at which two drones touch (twice the airframe collision radius)
    samples: list[DroneSample] = field(default_factory=list)
    steps: list[StepRecord] = field(default_factory=list)
    events: list[EventRecord] = field(default_factory=list)
    # Paced flights: the speed factor asked for, and the drones' achieved real-time factor, measured every few
    # seconds (gcs/fleet/pace_monitor.py); None and empty in lockstep, where pace cannot change the result.
    requested_speed: float | None = None
    realtime_factors: list[float] = field(default_factory=list)
    loss_policy: str = "continue"  # what the survivors did on a loss (gcs/fleet/losses.py LossPolicy)
    signing_key_id: str | None = None  # MAVLink signing on (gcs/mavlink/signing.py key_id of the key), None when off
    neighbours: str = "relay"  # how neighbours' positions travelled (gcs/fleet/links.py NeighbourPlan.describe)
    # What the link model did, by channel ("gcs up", ...), summed over the drones (SimulationHarness.link_counters)
    link_counters: dict[str, dict[str, float]] = field(default_factory=dict)
    losses: list[DroneLoss] = field(default_factory=list)  # as finally known (where each came down, once it did)
    regained: list[DroneLoss] = field(default_factory=list)  # silent drones heard again (each with regained_s)
    faults: list[FaultRecord] = field(default_factory=list)
    failsafes: list[EventRecord] = field(default_factory=list)  # a drone entering failsafe, with its warning
    policy_events: list[EventRecord] = field(default_factory=list)  # what the swarm did about each loss
    items_reached: list[ItemReached] = field(default_factory=list)  # mission items reached (each arrival once)
    obstacles: list[ObstacleShape] = field(default_factory=list)  # the mission's static obstacles
    # Vehicles the simulation did not run (docs/external.md): sysid -> (role, link), and where each reported itself
    # (its GLOBAL_POSITION_INT in the swarm frame, its slot when it is a member)
    attached: dict[int, tuple[str, str]] = field(default_factory=dict)
    attached_samples: list[DroneSample] = field(default_factory=list)
    # The flight's invariants (docs/invariants.md), as each describes itself, and the first violation of each
    invariants: list[str] = field(default_factory=list)
    violations: list[Violation] = field(default_factory=list)
