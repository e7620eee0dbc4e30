"""The shared world table: rows written by one process are seen by another; contacts use both radii."""

from __future__ import annotations

import numpy as np
import pytest

from sitl.dynamics.plant import GeoPoint, PlantState
from sitl.mathutil import vec3
from sitl.world import SharedWorld, WorldParticipant

LAT, LON, ALT = 47.397742, 8.545594, 490.0
M_PER_DEG_LAT = 6_371_000.0 * 3.141592653589793 / 180.0


def test_an_attached_table_sees_rows_written_by_the_creator_and_contacts_need_both_radii() -> None:
    world = SharedWorld.create()
    try:
        other = SharedWorld.attach(world.name)
        # GIVEN two drones 0.6 m apart north-south with collision radii 0.35 m each (contact below 0.7 m)
        world.write(0, 1.0, (LAT, LON, ALT), (0.0, 0.0, 0.0), 0.35, False)
        world.write(1, 1.0, (LAT + 0.6 / M_PER_DEG_LAT, LON, ALT), (0.0, 0.0, 0.0), 0.35, False)
        # THEN each sees the other, from either handle
        ids, offsets = other.others_ned_m(0)
        assert list(ids) == [1] and abs(offsets[0][0] - 0.6) < 1e-6
        contacts = other.contacts(1)
        assert [c.instance for c in contacts] == [0] and abs(contacts[0].distance_m - 0.6) < 1e-6
        # WHEN one moves to 0.8 m THEN there is no contact
        world.write(1, 1.1, (LAT + 0.8 / M_PER_DEG_LAT, LON, ALT), (0.0, 0.0, 0.0), 0.35, False)
        assert other.contacts(0) == []
        other.close()
    finally:
        world.close()


def _truth(time_s: float, alt_amsl_m: float) -> PlantState:
    zero = vec3(0.0, 0.0, 0.0)
    return PlantState(time_s=time_s, pos_ned_m=zero, vel_ned_mps=zero, att_q_frd_to_ned=np.array([1.0, 0.0, 0.0, 0.0]),
                      rates_frd_radps=zero, specific_force_frd_mps2=zero,
                      geo=GeoPoint(lat_deg=LAT, lon_deg=LON, alt_amsl_m=alt_amsl_m), on_ground=False,
                      motor_speeds_radps=(0.0,) * 4)  # fmt: skip


def test_a_participant_publishes_every_n_steps_and_reports_no_contact_once_crashed() -> None:
    world = SharedWorld.create()
    try:
        world.write(1, 0.0, (LAT, LON, ALT), (0.0, 0.0, 0.0), 0.35, False)
        participant = WorldParticipant(SharedWorld.attach(world.name), 0, 0.35, every_n_steps=4)
        results = [participant.after_step(_truth(0.01 * k, ALT + 0.2), crashed=False) for k in range(8)]
        assert [len(r) for r in results] == [0, 0, 0, 1, 0, 0, 0, 1]
        assert world.table[0, 1] == pytest.approx(0.07)  # published on the steps it checks
        assert participant.update(0.1, (LAT, LON, ALT), (0.0, 0.0, 0.0), True) == []
        participant.close()
        assert world.table[0, 0] == 0.0  # its row is cleared when it leaves
    finally:
        world.close()


def test_declared_obstacles_are_seen_from_each_drone_and_touching_one_is_a_contact() -> None:
    world = SharedWorld.create()
    try:
        # GIVEN a pole 0.25 m thick and 8 m tall 1 m north of a drone at 3 m, and a 1 m ball 10 m up
        world.write(0, 1.0, (LAT, LON, ALT + 3.0), (0.0, 0.0, 0.0), 0.35, False)
        world.add_obstacle(cylinder=True, centre=(LAT + 1.0 / M_PER_DEG_LAT, LON, ALT + 4.0), radius_m=0.25,
                           height_m=8.0)  # fmt: skip
        world.add_obstacle(cylinder=False, centre=(LAT, LON, ALT + 13.0), radius_m=1.0)
        pole, ball = world.obstacles_from(0)
        assert pole.cylinder and abs(pole.offset_ned_m[0] - 1.0) < 1e-6 and abs(pole.offset_ned_m[2] + 1.0) < 1e-6
        assert not ball.cylinder and abs(ball.offset_ned_m[2] + 10.0) < 1e-6
        assert world.contacts(0) == []  # 0.75 m from the pole's surface, 9 m below the ball's
        # WHEN the drone drifts to 0.5 m from the pole's axis THEN it touches it (0.25 + 0.35 > 0.5)
        world.write(0, 1.1, (LAT + 0.5 / M_PER_DEG_LAT, LON, ALT + 3.0), (0.0, 0.0, 0.0), 0.35, False)
        (contact,) = world.contacts(0)
        assert contact.obstacle == 0 and contact.text().startswith("Collision with obstacle 1 at 0.25 m")
        # AND above the pole's top (8 m + radius) there is nothing to touch
        world.write(0, 1.2, (LAT + 0.5 / M_PER_DEG_LAT, LON, ALT + 8.5), (0.0, 0.0, 0.0), 0.35, False)
        assert world.contacts(0) == []
    finally:
        world.close()
