"""The faults the ground station can inject, by the names the CLI and mission files use (pure: no IO).

On the wire a fault is PX4's MAV_CMD_INJECT_FAILURE (420): param1 = FAILURE_UNIT, param2 = FAILURE_TYPE, param3 =
instance (0 = all, else 1-based). A drone honours it only with SYS_FAILURE_EN = 1, as PX4 does; the ground station
sets that parameter first, as a simulator convenience (on hardware nobody should). Battery levels are chosen by
SYS_FAIL_BAT_LVL (1 low, 2 critical, 3 emergency), set before the injection.

A crash of the drone process is no MAVLink fault: the supervisor SIGKILLs the process by its PID (``crash``).
"""

from __future__ import annotations

from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink

# MAVLink's FAILURE_UNIT and FAILURE_TYPE values, by short names for the table below
_GPS, _BATTERY = mavlink.FAILURE_UNIT_SENSOR_GPS, mavlink.FAILURE_UNIT_SYSTEM_BATTERY
_MOTOR, _LINK = mavlink.FAILURE_UNIT_SYSTEM_MOTOR, mavlink.FAILURE_UNIT_SYSTEM_MAVLINK_SIGNAL
_OK, _OFF, _WRONG = mavlink.FAILURE_TYPE_OK, mavlink.FAILURE_TYPE_OFF, mavlink.FAILURE_TYPE_WRONG
ENABLE_PARAM = "SYS_FAILURE_EN"
BATTERY_LEVEL_PARAM = "SYS_FAIL_BAT_LVL"
CRASH = "crash"
MAX_LINK_FAULT_S = 86_400.0  # a link fault lasts at most a day of simulated time (longer: leave the duration out)


@dataclass(frozen=True, slots=True, kw_only=True)
class FaultKind:
    name: str
    unit: int  # FAILURE_UNIT
    failure_type: int  # FAILURE_TYPE
    battery_level: int | None = None  # SYS_FAIL_BAT_LVL set before injecting
    help: str = ""


FAULTS: dict[str, FaultKind] = {
    f.name: f
    for f in (
        FaultKind(name="motor", unit=_MOTOR, failure_type=_OFF,
                  help="one rotor stops (--motor M, 1-based; default 1)"),
        FaultKind(name="gps", unit=_GPS, failure_type=_OFF,
                  help="the GPS receiver stops reporting"),
        FaultKind(name="gps-glitch", unit=_GPS, failure_type=_WRONG,
                  help="the reported GPS position jumps"),
        FaultKind(name="battery-low", unit=_BATTERY, failure_type=_WRONG,
                  battery_level=1, help="the battery reads low"),
        FaultKind(name="battery-critical", unit=_BATTERY, failure_type=_WRONG,
                  battery_level=2, help="the battery reads critical"),
        FaultKind(name="battery-emergency", unit=_BATTERY, failure_type=_WRONG,
                  battery_level=3, help="the battery reads at its emergency level"),
        FaultKind(name="battery-off", unit=_BATTERY, failure_type=_OFF,
                  help="the pack reads empty"),
        FaultKind(name="link", unit=_LINK, failure_type=_OFF,
                  help="both MAVLink links go silent, for good or for a time (--for S); the drone flies on"),
        FaultKind(name="motor-ok", unit=_MOTOR, failure_type=_OK,
                  help="clears a motor fault"),
        FaultKind(name="gps-ok", unit=_GPS, failure_type=_OK,
                  help="clears a GPS fault"),
        FaultKind(name="battery-ok", unit=_BATTERY, failure_type=_OK,
                  help="clears a battery fault"),
    )
}  # fmt: skip
FAULT_NAMES = (*FAULTS, CRASH)
_RESULTS = {
    mavlink.MAV_RESULT_ACCEPTED: "accepted",
    mavlink.MAV_RESULT_TEMPORARILY_REJECTED: "temporarily rejected",
    mavlink.MAV_RESULT_DENIED: "denied",
    mavlink.MAV_RESULT_UNSUPPORTED: "unsupported",
    mavlink.MAV_RESULT_FAILED: "failed",
}


class FaultError(ValueError):
    """A fault that cannot be injected as asked (one line naming the problem)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class FaultRequest:
    """One injection: the fault, for a motor fault which rotor (1-based; 0 = all), for a link fault how long."""

    kind: str  # a key of FAULTS, or CRASH
    motor: int = 1
    for_s: float | None = None  # link: silent this long (INJECT_FAILURE param4, the simulator's own), else for good

    @property
    def instance(self) -> int:
        """INJECT_FAILURE param3: the rotor for a motor fault, else 0 (every instance of the unit)."""
        return self.motor if self.kind in FAULTS and FAULTS[self.kind].unit == _MOTOR else 0

    @property
    def duration_param(self) -> float:
        """INJECT_FAILURE param4: a link fault's duration in seconds, 0 (PX4's value: unused) for good."""
        return self.for_s if self.for_s is not None else 0.0

    def describe(self) -> str:
        if self.kind == "motor":
            return f"motor {self.motor} off"
        return f"{self.kind} for {self.for_s:g} s" if self.for_s is not None else self.kind


def fault_request(kind: object, motor: object = None, for_s: object = None) -> FaultRequest:
    """Check a fault name (and rotor number, or a link fault's duration) from the CLI or a mission file; FaultError
    says what is wrong."""
    if not isinstance(kind, str) or kind not in FAULT_NAMES:
        raise FaultError(f"unknown fault {kind!r} (faults: {', '.join(FAULT_NAMES)})")
    if for_s is not None:
        if kind != "link":
            raise FaultError(f"a duration applies only to the link fault, not to {kind!r}")
        if motor is not None:
            raise FaultError(f"a motor number applies only to the motor fault, not to {kind!r}")
        if isinstance(for_s, bool) or not isinstance(for_s, int | float) or not 0 < for_s <= MAX_LINK_FAULT_S:
            raise FaultError(f"a link fault's duration must be a number of seconds in (0, {MAX_LINK_FAULT_S:g}], "
                             f"got {for_s!r}")  # fmt: skip
        return FaultRequest(kind=kind, for_s=float(for_s))
    if motor is None:
        return FaultRequest(kind=kind)
    if kind not in ("motor", "motor-ok"):
        raise FaultError(f"a motor number applies only to the motor fault, not to {kind!r}")
    if isinstance(motor, bool) or not isinstance(motor, int) or not 0 <= motor <= 8:
        raise FaultError(f"motor must be a whole number in 0..8 (0 = all), got {motor!r}")
    return FaultRequest(kind=kind, motor=motor)


def result_text(result: int | None) -> str:
    """A COMMAND_ACK result in words (None: no answer)."""
    if result is None:
        return "no answer"
    return _RESULTS.get(result, f"result {result}")
