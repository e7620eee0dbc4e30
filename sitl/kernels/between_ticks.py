"""A drone's physics step in one or two compiled calls: the sensors and the estimator on every step without a GPS
sample (``sense``), and, between two commander ticks, the inner loops towards the attitude the commander's last tick
asked for as well (``step``; sitl/autopilot/commander.py, ``Commander.step``).

A third entry point takes a steady tick (``steady_tick``): a tick of a drone flying a streamed trajectory setpoint in
OFFBOARD on which no failsafe row acts and nothing else asks for the Python commander (sitl/autopilot/flight_tick.py
``FlightTick.steady_tick_ready`` says when). It senses, looks at the failsafe table's conditions on the new estimate,
and, when no row acts, flies the setpoint through the outer and inner loops (or, when collision prevention is due to
run on this estimate, returns ``TICK_QUIET`` and leaves the control step to the caller); when one does, it returns
``TICK_EVENT`` having only sensed, and the Python tick runs on that estimate as after ``sense``.

On most steps no GPS sample is due (10 Hz against 250 Hz physics) and what a step samples is numeric: the IMU, and at
their rates the barometer and the magnetometer. That was two Python shells each building records (the readings, the
estimate) around the estimator's kernel; here the samples are taken with the arithmetic sitl/sensors/models.py writes
(``Imu.sample``, ``Barometer.sample``, ``Magnetometer.sample``) from the same rows of each sensor's noise block, and
the estimator's kernel (sitl/kernels/estimator.py ``step``) and, between ticks, the cascade's inner loops
(sitl/kernels/cascade.py ``inner``) run back to back on the same rows, so a step taken here has the bits the shells
would give (the recorded flights are the check). sitl/drone/closed_loop.py decides when a step may be taken here; the
commander's tick itself stays Python and reads the estimate this leaves.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from sitl.kernels import avoidance as ak
from sitl.kernels import cascade as ck
from sitl.kernels import estimator as ek
from sitl.kernels import failsafe as fk
from sitl.kernels import kernel

# The sensors' constants (sitl/sensors/models.py SensorSuite.row): the IMU's gyro and accelerometer biases and noise
# scales, the barometer's noise scale, the magnetometer's noise scale and the Earth field it measures (NED, gauss).
I_GYRO_BIAS = 0
I_ACCEL_BIAS = 3
I_GYRO_NOISE = 6
I_ACCEL_NOISE = 7
I_BARO_NOISE = 8
I_MAG_NOISE = 9
I_MAG_FIELD = 10
SENSORS_SIZE = 13

# What the IMU samples, from the plant's step: the true body rates, then the true specific force.
I_IN_RATES = 0
I_IN_SPECIFIC_FORCE = 3


_SENSE_ARGS = (
    "float64[::1], float64[::1], float64[:, ::1], int64, boolean, float64[:, ::1], int64, float64, boolean,"
    " float64[:, ::1], int64, float64, float64, float64, float64, float64[::1], float64[::1], float64[::1],"
    " float64[::1], float64[::1], float64, float64"
)


@kernel(f"void({_SENSE_ARGS})")
def sense(
    imu_inputs: npt.NDArray[np.float64],
    sensors: npt.NDArray[np.float64],
    noise: npt.NDArray[np.float64],
    noise_row: int,
    baro_due: bool,
    baro_noise: npt.NDArray[np.float64],
    baro_row: int,
    alt_amsl_m: float,
    mag_due: bool,
    mag_noise: npt.NDArray[np.float64],
    mag_row: int,
    qw: float,
    qx: float,
    qy: float,
    qz: float,
    est_state: npt.NDArray[np.float64],
    est_cfg: npt.NDArray[np.float64],
    est_gps: npt.NDArray[np.float64],
    est_no_vec: npt.NDArray[np.float64],
    est_out: npt.NDArray[np.float64],
    time_s: float,
    dt_s: float,
) -> None:
    """The sensors sampled and the estimator stepped on them, the estimate written to ``est_out``.

    The IMU from the true rates and specific force (``imu_inputs``: rates, then specific force,
    sitl/dynamics/jsbsim_plant.py ``JsbsimPlant.imu_inputs``) with noise rows ``noise_row`` and ``noise_row + 1`` of
    its block; when ``baro_due``, the barometer from the true altitude ``alt_amsl_m`` with row ``baro_row`` of its
    block; when ``mag_due``, the magnetometer from the true attitude ``qw``..``qz`` with row ``mag_row`` of its block.
    The estimator's attitude must be initialised when the magnetometer is due (the shells initialise it)."""
    gyro = np.empty(3)
    accel = np.empty(3)
    k = sensors[I_GYRO_NOISE]
    for i in range(3):
        gyro[i] = imu_inputs[I_IN_RATES + i] + sensors[I_GYRO_BIAS + i] + k * noise[noise_row, i]
    k = sensors[I_ACCEL_NOISE]
    for i in range(3):
        accel[i] = imu_inputs[I_IN_SPECIFIC_FORCE + i] + sensors[I_ACCEL_BIAS + i] + k * noise[noise_row + 1, i]
    baro_alt_m = 0.0
    if baro_due:
        baro_alt_m = alt_amsl_m + sensors[I_BARO_NOISE] * baro_noise[baro_row, 0]
    mag = est_no_vec
    if mag_due:
        w, x, y, z = qw, qx, qy, qz
        fn = sensors[I_MAG_FIELD]
        fe = sensors[I_MAG_FIELD + 1]
        fd = sensors[I_MAG_FIELD + 2]
        # R(q)^T field_ned, with R(q) the body->NED rotation matrix, written as Magnetometer.sample writes it.
        bx = (1 - 2 * (y * y + z * z)) * fn + 2 * (x * y + w * z) * fe + 2 * (x * z - w * y) * fd
        by = 2 * (x * y - w * z) * fn + (1 - 2 * (x * x + z * z)) * fe + 2 * (y * z + w * x) * fd
        bz = 2 * (x * z + w * y) * fn + 2 * (y * z - w * x) * fe + (1 - 2 * (x * x + y * y)) * fd
        k = sensors[I_MAG_NOISE]
        mag = np.empty(3)
        mag[0] = bx + k * mag_noise[mag_row, 0]
        mag[1] = by + k * mag_noise[mag_row, 1]
        mag[2] = bz + k * mag_noise[mag_row, 2]
    ek.step(est_state, est_cfg, gyro, accel, mag_due, mag, False, est_gps, baro_due, baro_alt_m, time_s, dt_s,
            est_state[ek.ATT_INITIALISED] != 0.0, est_out)  # fmt: skip


@kernel(
    f"void({_SENSE_ARGS}, float64[::1], boolean, float64[::1], float64[::1], float64[::1], float64[:, ::1], float64,"
    " float64[::1])"
)
def step(
    imu_inputs: npt.NDArray[np.float64],
    sensors: npt.NDArray[np.float64],
    noise: npt.NDArray[np.float64],
    noise_row: int,
    baro_due: bool,
    baro_noise: npt.NDArray[np.float64],
    baro_row: int,
    alt_amsl_m: float,
    mag_due: bool,
    mag_noise: npt.NDArray[np.float64],
    mag_row: int,
    qw: float,
    qx: float,
    qy: float,
    qz: float,
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
    """A step between ticks: ``sense``, then the inner loops run on the new estimate towards what the outer loops
    hold (``held``, sitl/kernels/cascade.py ``U_*``); the motor commands go to ``inner_out``."""
    sense(imu_inputs, sensors, noise, noise_row, baro_due, baro_noise, baro_row, alt_amsl_m, mag_due, mag_noise,
          mag_row, qw, qx, qy, qz, est_state, est_cfg, est_gps, est_no_vec, est_out, time_s, dt_s)  # fmt: skip
    q = ek.O_Q
    r = ek.O_RATES
    ck.inner_held(est_out[q], est_out[q + 1], est_out[q + 2], est_out[q + 3], est_out[r], est_out[r + 1],
                  est_out[r + 2], held, dt_s, landed, attitude_cfg, rate_cfg, rate_state, alloc_rows, t_max,
                  inner_out)  # fmt: skip


# What ``steady_tick`` and ``steady_tick_avoiding`` return: the tick was flown; a failsafe row acts and the Python
# tick must run; no row acts and the control step is the caller's (collision prevention runs on this estimate first);
# collision prevention ran and the tick was flown, the outer loops holding or run.
TICK_STEADY = 0
TICK_EVENT = 1
TICK_QUIET = 2
TICK_AVOIDED = 3
TICK_AVOIDED_OUTER = 4
_CONDITIONS_ARGS = "boolean, boolean, float64, float64, float64, float64, float64, float64, int64, int64"
_TRAJECTORY_ARGS = (
    "float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], float64[::1],"
    " float64[:, ::1], float64, float64[::1]"
)


@kernel(f"boolean({_SENSE_ARGS}, {_CONDITIONS_ARGS})")
def sensed_acts(
    imu_inputs: npt.NDArray[np.float64],
    sensors: npt.NDArray[np.float64],
    noise: npt.NDArray[np.float64],
    noise_row: int,
    baro_due: bool,
    baro_noise: npt.NDArray[np.float64],
    baro_row: int,
    alt_amsl_m: float,
    mag_due: bool,
    mag_noise: npt.NDArray[np.float64],
    mag_row: int,
    qw: float,
    qx: float,
    qy: float,
    qz: float,
    est_state: npt.NDArray[np.float64],
    est_cfg: npt.NDArray[np.float64],
    est_gps: npt.NDArray[np.float64],
    est_no_vec: npt.NDArray[np.float64],
    est_out: npt.NDArray[np.float64],
    time_s: float,
    dt_s: float,
    needs_position: bool,
    offboard_alive: bool,
    gcs_heartbeat_s: float,
    battery_remaining: float,
    datalink_loss_s: float,
    battery_low: float,
    battery_critical: float,
    battery_emergency: float,
    fired: int,
    on_arming: int,
) -> bool:
    """A steady tick's start: ``sense``, then whether a failsafe row acts on the new estimate (sitl/kernels/failsafe.py:
    the conditions as the Python tick gives them, ``fired`` and ``on_arming`` from the framework)."""
    sense(imu_inputs, sensors, noise, noise_row, baro_due, baro_noise, baro_row, alt_amsl_m, mag_due, mag_noise,
          mag_row, qw, qx, qy, qz, est_state, est_cfg, est_gps, est_no_vec, est_out, time_s, dt_s)  # fmt: skip
    holds = fk.conditions(time_s, False, True, False, needs_position, offboard_alive, gcs_heartbeat_s,
                          battery_remaining, est_out[ek.O_POS_VALID] != 0.0, False, datalink_loss_s, battery_low,
                          battery_critical, battery_emergency)  # fmt: skip
    return fk.events(holds, fired, on_arming) != 0


@kernel(f"int64({_SENSE_ARGS}, {_CONDITIONS_ARGS}, boolean, float64[::1], boolean, float64, {_TRAJECTORY_ARGS})")
def steady_tick(
    imu_inputs: npt.NDArray[np.float64],
    sensors: npt.NDArray[np.float64],
    noise: npt.NDArray[np.float64],
    noise_row: int,
    baro_due: bool,
    baro_noise: npt.NDArray[np.float64],
    baro_row: int,
    alt_amsl_m: float,
    mag_due: bool,
    mag_noise: npt.NDArray[np.float64],
    mag_row: int,
    qw: float,
    qx: float,
    qy: float,
    qz: float,
    est_state: npt.NDArray[np.float64],
    est_cfg: npt.NDArray[np.float64],
    est_gps: npt.NDArray[np.float64],
    est_no_vec: npt.NDArray[np.float64],
    est_out: npt.NDArray[np.float64],
    time_s: float,
    dt_s: float,
    needs_position: bool,
    offboard_alive: bool,
    gcs_heartbeat_s: float,
    battery_remaining: float,
    datalink_loss_s: float,
    battery_low: float,
    battery_critical: float,
    battery_emergency: float,
    fired: int,
    on_arming: int,
    fly: bool,
    sp: npt.NDArray[np.float64],
    outer_due: bool,
    elapsed_s: float,
    position_cfg: npt.NDArray[np.float64],
    velocity_cfg: npt.NDArray[np.float64],
    velocity_state: npt.NDArray[np.float64],
    heading_cfg: npt.NDArray[np.float64],
    held: npt.NDArray[np.float64],
    attitude_cfg: npt.NDArray[np.float64],
    rate_cfg: npt.NDArray[np.float64],
    rate_state: npt.NDArray[np.float64],
    alloc_rows: npt.NDArray[np.float64],
    t_max: float,
    inner_out: npt.NDArray[np.float64],
) -> int:
    """A steady tick of a drone in OFFBOARD, in the air, with no fence: ``sensed_acts``; then, unless a failsafe row
    acts (``TICK_EVENT``, having only sensed), the control step towards the setpoint row ``sp`` (sitl/kernels/
    cascade.py ``trajectory``, the motor commands to ``inner_out``) and ``TICK_STEADY``, or, unless ``fly``,
    ``TICK_QUIET`` having only sensed."""
    if sensed_acts(imu_inputs, sensors, noise, noise_row, baro_due, baro_noise, baro_row, alt_amsl_m, mag_due,
                   mag_noise, mag_row, qw, qx, qy, qz, est_state, est_cfg, est_gps, est_no_vec, est_out, time_s, dt_s,
                   needs_position, offboard_alive, gcs_heartbeat_s, battery_remaining, datalink_loss_s, battery_low,
                   battery_critical, battery_emergency, fired, on_arming):  # fmt: skip
        return TICK_EVENT
    if not fly:
        return TICK_QUIET
    ck.trajectory(est_out[ek.O_POS : ek.O_POS + 3], est_out[ek.O_VEL : ek.O_VEL + 3], est_out[ek.O_Q : ek.O_Q + 4],
                  est_out[ek.O_RATES : ek.O_RATES + 3], sp, outer_due, elapsed_s, dt_s, False, position_cfg,
                  velocity_cfg, velocity_state, heading_cfg, held, attitude_cfg, rate_cfg, rate_state, alloc_rows,
                  t_max, inner_out)  # fmt: skip
    return TICK_STEADY


@kernel(
    f"int64({_SENSE_ARGS}, {_CONDITIONS_ARGS}, float64[::1], boolean, float64, boolean, boolean, float64, float64,"
    " float64[:, ::1], float64, float64[:, ::1], float64, float64, float64, int64, float64[::1], boolean,"
    f" float64[::1], {_TRAJECTORY_ARGS})"
)
def steady_tick_avoiding(
    imu_inputs: npt.NDArray[np.float64],
    sensors: npt.NDArray[np.float64],
    noise: npt.NDArray[np.float64],
    noise_row: int,
    baro_due: bool,
    baro_noise: npt.NDArray[np.float64],
    baro_row: int,
    alt_amsl_m: float,
    mag_due: bool,
    mag_noise: npt.NDArray[np.float64],
    mag_row: int,
    qw: float,
    qx: float,
    qy: float,
    qz: float,
    est_state: npt.NDArray[np.float64],
    est_cfg: npt.NDArray[np.float64],
    est_gps: npt.NDArray[np.float64],
    est_no_vec: npt.NDArray[np.float64],
    est_out: npt.NDArray[np.float64],
    time_s: float,
    dt_s: float,
    needs_position: bool,
    offboard_alive: bool,
    gcs_heartbeat_s: float,
    battery_remaining: float,
    datalink_loss_s: float,
    battery_low: float,
    battery_critical: float,
    battery_emergency: float,
    fired: int,
    on_arming: int,
    sp: npt.NDArray[np.float64],
    streamed_due: bool,
    elapsed_s: float,
    period_due: bool,
    static_equal: bool,
    last_vx: float,
    last_vy: float,
    camera: npt.NDArray[np.float64],
    camera_age_s: float,
    neighbours: npt.NDArray[np.float64],
    radius_m: float,
    stale_rate_mps: float,
    stale_max_m: float,
    keep: int,
    avoid_cfg: npt.NDArray[np.float64],
    correcting: bool,
    run_out: npt.NDArray[np.float64],
    position_cfg: npt.NDArray[np.float64],
    velocity_cfg: npt.NDArray[np.float64],
    velocity_state: npt.NDArray[np.float64],
    heading_cfg: npt.NDArray[np.float64],
    held: npt.NDArray[np.float64],
    attitude_cfg: npt.NDArray[np.float64],
    rate_cfg: npt.NDArray[np.float64],
    rate_state: npt.NDArray[np.float64],
    alloc_rows: npt.NDArray[np.float64],
    t_max: float,
    inner_out: npt.NDArray[np.float64],
) -> int:
    """A steady tick on which collision prevention is due to run: ``sensed_acts`` (``TICK_EVENT`` when a row acts);
    then collision prevention's run on the new estimate towards the streamed setpoint in ``sp`` (sitl/kernels/
    avoidance.py ``run``, found to ``run_out``), the setpoint row corrected as ``CollisionPrevention.held`` corrects
    it when the run holds a correction, and the control step towards it, as the Python tick flies it.

    Whether the outer loops run follows ``Cascade.outer_plan``: their period (``period_due``), or a setpoint other than
    the one they last ran for. The streamed setpoint's answer is ``streamed_due``; a corrected one equals the last
    only if everything but its horizontal velocity does (``static_equal``, worked out by the caller with Python's
    own comparison) and that velocity equals ``last_vx``, ``last_vy``. Returns ``TICK_AVOIDED_OUTER`` when they ran,
    else ``TICK_AVOIDED``."""
    if sensed_acts(imu_inputs, sensors, noise, noise_row, baro_due, baro_noise, baro_row, alt_amsl_m, mag_due,
                   mag_noise, mag_row, qw, qx, qy, qz, est_state, est_cfg, est_gps, est_no_vec, est_out, time_s, dt_s,
                   needs_position, offboard_alive, gcs_heartbeat_s, battery_remaining, datalink_loss_s, battery_low,
                   battery_critical, battery_emergency, fired, on_arming):  # fmt: skip
        return TICK_EVENT
    p, v = ek.O_POS, ek.O_VEL
    ak.run(est_out[p], est_out[p + 1], est_out[p + 2], est_out[v], est_out[v + 1], est_out[v + 2], sp[ck.SP_POS],
           sp[ck.SP_POS + 1], sp[ck.SP_POS + 2], sp[ck.SP_VEL], sp[ck.SP_VEL + 1], sp[ck.SP_VEL + 2], position_cfg,
           camera, camera_age_s, neighbours, time_s, radius_m, stale_rate_mps, stale_max_m, keep, avoid_cfg,
           correcting, run_out)  # fmt: skip
    due = streamed_due
    if run_out[ak.RUN_ACTIVE] != 0.0:
        vx = run_out[ak.RUN_VEL]
        vy = run_out[ak.RUN_VEL + 1]
        sp[ck.SP_POS] = np.nan
        sp[ck.SP_POS + 1] = np.nan
        sp[ck.SP_VEL] = vx
        sp[ck.SP_VEL + 1] = vy
        sp[ck.SP_ACC] = np.nan
        sp[ck.SP_ACC + 1] = np.nan
        due = period_due or not (static_equal and vx == last_vx and vy == last_vy)
    ck.trajectory(est_out[p : p + 3], est_out[v : v + 3], est_out[ek.O_Q : ek.O_Q + 4],
                  est_out[ek.O_RATES : ek.O_RATES + 3], sp, due, elapsed_s, dt_s, False, position_cfg, velocity_cfg,
                  velocity_state, heading_cfg, held, attitude_cfg, rate_cfg, rate_state, alloc_rows, t_max,
                  inner_out)  # fmt: skip
    return TICK_AVOIDED_OUTER if due else TICK_AVOIDED
