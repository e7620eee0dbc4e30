"""PX4's Orbit flown for real: a pymavlink-encoded MAV_CMD_DO_ORBIT through the drone's own MAVLink services.

Policy: a ClosedLoop stepped directly (JSBSim, sensor noise on), its link's services (``LinkServices``) fed
COMMAND_LONG and COMMAND_INT frames that pymavlink packed and parsed (``Wire``), its telemetry read back the same
way, as a ground station reads it. Lockstep by construction (no sockets, no wall clock): the pace of a paced drone
would prove nothing here. Ground truth only checks where the drone really flew.

Cost: under a second (0.65 s and 0.25 s on the machine they were written on) for about 60 s and 25 s of simulated
flight: takeoff, approach, two laps and the hold; takeoff and a counter-clockwise circle.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot.px4_modes import Px4Mode
from sitl.drone.sim_vehicle_api import SimVehicleApi
from sitl.protocol import Identity, LinkServices
from sitl.protocol.core import MAVLinkMessage
from sitl.protocol.testing import Wire, of_type
from tests.closed_loop.flight import boot_position, make_sim, take_off

pytestmark = pytest.mark.timeout(120)

SYSID = 1
POLL_STEPS = 8  # sitl/process/runtime.py PACED_WAKE_STEPS
RADIUS_M = 8.0
SPEED_MPS = 3.0
ALT_M = 6.0  # above the boot position (home is set there on arming)
CENTRE_N_M, CENTRE_E_M = 5.0, -4.0
RADIUS_TOL_M = 0.5


class Station:
    """A ground station's end of the drone's link: commands out through the wire, every reply parsed back."""

    def __init__(self, seed: int) -> None:
        self.sim = make_sim(seed=seed)
        self.api = SimVehicleApi(self.sim)
        self.link = LinkServices(Identity(sysid=SYSID), self.api, self.sim.params)
        self.up = Wire()  # station -> drone
        self.down = Wire(src_sysid=SYSID, src_compid=1)  # drone -> station
        self.heard: list[MAVLinkMessage] = []

    def send(self, msg: MAVLinkMessage) -> list[MAVLinkMessage]:
        replies = self.down.carry(self.link.handle(self.up(msg), self.sim.time_s))
        self.heard.extend(replies)
        return replies

    def command_long(self, command: int, *params: float) -> MAVLinkMessage:
        p = (*params, *(0.0,) * (7 - len(params)))  # pymavlink fills what it is not given with 0
        ack = of_type(self.send(mavlink.MAVLink_command_long_message(SYSID, 0, command, 0, *p)), "COMMAND_ACK")
        assert len(ack) == 1, ack
        return ack[0]

    def fly(self, seconds: float) -> None:
        """Step the drone, polling its link as the drone's loop does."""
        end = self.sim.time_s + seconds
        while self.sim.time_s < end:
            for _ in range(POLL_STEPS):
                self.sim.step()
            self.heard.extend(self.down.carry(self.link.poll(self.sim.time_s)))

    def last(self, name: str) -> MAVLinkMessage:
        return of_type(self.heard, name)[-1]

    def true_ne_m(self, home: np.ndarray) -> np.ndarray:
        return (self.sim.truth.pos_ned_m - home)[:2]


def hovering(*, seed: int, alt_m: float) -> tuple[Station, np.ndarray]:
    """A drone taken off to ``alt_m`` and settled for a second; its boot position (NED) beside it."""
    station = Station(seed=seed)
    home = boot_position(station.sim)
    take_off(station.sim, alt_m)
    station.fly(1.0)
    return station, home


def test_do_orbit_circles_the_centre_at_the_radius_reports_orbit_and_leaves_it_for_hold() -> None:
    station, home = hovering(seed=34, alt_m=3.0)
    sim = station.sim

    # WHEN a pymavlink script sends DO_ORBIT: radius 8 m clockwise, 3 m/s, facing the centre, at a centre given in
    # lat/lon and an AMSL altitude
    centre = station.api.frame.geo_from_ned((home[0] + CENTRE_N_M, home[1] + CENTRE_E_M, home[2] - ALT_M))
    ack = station.command_long(
        mavlink.MAV_CMD_DO_ORBIT,
        RADIUS_M,
        SPEED_MPS,
        mavlink.ORBIT_YAW_BEHAVIOUR_HOLD_FRONT_TO_CIRCLE_CENTER,
        0.0,
        centre.lat_deg,
        centre.lon_deg,
        centre.alt_amsl_m,
    )
    # THEN it is accepted and the heartbeat sent at once shows Orbit: POSCTL with sub mode ORBIT
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED, ack
    station.fly(0.1)
    hb = station.last("HEARTBEAT")
    assert hb.custom_mode == Px4Mode.ORBIT.custom_mode == 3 << 16 | 1 << 24, hb
    assert hb.base_mode & mavlink.MAV_MODE_FLAG_GUIDED_ENABLED, hb

    # AND after the approach the drone circles the centre at the radius and altitude, clockwise, nose to the centre
    station.fly(12.0)
    centre_ne = np.array([CENTRE_N_M, CENTRE_E_M])
    radii, angles, heading_errors = [], [], []
    lap_s = 2 * math.pi * RADIUS_M / SPEED_MPS
    end = sim.time_s + 2 * lap_s
    while sim.time_s < end:
        station.fly(0.2)
        offset = station.true_ne_m(home) - centre_ne
        radii.append(math.hypot(*offset))
        angles.append(math.atan2(offset[1], offset[0]))
        assert abs(sim.altitude_above_start_m() - ALT_M) < 0.5, sim.altitude_above_start_m()
        est = sim.vehicle.estimate
        assert est is not None
        facing = math.atan2(-offset[1], -offset[0])
        heading_errors.append(abs(math.remainder(est.yaw_rad - facing, math.tau)))
    assert max(abs(r - RADIUS_M) for r in radii) < RADIUS_TOL_M, (min(radii), max(radii))
    swept = np.unwrap(angles)
    assert swept[-1] - swept[0] > 1.8 * 2 * math.pi  # clockwise seen from above: the bearing grows
    assert max(heading_errors) < math.radians(10), math.degrees(max(heading_errors))
    # AND ORBIT_EXECUTION_STATUS reports the circle (signed radius, centre, altitude), at PX4's 2 Hz
    statuses = of_type(station.heard, "ORBIT_EXECUTION_STATUS")
    assert len(statuses) >= 2 * (12 + 2 * lap_s) * 0.9, len(statuses)
    status = statuses[-1]
    assert status.radius == pytest.approx(RADIUS_M) and status.frame == mavlink.MAV_FRAME_GLOBAL
    # COMMAND_LONG carries lat/lon as float32: at 47 degrees, 38e-7 degrees (0.4 m) from one value to the next
    assert abs(status.x - centre.lat_deg * 1e7) < 40 and abs(status.y - centre.lon_deg * 1e7) < 40, status
    assert status.z == pytest.approx(centre.alt_amsl_m, abs=0.01)

    # WHEN the script asks for Hold (pymavlink's set_mode('LOITER'): DO_SET_MODE main 4, sub 3)
    ack = station.command_long(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 3)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED, ack
    heard_before = len(station.heard)
    station.fly(6.0)
    # THEN the drone stops where it was (within its braking distance) and holds, and the status stops
    assert station.last("HEARTBEAT").custom_mode == Px4Mode.AUTO_LOITER.custom_mode
    assert not of_type(station.heard[heard_before:], "ORBIT_EXECUTION_STATUS")
    held = station.true_ne_m(home)
    station.fly(3.0)
    assert float(np.hypot(*(station.true_ne_m(home) - held))) < 0.3
    assert float(np.hypot(*(held - centre_ne))) < RADIUS_M + SPEED_MPS**2 / (2 * sim.params["MPC_ACC_HOR"]) + 1.0


def test_do_orbit_as_mavsdk_sends_it_counter_clockwise_around_where_the_drone_is() -> None:
    station, home = hovering(seed=35, alt_m=4.0)
    sim = station.sim
    start_ne = station.true_ne_m(home)

    # WHEN MAVSDK's do_orbit(-5 m, 2 m/s, yaw unchanged, centre not given) arrives: COMMAND_INT, frame
    # GLOBAL_RELATIVE_ALT, x/y INT32_MAX, z NaN
    nan = math.nan
    msg = mavlink.MAVLink_command_int_message(
        SYSID, 1, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_CMD_DO_ORBIT, 0, 0,
        -5.0, 2.0, mavlink.ORBIT_YAW_BEHAVIOUR_UNCHANGED, nan, 2**31 - 1, 2**31 - 1, nan,
    )  # fmt: skip
    acks = of_type(station.send(msg), "COMMAND_ACK")
    assert [a.result for a in acks] == [mavlink.MAV_RESULT_ACCEPTED], acks
    # THEN it circles counter-clockwise around where it was, at its altitude
    station.fly(10.0)
    angles = []
    for _ in range(40):
        station.fly(0.25)
        offset = station.true_ne_m(home) - start_ne
        assert abs(math.hypot(*offset) - 5.0) < RADIUS_TOL_M, offset
        assert abs(sim.altitude_above_start_m() - 4.0) < 0.5
        angles.append(math.atan2(offset[1], offset[0]))
    swept = np.unwrap(angles)
    assert swept[-1] - swept[0] < -0.8 * 10.0 * 2.0 / 5.0  # 10 s at 2 m/s on 5 m: 4 rad, bearing falling
    assert station.last("ORBIT_EXECUTION_STATUS").radius == pytest.approx(-5.0)


def test_do_orbit_is_refused_on_the_ground_and_beyond_mc_orbit_rad_max_and_a_mode_switch_enters_px4s_default() -> None:
    station = Station(seed=36)
    sim = station.sim
    assert sim.run_until(lambda s: s.vehicle.preflight_problem() is None, 10.0)

    def refused(radius_m: float) -> tuple[int, list[str]]:
        before = len(station.heard)
        ack = station.command_long(mavlink.MAV_CMD_DO_ORBIT, radius_m, 2.0)
        return ack.result, [t.text for t in of_type(station.heard[before:], "STATUSTEXT")]

    # Disarmed, then armed on the ground: PX4's answer to a mode it cannot enter, and why
    not_flying = (mavlink.MAV_RESULT_TEMPORARILY_REJECTED, ["Orbit command rejected: not flying"])
    assert refused(10.0) == not_flying
    assert sim.vehicle.arm().ok
    assert refused(10.0) == not_flying
    assert sim.vehicle.takeoff(3.0).ok
    assert sim.run_until(lambda s: s.vehicle.status.mode is Px4Mode.AUTO_LOITER, 15.0)
    # Flying: a radius beyond MC_ORBIT_RAD_MAX (1000 m, then lowered to 10 m) is DENIED and nothing changes
    assert refused(1500.0) == (mavlink.MAV_RESULT_DENIED, ["Orbit radius limit exceeded"])
    set_max = mavlink.MAVLink_param_set_message(SYSID, 1, b"MC_ORBIT_RAD_MAX", 10.0, mavlink.MAV_PARAM_TYPE_REAL32)
    assert [m.param_value for m in of_type(station.send(set_max), "PARAM_VALUE")] == [10.0]
    assert refused(-12.0) == (mavlink.MAV_RESULT_DENIED, ["Orbit radius limit exceeded"])
    assert sim.vehicle.status.mode is Px4Mode.AUTO_LOITER
    # A mode switch to Orbit (DO_SET_MODE main POSCTL, sub ORBIT) flies PX4's default: 1 m around where it is
    ack = station.command_long(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 3, 1)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
    station.fly(8.0)
    assert station.last("HEARTBEAT").custom_mode == Px4Mode.ORBIT.custom_mode
    assert station.last("ORBIT_EXECUTION_STATUS").radius == pytest.approx(1.0)
    # AND a Land request ends it like any other mode
    assert station.command_long(mavlink.MAV_CMD_NAV_LAND).result == mavlink.MAV_RESULT_ACCEPTED
    assert sim.vehicle.status.mode is Px4Mode.AUTO_LAND
