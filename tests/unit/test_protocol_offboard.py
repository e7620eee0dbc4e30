"""Offboard setpoint decoding (pure) and the offboard service that feeds the vehicle."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot.vehicle_api import NAN3
from sitl.control.cascade import AttitudeSetpoint, TrajectorySetpoint
from sitl.dynamics.geodesy import geo_from_ned
from sitl.protocol.core import Identity, MAVLinkMessage
from sitl.protocol.offboard import (
    OffboardService,
    SetpointRejected,
    VehiclePose,
    decode_attitude_target,
    decode_global_int,
    decode_local_ned,
)
from sitl.protocol.testing import HOME, FakeVehicle, Wire, isclose_tuple, make_snapshot, of_type

NAN = math.nan
SYSID = 1
POSITION_YAW = 2552  # MAVSDK set_position_ned
VELOCITY_YAW = 2503  # MAVSDK set_velocity_ned
POSE = VehiclePose(pos_ned_m=(10.0, -5.0, -20.0), yaw_rad=math.pi / 2, local_origin=HOME, home_alt_amsl_m=490.0)


Triple = tuple[float, float, float]


def local(
    frame: int,
    mask: int,
    pos: Triple = (0.0, 0.0, 0.0),
    vel: Triple = (0.0, 0.0, 0.0),
    acc: Triple = (0.0, 0.0, 0.0),
    yaw: float = 0.0,
    rate: float = 0.0,
) -> MAVLinkMessage:
    return Wire()(
        mavlink.MAVLink_set_position_target_local_ned_message(0, SYSID, 1, frame, mask, *pos, *vel, *acc, yaw, rate)
    )


def global_int(frame: int, mask: int, lat: int, lon: int, alt: float) -> MAVLinkMessage:
    return Wire()(
        mavlink.MAVLink_set_position_target_global_int_message(
            0, SYSID, 1, frame, mask, lat, lon, alt, 0, 0, 0, 0, 0, 0, 0.3, 0
        )
    )


# ---- local NED ---------------------------------------------------------------------------------------------
def test_mavsdk_position_and_yaw_mask() -> None:
    sp = decode_local_ned(local(mavlink.MAV_FRAME_LOCAL_NED, POSITION_YAW, pos=(1, 2, -3), yaw=0.5), POSE)
    assert sp.pos_ned_m == (1.0, 2.0, -3.0)
    assert isclose_tuple(sp.vel_ned_mps, NAN3) and isclose_tuple(sp.acc_ned_mps2, NAN3)
    assert sp.yaw_rad == 0.5 and math.isnan(sp.yawspeed_radps)


def test_mavsdk_velocity_and_yaw_mask() -> None:
    sp = decode_local_ned(local(mavlink.MAV_FRAME_LOCAL_NED, VELOCITY_YAW, vel=(1, 0, -0.5), yaw=0.25), POSE)
    assert isclose_tuple(sp.pos_ned_m, NAN3)
    assert sp.vel_ned_mps == (1.0, 0.0, -0.5)


def test_partial_mask_keeps_per_axis_not_set() -> None:
    # GIVEN x/y position with z ignored, and a vertical velocity instead (an altitude-rate setpoint)
    mask = 0b1111_1101_1100 | 0b100  # ignore z pos, vx, vy, acc, force, yaw rate... keep x, y, vz and yaw
    mask = (
        mavlink.POSITION_TARGET_TYPEMASK_Z_IGNORE
        | mavlink.POSITION_TARGET_TYPEMASK_VX_IGNORE
        | mavlink.POSITION_TARGET_TYPEMASK_VY_IGNORE
        | 64 | 128 | 256 | 2048
    )  # fmt: skip
    sp = decode_local_ned(local(1, mask, pos=(4, 5, 99), vel=(9, 9, 1.5)), POSE)
    assert isclose_tuple(sp.pos_ned_m, (4.0, 5.0, NAN))
    assert isclose_tuple(sp.vel_ned_mps, (NAN, NAN, 1.5))


def test_local_offset_ned_is_relative_to_the_current_position() -> None:
    sp = decode_local_ned(local(mavlink.MAV_FRAME_LOCAL_OFFSET_NED, POSITION_YAW, pos=(1, 1, -1)), POSE)
    assert sp.pos_ned_m == (11.0, -4.0, -21.0)


def test_body_ned_velocity_is_rotated_by_heading_and_position_ignored() -> None:
    # GIVEN the vehicle heading east (yaw 90 deg)  WHEN "forward 2 m/s" in BODY_NED  THEN 2 m/s east
    sp = decode_local_ned(local(mavlink.MAV_FRAME_BODY_NED, VELOCITY_YAW, vel=(2, 0, 0.5)), POSE)
    assert isclose_tuple(sp.vel_ned_mps, (0.0, 2.0, 0.5))
    assert isclose_tuple(sp.pos_ned_m, NAN3)


def test_body_ned_with_only_a_position_is_rejected() -> None:
    with pytest.raises(SetpointRejected):
        decode_local_ned(local(mavlink.MAV_FRAME_BODY_NED, POSITION_YAW, pos=(1, 0, 0)), POSE)


def test_body_offset_ned_position_is_rotated_and_added() -> None:
    # GIVEN heading east  WHEN 3 m forward, 1 m right, 2 m up  THEN 3 m east, 1 m south of the current position
    sp = decode_local_ned(local(mavlink.MAV_FRAME_BODY_OFFSET_NED, POSITION_YAW, pos=(3, 1, -2)), POSE)
    assert isclose_tuple(sp.pos_ned_m, (10.0 - 1.0, -5.0 + 3.0, -22.0))


@pytest.mark.parametrize(
    ("msg", "why"),
    [
        (local(1, POSITION_YAW, pos=(NAN, 0, 0)), "position x"),
        (local(1, VELOCITY_YAW, vel=(0, math.inf, 0)), "velocity y"),
        (local(1, 0b0000_1111_1111_1111), "no position"),
        (local(1, 0b0000_0010_0011_1111, acc=(1, 1, 1)), "force"),
        (local(mavlink.MAV_FRAME_GLOBAL, POSITION_YAW), "frame"),
        (local(1, POSITION_YAW & ~mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE, yaw=NAN), "yaw"),
    ],
)
def test_malformed_local_setpoints_are_rejected(msg: MAVLinkMessage, why: str) -> None:
    with pytest.raises(SetpointRejected, match=why):
        decode_local_ned(msg, POSE)


def test_offset_without_a_local_position_is_rejected() -> None:
    with pytest.raises(SetpointRejected):
        decode_local_ned(local(mavlink.MAV_FRAME_LOCAL_OFFSET_NED, POSITION_YAW, pos=(1, 1, 1)), VehiclePose())


# ---- global ------------------------------------------------------------------------------------------------
def test_global_setpoint_lands_where_the_project_geodesy_puts_that_point() -> None:
    # GIVEN a point 120 m north and 80 m west of the origin, as the vehicle would report it
    target = geo_from_ned((120.0, -80.0, 0.0), HOME)
    lat_e7, lon_e7 = round(target.lat_deg * 1e7), round(target.lon_deg * 1e7)
    # WHEN a client sends it as a global setpoint  THEN the local setpoint is that point (to degE7 resolution)
    sp = decode_global_int(global_int(mavlink.MAV_FRAME_GLOBAL_INT, POSITION_YAW, lat_e7, lon_e7, 500.0), POSE)
    assert sp.pos_ned_m == pytest.approx((120.0, -80.0, HOME.alt_amsl_m - 500.0), abs=0.01)
    assert sp.yaw_rad == pytest.approx(0.3)


def test_global_relative_altitude_is_above_home() -> None:
    sp = decode_global_int(
        global_int(mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, POSITION_YAW, 473977420, 85455940, 15.0), POSE
    )
    assert sp.pos_ned_m[2] == pytest.approx(HOME.alt_amsl_m - (490.0 + 15.0))
    assert sp.pos_ned_m[0] == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize(
    ("msg", "pose"),
    [
        (global_int(mavlink.MAV_FRAME_GLOBAL_INT, POSITION_YAW, 473977420, 85455940, 500.0), VehiclePose()),
        (global_int(mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT, POSITION_YAW, 473977420, 85455940, 5.0), POSE),
        (global_int(mavlink.MAV_FRAME_GLOBAL_INT, POSITION_YAW, 950000000, 85455940, 5.0), POSE),
        (global_int(mavlink.MAV_FRAME_GLOBAL_INT, POSITION_YAW | 1, 473977420, 85455940, 5.0), POSE),
    ],
)
def test_unusable_global_setpoints_are_rejected(msg: MAVLinkMessage, pose: VehiclePose) -> None:
    with pytest.raises(SetpointRejected):
        decode_global_int(msg, pose)


COLLECTIVE_MAX_N = 40.0  # the vehicle's, as its snapshot reports it


# ---- attitude ----------------------------------------------------------------------------------------------
def attitude(mask: int, q: tuple[float, ...], rates: Triple = (0.0, 0.0, 0.0), thrust: float = 0.5) -> MAVLinkMessage:
    return Wire()(mavlink.MAVLink_set_attitude_target_message(0, SYSID, 1, mask, q, *rates, thrust))


def test_attitude_target_with_thrust() -> None:
    sp = decode_attitude_target(attitude(0b0000_0111, (1, 0, 0, 0), thrust=0.6), COLLECTIVE_MAX_N)
    assert sp.att_q == (1.0, 0.0, 0.0, 0.0)
    assert sp.rates_sp_frd_radps == (0.0, 0.0, 0.0)  # ignored: none asked
    assert sp.thrust_n == pytest.approx(0.6 * COLLECTIVE_MAX_N)  # MAVLink's normalised thrust, in newtons


def test_body_rates_only() -> None:
    sp = decode_attitude_target(attitude(0b1000_0000, (0, 0, 0, 0), rates=(0.1, 0.2, 0.3)), COLLECTIVE_MAX_N)
    assert sp.att_q is None
    assert isclose_tuple(sp.rates_sp_frd_radps, (0.1, 0.2, 0.3))


@pytest.mark.parametrize(
    "msg",
    [
        attitude(0b0000_0111, (0, 0, 0, 0)),
        attitude(0b0000_0111, (1, 0, 0, 0), thrust=3.0),
        attitude(0b1000_0111, (1, 0, 0, 0)),
    ],
)
def test_bad_attitude_targets_are_rejected(msg: MAVLinkMessage) -> None:
    with pytest.raises(SetpointRejected):
        decode_attitude_target(msg, COLLECTIVE_MAX_N)


# ---- the service -------------------------------------------------------------------------------------------
def test_service_forwards_setpoints_with_their_arrival_time() -> None:
    vehicle = FakeVehicle(make_snapshot(pos_ned_m=(0.0, 0.0, -2.0)))
    service = OffboardService(Identity(sysid=SYSID), vehicle)
    assert service.handle(local(1, POSITION_YAW, pos=(0, 0, -5)), 3.25) == []
    assert service.handle(attitude(0b0000_0111, (1, 0, 0, 0)), 3.5) == []
    (sp, t), (att, t2) = vehicle.setpoints
    assert isinstance(sp, TrajectorySetpoint) and sp.pos_ned_m == (0.0, 0.0, -5.0) and t == 3.25
    assert isinstance(att, AttitudeSetpoint) and t2 == 3.5


def test_service_explains_rejections_at_a_limited_rate() -> None:
    # GIVEN a client streaming a broken setpoint at 20 Hz for 6 s
    vehicle = FakeVehicle()
    service = OffboardService(Identity(sysid=SYSID), vehicle)
    down = Wire(SYSID, 1)
    texts = []
    for i in range(120):
        texts += of_type(down.carry(service.handle(local(1, POSITION_YAW, pos=(NAN, 0, 0)), i * 0.05)), "STATUSTEXT")
    # THEN nothing reaches the vehicle and only two explanations went out
    assert vehicle.setpoints == []
    assert len(texts) == 2
    assert service.rejected_count == 120


def test_service_ignores_setpoints_for_other_vehicles() -> None:
    vehicle = FakeVehicle()
    service = OffboardService(Identity(sysid=SYSID), vehicle)
    msg = Wire()(
        mavlink.MAVLink_set_position_target_local_ned_message(
            0, 9, 1, 1, POSITION_YAW, 0, 0, -5, 0, 0, 0, 0, 0, 0, 0, 0
        )
    )
    assert service.handle(msg, 1.0) == []
    assert vehicle.setpoints == []
