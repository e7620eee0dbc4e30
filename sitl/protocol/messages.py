"""Message builders: a ``VehicleSnapshot`` in, one MAVLink message out, with MAVLink's field units.

Pure functions, one per message, so the telemetry scheduler, REQUEST_MESSAGE and the mission server all send the same
bytes. Units follow common.xml: lat/lon in degE7, altitudes in mm, GLOBAL_POSITION_INT speeds in cm/s, headings in
centidegrees, battery in mV/cA. Every value is clamped to its field so a diverging simulation can never make a
message unpackable. A builder returns None when the vehicle has nothing valid to report (PX4 then stays silent too).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final

from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot.px4_modes import Px4Mode
from sitl.autopilot.vehicle_api import MissionState, VehicleSnapshot
from sitl.protocol.core import (
    INT16_MAX,
    INT32_MAX,
    UINT16_MAX,
    Identity,
    MAVLinkMessage,
    f32,
    to_int,
)
from sitl.protocol.modes import base_mode, system_status

INT32_MIN: Final = -INT32_MAX - 1

# What AUTOPILOT_VERSION advertises. MISSION_INT is essential: without it MAVSDK refuses every mission transfer.
CAPABILITIES: Final = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_FLIGHT_TERMINATION
    | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
)


@dataclass(frozen=True, slots=True, kw_only=True)
class FirmwareVersion:
    """Reported as a PX4 release (MAVSDK's Info plugin decodes major/minor/patch from flight_sw_version)."""

    major: int = 1
    minor: int = 15
    patch: int = 0
    release_type: int = mavlink.FIRMWARE_VERSION_TYPE_OFFICIAL

    @property
    def packed(self) -> int:
        return (self.major & 0xFF) << 24 | (self.minor & 0xFF) << 16 | (self.patch & 0xFF) << 8 | self.release_type


FIRMWARE_VERSION = FirmwareVersion()
_UID_PREFIX: Final = 0x5357_524D_0000_0000  # "SWRM": a stable, per-sysid hardware uid for MAVSDK's Info plugin


def _deg_e7(deg: float) -> int:
    return to_int(deg * 1e7, INT32_MIN, INT32_MAX, 0)


def _mm(metres: float) -> int:
    return to_int(metres * 1000.0, INT32_MIN, INT32_MAX, 0)


def _cdeg_heading(yaw_rad: float) -> int:
    """Heading in centidegrees 0..35999; UINT16_MAX when unknown."""
    if not math.isfinite(yaw_rad):
        return UINT16_MAX
    return to_int(math.degrees(yaw_rad) % 360.0 * 100.0, 0, 35999, UINT16_MAX) % 36000


def _all_finite(values: tuple[float, ...]) -> bool:
    return all(math.isfinite(v) for v in values)


# ---- one builder per message -------------------------------------------------------------------------------
def heartbeat(snap: VehicleSnapshot, ident: Identity) -> MAVLinkMessage:
    return mavlink.MAVLink_heartbeat_message(
        ident.mav_type,
        ident.autopilot,
        base_mode(snap.mode, snap.armed),
        snap.mode.custom_mode,
        system_status(armed=snap.armed, failsafe=snap.failsafe, terminated=snap.flight_terminated),
        3,
    )


def sys_status(snap: VehicleSnapshot, ident: Identity) -> MAVLinkMessage:
    prearm = mavlink.MAV_SYS_STATUS_PREARM_CHECK
    sensors = snap.sensors
    battery = snap.battery
    healthy = sensors.healthy & ~prearm
    if snap.prearm_ok:
        healthy |= prearm
    return mavlink.MAVLink_sys_status_message(
        (sensors.present | prearm) & 0xFFFFFFFF,
        (sensors.enabled | prearm) & 0xFFFFFFFF,
        healthy & 0xFFFFFFFF,
        to_int(snap.cpu_load * 1000.0, 0, 1000, 0),
        to_int(battery.voltage_v * 1000.0, 0, UINT16_MAX - 1, UINT16_MAX),
        to_int(battery.current_a * 100.0, -1, INT16_MAX, -1),
        to_int(battery.remaining * 100.0, 0, 100, -1),
        0,
        0,
        0,
        0,
        0,
        0,
    )


def extended_sys_state(snap: VehicleSnapshot, ident: Identity) -> MAVLinkMessage:
    return mavlink.MAVLink_extended_sys_state_message(mavlink.MAV_VTOL_STATE_UNDEFINED, int(snap.landed_state))


def gps_raw_int(snap: VehicleSnapshot, ident: Identity) -> MAVLinkMessage:
    gps = snap.gps
    pos = gps.position
    has_pos = pos is not None and _all_finite((pos.lat_deg, pos.lon_deg, pos.alt_amsl_m))
    return mavlink.MAVLink_gps_raw_int_message(
        max(0, snap.time_boot_us),
        int(gps.fix_type),
        _deg_e7(pos.lat_deg) if has_pos and pos is not None else 0,
        _deg_e7(pos.lon_deg) if has_pos and pos is not None else 0,
        _mm(pos.alt_amsl_m) if has_pos and pos is not None else 0,
        to_int(gps.eph_m * 100.0, 0, UINT16_MAX - 1, UINT16_MAX),
        to_int(gps.epv_m * 100.0, 0, UINT16_MAX - 1, UINT16_MAX),
        to_int(gps.ground_speed_mps * 100.0, 0, UINT16_MAX - 1, UINT16_MAX),
        _cdeg_heading(gps.course_over_ground_rad),
        gps.satellites_visible if 0 <= gps.satellites_visible <= 255 else 255,
        0,
        to_int(gps.h_acc_m * 1000.0, 0, 0xFFFFFFFF, 0),
        to_int(gps.v_acc_m * 1000.0, 0, 0xFFFFFFFF, 0),
        0,
        0,
        0,
    )


def global_position_int(snap: VehicleSnapshot, ident: Identity) -> MAVLinkMessage | None:
    pos = snap.global_position
    if pos is None or not _all_finite((pos.lat_deg, pos.lon_deg, pos.alt_amsl_m)):
        return None
    vel = snap.vel_ned_mps
    return mavlink.MAVLink_global_position_int_message(
        snap.time_boot_ms & 0xFFFFFFFF,
        _deg_e7(pos.lat_deg),
        _deg_e7(pos.lon_deg),
        _mm(pos.alt_amsl_m),
        _mm(snap.alt_above_home_m),
        to_int(vel[0] * 100.0, -INT16_MAX - 1, INT16_MAX, 0),
        to_int(vel[1] * 100.0, -INT16_MAX - 1, INT16_MAX, 0),
        to_int(vel[2] * 100.0, -INT16_MAX - 1, INT16_MAX, 0),
        _cdeg_heading(snap.euler_rad[2]),
    )


def local_position_ned(snap: VehicleSnapshot, ident: Identity) -> MAVLinkMessage | None:
    if not _all_finite(snap.pos_ned_m):
        return None
    x, y, z = (f32(v) for v in snap.pos_ned_m)
    vx, vy, vz = (f32(v) for v in snap.vel_ned_mps)
    return mavlink.MAVLink_local_position_ned_message(snap.time_boot_ms & 0xFFFFFFFF, x, y, z, vx, vy, vz)


def attitude(snap: VehicleSnapshot, ident: Identity) -> MAVLinkMessage | None:
    roll, pitch, yaw = snap.euler_rad
    if not _all_finite((roll, pitch, yaw)):
        return None
    p, q, r = (f32(v) for v in snap.rates_frd_radps)
    return mavlink.MAVLink_attitude_message(snap.time_boot_ms & 0xFFFFFFFF, roll, pitch, yaw, p, q, r)


def attitude_quaternion(snap: VehicleSnapshot, ident: Identity) -> MAVLinkMessage | None:
    if not _all_finite(snap.att_q_wxyz):
        return None
    w, x, y, z = (f32(v) for v in snap.att_q_wxyz)
    p, q, r = (f32(v) for v in snap.rates_frd_radps)
    return mavlink.MAVLink_attitude_quaternion_message(
        snap.time_boot_ms & 0xFFFFFFFF, w, x, y, z, p, q, r, (0.0, 0.0, 0.0, 0.0)
    )


def vfr_hud(snap: VehicleSnapshot, ident: Identity) -> MAVLinkMessage | None:
    pos = snap.global_position
    vel = snap.vel_ned_mps
    ground_speed = math.hypot(vel[0], vel[1]) if _all_finite(vel) else math.nan
    heading = _cdeg_heading(snap.euler_rad[2])
    return mavlink.MAVLink_vfr_hud_message(
        f32(ground_speed),  # no airspeed sensor: PX4 SITL reports ground speed
        f32(ground_speed),
        heading // 100 if heading != UINT16_MAX else 0,
        to_int(snap.throttle * 100.0, 0, 100, 0),
        f32(pos.alt_amsl_m) if pos is not None else math.nan,
        f32(-vel[2]),
    )


def altitude(snap: VehicleSnapshot, ident: Identity) -> MAVLinkMessage | None:
    pos = snap.global_position
    if pos is None:
        return None
    return mavlink.MAVLink_altitude_message(
        max(0, snap.time_boot_us),
        f32(pos.alt_amsl_m),
        f32(pos.alt_amsl_m),
        f32(-snap.pos_ned_m[2]),
        f32(snap.alt_above_home_m),
        math.nan,
        math.nan,
    )


def battery_status(snap: VehicleSnapshot, ident: Identity) -> MAVLinkMessage:
    bat = snap.battery
    cells = [UINT16_MAX] * 10
    if math.isfinite(bat.voltage_v):
        # MAVSDK adds up the valid cell entries, so the pack voltage is split over the cells it is made of.
        n = bat.cell_count if 1 <= bat.cell_count <= 10 else 1
        total_mv = to_int(bat.voltage_v * 1000.0, 0, n * (UINT16_MAX - 1), 0)
        cells[:n] = [total_mv // n] * n
        cells[0] += total_mv - n * (total_mv // n)  # the rounding remainder, so the cells add up exactly
    return mavlink.MAVLink_battery_status_message(
        0,
        mavlink.MAV_BATTERY_FUNCTION_ALL,
        mavlink.MAV_BATTERY_TYPE_LIPO,
        to_int(bat.temperature_c * 100.0, -INT16_MAX, INT16_MAX - 1, INT16_MAX),
        cells,
        to_int(bat.current_a * 100.0, -1, INT16_MAX, -1),
        to_int(bat.consumed_mah, -1, INT32_MAX, -1),
        -1,
        to_int(bat.remaining * 100.0, 0, 100, -1),
        0,
        bat.charge_state if math.isfinite(bat.remaining) else mavlink.MAV_BATTERY_CHARGE_STATE_UNDEFINED,
        (0, 0, 0, 0),
        0,
        0,
    )


def home_position(snap: VehicleSnapshot, ident: Identity) -> MAVLinkMessage | None:
    home = snap.home
    if home is None or not _all_finite((home.position.lat_deg, home.position.lon_deg, home.position.alt_amsl_m)):
        return None
    yaw = home.yaw_rad if math.isfinite(home.yaw_rad) else 0.0
    x, y, z = (f32(v) if math.isfinite(v) else 0.0 for v in home.pos_ned_m)
    return mavlink.MAVLink_home_position_message(
        _deg_e7(home.position.lat_deg),
        _deg_e7(home.position.lon_deg),
        _mm(home.position.alt_amsl_m),
        x,
        y,
        z,
        (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)),
        0.0,
        0.0,
        0.0,
        max(0, snap.time_boot_us),
    )


def orbit_execution_status(snap: VehicleSnapshot, ident: Identity) -> MAVLinkMessage | None:
    """ORBIT_EXECUTION_STATUS while in Orbit, as PX4 streams it from its orbit_status topic: the signed radius (> 0
    clockwise), the centre in MAV_FRAME_GLOBAL (lat/lon degE7) and the circle's altitude AMSL. None otherwise."""
    orbit = snap.orbit
    if orbit is None:
        return None
    centre = orbit.centre
    return mavlink.MAVLink_orbit_execution_status_message(
        max(0, snap.time_boot_us),
        f32(orbit.radius_m),
        mavlink.MAV_FRAME_GLOBAL,
        _deg_e7(centre.lat_deg),
        _deg_e7(centre.lon_deg),
        f32(centre.alt_amsl_m),
    )


def mission_current(snap: VehicleSnapshot, ident: Identity, *, seq: int | None = None) -> MAVLinkMessage:
    """MISSION_CURRENT; ``seq`` overrides the snapshot's (the mission server answers MISSION_SET_CURRENT with it)."""
    progress = snap.mission
    current = progress.current_seq if seq is None else seq
    in_mission = snap.mode is Px4Mode.AUTO_MISSION
    state = progress.state
    # mission_mode: 1 executing mission items, 2 suspended in another mode, 0 unknown (no mission)
    mode_field = 0 if state is MissionState.NO_MISSION else 1 if in_mission else 2
    return mavlink.MAVLink_mission_current_message(
        max(0, min(UINT16_MAX, current)),
        max(0, min(UINT16_MAX - 1, progress.total)),
        int(state),
        mode_field,
    )


def mission_item_reached(snap: VehicleSnapshot, ident: Identity) -> MAVLinkMessage | None:
    seq = snap.mission.reached_seq
    if not 0 <= seq <= UINT16_MAX:
        return None
    return mavlink.MAVLink_mission_item_reached_message(seq)


def system_time(snap: VehicleSnapshot, ident: Identity) -> MAVLinkMessage | None:
    if snap.time_unix_usec <= 0:
        return None
    return mavlink.MAVLink_system_time_message(snap.time_unix_usec, snap.time_boot_ms & 0xFFFFFFFF)


def autopilot_version(snap: VehicleSnapshot, ident: Identity) -> MAVLinkMessage:
    return mavlink.MAVLink_autopilot_version_message(
        CAPABILITIES,
        FIRMWARE_VERSION.packed,
        0,
        0,
        0,
        [0] * 8,
        [0] * 8,
        [0] * 8,
        0,
        0,
        _UID_PREFIX | ident.sysid,
        [0] * 18,
    )


Builder = Callable[[VehicleSnapshot, Identity], MAVLinkMessage | None]

# Every message the vehicle can produce on request (REQUEST_MESSAGE) or as a stream (SET_MESSAGE_INTERVAL).
BUILDERS: Final[dict[int, Builder]] = {
    mavlink.MAVLINK_MSG_ID_HEARTBEAT: heartbeat,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: sys_status,
    mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: system_time,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: gps_raw_int,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: attitude,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: attitude_quaternion,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: local_position_ned,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: global_position_int,
    mavlink.MAVLINK_MSG_ID_MISSION_CURRENT: mission_current,
    mavlink.MAVLINK_MSG_ID_MISSION_ITEM_REACHED: mission_item_reached,
    mavlink.MAVLINK_MSG_ID_VFR_HUD: vfr_hud,
    mavlink.MAVLINK_MSG_ID_ALTITUDE: altitude,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: battery_status,
    mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: autopilot_version,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: home_position,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: extended_sys_state,
    mavlink.MAVLINK_MSG_ID_ORBIT_EXECUTION_STATUS: orbit_execution_status,
}


def command_ack(command: int, result: int, target_sysid: int, target_compid: int) -> MAVLinkMessage:
    """COMMAND_ACK addressed to whoever sent the command (MAVSDK matches on it)."""
    return mavlink.MAVLink_command_ack_message(command & 0xFFFF, result, 0, 0, target_sysid, target_compid)
