"""Battery model: a LiPo pack drained by the electrical power the motors draw.

Mechanical rotor power is torque times speed (k_q * omega^3 per rotor); electrical power divides that by a
motor+ESC efficiency and adds the avionics. Pack voltage follows a LiPo open-circuit curve minus the internal
resistance drop, so voltage sags under load and recovers at rest, as a real pack does. An F450 on a 3S 5000 mAh
pack hovers about 15 minutes with these figures, which matches the class.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

# Open-circuit voltage per LiPo cell against state of charge (typical curve, 0 %..100 %).
_SOC_POINTS = (0.0, 0.05, 0.10, 0.20, 0.30, 0.40, 0.50, 0.60, 0.70, 0.80, 0.90, 1.0)
_OCV_POINTS = (3.27, 3.61, 3.69, 3.73, 3.77, 3.79, 3.82, 3.87, 3.92, 3.97, 4.06, 4.20)


def _segment(remaining: float) -> int:
    """The curve's segment ``remaining`` lies on: the first point j with ``remaining <= _SOC_POINTS[j]`` (0 at or
    below the first point, len(_SOC_POINTS) above the last)."""
    for j in range(len(_SOC_POINTS)):
        if remaining <= _SOC_POINTS[j]:
            return j
    return len(_SOC_POINTS)


def _ocv_on(j: int, remaining: float) -> float:
    """The cell's voltage at ``remaining`` on segment ``j`` (``_segment``): linear between the points."""
    if j == 0:
        return _OCV_POINTS[0]
    if j == len(_SOC_POINTS):
        return _OCV_POINTS[-1]
    x0, x1, y0, y1 = _SOC_POINTS[j - 1], _SOC_POINTS[j], _OCV_POINTS[j - 1], _OCV_POINTS[j]
    return y0 + (y1 - y0) * (remaining - x0) / (x1 - x0)


def _cell_ocv_v(remaining: float) -> float:
    """Linear interpolation of the cell curve (plain floats)."""
    return _ocv_on(_segment(remaining), remaining)


@dataclass(frozen=True, slots=True, kw_only=True)
class BatteryConfig:
    cells: int = 3
    capacity_mah: float = 5000.0
    internal_resistance_ohm: float = 0.025
    efficiency: float = 0.70  # motor + ESC
    avionics_w: float = 3.0


@dataclass(frozen=True, slots=True, kw_only=True)
class BatteryState:
    voltage_v: float
    current_a: float
    consumed_mah: float
    remaining: float  # 0..1


def _current_for_power(power_w: float, ocv_v: float, resistance_ohm: float) -> float:
    """Current that delivers ``power_w`` at the terminal: P = (ocv - I R) I, the smaller root.

    Dividing by the open-circuit voltage instead understates the current by the sag (about 4 % at hover, 10 % at
    full throttle). Beyond the most the pack can deliver (ocv^2 / 4R) the current is that of the maximum-power point.
    """
    if resistance_ohm <= 0.0:
        return power_w / ocv_v
    discriminant = ocv_v * ocv_v - 4.0 * resistance_ohm * power_w
    return (ocv_v - math.sqrt(max(0.0, discriminant))) / (2.0 * resistance_ohm)


class Battery:
    def __init__(self, config: BatteryConfig, initial_remaining: float = 1.0) -> None:
        self.config = config
        self._consumed_mah = (1.0 - initial_remaining) * config.capacity_mah
        self._current_a = 0.0
        # The curve's segment of the last update: the charge moves along one for minutes, so each physics step
        # checks that it still lies on it instead of searching the curve from its first point.
        self._segment = _segment(self.true_remaining)
        # An injected battery failure (sitl/faults/failures.py) is a fault of the monitor, not of the cells: the pack
        # goes on powering the motors from its true charge while the monitor reports this charge (None: the true one).
        self.reported_remaining: float | None = None

    @property
    def true_remaining(self) -> float:
        """The cells' true state of charge, 0..1."""
        return max(0.0, 1.0 - self._consumed_mah / self.config.capacity_mah)

    @property
    def remaining(self) -> float:
        """State of charge the battery monitor reports, 0..1 (read by the autopilot's battery failsafe every step)."""
        reported = self.reported_remaining
        return self.true_remaining if reported is None else reported

    def state(self) -> BatteryState:
        """What the monitor reports (BATTERY_STATUS): under an injected fault, voltage matches the faked charge."""
        cfg = self.config
        remaining = self.remaining
        ocv = _cell_ocv_v(remaining) * cfg.cells
        return BatteryState(
            voltage_v=ocv - self._current_a * cfg.internal_resistance_ohm,
            current_a=self._current_a,
            consumed_mah=self._consumed_mah,
            remaining=remaining,
        )

    def update(self, mechanical_power_w: float, dt_s: float) -> None:
        cfg = self.config
        remaining = self.true_remaining
        j = self._segment
        if not ((j == 0 or _SOC_POINTS[j - 1] < remaining) and (j == len(_SOC_POINTS) or remaining <= _SOC_POINTS[j])):
            self._segment = j = _segment(remaining)
        ocv = _ocv_on(j, remaining) * cfg.cells
        power_w = mechanical_power_w / cfg.efficiency + cfg.avionics_w
        self._current_a = _current_for_power(power_w, max(ocv, 1.0), cfg.internal_resistance_ohm)
        self._consumed_mah += self._current_a * dt_s / 3.6
