"""Wind: a steady component plus seeded gusts.

Gusts are three independent first-order Gauss-Markov processes (a Dryden-like low-pass of white noise) with a given
RMS intensity and correlation time, stepped with the physics. The plant receives the total wind; the controller
only feels it through the drag it causes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sitl.dynamics.noise import NoiseSource
from sitl.mathutil import Vec3


@dataclass(frozen=True, slots=True, kw_only=True)
class WindConfig:
    steady_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gust_rms_mps: float = 0.0
    gust_time_s: float = 2.0


class WindModel:
    def __init__(self, config: WindConfig, rng: np.random.Generator) -> None:
        self.config = config
        self._noise = NoiseSource(rng)
        self._gust = np.zeros(3)
        self._steady = np.array(config.steady_ned_mps, dtype=np.float64)
        # Constant for the flight: no wind at all lets the simulation skip the wind step.
        self.calm = config.gust_rms_mps == 0.0 and not self._steady.any()

    def update(self, dt_s: float) -> Vec3:
        cfg = self.config
        if cfg.gust_rms_mps > 0.0:
            alpha = math.exp(-dt_s / cfg.gust_time_s)
            self._gust = alpha * self._gust + math.sqrt(1.0 - alpha * alpha) * cfg.gust_rms_mps * self._noise.vec3()
        return self._steady + self._gust
