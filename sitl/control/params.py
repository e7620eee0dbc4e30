"""Controller parameters: the declarations of every cascade gain and limit.

Names, meanings and (where the units agree) defaults follow PX4, so a PX4 user finds the knob they expect. The
exceptions are written in the descriptions: the rate-loop gains are in physical units (angular acceleration
per rate error, see sitl/control/rate.py), and there is no hover-thrust parameter because the velocity stage
converts acceleration to force with the airframe mass. Defaults are tuned for airframes/quad_x_f450.toml at a
400 Hz loop, and fly the same at the 250 Hz default physics rate (docs/control.md).

The builders of the stages' configs are in sitl/control/configs.py: this module imports nothing of the controller,
so a ground station can check a parameter against this table without loading the compiled kernels.
"""

from __future__ import annotations

from sitl.params import ParamDef, ParamStore, ParamType


def _p(name: str, default: float, lo: float, hi: float, unit: str, description: str) -> ParamDef:
    return ParamDef(name=name, default=default, min=lo, max=hi, unit=unit, description=description)


_RATE_UNITS = " Physical units: (rad/s^2) of angular acceleration demand, unlike PX4's normalised torque."

CONTROL_PARAMS: tuple[ParamDef, ...] = (
    # Position loop.
    _p("MPC_XY_P", 0.95, 0.0, 2.0, "1/s", "Horizontal position P gain: velocity setpoint per metre of error"),
    _p("MPC_Z_P", 1.0, 0.0, 1.5, "1/s", "Vertical position P gain: velocity setpoint per metre of error"),
    _p("MPC_XY_VEL_MAX", 12.0, 0.5, 20.0, "m/s", "Maximum horizontal velocity setpoint (limits the vector)"),
    _p("MPC_Z_VEL_MAX_UP", 3.0, 0.5, 8.0, "m/s", "Maximum climb rate setpoint"),
    _p("MPC_Z_VEL_MAX_DN", 1.5, 0.5, 4.0, "m/s", "Maximum descent rate setpoint"),
    # Velocity loop (acceleration units, as PX4). The horizontal P is above PX4's 1.8 because offboard and goto
    # position setpoints reach this loop as raw steps: on the toy plant 1.8 overshoots a 5 m step by 13 %, 3.0 by
    # under 1 % and settles in 2.1 s instead of 3.9 s.
    _p("MPC_XY_VEL_P_ACC", 3.0, 1.2, 5.0, "1/s", "Horizontal velocity P gain: m/s^2 per m/s of error"),
    _p("MPC_XY_VEL_I_ACC", 0.4, 0.0, 60.0, "1/s^2", "Horizontal velocity I gain: m/s^2 per m/s per second"),
    _p("MPC_XY_VEL_D_ACC", 0.2, 0.0, 2.0, "", "Horizontal velocity D gain on measured acceleration"),
    _p("MPC_Z_VEL_P_ACC", 4.0, 2.0, 15.0, "1/s", "Vertical velocity P gain: m/s^2 per m/s of error"),
    _p("MPC_Z_VEL_I_ACC", 2.0, 0.2, 3.0, "1/s^2", "Vertical velocity I gain: m/s^2 per m/s per second"),
    _p("MPC_Z_VEL_D_ACC", 0.0, 0.0, 2.0, "", "Vertical velocity D gain on measured acceleration"),
    _p("MPC_VELD_LP", 5.0, 0.0, 50.0, "Hz", "Low-pass cutoff of the velocity derivative (D term); 0 = off"),
    _p("MPC_TILTMAX_AIR", 45.0, 20.0, 89.0, "deg", "Maximum tilt of the thrust vector in flight"),
    _p("MPC_THR_MIN", 0.12, 0.05, 0.5, "", "Minimum collective thrust in flight, fraction of maximum"),
    _p("MPC_THR_MAX", 1.0, 0.0, 1.0, "", "Maximum collective thrust, fraction of maximum"),
    _p("MPC_THR_XY_MARG", 0.3, 0.0, 0.5, "", "Thrust kept for horizontal control at full climb, fraction"),
    # PX4 runs its position controller at the estimator's output rate (50-100 Hz), below the attitude and rate
    # loops. At 100 Hz the closed-loop acceptance flights measured the same as with the single-rate cascade (at the
    # then 400 Hz physics rate) to within a few millimetres, and a hovering drone cost about 7 % less CPU time.
    _p(
        "MPC_LOOP_HZ",
        100.0,
        10.0,
        1000.0,
        "Hz",
        "Rate of the autopilot's commander (modes, failsafes, land detector) and of the position and velocity loops"
        " while the setpoint holds still (a command or a new setpoint is acted on at once; attitude, rate and"
        " allocation run every physics step); at or above the physics rate: every step",
    ),
    # Attitude loop.
    _p("MC_ROLL_P", 6.5, 0.0, 12.0, "1/s", "Roll attitude P gain: rate setpoint per radian of error"),
    _p("MC_PITCH_P", 6.5, 0.0, 12.0, "1/s", "Pitch attitude P gain: rate setpoint per radian of error"),
    _p("MC_YAW_P", 2.8, 0.0, 5.0, "1/s", "Yaw attitude P gain: rate setpoint per radian of error"),
    _p("MC_YAW_WEIGHT", 0.4, 0.0, 1.0, "", "Share of the yaw error used beside roll/pitch (priority)"),
    _p("MC_ROLLRATE_MAX", 220.0, 0.0, 1800.0, "deg/s", "Maximum roll rate setpoint"),
    _p("MC_PITCHRATE_MAX", 220.0, 0.0, 1800.0, "deg/s", "Maximum pitch rate setpoint"),
    # Below PX4's 200 deg/s: an F450 has about 4 rad/s^2 of yaw authority at hover, too little to stop a
    # 200 deg/s turn on the attitude loop's approach (a 180 degree heading step overshot by 20 degrees).
    _p("MC_YAWRATE_MAX", 120.0, 0.0, 1800.0, "deg/s", "Maximum yaw rate setpoint"),
    # Heading when a setpoint leaves yaw free (sitl/control/heading.py; the default is measured in
    # docs/avoidance.md: the forward camera must look where the drone flies).
    ParamDef(
        name="MPC_YAW_FOLLOW",
        default=0,
        min=0,
        max=1,
        unit="",
        description="Heading when a setpoint leaves yaw free: 1 turn towards the direction of travel (above"
        " 0.5 m/s), 0 hold the last heading (PX4 offboard)",
        type=ParamType.INT,
    ),
    _p("MPC_YAWRAUTO_MAX", 45.0, 5.0, 360.0, "deg/s", "Maximum rate of a heading that follows the direction of travel"),
    # Rate loop (physical units).
    _p("MC_ROLLRATE_P", 25.0, 0.0, 100.0, "1/s", "Roll rate P gain." + _RATE_UNITS),
    _p("MC_ROLLRATE_I", 20.0, 0.0, 200.0, "1/s^2", "Roll rate I gain." + _RATE_UNITS),
    _p("MC_ROLLRATE_D", 0.2, 0.0, 2.0, "", "Roll rate D gain on measured rate." + _RATE_UNITS),
    _p("MC_PITCHRATE_P", 25.0, 0.0, 100.0, "1/s", "Pitch rate P gain." + _RATE_UNITS),
    _p("MC_PITCHRATE_I", 20.0, 0.0, 200.0, "1/s^2", "Pitch rate I gain." + _RATE_UNITS),
    _p("MC_PITCHRATE_D", 0.2, 0.0, 2.0, "", "Pitch rate D gain on measured rate." + _RATE_UNITS),
    _p("MC_YAWRATE_P", 8.0, 0.0, 100.0, "1/s", "Yaw rate P gain." + _RATE_UNITS),
    _p("MC_YAWRATE_I", 5.0, 0.0, 200.0, "1/s^2", "Yaw rate I gain." + _RATE_UNITS),
    _p("MC_YAWRATE_D", 0.0, 0.0, 2.0, "", "Yaw rate D gain on measured rate." + _RATE_UNITS),
    _p("MC_RR_INT_LIM", 30.0, 0.0, 500.0, "rad/s^2", "Roll rate integrator limit (angular acceleration)"),
    _p("MC_PR_INT_LIM", 30.0, 0.0, 500.0, "rad/s^2", "Pitch rate integrator limit (angular acceleration)"),
    _p("MC_YR_INT_LIM", 5.0, 0.0, 500.0, "rad/s^2", "Yaw rate integrator limit (angular acceleration)"),
    _p("IMU_DGYRO_CUTOFF", 30.0, 0.0, 200.0, "Hz", "Low-pass cutoff of the rate derivative (D term); 0 = off"),
)


def outer_loop_period_s(store: ParamStore) -> float:
    """Time between runs of the position and velocity loops (MPC_LOOP_HZ)."""
    return 1.0 / store["MPC_LOOP_HZ"]
