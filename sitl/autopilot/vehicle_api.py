"""The contract between the MAVLink services and the autopilot: what the services ask and what they read.

The services never reach into the autopilot. They call the four methods of ``VehicleApi`` and nothing else:
- ``command(request, now_s)`` with one of the request dataclasses below, answered by a ``CommandOutcome`` whose
  result becomes the COMMAND_ACK (or MISSION_ACK) and whose reason becomes a STATUSTEXT when refused;
- ``snapshot()`` for everything telemetry reports (one frozen ``VehicleSnapshot``, sim-time stamped);
- ``mission_items()`` for mission download;
- ``set_offboard_setpoint(setpoint, now_s)`` for every accepted offboard setpoint.

Conventions: SI units with the unit in the name; NED local frame anchored at ``local_origin`` and converted to and
from geodetic coordinates by sitl/dynamics/geodesy.py, the project's single definition; body frame FRD;
quaternions (w, x, y, z) rotating body vectors into NED; NaN means "not set / unknown" for a float, None for a
missing group. Requests must be idempotent: a client retries a command whose ACK it missed, and a retried arm while
armed must be ACCEPTED (pymavlink retries look like new commands; only MAVSDK marks retries).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum, IntEnum
from typing import TYPE_CHECKING, Protocol, TypeAlias

from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot.px4_modes import Px4Mode
from sitl.dynamics.plant import GeoPoint

if TYPE_CHECKING:  # the setpoint types only: the cascade's module loads the compiled kernels, which a parameter check
    # (sitl/drone/param_table.py) or a ground station must not pay for
    from sitl.control.cascade import AttitudeSetpoint, TrajectorySetpoint

NAN = math.nan
NAN3: tuple[float, float, float] = (NAN, NAN, NAN)
Vec3: TypeAlias = tuple[float, float, float]
QuatWxyz: TypeAlias = tuple[float, float, float, float]


# ---- outcomes ----------------------------------------------------------------------------------------------
class CommandResult(IntEnum):
    """The autopilot's answer; values are MAV_RESULT so they go on the wire unchanged."""

    ACCEPTED = mavlink.MAV_RESULT_ACCEPTED
    TEMPORARILY_REJECTED = mavlink.MAV_RESULT_TEMPORARILY_REJECTED  # PX4's answer to a refused mode change
    DENIED = mavlink.MAV_RESULT_DENIED
    UNSUPPORTED = mavlink.MAV_RESULT_UNSUPPORTED
    FAILED = mavlink.MAV_RESULT_FAILED


@dataclass(frozen=True, slots=True)
class CommandOutcome:
    """Result plus a human-readable reason (sent as STATUSTEXT when the request is refused)."""

    result: CommandResult
    reason: str = ""

    @property
    def ok(self) -> bool:
        return self.result is CommandResult.ACCEPTED

    @classmethod
    def accepted(cls) -> CommandOutcome:
        return cls(CommandResult.ACCEPTED)

    @classmethod
    def denied(cls, reason: str) -> CommandOutcome:
        return cls(CommandResult.DENIED, reason)

    @classmethod
    def temporarily_rejected(cls, reason: str) -> CommandOutcome:
        return cls(CommandResult.TEMPORARILY_REJECTED, reason)


# ---- mission items -----------------------------------------------------------------------------------------
GLOBAL_FRAMES = frozenset(
    {
        mavlink.MAV_FRAME_GLOBAL,
        mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
        mavlink.MAV_FRAME_GLOBAL_INT,
        mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT,
        mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
    }
)
RELATIVE_ALT_FRAMES = frozenset({mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT})


class MissionType(IntEnum):
    MISSION = mavlink.MAV_MISSION_TYPE_MISSION
    FENCE = mavlink.MAV_MISSION_TYPE_FENCE
    RALLY = mavlink.MAV_MISSION_TYPE_RALLY


@dataclass(frozen=True, slots=True, kw_only=True)
class MissionItem:
    """One item exactly as MISSION_ITEM_INT carries it, so a download returns what was uploaded.

    ``x``/``y`` are latitude/longitude in degE7 for global frames (MAV_FRAME_GLOBAL* / *_INT), metres * 1e4 for
    local frames and the raw integer param5/param6 for MAV_FRAME_MISSION. ``z`` is the altitude in metres (AMSL for
    GLOBAL, above home for *RELATIVE_ALT*) or param7.
    """

    seq: int
    frame: int
    command: int  # MAV_CMD
    current: bool = False
    autocontinue: bool = True
    param1: float = NAN
    param2: float = NAN
    param3: float = NAN
    param4: float = NAN
    x: int = 0
    y: int = 0
    z: float = NAN
    mission_type: MissionType = MissionType.MISSION

    @property
    def is_global(self) -> bool:
        return self.frame in GLOBAL_FRAMES

    @property
    def lat_deg(self) -> float:
        return self.x * 1e-7 if self.is_global else NAN

    @property
    def lon_deg(self) -> float:
        return self.y * 1e-7 if self.is_global else NAN

    @property
    def alt_is_relative_to_home(self) -> bool:
        return self.frame in RELATIVE_ALT_FRAMES


# ---- offboard setpoints: the controller's own types (sitl/control/cascade.py), decoded by the services ---------
# ``TrajectorySetpoint``: absolute local NED, NaN components "not controlled" (type_mask); whatever frame the client
# used, the services convert it first, and at least one of position, velocity, acceleration is set.
# ``AttitudeSetpoint``: an attitude or body rates, and a collective thrust (MAVLink's normalised one times the
# snapshot's ``collective_max_n``).


# ---- requests ----------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True, kw_only=True)
class Arm:
    force: bool = False  # param2 = 21196: skip pre-arm checks


@dataclass(frozen=True, slots=True, kw_only=True)
class Disarm:
    force: bool = False  # param2 = 21196: disarm even in the air (this is MAVSDK's kill())


@dataclass(frozen=True, slots=True, kw_only=True)
class Kill:
    """MAV_CMD_DO_FLIGHTTERMINATION: stop the motors now, wherever the vehicle is."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Takeoff:
    """Climb and hold. PX4: NaN altitude -> MIS_TAKEOFF_ALT above home; a finite AMSL altitude lower than home +
    MIS_TAKEOFF_ALT is raised to it (pymavlink scripts often send 0 or a relative altitude here)."""

    alt_amsl_m: float = NAN
    lat_deg: float = NAN  # NaN: take off where the vehicle is
    lon_deg: float = NAN
    yaw_rad: float = NAN


@dataclass(frozen=True, slots=True, kw_only=True)
class Land:
    lat_deg: float = NAN  # NaN: land here
    lon_deg: float = NAN
    yaw_rad: float = NAN


@dataclass(frozen=True, slots=True, kw_only=True)
class ReturnToLaunch:
    pass


@dataclass(frozen=True, slots=True, kw_only=True)
class SetMode:
    mode: Px4Mode


@dataclass(frozen=True, slots=True, kw_only=True)
class Reposition:
    """DO_REPOSITION (MAVSDK goto_location): fly to a point and hold there. NaN lat/lon/alt keep the current one."""

    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    yaw_rad: float = NAN  # NaN: keep heading
    ground_speed_mps: float = NAN  # NaN: default speed
    change_mode: bool = True  # MAV_DO_REPOSITION_FLAGS_CHANGE_MODE: switch to Hold if not in it


class OrbitYaw(IntEnum):
    """MAVLink's ORBIT_YAW_BEHAVIOUR: where the vehicle faces while it orbits (MAV_CMD_DO_ORBIT param3)."""

    FRONT_TO_CENTRE = mavlink.ORBIT_YAW_BEHAVIOUR_HOLD_FRONT_TO_CIRCLE_CENTER  # PX4's default
    INITIAL_HEADING = mavlink.ORBIT_YAW_BEHAVIOUR_HOLD_INITIAL_HEADING  # the heading when the command came
    UNCONTROLLED = mavlink.ORBIT_YAW_BEHAVIOUR_UNCONTROLLED  # no heading control: the yaw rate is held at zero
    TANGENT = mavlink.ORBIT_YAW_BEHAVIOUR_HOLD_FRONT_TANGENT_TO_CIRCLE  # nose along the direction of flight
    RC_CONTROLLED = mavlink.ORBIT_YAW_BEHAVIOUR_RC_CONTROLLED  # the yaw stick's; without RC the heading is held


@dataclass(frozen=True, slots=True, kw_only=True)
class Orbit:
    """MAV_CMD_DO_ORBIT (MAVSDK ``action.do_orbit``): circle a centre at a radius and tangential speed, in PX4's
    Orbit mode. NaN means "not given": the orbit flown now keeps its value, a new orbit takes PX4's default (radius
    1 m, 1 m/s clockwise, centre and altitude where the vehicle is)."""

    radius_m: float = NAN  # its sign is the direction: > 0 clockwise seen from above, < 0 counter-clockwise
    velocity_mps: float = NAN  # tangential speed; negative reverses the direction the radius gives
    yaw: OrbitYaw | None = None  # None: unchanged (ORBIT_YAW_BEHAVIOUR_UNCHANGED, or param3 not given)
    lat_deg: float = NAN  # the centre; NaN: the current centre, or where the vehicle is
    lon_deg: float = NAN
    alt_amsl_m: float = NAN  # the circle's altitude; NaN: the current one


class SpeedKind(Enum):
    HORIZONTAL = "horizontal"  # DO_CHANGE_SPEED types 0 (airspeed) and 1 (ground speed) on a multicopter
    CLIMB = "climb"
    DESCENT = "descent"


@dataclass(frozen=True, slots=True, kw_only=True)
class ChangeSpeed:
    kind: SpeedKind
    speed_mps: float  # NaN: back to the default (param2 = -2)


@dataclass(frozen=True, slots=True, kw_only=True)
class SetHome:
    use_current: bool
    lat_deg: float = NAN
    lon_deg: float = NAN
    alt_amsl_m: float = NAN


@dataclass(frozen=True, slots=True, kw_only=True)
class MissionStart:
    """MAV_CMD_MISSION_START (pymavlink's way): switch to AUTO.MISSION (PX4 also arms if needed)."""

    first_seq: int | None = None  # None: continue from the current item
    last_seq: int | None = None  # None: to the end


@dataclass(frozen=True, slots=True, kw_only=True)
class SetMissionCurrent:
    seq: int
    reset: bool = False  # MAV_CMD_DO_SET_MISSION_CURRENT param2 = 1: also reset jump counters


@dataclass(frozen=True, slots=True, kw_only=True)
class SetMission:
    """Replace the whole mission (an empty tuple clears it). Items are validated by the protocol already."""

    items: tuple[MissionItem, ...]


@dataclass(frozen=True, slots=True, kw_only=True)
class SetFence:
    """Replace the whole geofence (mission type 1; an empty tuple clears it). Items are validated already."""

    items: tuple[MissionItem, ...]


@dataclass(frozen=True, slots=True, kw_only=True)
class InjectFailure:
    """MAV_CMD_INJECT_FAILURE: param1 FAILURE_UNIT, param2 FAILURE_TYPE, param3 instance (0 all, else 1-based);
    param4, this simulator's own, how long a MAVLink signal fault lasts (PX4 ignores it; see sitl/faults/failures.py).

    The vehicle refuses it (DENIED) unless SYS_FAILURE_EN = 1, as PX4 does; an accepted outcome's ``reason`` is the
    text announcing the failure, which the command service sends as a STATUSTEXT."""

    unit: int | None  # None: the parameter was not a usable integer
    failure_type: int | None
    instance: int | None
    duration_s: float = math.inf  # param4 (unset: for good)


VehicleRequest: TypeAlias = (
    Arm
    | Disarm
    | Kill
    | Takeoff
    | Land
    | ReturnToLaunch
    | SetMode
    | Reposition
    | ChangeSpeed
    | SetHome
    | MissionStart
    | SetMissionCurrent
    | SetMission
    | SetFence
    | InjectFailure
    | Orbit
)


# ---- snapshot ----------------------------------------------------------------------------------------------
class LandedState(IntEnum):
    """MAV_LANDED_STATE."""

    UNDEFINED = mavlink.MAV_LANDED_STATE_UNDEFINED
    ON_GROUND = mavlink.MAV_LANDED_STATE_ON_GROUND
    IN_AIR = mavlink.MAV_LANDED_STATE_IN_AIR
    TAKEOFF = mavlink.MAV_LANDED_STATE_TAKEOFF
    LANDING = mavlink.MAV_LANDED_STATE_LANDING


class MissionState(IntEnum):
    """MISSION_STATE (MISSION_CURRENT.mission_state); MAVSDK's is_mission_finished() waits for COMPLETE."""

    UNKNOWN = mavlink.MISSION_STATE_UNKNOWN
    NO_MISSION = mavlink.MISSION_STATE_NO_MISSION
    NOT_STARTED = mavlink.MISSION_STATE_NOT_STARTED
    ACTIVE = mavlink.MISSION_STATE_ACTIVE
    PAUSED = mavlink.MISSION_STATE_PAUSED
    COMPLETE = mavlink.MISSION_STATE_COMPLETE


class GpsFixType(IntEnum):
    NO_GPS = mavlink.GPS_FIX_TYPE_NO_GPS
    NO_FIX = mavlink.GPS_FIX_TYPE_NO_FIX
    FIX_2D = mavlink.GPS_FIX_TYPE_2D_FIX
    FIX_3D = mavlink.GPS_FIX_TYPE_3D_FIX
    DGPS = mavlink.GPS_FIX_TYPE_DGPS
    RTK_FLOAT = mavlink.GPS_FIX_TYPE_RTK_FLOAT
    RTK_FIXED = mavlink.GPS_FIX_TYPE_RTK_FIXED


# SYS_STATUS sensor bits a simulated PX4 multicopter reports as present/enabled/healthy. MAVSDK's health() reads
# gyro, accel, mag and GPS from these (and "armable" from MAV_SYS_STATUS_PREARM_CHECK, added from prearm_ok).
SIM_SENSOR_BITS = (
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mavlink.MAV_SYS_STATUS_SENSOR_GPS
    | mavlink.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | mavlink.MAV_SYS_STATUS_SENSOR_YAW_POSITION
    | mavlink.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | mavlink.MAV_SYS_STATUS_AHRS
    | mavlink.MAV_SYS_STATUS_SENSOR_BATTERY
)


@dataclass(frozen=True, slots=True, kw_only=True)
class SensorHealth:
    """SYS_STATUS bitmasks (MAV_SYS_STATUS_SENSOR); PREARM_CHECK is added by the services from ``prearm_ok``."""

    present: int = SIM_SENSOR_BITS
    enabled: int = SIM_SENSOR_BITS
    healthy: int = SIM_SENSOR_BITS


@dataclass(frozen=True, slots=True, kw_only=True)
class GpsStatus:
    """What the GPS receiver reports (GPS_RAW_INT), not the fused estimate."""

    fix_type: GpsFixType
    satellites_visible: int  # 255: unknown
    eph_m: float  # horizontal dilution / accuracy as PX4 reports it; NaN unknown
    epv_m: float
    position: GeoPoint | None
    ground_speed_mps: float = NAN
    course_over_ground_rad: float = NAN
    h_acc_m: float = NAN
    v_acc_m: float = NAN


@dataclass(frozen=True, slots=True, kw_only=True)
class BatteryStatus:
    voltage_v: float  # NaN unknown
    current_a: float  # NaN unknown
    remaining: float  # 0..1, NaN unknown
    consumed_mah: float  # NaN unknown
    cell_count: int = 0  # 0: unknown, report the pack voltage as one value
    temperature_c: float = NAN
    # MAV_BATTERY_CHARGE_STATE: PX4 reports LOW/CRITICAL/EMERGENCY once the charge is below BAT_LOW_THR/_CRIT_/_EMERGEN_
    charge_state: int = mavlink.MAV_BATTERY_CHARGE_STATE_OK


@dataclass(frozen=True, slots=True, kw_only=True)
class HomePosition:
    position: GeoPoint
    pos_ned_m: Vec3  # home in the local frame
    yaw_rad: float = 0.0


@dataclass(frozen=True, slots=True, kw_only=True)
class MissionProgress:
    current_seq: int = 0
    total: int = 0
    state: MissionState = MissionState.NO_MISSION
    reached_seq: int = -1  # last MISSION_ITEM_REACHED, -1 none yet


@dataclass(frozen=True, slots=True, kw_only=True)
class OrbitStatus:
    """The orbit being flown, as ORBIT_EXECUTION_STATUS reports it."""

    radius_m: float  # signed as MAV_CMD_DO_ORBIT's: > 0 clockwise seen from above
    centre: GeoPoint  # its altitude is the circle's (AMSL)
    yaw: OrbitYaw


@dataclass(frozen=True, slots=True, kw_only=True)
class VehicleSnapshot:
    """Everything telemetry needs at one simulation instant. Cheap to build; the vehicle may cache it per step."""

    time_boot_us: int  # simulation time since boot; every time_boot_ms/time_usec on the wire comes from here
    armed: bool
    mode: Px4Mode
    landed_state: LandedState
    failsafe: bool  # HEARTBEAT system_status CRITICAL
    prearm_ok: bool  # SYS_STATUS PREARM_CHECK health bit ("armable" in MAVSDK)
    # Estimate, local frame (NaN when the estimator has no valid local position/velocity).
    pos_ned_m: Vec3
    vel_ned_mps: Vec3
    # Estimate, global (None when there is no global position yet).
    global_position: GeoPoint | None
    # Attitude estimate; NaN quaternion when attitude is not valid.
    att_q_wxyz: QuatWxyz
    rates_frd_radps: Vec3
    gps: GpsStatus
    battery: BatteryStatus
    home: HomePosition | None  # None until home is set (PX4 sets it on arming, or at the first valid position)
    local_origin: GeoPoint | None  # geodetic point of NED (0, 0, 0); needed for global offboard setpoints
    mission: MissionProgress = MissionProgress()  # frozen: one instance serves every snapshot
    sensors: SensorHealth = SensorHealth()
    flight_terminated: bool = False
    throttle: float = NAN  # 0..1 collective, for VFR_HUD
    collective_max_n: float = NAN  # the collective thrust the motors can give: MAVLink's normalised thrust times this
    time_unix_usec: int = 0  # 0: unknown (SYSTEM_TIME is only sent when known)
    cpu_load: float = NAN  # 0..1, SYS_STATUS load
    orbit: OrbitStatus | None = None  # set while the vehicle flies PX4's Orbit mode

    @property
    def time_boot_ms(self) -> int:
        return self.time_boot_us // 1000

    @property
    def euler_rad(self) -> Vec3:
        """(roll, pitch, yaw), ZYX, from the attitude quaternion; NaN when the quaternion is not finite."""
        w, x, y, z = self.att_q_wxyz
        if not all(math.isfinite(c) for c in (w, x, y, z)):
            return NAN3
        roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
        pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
        yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        return roll, pitch, yaw

    @property
    def alt_above_home_m(self) -> float:
        """GLOBAL_POSITION_INT.relative_alt as PX4 computes it: local altitude above home (above origin without)."""
        down = self.pos_ned_m[2]
        home_down = self.home.pos_ned_m[2] if self.home is not None else 0.0
        return home_down - down


class VehicleApi(Protocol):
    """What the MAVLink services need from the autopilot. All calls are synchronous and must not block."""

    def snapshot(self) -> VehicleSnapshot:
        """The current state for telemetry (called on every poll of every link; cache it per physics step)."""
        ...

    def command(self, request: VehicleRequest, now_s: float) -> CommandOutcome:
        """Carry out one request now. Must be idempotent (see the module docstring)."""
        ...

    def mission_items(self) -> Sequence[MissionItem]:
        """The stored mission (type 0), in order, as last accepted by ``command(SetMission(...))``."""
        ...

    def set_offboard_setpoint(self, setpoint: TrajectorySetpoint | AttitudeSetpoint, now_s: float) -> None:
        """A valid offboard setpoint arrived at ``now_s`` (the vehicle tracks COM_OF_LOSS_T from these times)."""
        ...

    def fence_items(self) -> Sequence[MissionItem]:
        """The stored geofence (mission type 1), in order, as last accepted by ``command(SetFence(...))``."""
        ...

    def note_gcs_heartbeat(self, now_s: float) -> None:
        """A HEARTBEAT from a ground station (MAV_TYPE_GCS) arrived at ``now_s`` (datalink-loss failsafe input)."""
        ...

    def mavlink_silent_until_s(self) -> float:
        """Until when (simulated seconds) an injected failure has cut the MAVLink signal: every link stops sending
        and receiving until then; -inf when no such failure is in force, inf when it is for good."""
        ...
