"""A drone's physics step between two commander ticks, in one call: the IMU sample, the estimator's step and the
inner loops towards the attitude the commander's last tick asked for (sitl/autopilot/commander.py, ``Commander.step``).

Between ticks nothing in a drone's step is event-driven: no mode, failsafe or land detector runs, and on most steps
no GPS, barometer or magnetometer sample is due. What is left is numeric, and was three Python shells each building
a record (the IMU sample, the estimate, the cascade's output) around its kernel; here the same kernels
(sitl/kernels/estimator.py ``step``, sitl/kernels/cascade.py ``inner``) run back to back on the same rows, with the
IMU's arithmetic written as sitl/sensors/models.py ``Imu.sample`` writes it, so a step taken here has the bits the
shells would give (the recorded flights are the check). sitl/drone/closed_loop.py decides when a step may be taken here.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from sitl.kernels import cascade as ck
from sitl.kernels import estimator as ek
from sitl.kernels import kernel

# The IMU's constants: gyro and accelerometer biases, then the two noise scales (sitl/sensors/models.py Imu).
I_GYRO_BIAS = 0
I_ACCEL_BIAS = 3
I_GYRO_NOISE = 6
I_ACCEL_NOISE = 7
IMU_SIZE = 8

# What the IMU samples, from the plant's step: the true body rates, then the true specific force.
I_IN_RATES = 0
I_IN_SPECIFIC_FORCE = 3

# What the commander's last tick left for the inner loops: the attitude setpoint, the yaw-rate feed-forward and the
# collective thrust (sitl/control/cascade.py, the position loops' output).
H_ATT_SP = 0
H_YAWSPEED_FF = 4
H_COLLECTIVE = 5
HELD_SIZE = 6


@kernel(
    "void(float64[::1], float64[:, ::1], int64, float64[::1], float64[::1], float64[::1],"
    " float64[::1], float64[::1], float64[::1], float64, float64, float64[::1], boolean, float64[::1],"
    " float64[::1], float64[::1], float64[:, ::1], float64, float64[::1])"
)
def step(
    imu_inputs: npt.NDArray[np.float64],
    noise: npt.NDArray[np.float64],
    noise_row: int,
    imu: npt.NDArray[np.float64],
    est_state: npt.NDArray[np.float64],
    est_cfg: npt.NDArray[np.float64],
    est_gps: npt.NDArray[np.float64],
    est_no_vec: npt.NDArray[np.float64],
    est_out: npt.NDArray[np.float64],
    time_s: float,
    dt_s: float,
    held: npt.NDArray[np.float64],
    landed: bool,
    attitude_cfg: npt.NDArray[np.float64],
    rate_cfg: npt.NDArray[np.float64],
    rate_state: npt.NDArray[np.float64],
    alloc_rows: npt.NDArray[np.float64],
    t_max: float,
    inner_out: npt.NDArray[np.float64],
) -> None:
    """One step: the IMU sampled from the true rates and specific force (``imu_inputs``: rates, then specific force,
    sitl/dynamics/jsbsim_plant.py ``JsbsimPlant.imu_inputs``) with noise rows ``noise_row`` and
    ``noise_row + 1`` of the IMU's noise block, the estimator stepped on it alone, and the inner loops run on the new
    estimate towards ``held``; the estimate goes to ``est_out`` and the motor commands to ``inner_out``."""
    gyro = np.empty(3)
    accel = np.empty(3)
    k = imu[I_GYRO_NOISE]
    for i in range(3):
        gyro[i] = imu_inputs[I_IN_RATES + i] + imu[I_GYRO_BIAS + i] + k * noise[noise_row, i]
    k = imu[I_ACCEL_NOISE]
    for i in range(3):
        accel[i] = imu_inputs[I_IN_SPECIFIC_FORCE + i] + imu[I_ACCEL_BIAS + i] + k * noise[noise_row + 1, i]
    ek.step(est_state, est_cfg, gyro, accel, False, est_no_vec, False, est_gps, False, 0.0, time_s, dt_s,
            est_state[ek.ATT_INITIALISED] != 0.0, est_out)  # fmt: skip
    q = ek.O_Q
    r = ek.O_RATES
    a = H_ATT_SP
    ck.inner(est_out[q], est_out[q + 1], est_out[q + 2], est_out[q + 3],
             held[a], held[a + 1], held[a + 2], held[a + 3], held[H_YAWSPEED_FF], False, math.nan, math.nan, math.nan,
             est_out[r], est_out[r + 1], est_out[r + 2], held[H_COLLECTIVE], dt_s, landed,
             attitude_cfg, rate_cfg, rate_state, alloc_rows, t_max, inner_out)  # fmt: skip
