"""The ground station's picture of the swarm, built only from MAVLink telemetry (pure: messages and time in).

One ``DroneView`` per system id with what PX4 telemetry says: mode, armed, position, home, battery, landed state,
and when it was last heard. The supervisor uses it for readiness and liveness, the CLI prints it, the relay and the
formation engine read positions from it. Nothing here knows the drones are simulated.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from gcs.mavlink.modes import mode_name
from gcs.mavlink.statustext import StatusTextAssembler

# A drone is lost when nothing has been heard from it for this long. QGroundControl counts any message but RADIO_STATUS
# (a radio's own report says nothing of the vehicle behind it) as a sign of life and says "communication regained" when
# one arrives again; MAVSDK times out after 3 s without a heartbeat. Counting any message matters on a lossy link: at
# 10 % loss, three 1 Hz heartbeats in a row go missing about once in a thousand seconds, while a drone streaming
# telemetry at tens of messages a second is never silent for 3 s unless its link is really down.
LINK_LOST_S = 3.0


@dataclass(slots=True)
class DroneView:
    sysid: int
    first_heartbeat_s: float
    last_heard_s: float  # any message from its autopilot but RADIO_STATUS
    armed: bool = False
    mode: str = "UNKNOWN"
    autopilot: int = mavlink.MAV_AUTOPILOT_PX4  # HEARTBEAT.autopilot: whose modes ``mode`` is read with
    vehicle_type: int = mavlink.MAV_TYPE_QUADROTOR  # HEARTBEAT.type
    system_status: int = 0
    lat_deg: float = math.nan
    lon_deg: float = math.nan
    alt_amsl_m: float = math.nan
    relative_alt_m: float = math.nan
    vel_ned_mps: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    heading_deg: float = math.nan  # GLOBAL_POSITION_INT.hdg: 0..360 from north, NaN unknown
    local_ned_m: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    home: tuple[float, float, float] | None = None  # lat, lon, alt AMSL
    home_local_ned_m: tuple[float, float, float] | None = None  # home in the drone's own local frame
    battery_remaining: float = math.nan  # 0..1
    battery_voltage_v: float = math.nan
    landed_state: int = 0  # MAV_LANDED_STATE
    prearm_ok: bool = False
    texts: list[tuple[float, int, str]] = field(default_factory=list)  # (time, severity, text), newest last

    def link_age_s(self, now_s: float) -> float:
        return now_s - self.last_heard_s

    def lost(self, now_s: float) -> bool:
        return self.link_age_s(now_s) > LINK_LOST_S

    def in_air(self) -> bool:
        """Whether it flies: its EXTENDED_SYS_STATE says so, or (a vehicle that sends none) it reports itself more
        than IN_AIR_ALT_M above its home."""
        if self.landed_state != mavlink.MAV_LANDED_STATE_UNDEFINED:
            return self.landed_state in _IN_AIR
        return math.isfinite(self.relative_alt_m) and self.relative_alt_m > IN_AIR_ALT_M


_IN_AIR = (mavlink.MAV_LANDED_STATE_IN_AIR, mavlink.MAV_LANDED_STATE_TAKEOFF, mavlink.MAV_LANDED_STATE_LANDING)
IN_AIR_ALT_M = 1.0  # a vehicle that does not say whether it flies: flying above this (GLOBAL_POSITION_INT)
PREARM_BIT = 0x10000000
HEADING_UNKNOWN = 0xFFFF  # GLOBAL_POSITION_INT.hdg: UINT16_MAX when not known  # MAV_SYS_STATUS_PREARM_CHECK


class Fleet:
    def __init__(self) -> None:
        self.drones: dict[int, DroneView] = {}
        self._texts = StatusTextAssembler()  # long texts arrive in chunks

    def handle(self, msg: Any, now_s: float) -> None:
        """Update from one message of any system (messages from other components than the autopilot are ignored)."""
        if msg.get_srcComponent() != 1:
            return
        sysid = msg.get_srcSystem()
        kind = msg.get_type()
        view = self.drones.get(sysid)
        if kind == "HEARTBEAT":
            if view is None:
                view = self.drones[sysid] = DroneView(sysid=sysid, first_heartbeat_s=now_s, last_heard_s=now_s)
            view.last_heard_s = now_s
            view.armed = bool(msg.base_mode & 128)
            view.autopilot, view.vehicle_type = msg.autopilot, msg.type
            view.mode = mode_name(msg.custom_mode, msg.autopilot, msg.type)
            view.system_status = msg.system_status
            return
        if view is None or kind == "RADIO_STATUS":
            return
        view.last_heard_s = now_s
        if kind == "GLOBAL_POSITION_INT":
            view.lat_deg, view.lon_deg = msg.lat * 1e-7, msg.lon * 1e-7
            view.alt_amsl_m, view.relative_alt_m = msg.alt * 1e-3, msg.relative_alt * 1e-3
            view.vel_ned_mps = (msg.vx * 0.01, msg.vy * 0.01, msg.vz * 0.01)
            view.heading_deg = msg.hdg * 0.01 if msg.hdg != HEADING_UNKNOWN else math.nan
        elif kind == "LOCAL_POSITION_NED":
            view.local_ned_m = (msg.x, msg.y, msg.z)
            view.vel_ned_mps = (msg.vx, msg.vy, msg.vz)
        elif kind == "HOME_POSITION":
            view.home = (msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3)
            view.home_local_ned_m = (msg.x, msg.y, msg.z)
        elif kind == "SYS_STATUS":
            view.battery_voltage_v = msg.voltage_battery * 1e-3 if msg.voltage_battery != 0xFFFF else math.nan
            view.battery_remaining = msg.battery_remaining / 100.0 if msg.battery_remaining >= 0 else math.nan
            view.prearm_ok = bool(msg.onboard_control_sensors_health & PREARM_BIT)
        elif kind == "EXTENDED_SYS_STATE":
            view.landed_state = msg.landed_state
        elif kind == "STATUSTEXT":
            text = self._texts.feed(sysid, msg)
            if text is not None:
                view.texts.append((now_s, msg.severity, text))
                del view.texts[:-50]

    def lost(self, now_s: float) -> list[int]:
        return sorted(s for s, v in self.drones.items() if v.lost(now_s))
