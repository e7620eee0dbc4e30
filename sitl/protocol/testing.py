"""Test doubles for the MAVLink services: a scriptable vehicle, a snapshot factory and a wire that really packs.

Used by the unit tests of this package and meant for anyone testing code that drives the services (the IO shell,
the autopilot's adapter): ``FakeVehicle`` implements ``VehicleApi`` with a little state so sequences such as
"arm, then arm again" behave, and ``Wire`` sends a message through pymavlink's encoder and parser so tests see
exactly what a peer would (source ids, float32 rounding, MAVLink 2 truncation).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot.px4_modes import Px4Mode
from sitl.autopilot.vehicle_api import (
    Arm,
    BatteryStatus,
    CommandOutcome,
    CommandResult,
    Disarm,
    GpsFixType,
    GpsStatus,
    HomePosition,
    Kill,
    LandedState,
    MissionItem,
    MissionProgress,
    MissionState,
    SetFence,
    SetMission,
    SetMissionCurrent,
    SetMode,
    VehicleRequest,
    VehicleSnapshot,
)
from sitl.control.cascade import AttitudeSetpoint, TrajectorySetpoint
from sitl.dynamics.plant import DEFAULT_HOME
from sitl.protocol.core import Effect, MAVLinkMessage, Send

HOME = DEFAULT_HOME  # PX4 SITL's default home


def make_snapshot(**overrides: Any) -> VehicleSnapshot:
    """A plausible snapshot of a disarmed vehicle on the ground at PX4's default home; override any field."""
    base = VehicleSnapshot(
        time_boot_us=12_345_678,
        armed=False,
        mode=Px4Mode.AUTO_LOITER,
        landed_state=LandedState.ON_GROUND,
        failsafe=False,
        prearm_ok=True,
        pos_ned_m=(0.0, 0.0, 0.0),
        vel_ned_mps=(0.0, 0.0, 0.0),
        global_position=HOME,
        att_q_wxyz=(1.0, 0.0, 0.0, 0.0),
        rates_frd_radps=(0.0, 0.0, 0.0),
        collective_max_n=40.0,
        gps=GpsStatus(fix_type=GpsFixType.FIX_3D, satellites_visible=12, eph_m=0.8, epv_m=1.2, position=HOME),
        battery=BatteryStatus(voltage_v=12.4, current_a=0.5, remaining=0.95, consumed_mah=120.0, cell_count=3),
        home=HomePosition(position=HOME, pos_ned_m=(0.0, 0.0, 0.0), yaw_rad=0.0),
        local_origin=HOME,
        mission=MissionProgress(),
    )
    return dataclasses.replace(base, **overrides)


class FakeVehicle:
    """A ``VehicleApi`` that records requests and answers from a table (ACCEPTED unless told otherwise).

    With ``simulate`` on, accepted requests change the snapshot the obvious way (arm/disarm, mode, mission), which
    is what a retry or an extra-HEARTBEAT test needs.
    """

    def __init__(self, snapshot: VehicleSnapshot | None = None, *, simulate: bool = True) -> None:
        self.snap = snapshot or make_snapshot()
        self.simulate = simulate
        self.requests: list[VehicleRequest] = []
        self.request_times: list[float] = []
        self.outcomes: dict[type, CommandOutcome] = {}
        self.mission: list[MissionItem] = []
        self.setpoints: list[tuple[TrajectorySetpoint | AttitudeSetpoint, float]] = []
        self.fence: list[MissionItem] = []
        self.gcs_heartbeats: list[float] = []
        self.link_silent_until_s = -math.inf

    # ---- VehicleApi ------------------------------------------------------------------------------------------------
    def snapshot(self) -> VehicleSnapshot:
        return self.snap

    def command(self, request: VehicleRequest, now_s: float) -> CommandOutcome:
        self.requests.append(request)
        self.request_times.append(now_s)
        outcome = self.outcomes.get(type(request), CommandOutcome.accepted())
        if outcome.ok and self.simulate:
            self._apply(request)
        return outcome

    def mission_items(self) -> Sequence[MissionItem]:
        return tuple(self.mission)

    def set_offboard_setpoint(self, setpoint: TrajectorySetpoint | AttitudeSetpoint, now_s: float) -> None:
        self.setpoints.append((setpoint, now_s))

    def fence_items(self) -> Sequence[MissionItem]:
        return tuple(self.fence)

    def note_gcs_heartbeat(self, now_s: float) -> None:
        self.gcs_heartbeats.append(now_s)

    def mavlink_silent_until_s(self) -> float:
        return self.link_silent_until_s

    # ---- test helpers ----------------------------------------------------------------------------------------------
    def refuse(self, request_type: type, result: CommandResult, reason: str = "") -> None:
        self.outcomes[request_type] = CommandOutcome(result, reason)

    def update(self, **changes: Any) -> None:
        self.snap = dataclasses.replace(self.snap, **changes)

    def _apply(self, request: VehicleRequest) -> None:
        if isinstance(request, Arm):
            self.update(armed=True)
        elif isinstance(request, Disarm | Kill):
            self.update(armed=False)
        elif isinstance(request, SetMode):
            self.update(mode=request.mode)
        elif isinstance(request, SetMission):
            self.mission = list(request.items)
            state = MissionState.NOT_STARTED if request.items else MissionState.NO_MISSION
            self.update(mission=MissionProgress(current_seq=0, total=len(request.items), state=state))
        elif isinstance(request, SetFence):
            self.fence = list(request.items)
        elif isinstance(request, SetMissionCurrent):
            self.update(mission=dataclasses.replace(self.snap.mission, current_seq=request.seq))


class Wire:
    """One direction of a MAVLink link: pack with the sender's ids, parse like the receiver would."""

    def __init__(self, src_sysid: int = 255, src_compid: int = mavlink.MAV_COMP_ID_MISSIONPLANNER) -> None:
        self.encoder = mavlink.MAVLink(None, srcSystem=src_sysid, srcComponent=src_compid)
        self.decoder = mavlink.MAVLink(None)
        self.decoder.robust_parsing = True

    def __call__(self, msg: MAVLinkMessage) -> MAVLinkMessage:
        """The message as the other end decodes it."""
        data = msg.pack(self.encoder)
        self.encoder.seq = (self.encoder.seq + 1) % 256  # pack() alone does not advance the sequence
        decoded = self.decoder.parse_buffer(data)
        if not decoded or len(decoded) != 1:
            raise AssertionError(f"{msg.get_type()} did not survive the wire: {decoded!r}")
        return decoded[0]

    def carry(self, effects: Sequence[Effect]) -> list[MAVLinkMessage]:
        """Every message of a list of effects, through the wire."""
        return [self(e.msg) for e in effects if isinstance(e, Send)]


def of_type(messages: Sequence[MAVLinkMessage], name: str) -> list[MAVLinkMessage]:
    """The messages of one type (``"COMMAND_ACK"``...) in order."""
    return [m for m in messages if m.get_type() == name]


def isclose_tuple(a: Sequence[float], b: Sequence[float], tol: float = 1e-6) -> bool:
    """Element-wise closeness where NaN equals NaN."""
    return len(a) == len(b) and all(
        (math.isnan(x) and math.isnan(y)) or math.isclose(x, y, abs_tol=tol) for x, y in zip(a, b, strict=True)
    )
