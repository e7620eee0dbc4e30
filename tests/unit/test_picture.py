"""The swarm-frame picture (gcs/fleet/picture.py): the one conversion of every vehicle's report into the swarm
frame, kept current as each message arrives, and what its readers get from it."""

from __future__ import annotations

import math
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink

from gcs.fleet.picture import SwarmPicture
from gcs.fleet.telemetry import Fleet
from gcs.flight.frames import SwarmFrame, origin_from_home
from gcs.flight.geodesy import DEFAULT_ORIGIN, GeoPoint
from tests.unit.test_gcs_core import decoded, heartbeat

pytestmark = pytest.mark.timeout(30)

HOME = GeoPoint(lat_deg=DEFAULT_ORIGIN.lat_deg + 1e-4, lon_deg=DEFAULT_ORIGIN.lon_deg - 2e-4,
                alt_amsl_m=DEFAULT_ORIGIN.alt_amsl_m + 1.0)  # fmt: skip


def _home(home: GeoPoint, local_ned_m: tuple[float, float, float]) -> Any:
    lat, lon, alt = round(home.lat_deg * 1e7), round(home.lon_deg * 1e7), round(home.alt_amsl_m * 1e3)
    return mavlink.MAVLink_home_position_message(lat, lon, alt, *local_ned_m, [1, 0, 0, 0], 0, 0, 0)


def _local(pos: tuple[float, float, float], vel: tuple[float, float, float]) -> Any:
    return mavlink.MAVLink_local_position_ned_message(0, *pos, *vel)


class _Swarm:
    """A fleet view and its picture, fed as the pump feeds them: the fleet view first, then the picture."""

    def __init__(self, attached: set[int]) -> None:
        self.fleet = Fleet()
        self.frame = SwarmFrame(DEFAULT_ORIGIN)
        self.picture = SwarmPicture(self.frame, self.fleet, attached)

    def feed(self, msg: Any, sysid: int) -> None:
        message = decoded(msg, sysid)
        self.fleet.handle(message, 0.0)
        self.picture.observe(message)


def test_a_drone_is_placed_through_the_frame_of_its_first_home_and_kept_there_when_home_moves() -> None:
    swarm = _Swarm(attached=set())
    swarm.feed(heartbeat(393216, armed=True), 3)
    swarm.feed(_local((1.0, 2.0, -3.0), (0.5, 0.0, 0.0)), 3)
    assert swarm.picture.placed(3) is None  # no home yet: no frame to convert with
    swarm.feed(_home(HOME, (0.2, -0.1, 0.0)), 3)
    swarm.feed(_local((1.0, 2.0, -3.0), (0.5, 0.0, 0.0)), 3)
    view = swarm.fleet.drones[3]
    assert view.home is not None and view.home_local_ned_m is not None
    first_home = GeoPoint(lat_deg=view.home[0], lon_deg=view.home[1], alt_amsl_m=view.home[2])
    frame = swarm.frame.drone_frame(origin_from_home(first_home, view.home_local_ned_m))
    placed = swarm.picture.placed(3)
    assert placed is not None
    assert placed.pos_ned_m == frame.to_swarm((1.0, 2.0, -3.0))  # the same conversion, to the bit
    assert placed.vel_ned_mps == frame.vector_to_swarm((0.5, 0.0, 0.0))
    # WHEN it arms and PX4 moves home to where it stands: its local origin does not move, nor does its frame
    swarm.feed(_home(GeoPoint(lat_deg=HOME.lat_deg + 1e-5, lon_deg=HOME.lon_deg, alt_amsl_m=HOME.alt_amsl_m),
                     (1.1, 2.0, 0.0)), 3)  # fmt: skip
    swarm.feed(_local((4.0, 2.0, -3.0), (0.0, 0.0, 0.0)), 3)
    placed = swarm.picture.placed(3)
    assert placed is not None and placed.pos_ned_m == frame.to_swarm((4.0, 2.0, -3.0))
    assert view.home_local_ned_m == pytest.approx((1.1, 2.0, 0.0))  # (float32 on the wire)
    assert swarm.picture.home(3) == frame.to_swarm(view.home_local_ned_m)
    assert swarm.picture.positions([3, 9]) == {3: placed.pos_ned_m}


def test_an_attached_vehicle_is_placed_where_it_says_it_is_and_a_report_s_velocity_is_its_latest() -> None:
    swarm = _Swarm(attached={200})
    swarm.feed(heartbeat(0, armed=True), 200)
    here = GeoPoint(lat_deg=DEFAULT_ORIGIN.lat_deg + 2e-4, lon_deg=DEFAULT_ORIGIN.lon_deg, alt_amsl_m=500.0)
    swarm.feed(mavlink.MAVLink_global_position_int_message(0, round(here.lat_deg * 1e7), round(here.lon_deg * 1e7),
                                                           500000, 4000, 120, -30, 10, 0), 200)  # fmt: skip
    placed = swarm.picture.placed(200)
    view = swarm.fleet.drones[200]
    assert placed is not None
    assert placed.pos_ned_m == swarm.frame.ned_from_geo(GeoPoint(lat_deg=view.lat_deg, lon_deg=view.lon_deg,
                                                                 alt_amsl_m=view.alt_amsl_m))  # fmt: skip
    assert placed.vel_ned_mps == pytest.approx((1.2, -0.3, 0.1))
    state = swarm.picture.state([200])
    assert state.sysids == (200,) and tuple(state.pos_ned_m[0]) == placed.pos_ned_m


def test_a_flight_law_starts_only_from_armed_vehicles_that_said_how_they_move() -> None:
    swarm = _Swarm(attached=set())
    for sysid, armed in ((1, True), (2, False), (3, True)):
        swarm.feed(heartbeat(393216, armed=armed), sysid)
        swarm.feed(_home(HOME, (0.0, 0.0, 0.0)), sysid)
        swarm.feed(_local((float(sysid), 0.0, -2.0), (0.0, 0.0, 0.0) if sysid != 3 else (math.nan,) * 3), sysid)
    assert set(swarm.picture.positions([1, 2, 3])) == {1, 2, 3}
    assert swarm.picture.state([1, 2, 3]).sysids == (1,)  # 2 is not armed; 3 has not said how it moves
