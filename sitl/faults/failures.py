"""Injected faults: which units of one drone have failed, decoded from MAV_CMD_INJECT_FAILURE as PX4 decodes it.

Pure, no IO. The MAVLink side (sitl/drone/sim_vehicle_api.py) turns an accepted ``FaultRequest`` into a change of
``FaultState`` and pushes the state into the parts that make each fault real: the plant (a failed rotor gives no
thrust), the GPS receiver (no fix, or a fix offset by ``GPS_GLITCH_OFFSET_NE_M``), the battery monitor (a reading
just below a failsafe threshold, or empty) and the MAVLink endpoint (silent for the rest of the process, or for
param4 seconds).

Faults the project supports (param1 unit, param2 type, param3 instance: 0 = all, else 1-based):

| unit | OFF (1) | WRONG (4) | OK (0) |
|---|---|---|---|
| 101 SYSTEM_MOTOR | rotor N (or all) gives no thrust | - | rotor works again |
| 4 SENSOR_GPS | the receiver reports no fix | every fix jumps by GPS_GLITCH_OFFSET_NE_M | normal fixes |
| 100 SYSTEM_BATTERY | the pack reads empty | charge reads just below the SYS_FAIL_BAT_LVL threshold | true reading |
| 105 SYSTEM_MAVLINK_SIGNAL | both links silent for good, or for param4 seconds | - | (cannot be heard) |

Everything else is UNSUPPORTED, as PX4 answers a failure its simulator cannot produce. param4 (a duration) is this
simulator's own: PX4 ignores it (it is reserved there), so a client that leaves it 0 gets PX4's behaviour. A radio
that comes back is what a link fault is mostly about in a swarm (the ground station must take the drone back), and a
drone whose links are off cannot hear the OK that would end the fault.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from enum import Enum, IntEnum
from typing import Final

from pymavlink.dialects.v20 import common as mavlink


class FailureUnit(IntEnum):
    """MAVLink FAILURE_UNIT values this simulator can inject."""

    SENSOR_GPS = mavlink.FAILURE_UNIT_SENSOR_GPS
    SYSTEM_BATTERY = mavlink.FAILURE_UNIT_SYSTEM_BATTERY
    SYSTEM_MOTOR = mavlink.FAILURE_UNIT_SYSTEM_MOTOR
    SYSTEM_MAVLINK_SIGNAL = mavlink.FAILURE_UNIT_SYSTEM_MAVLINK_SIGNAL


class FailureType(IntEnum):
    """MAVLink FAILURE_TYPE values this simulator can inject."""

    OK = mavlink.FAILURE_TYPE_OK
    OFF = mavlink.FAILURE_TYPE_OFF
    WRONG = mavlink.FAILURE_TYPE_WRONG


class GpsFault(Enum):
    NONE = "none"
    OFF = "off"  # the receiver reports NO_FIX
    GLITCH = "glitch"  # each fix is offset by GPS_GLITCH_OFFSET_NE_M


class BatteryFault(Enum):
    NONE = "none"
    LOW = "low"  # SYS_FAIL_BAT_LVL 1: just below BAT_LOW_THR
    CRITICAL = "critical"  # 2: just below BAT_CRIT_THR
    EMERGENCY = "emergency"  # 3: just below BAT_EMERGEN_THR
    EMPTY = "empty"  # OFF: the pack reads empty


# A GPS glitch moves every reported fix this far (north, east). 30 m is a typical multipath or spoofing jump; it is
# six times the estimator's innovation gate (GPS_POS_GATE_M in sitl/estimation/estimator.py), so the gate must reject
# it.
GPS_GLITCH_OFFSET_NE_M: Final = (30.0, 0.0)
# PX4 reports the charge this much below the chosen threshold, so that stage of the battery failsafe triggers.
BATTERY_TRIGGER_MARGIN: Final = 0.01
# SYS_FAIL_BAT_LVL -> (fault, threshold parameter), as PX4's battery_status warning levels 1/2/3.
BATTERY_LEVELS: Final[dict[int, tuple[BatteryFault, str]]] = {
    1: (BatteryFault.LOW, "BAT_LOW_THR"),
    2: (BatteryFault.CRITICAL, "BAT_CRIT_THR"),
    3: (BatteryFault.EMERGENCY, "BAT_EMERGEN_THR"),
}


@dataclass(frozen=True, slots=True, kw_only=True)
class FaultRequest:
    """One MAV_CMD_INJECT_FAILURE, decoded."""

    unit: FailureUnit
    type: FailureType
    instance: int  # 0 = all, else 1-based
    duration_s: float = math.inf  # param4 for a MAVLink signal fault: how long the links stay silent


@dataclass(frozen=True, slots=True, kw_only=True)
class FaultState:
    """The faults in force on one drone. Empty by default."""

    motors_off: frozenset[int] = frozenset()  # 0-based rotor indices that give no thrust
    gps: GpsFault = GpsFault.NONE
    battery: BatteryFault = BatteryFault.NONE
    battery_remaining: float | None = None  # the reading the monitor reports while a battery fault is in force
    link_off_until_s: float = -math.inf  # simulated time until which every MAVLink link is silent (inf: for good)


class FaultError(ValueError):
    """An injection that cannot be carried out; ``unsupported`` selects MAV_RESULT_UNSUPPORTED over DENIED."""

    def __init__(self, text: str, *, unsupported: bool) -> None:
        super().__init__(text)
        self.unsupported = unsupported


def decode_request(
    unit: int | None, failure_type: int | None, instance: int | None, duration_s: float = math.inf
) -> FaultRequest:
    """The request of INJECT_FAILURE params 1-3 (already rounded to ints) and param4 (a link fault's duration:
    anything but a finite positive number means for good); FaultError when it is not supported."""
    if unit is None or failure_type is None or instance is None or instance < 0:
        raise FaultError("Failure injection: parameters not valid", unsupported=False)
    if unit not in FailureUnit.__members__.values():
        raise FaultError(f"Failure unit {unit} not supported", unsupported=True)
    if failure_type not in FailureType.__members__.values():
        raise FaultError(f"Failure type {failure_type} not supported", unsupported=True)
    lasting = unit == FailureUnit.SYSTEM_MAVLINK_SIGNAL and math.isfinite(duration_s) and duration_s > 0
    request = FaultRequest(unit=FailureUnit(unit), type=FailureType(failure_type), instance=instance,
                           duration_s=duration_s if lasting else math.inf)  # fmt: skip
    if request.type is FailureType.WRONG and request.unit not in (FailureUnit.SENSOR_GPS, FailureUnit.SYSTEM_BATTERY):
        raise FaultError(f"Failure type wrong not supported for {_UNIT_NAMES[request.unit]}", unsupported=True)
    return request


# PX4's names in its announcements (the keys of its `failure` console command).
_UNIT_NAMES: Final = {
    FailureUnit.SENSOR_GPS: "gps",
    FailureUnit.SYSTEM_BATTERY: "battery",
    FailureUnit.SYSTEM_MOTOR: "motor",
    FailureUnit.SYSTEM_MAVLINK_SIGNAL: "mavlink_signal",
}


def announcement(request: FaultRequest) -> str:
    """The STATUSTEXT of an accepted injection, in PX4's words ("Injected: gps off, all instances")."""
    which = "all instances" if request.instance == 0 else f"instances {request.instance}"
    unit = _UNIT_NAMES[request.unit]
    if request.type is FailureType.OK:
        return f"Cleared: {unit}, {which}"
    # (PX4's words, plus how long: "Injected: mavlink_signal off 5 s, all instances" fits one 50-character text)
    lasting = f" {request.duration_s:g} s" if math.isfinite(request.duration_s) else ""
    return f"Injected: {unit} {request.type.name.lower()}{lasting}, {which}"


def apply_request(
    state: FaultState,
    request: FaultRequest,
    *,
    rotor_count: int,
    battery_level: int,
    battery_thresholds: dict[str, float],
    now_s: float = 0.0,
) -> tuple[FaultState, str]:
    """The fault state after ``request`` (at simulated time ``now_s``) and the STATUSTEXT that announces it;
    FaultError if it cannot be done.

    ``battery_level`` is SYS_FAIL_BAT_LVL; ``battery_thresholds`` holds the BAT_*_THR parameters by name (only
    those declared: a level whose threshold is missing is refused rather than guessed)."""
    unit, kind, instance = request.unit, request.type, request.instance
    text = announcement(request)
    if unit is FailureUnit.SYSTEM_MOTOR:
        if instance > rotor_count:
            raise FaultError(f"Motor {instance} does not exist ({rotor_count} rotors)", unsupported=False)
        chosen = frozenset(range(rotor_count)) if instance == 0 else frozenset({instance - 1})
        if kind is FailureType.OFF:
            return replace(state, motors_off=state.motors_off | chosen), text
        return replace(state, motors_off=state.motors_off - chosen), text
    if unit is FailureUnit.SENSOR_GPS:
        gps = {FailureType.OFF: GpsFault.OFF, FailureType.WRONG: GpsFault.GLITCH}.get(kind, GpsFault.NONE)
        return replace(state, gps=gps), text
    if unit is FailureUnit.SYSTEM_BATTERY:
        if kind is FailureType.OFF:
            return replace(state, battery=BatteryFault.EMPTY, battery_remaining=0.0), text
        if kind is FailureType.WRONG:
            fault, threshold_name = BATTERY_LEVELS.get(battery_level, BATTERY_LEVELS[2])
            threshold = battery_thresholds.get(threshold_name)
            if threshold is None:
                raise FaultError(f"Battery failure: {threshold_name} not available", unsupported=True)
            remaining = max(0.0, threshold - BATTERY_TRIGGER_MARGIN)
            return replace(state, battery=fault, battery_remaining=remaining), text
        return replace(state, battery=BatteryFault.NONE, battery_remaining=None), text
    # SYSTEM_MAVLINK_SIGNAL: OK changes nothing (a drone whose link is off never hears it)
    if kind is FailureType.OFF:
        return replace(state, link_off_until_s=max(state.link_off_until_s, now_s + request.duration_s)), text
    return state, text
