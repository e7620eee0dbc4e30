"""The builders that turn a ParamStore (plus the airframe's physical constants) into the frozen config of each
controller stage; the stages themselves never see the store. The parameters they read are declared in
sitl/control/params.py."""

from __future__ import annotations

import math

from sitl.control.attitude import AttitudeConfig
from sitl.control.heading import HeadingConfig
from sitl.control.position import PositionConfig
from sitl.control.rate import RateConfig
from sitl.control.velocity import VelocityConfig
from sitl.dynamics.airframe import Airframe
from sitl.params import ParamStore


def position_config(store: ParamStore) -> PositionConfig:
    return PositionConfig(
        xy_p_per_s=store["MPC_XY_P"],
        z_p_per_s=store["MPC_Z_P"],
        xy_vel_max_mps=store["MPC_XY_VEL_MAX"],
        z_vel_max_up_mps=store["MPC_Z_VEL_MAX_UP"],
        z_vel_max_dn_mps=store["MPC_Z_VEL_MAX_DN"],
    )


def velocity_config(store: ParamStore, airframe: Airframe) -> VelocityConfig:
    collective_max_n = airframe.max_thrust_per_rotor_n * len(airframe.rotors)
    thrust_min = store["MPC_THR_MIN"]
    # Each value is valid alone; an inverted pair (minimum above maximum) resolves in favour of the minimum.
    thrust_max = max(store["MPC_THR_MAX"], thrust_min)
    return VelocityConfig(
        xy_p_per_s=store["MPC_XY_VEL_P_ACC"],
        xy_i_per_s2=store["MPC_XY_VEL_I_ACC"],
        xy_d=store["MPC_XY_VEL_D_ACC"],
        z_p_per_s=store["MPC_Z_VEL_P_ACC"],
        z_i_per_s2=store["MPC_Z_VEL_I_ACC"],
        z_d=store["MPC_Z_VEL_D_ACC"],
        vel_deriv_cutoff_hz=store["MPC_VELD_LP"],
        tilt_max_rad=math.radians(store["MPC_TILTMAX_AIR"]),
        thrust_min_n=thrust_min * collective_max_n,
        thrust_max_n=thrust_max * collective_max_n,
        thrust_xy_margin_n=store["MPC_THR_XY_MARG"] * collective_max_n,
        mass_kg=airframe.mass_kg,
    )


def heading_config(store: ParamStore) -> HeadingConfig:
    return HeadingConfig(
        follow_travel=store["MPC_YAW_FOLLOW"] == 1,
        follow_rate_max_radps=math.radians(store["MPC_YAWRAUTO_MAX"]),
    )


def attitude_config(store: ParamStore) -> AttitudeConfig:
    return AttitudeConfig(
        roll_p_per_s=store["MC_ROLL_P"],
        pitch_p_per_s=store["MC_PITCH_P"],
        yaw_p_per_s=store["MC_YAW_P"],
        yaw_weight=store["MC_YAW_WEIGHT"],
        roll_rate_max_radps=math.radians(store["MC_ROLLRATE_MAX"]),
        pitch_rate_max_radps=math.radians(store["MC_PITCHRATE_MAX"]),
        yaw_rate_max_radps=math.radians(store["MC_YAWRATE_MAX"]),
    )


def rate_config(store: ParamStore, airframe: Airframe) -> RateConfig:
    ixx, iyy, izz = airframe.inertia_diag_kg_m2
    return RateConfig(
        p_per_s=(store["MC_ROLLRATE_P"], store["MC_PITCHRATE_P"], store["MC_YAWRATE_P"]),
        i_per_s2=(store["MC_ROLLRATE_I"], store["MC_PITCHRATE_I"], store["MC_YAWRATE_I"]),
        d=(store["MC_ROLLRATE_D"], store["MC_PITCHRATE_D"], store["MC_YAWRATE_D"]),
        int_lim_radps2=(store["MC_RR_INT_LIM"], store["MC_PR_INT_LIM"], store["MC_YR_INT_LIM"]),
        deriv_cutoff_hz=store["IMU_DGYRO_CUTOFF"],
        inertia_kg_m2=(ixx, iyy, izz),
    )
