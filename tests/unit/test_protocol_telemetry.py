"""Telemetry: default PX4-like streams, units of every message, rate control, events and STATUSTEXT chunking."""

from __future__ import annotations

import dataclasses
import math
from collections import Counter

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot.px4_modes import Px4Mode
from sitl.autopilot.vehicle_api import (
    BatteryStatus,
    CommandResult,
    GeoPoint,
    GpsFixType,
    GpsStatus,
    HomePosition,
    LandedState,
    MissionProgress,
    MissionState,
    OrbitStatus,
    OrbitYaw,
    SensorHealth,
    VehicleSnapshot,
)
from sitl.protocol import messages
from sitl.protocol.core import Identity
from sitl.protocol.statustext import StatusTextEncoder
from sitl.protocol.telemetry import DEFAULT_RATES_HZ, TelemetryScheduler
from sitl.protocol.testing import HOME, FakeVehicle, Wire, make_snapshot, of_type

IDENT = Identity(sysid=3)
DOWN = Wire(3, 1)


def run(scheduler: TelemetryScheduler, seconds: float, step_s: float = 0.01, start_s: float = 0.0) -> list:
    out = []
    t = start_s
    while t < start_s + seconds - 1e-9:
        out += DOWN.carry(scheduler.poll(t))
        t += step_s
    return out


def flying() -> VehicleSnapshot:
    yaw = math.radians(135.0)
    return make_snapshot(
        time_boot_us=61_234_567,
        armed=True,
        mode=Px4Mode.AUTO_MISSION,
        landed_state=LandedState.IN_AIR,
        pos_ned_m=(12.0, -3.5, -20.0),
        vel_ned_mps=(1.5, -0.25, -0.5),
        global_position=GeoPoint(lat_deg=47.3978, lon_deg=8.5457, alt_amsl_m=508.25),
        att_q_wxyz=(math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)),
        rates_frd_radps=(0.01, -0.02, 0.03),
        mission=MissionProgress(current_seq=2, total=5, state=MissionState.ACTIVE, reached_seq=1),
        throttle=0.55,
    )


# ---- streams -----------------------------------------------------------------------------------------------
def test_default_streams_come_at_their_rates_in_simulation_time() -> None:
    # GIVEN a vehicle polled at 100 Hz for 10 simulated seconds
    counts = Counter(m.get_type() for m in run(TelemetryScheduler(IDENT, FakeVehicle(flying())), 10.0))
    # THEN each default stream came rate * 10 times (one more for the immediate first send)
    for msg_id, hz in DEFAULT_RATES_HZ.items():
        name = mavlink.mavlink_map[msg_id].msgname
        if name == "SYSTEM_TIME":
            assert counts[name] == 0  # unix time unknown in simulation unless the vehicle provides it
            continue
        if name == "ORBIT_EXECUTION_STATUS":
            assert counts[name] == 0  # only while in Orbit (below)
            continue
        assert abs(counts[name] - hz * 10) <= 1, (name, counts[name])


def test_orbit_execution_status_reports_the_circle_at_px4s_two_hertz_while_in_orbit() -> None:
    # GIVEN a vehicle orbiting 25 m counter-clockwise around a centre at 510 m AMSL
    centre = GeoPoint(lat_deg=47.3979, lon_deg=8.5461, alt_amsl_m=510.0)
    orbiting = dataclasses.replace(
        flying(), mode=Px4Mode.ORBIT, orbit=OrbitStatus(radius_m=-25.0, centre=centre, yaw=OrbitYaw.TANGENT)
    )
    statuses = of_type(run(TelemetryScheduler(IDENT, FakeVehicle(orbiting)), 10.0), "ORBIT_EXECUTION_STATUS")
    # THEN 20 in 10 s, each with the signed radius, the centre in MAV_FRAME_GLOBAL and the altitude
    assert abs(len(statuses) - 20) <= 1
    status = statuses[-1]
    assert (status.radius, status.frame, status.x, status.y) == (-25.0, mavlink.MAV_FRAME_GLOBAL, 473979000, 85461000)
    assert status.z == 510.0 and status.time_usec == orbiting.time_boot_us


def test_heartbeat_is_a_px4_quadrotor() -> None:
    (hb,) = of_type(run(TelemetryScheduler(IDENT, FakeVehicle(flying())), 0.01), "HEARTBEAT")
    assert (hb.type, hb.autopilot, hb.mavlink_version) == (mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 3)
    assert hb.custom_mode == Px4Mode.AUTO_MISSION.custom_mode
    assert hb.base_mode == 1 | 128 | 16 | 8 | 4
    assert hb.system_status == mavlink.MAV_STATE_ACTIVE
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (3, 1)


def test_streams_skip_what_the_vehicle_does_not_know() -> None:
    # GIVEN no attitude, no local or global position and no home yet
    snap = make_snapshot(
        att_q_wxyz=(math.nan,) * 4, pos_ned_m=(math.nan,) * 3, global_position=None, home=None, local_origin=None
    )
    names = {m.get_type() for m in run(TelemetryScheduler(IDENT, FakeVehicle(snap)), 3.0)}
    # THEN those messages are not sent at all (PX4 stays silent too) while the rest is
    assert names.isdisjoint(
        {"ATTITUDE", "ATTITUDE_QUATERNION", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "HOME_POSITION"}
    )
    assert {"HEARTBEAT", "SYS_STATUS", "GPS_RAW_INT", "BATTERY_STATUS", "EXTENDED_SYS_STATE"} <= names


# ---- units -------------------------------------------------------------------------------------------------
def test_global_position_int_units() -> None:
    msg = DOWN(messages.global_position_int(flying(), IDENT))
    assert msg.time_boot_ms == 61234
    assert (msg.lat, msg.lon) == (473978000, 85457000)
    assert msg.alt == 508250  # mm AMSL
    assert msg.relative_alt == 20000  # mm above home
    assert (msg.vx, msg.vy, msg.vz) == (150, -25, -50)  # cm/s
    assert msg.hdg == 13500  # cdeg


def test_local_position_and_attitude() -> None:
    snap = flying()
    lpos = DOWN(messages.local_position_ned(snap, IDENT))
    assert (lpos.x, lpos.y, lpos.z, lpos.vx) == pytest.approx((12.0, -3.5, -20.0, 1.5))
    att = DOWN(messages.attitude(snap, IDENT))
    assert (att.roll, att.pitch) == pytest.approx((0.0, 0.0), abs=1e-6)
    assert att.yaw == pytest.approx(math.radians(135.0), abs=1e-6)
    assert (att.rollspeed, att.pitchspeed, att.yawspeed) == pytest.approx((0.01, -0.02, 0.03))
    quat = DOWN(messages.attitude_quaternion(snap, IDENT))
    assert (quat.q1, quat.q4) == pytest.approx(snap.att_q_wxyz[0::3], abs=1e-6)


def test_gps_raw_int_units_and_unknowns() -> None:
    gps = GpsStatus(
        fix_type=GpsFixType.FIX_3D,
        satellites_visible=14,
        eph_m=0.9,
        epv_m=math.nan,
        position=HOME,
        ground_speed_mps=2.5,
    )
    msg = DOWN(messages.gps_raw_int(make_snapshot(gps=gps), IDENT))
    assert (msg.fix_type, msg.satellites_visible, msg.eph, msg.epv) == (3, 14, 90, 0xFFFF)
    assert (msg.lat, msg.alt, msg.vel, msg.cog) == (473977420, 488000, 250, 0xFFFF)


def test_battery_status_cells_add_up_to_the_pack_voltage() -> None:
    bat = BatteryStatus(voltage_v=12.401, current_a=8.25, remaining=0.731, consumed_mah=1234.4, cell_count=3)
    msg = DOWN(messages.battery_status(make_snapshot(battery=bat), IDENT))
    assert sum(v for v in msg.voltages if v != 0xFFFF) == 12401
    assert msg.voltages[3:] == [0xFFFF] * 7
    assert (msg.current_battery, msg.current_consumed, msg.battery_remaining) == (825, 1234, 73)


def test_sys_status_health_bits_and_armable() -> None:
    snap = make_snapshot(prearm_ok=False, sensors=SensorHealth(healthy=mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO))
    msg = DOWN(messages.sys_status(snap, IDENT))
    assert msg.onboard_control_sensors_present & mavlink.MAV_SYS_STATUS_PREARM_CHECK
    assert not msg.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_PREARM_CHECK
    assert msg.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    assert not msg.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_SENSOR_GPS
    ok = DOWN(messages.sys_status(make_snapshot(), IDENT))
    for bit in (1, 2, 4, 0x20, mavlink.MAV_SYS_STATUS_PREARM_CHECK):  # what MAVSDK's health() needs
        for field in ("present", "enabled", "health"):
            assert getattr(ok, f"onboard_control_sensors_{field}") & bit
    assert ok.voltage_battery == 12400 and ok.battery_remaining == 95


def test_home_position_and_mission_current() -> None:
    snap = make_snapshot(home=HomePosition(position=HOME, pos_ned_m=(1.0, 2.0, 0.5), yaw_rad=math.pi))
    home = DOWN(messages.home_position(snap, IDENT))
    assert (home.latitude, home.longitude, home.altitude) == (473977420, 85455940, 488000)
    assert (home.x, home.y, home.z) == (1.0, 2.0, 0.5)
    assert home.q[3] == pytest.approx(1.0)
    current = DOWN(messages.mission_current(flying(), IDENT))
    assert (current.seq, current.total, current.mission_state, current.mission_mode) == (2, 5, 3, 1)


def test_absurd_values_are_clamped_so_every_message_still_packs() -> None:
    # GIVEN a diverging simulation
    crazy = make_snapshot(
        time_boot_us=2**40,
        pos_ned_m=(1e300, -1e300, 1e40),
        vel_ned_mps=(1e9, -1e9, math.inf),
        global_position=GeoPoint(lat_deg=1e10, lon_deg=-1e10, alt_amsl_m=1e12),
        rates_frd_radps=(1e200, math.nan, -math.inf),
        battery=BatteryStatus(voltage_v=1e9, current_a=-1e9, remaining=7.0, consumed_mah=math.inf, cell_count=99),
        gps=GpsStatus(fix_type=GpsFixType.FIX_3D, satellites_visible=999, eph_m=1e9, epv_m=-5, position=None),
        throttle=1e6,
        cpu_load=-3.0,
    )
    # WHEN every buildable message is built  THEN each survives packing and parsing
    for msg_id, build in messages.BUILDERS.items():
        msg = build(crazy, IDENT)
        if msg is not None:
            assert DOWN(msg).get_msgId() == msg_id


# ---- rate control and requests -----------------------------------------------------------------------------
def test_set_message_interval_changes_off_and_default() -> None:
    scheduler = TelemetryScheduler(IDENT, FakeVehicle(flying()))
    gpi = mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
    assert scheduler.set_message_interval(gpi, 20_000, 0.0) is CommandResult.ACCEPTED  # 50 Hz
    assert len(of_type(run(scheduler, 1.0, step_s=0.005), "GLOBAL_POSITION_INT")) == pytest.approx(50, abs=1)
    scheduler.set_message_interval(gpi, -1, 1.0)
    assert of_type(run(scheduler, 1.0, start_s=1.0), "GLOBAL_POSITION_INT") == []
    scheduler.set_message_interval(gpi, 0, 2.0)
    assert len(of_type(run(scheduler, 1.0, start_s=2.0), "GLOBAL_POSITION_INT")) == pytest.approx(10, abs=1)
    assert scheduler.message_interval_us(gpi) == 100_000


def test_a_message_without_default_stream_can_be_switched_on() -> None:
    scheduler = TelemetryScheduler(IDENT, FakeVehicle(flying()))
    scheduler.set_message_interval(mavlink.MAVLINK_MSG_ID_MISSION_ITEM_REACHED, 500_000, 0.0)
    assert len(of_type(run(scheduler, 2.0), "MISSION_ITEM_REACHED")) >= 4
    assert scheduler.set_message_interval(mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0, 0.0) is CommandResult.ACCEPTED
    assert scheduler.message_interval_us(mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == -1


def test_request_message_for_each_kind() -> None:
    scheduler = TelemetryScheduler(IDENT, FakeVehicle(make_snapshot(home=None)))
    result, effects = scheduler.request_message(mavlink.MAVLINK_MSG_ID_SYS_STATUS, 0.0)
    assert result is CommandResult.ACCEPTED and effects[0].msg.get_type() == "SYS_STATUS"
    assert scheduler.request_message(mavlink.MAVLINK_MSG_ID_HOME_POSITION, 0.0) == (CommandResult.DENIED, [])
    assert scheduler.request_message(999_999, 0.0) == (CommandResult.DENIED, [])


# ---- events ------------------------------------------------------------------------------------------------
def test_state_changes_send_an_extra_heartbeat_at_once_but_not_when_flapping() -> None:
    # GIVEN a running scheduler
    vehicle = FakeVehicle()
    scheduler = TelemetryScheduler(IDENT, vehicle)
    run(scheduler, 0.5)
    # WHEN the vehicle arms  THEN the very next poll carries a HEARTBEAT showing it
    vehicle.update(armed=True)
    (hb,) = of_type(DOWN.carry(scheduler.poll(0.5)), "HEARTBEAT")
    assert hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    # WHEN the mode flaps every poll  THEN extra heartbeats come at most every 50 ms
    beats = 0
    for i in range(20):
        vehicle.update(mode=Px4Mode.OFFBOARD if i % 2 else Px4Mode.AUTO_LOITER)
        beats += len(of_type(DOWN.carry(scheduler.poll(0.51 + i * 0.005)), "HEARTBEAT"))
    assert 1 <= beats <= 3


def test_mission_progress_events() -> None:
    vehicle = FakeVehicle(flying())
    scheduler = TelemetryScheduler(IDENT, vehicle)
    run(scheduler, 0.05)
    vehicle.update(mission=MissionProgress(current_seq=3, total=5, state=MissionState.ACTIVE, reached_seq=2))
    out = DOWN.carry(scheduler.poll(0.06))
    assert [m.seq for m in of_type(out, "MISSION_CURRENT")] == [3]
    assert [m.seq for m in of_type(out, "MISSION_ITEM_REACHED")] == [2]


def test_home_landed_state_events() -> None:
    vehicle = FakeVehicle(make_snapshot(home=None))
    scheduler = TelemetryScheduler(IDENT, vehicle)
    run(scheduler, 0.05)
    vehicle.update(home=make_snapshot().home, landed_state=LandedState.TAKEOFF)
    out = DOWN.carry(scheduler.poll(0.06))
    assert of_type(out, "HOME_POSITION")
    assert [m.landed_state for m in of_type(out, "EXTENDED_SYS_STATE")] == [LandedState.TAKEOFF]


# ---- STATUSTEXT --------------------------------------------------------------------------------------------
def test_short_statustext_is_one_message_with_id_zero() -> None:
    (msg,) = [DOWN(m) for m in StatusTextEncoder().encode(mavlink.MAV_SEVERITY_WARNING, "Low battery")]
    assert (msg.severity, msg.text, msg.id, msg.chunk_seq) == (4, "Low battery", 0, 0)


def test_long_statustext_is_chunked_with_one_id() -> None:
    text = "A" * 50 + "B" * 50 + "C" * 7
    chunks = [DOWN(m) for m in StatusTextEncoder().encode(2, text)]
    assert [c.chunk_seq for c in chunks] == [0, 1, 2]
    assert len({c.id for c in chunks}) == 1 and chunks[0].id != 0
    assert "".join(c.text for c in chunks) == text


def test_text_of_exactly_two_fields_gets_an_empty_terminating_chunk() -> None:
    chunks = [DOWN(m) for m in StatusTextEncoder().encode(6, "x" * 100)]
    assert [c.text for c in chunks] == ["x" * 50, "x" * 50, ""]


def test_huge_text_is_truncated_and_non_ascii_replaced() -> None:
    encoder = StatusTextEncoder()
    chunks = encoder.encode(6, "é" + "y" * 1000)
    text = "".join(DOWN(m).text for m in chunks)
    assert text.startswith("?y") and text.endswith("...") and len(text) == 200
    assert encoder.encode(6, "   ") == []
    assert DOWN(encoder.encode(99, "bad severity")[0]).severity == mavlink.MAV_SEVERITY_INFO


class CountingVehicle(FakeVehicle):
    def __init__(self) -> None:
        super().__init__()
        self.snapshots = 0

    def snapshot(self) -> VehicleSnapshot:
        self.snapshots += 1
        return super().snapshot()


def test_polls_between_due_streams_and_event_checks_cost_no_snapshot() -> None:
    # GIVEN a scheduler streaming only HEARTBEAT at 1 Hz, polled every physics step (400 Hz) for 2 s
    vehicle = CountingVehicle()
    scheduler = TelemetryScheduler(IDENT, vehicle, rates_hz={mavlink.MAVLINK_MSG_ID_HEARTBEAT: 1.0})
    sent = run(scheduler, 2.0, step_s=0.0025)
    # THEN the heartbeats still go out on time, and the vehicle is looked at only for event checks (every 10 ms),
    # not at each of the 800 polls
    assert [m.get_type() for m in sent] == ["HEARTBEAT", "HEARTBEAT"]
    assert vehicle.snapshots <= 2.0 / 0.01 + 2


def test_a_state_change_the_vehicle_makes_itself_goes_out_within_the_event_check_interval() -> None:
    vehicle = FakeVehicle()
    scheduler = TelemetryScheduler(IDENT, vehicle, rates_hz={mavlink.MAVLINK_MSG_ID_HEARTBEAT: 1.0})
    run(scheduler, 0.5, step_s=0.0025)
    vehicle.snap = dataclasses.replace(vehicle.snap, armed=True)
    sent = run(scheduler, 0.0125, step_s=0.0025, start_s=0.5)  # 10 ms and one step
    assert [m.get_type() for m in sent] == ["HEARTBEAT"]
