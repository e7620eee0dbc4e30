"""Land detection: has the vehicle touched down (or left the ground)?

Modelled on PX4's multicopter land detector: on the ground the vehicle cannot descend although the controller
asks it to, so the collective thrust falls well below hover while the vertical speed stays near zero. Both must hold
for a dwell time (the ground-contact -> maybe-landed -> landed stages collapsed into one timer). The detector reads
only the estimate and the controller's own thrust output, never ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True, kw_only=True)
class LandDetectorConfig:
    max_climb_rate_mps: float = 0.3  # |vz| below this counts as not moving vertically (PX4 LNDMC_Z_VEL_MAX 0.5)
    low_thrust_ratio: float = 0.6  # collective below this fraction of hover thrust counts as "pushing down"
    trigger_time_s: float = 0.35
    takeoff_thrust_ratio: float = 0.85  # above this fraction of hover with upward motion -> airborne


class LandDetector:
    def __init__(self, config: LandDetectorConfig) -> None:
        self.config = config
        self.landed = True
        self._since_s: float | None = None

    def reset(self, landed: bool) -> None:
        self.landed = landed
        self._since_s = None

    def update(self, now_s: float, vel_down_mps: float, thrust_ratio_of_hover: float, altitude_agl_m: float) -> bool:
        """Returns the landed state after this update."""
        cfg = self.config
        if self.landed:
            if thrust_ratio_of_hover > cfg.takeoff_thrust_ratio and (vel_down_mps < -0.2 or altitude_agl_m > 0.3):
                self.landed = False
                self._since_s = None
            return self.landed
        still = abs(vel_down_mps) < cfg.max_climb_rate_mps
        if still and thrust_ratio_of_hover < cfg.low_thrust_ratio:
            if self._since_s is None:
                self._since_s = now_s
            elif now_s - self._since_s >= cfg.trigger_time_s:
                self.landed = True
                self._since_s = None
        else:
            self._since_s = None
        return self.landed
