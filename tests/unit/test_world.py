"""The shared world table: rows written by one process are seen by another; contacts use both radii."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sitl.dynamics.plant import GeoPoint, PlantState
from sitl.mathutil import GRAVITY_MPS2, vec3
from sitl.world.lockstep import LockstepGate, LockstepMember
from sitl.world.shared import RADIUS, STEP, SharedWorld, lockstep_epoch_steps
from sitl.world.view import WorldParticipant, contacts, others_ned_m

LAT, LON, ALT = 47.397742, 8.545594, 490.0
M_PER_DEG_LAT = 6_371_000.0 * 3.141592653589793 / 180.0


def test_an_attached_table_sees_rows_written_by_the_creator_and_contacts_need_both_radii() -> None:
    world = SharedWorld.create()
    try:
        other = SharedWorld.attach(world.name)
        # GIVEN two drones 0.6 m apart north-south with collision radii 0.35 m each (contact below 0.7 m)
        world.write(0, 1.0, (LAT, LON, ALT), (0.0, 0.0, 0.0), 0.35, False, rest_alt_amsl_m=ALT)
        world.write(1, 1.0, (LAT + 0.6 / M_PER_DEG_LAT, LON, ALT), (0.0, 0.0, 0.0), 0.35, False, rest_alt_amsl_m=ALT)
        # THEN each sees the other, from either handle
        ids, offsets = others_ned_m(other, 0)
        assert list(ids) == [1] and abs(offsets[0][0] - 0.6) < 1e-6
        found = contacts(other, 1)
        assert [c.instance for c in found] == [0] and abs(found[0].distance_m - 0.6) < 1e-6
        # WHEN one moves to 0.8 m THEN there is no contact
        world.write(1, 1.1, (LAT + 0.8 / M_PER_DEG_LAT, LON, ALT), (0.0, 0.0, 0.0), 0.35, False, rest_alt_amsl_m=ALT)
        assert contacts(other, 0) == []
        other.close()
    finally:
        world.close()


def test_contacts_in_a_crowd_are_every_body_within_both_radii_measured_in_one_fixed_order() -> None:
    world = SharedWorld.create()
    try:
        # GIVEN 60 bodies of different sizes scattered within a metre or two of each other, one of them ended and fallen
        rng = np.random.default_rng(11)
        for i in range(60):
            north, east, up = rng.uniform(-1.0, 1.0, 3)
            world.write(i, 1.0, (LAT + north / M_PER_DEG_LAT, LON + east / M_PER_DEG_LAT, ALT + 3.0 + up),
                        (0.0, 0.0, 0.0), float(rng.uniform(0.2, 0.6)), False, rest_alt_amsl_m=ALT)  # fmt: skip
        for me in (0, 7, 59):
            # WHEN a drone looks for contacts THEN it finds exactly the bodies closer than both radii, their centre
            # distances with the squares added as (n^2 + d^2) + e^2
            ids, offsets = others_ned_m(world, me)
            radius = world.table[:, RADIUS]
            expected = []
            for i, (n, e, d) in zip(ids, offsets.tolist(), strict=True):
                distance = math.sqrt((n * n + d * d) + e * e)
                if distance < radius[i] + radius[me]:
                    expected.append((int(i), distance))
            found = [(c.instance, c.distance_m) for c in contacts(world, me)]
            assert found == expected and len(found) > 3
        # AND with a body that has ended (its fall worked out in numpy) the same rule holds
        world.mark_ended(30, 1.0)
        ids, offsets = others_ned_m(world, 0)
        radius = world.table[:, RADIUS]
        lengths = [math.sqrt((n * n + d * d) + e * e) for n, e, d in offsets.tolist()]
        expected = [(int(i), x) for i, x in zip(ids, lengths, strict=True) if x < radius[i] + radius[0]]
        assert [(c.instance, c.distance_m) for c in contacts(world, 0)] == expected
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
        world.write(1, 0.0, (LAT, LON, ALT), (0.0, 0.0, 0.0), 0.35, False, rest_alt_amsl_m=ALT)
        participant = WorldParticipant(SharedWorld.attach(world.name), 0, 0.35, rest_alt_amsl_m=ALT, every_n_steps=4)
        results = [participant.after_step(_truth(0.01 * k, ALT + 0.2), crashed=False) for k in range(8)]
        assert [len(r) for r in results] == [0, 0, 0, 1, 0, 0, 0, 1]
        assert world.table[0, 1] == pytest.approx(0.07)  # published on the steps it checks
        assert participant.update(0.1, (LAT, LON, ALT), (0.0, 0.0, 0.0), True) == []
        participant.close()
        # when it leaves, its body stays behind (and would fall if it were in the air)
        assert world.ended(0) and world.body_geo(0, 1.0) == pytest.approx((LAT, LON, ALT))
    finally:
        world.close()


def test_declared_obstacles_are_seen_from_each_drone_and_touching_one_is_a_contact() -> None:
    world = SharedWorld.create()
    try:
        # GIVEN a pole 0.25 m thick and 8 m tall 1 m north of a drone at 3 m, and a 1 m ball 10 m up
        world.write(0, 1.0, (LAT, LON, ALT + 3.0), (0.0, 0.0, 0.0), 0.35, False, rest_alt_amsl_m=ALT)
        world.add_obstacle(cylinder=True, centre=(LAT + 1.0 / M_PER_DEG_LAT, LON, ALT + 4.0), radius_m=0.25,
                           height_m=8.0)  # fmt: skip
        world.add_obstacle(cylinder=False, centre=(LAT, LON, ALT + 13.0), radius_m=1.0)
        pole, ball = world.obstacles_from(0)
        assert pole.cylinder and abs(pole.offset_ned_m[0] - 1.0) < 1e-6 and abs(pole.offset_ned_m[2] + 1.0) < 1e-6
        assert not ball.cylinder and abs(ball.offset_ned_m[2] + 10.0) < 1e-6
        assert contacts(world, 0) == []  # 0.75 m from the pole's surface, 9 m below the ball's
        # WHEN the drone drifts to 0.5 m from the pole's axis THEN it touches it (0.25 + 0.35 > 0.5)
        world.write(
            0, 1.1, (LAT + 0.5 / M_PER_DEG_LAT, LON, ALT + 3.0), (0.0, 0.0, 0.0), 0.35, False, rest_alt_amsl_m=ALT
        )
        (contact,) = contacts(world, 0)
        assert contact.obstacle == 0 and contact.text().startswith("Collision with obstacle 1 at 0.25 m")
        # AND above the pole's top (8 m + radius) there is nothing to touch
        world.write(
            0, 1.2, (LAT + 0.5 / M_PER_DEG_LAT, LON, ALT + 8.5), (0.0, 0.0, 0.0), 0.35, False, rest_alt_amsl_m=ALT
        )
        assert contacts(world, 0) == []
    finally:
        world.close()


def test_an_ended_body_falls_3_m_in_0_78_s_and_then_lies_on_the_ground() -> None:
    world = SharedWorld.create()
    try:
        # GIVEN a drone hovering 3 m above where it rests, last written at t = 10 s, then its process ends
        world.write(0, 10.0, (LAT, LON, ALT + 3.0), (0.0, 0.0, 0.0), 0.35, False, rest_alt_amsl_m=ALT)
        assert not world.ended(0)
        world.mark_ended(0)
        assert world.ended(0)
        fall_s = math.sqrt(2.0 * 3.0 / GRAVITY_MPS2)
        assert fall_s == pytest.approx(0.782, abs=1e-3)
        # THEN it is where it was at the last write, free-falls, and lands at 0.78 s
        assert world.body_geo(0, 10.0) == pytest.approx((LAT, LON, ALT + 3.0))
        assert world.body_geo(0, 9.0) == pytest.approx((LAT, LON, ALT + 3.0))  # a reader whose clock lags
        _, _, alt_half = world.body_geo(0, 10.5)  # type: ignore[misc]
        assert alt_half == pytest.approx(ALT + 3.0 - 0.5 * GRAVITY_MPS2 * 0.25)
        _, _, alt_before = world.body_geo(0, 10.0 + fall_s - 0.01)  # type: ignore[misc]
        assert alt_before > ALT + 0.05
        # AND stays on the ground
        for t in (10.0 + fall_s, 11.0, 100.0, math.inf):
            assert world.body_geo(0, t) == pytest.approx((LAT, LON, ALT), abs=1e-9)
    finally:
        world.close()


def test_a_moving_body_carries_its_velocity_until_it_lands_and_an_unwritten_row_has_none() -> None:
    world = SharedWorld.create()
    try:
        # GIVEN a drone 3 m up flying 2 m/s north and climbing at 1 m/s when its process ends
        world.write(4, 5.0, (LAT, LON, ALT + 3.0), (2.0, 0.0, -1.0), 0.35, False, rest_alt_amsl_m=ALT)
        world.mark_ended(4)
        landing_s = (1.0 + math.sqrt(1.0 + 2.0 * GRAVITY_MPS2 * 3.0)) / GRAVITY_MPS2  # up, then down
        lat, lon, alt = world.body_geo(4, math.inf)  # type: ignore[misc]
        # THEN it comes down 2 m/s * landing time further north, on the ground
        assert (lat - LAT) * M_PER_DEG_LAT == pytest.approx(2.0 * landing_s, abs=1e-6)
        assert lon == pytest.approx(LON) and alt == pytest.approx(ALT, abs=1e-9)
        # AND a row never written has no body, even if marked ended
        world.mark_ended(5)
        assert world.body_geo(5, 1.0) is None and not world.ended(5)
        # AND a live drone reusing the row is live again
        world.write(4, 6.0, (LAT, LON, ALT + 1.0), (0.0, 0.0, 0.0), 0.35, False, rest_alt_amsl_m=ALT)
        assert not world.ended(4) and world.body_geo(4, 50.0) == pytest.approx((LAT, LON, ALT + 1.0))
    finally:
        world.close()


def test_a_falling_body_is_a_contact_where_it_is_at_the_readers_time_and_frees_lockstep() -> None:
    world = SharedWorld.create()
    try:
        # GIVEN drone 1 hovering 1.5 m up, and drone 0 directly above it at 4.5 m when drone 0's process ends
        world.write(0, 2.0, (LAT, LON, ALT + 4.5), (0.0, 0.0, 0.0), 0.35, False, rest_alt_amsl_m=ALT)
        world.table[0, STEP] = 500.0  # a lockstep member
        world.write(1, 2.0, (LAT, LON, ALT + 1.5), (0.0, 0.0, 0.0), 0.35, False, rest_alt_amsl_m=ALT)
        world.mark_ended(0)
        assert world.table[0, STEP] == math.inf  # it holds no lockstep member back
        # THEN at drone 1's time 2.0 s the body is 3 m above it, no contact
        assert contacts(world, 1) == []
        ids, offsets = others_ned_m(world, 1)
        assert list(ids) == [0] and offsets[0][2] == pytest.approx(-3.0)
        # WHEN drone 1's clock reaches 2.7 s the body has fallen 2.4 m: 0.6 m above it, closer than 0.7 m: contact
        world.write(1, 2.7, (LAT, LON, ALT + 1.5), (0.0, 0.0, 0.0), 0.35, False, rest_alt_amsl_m=ALT)
        (contact,) = contacts(world, 1)
        assert contact.instance == 0 and contact.distance_m == pytest.approx(3.0 - 0.5 * GRAVITY_MPS2 * 0.49)
        # AND a drone 1 m beside where it lies touches nothing once it is down
        world.write(1, 9.0, (LAT + 1.0 / M_PER_DEG_LAT, LON, ALT), (0.0, 0.0, 0.0), 0.35, False, rest_alt_amsl_m=ALT)
        assert contacts(world, 1) == []
        ids, offsets = others_ned_m(world, 1)
        assert offsets[0] == pytest.approx((-1.0, 0.0, 0.0), abs=1e-6)
    finally:
        world.close()


def test_a_member_that_ended_holds_no_lockstep_member_back() -> None:
    world = SharedWorld.create()
    try:
        gate = LockstepGate(world, 0.004)
        alive, dead = LockstepMember(world, 0), LockstepMember(world, 1)
        alive.join()
        dead.join()
        gate.open_until(1.0)
        # GIVEN both at step 10, and the dead one's row written (it has a body)
        for k in range(1, 11):
            alive.completed(k)
            dead.completed(k)
        world.write(1, 0.04, (LAT, LON, ALT + 3.0), (0.0, 0.0, 0.0), 0.35, False, rest_alt_amsl_m=ALT)
        alive.completed(11)
        assert alive.steps_allowed(11) == (0, False)  # one step ahead of the other: waits for it
        # WHEN the dead member's process is gone and its row marked ended (it never left)
        world.mark_ended(1)
        # THEN the survivor may go on (a step at a time past its own count, as any lone member), and the gate's
        # clock follows the survivor alone
        assert alive.steps_allowed(11) == (1, False)
        assert gate.completed_steps() == 11 and gate.members() == 1
        for m in (alive, dead):
            m.leave()
        gate.close()
    finally:
        world.close()


def _north_truth(time_s: float, north_m: float) -> PlantState:
    state = _truth(time_s, ALT + 3.0)
    geo = GeoPoint(lat_deg=LAT + north_m / M_PER_DEG_LAT, lon_deg=LON, alt_amsl_m=ALT + 3.0)
    return dataclasses.replace(state, geo=geo)


def test_in_lockstep_a_drone_sees_the_others_as_they_were_at_the_end_of_the_last_epoch() -> None:
    world = SharedWorld.create()
    try:
        # GIVEN two lockstep drones with epochs of 4 steps; drone 1 stands 0.5 m north of where drone 0 hovers
        a = WorldParticipant(SharedWorld.attach(world.name), 0, 0.35, rest_alt_amsl_m=ALT, epoch_steps=4)
        b = WorldParticipant(SharedWorld.attach(world.name), 1, 0.35, rest_alt_amsl_m=ALT, epoch_steps=4)
        for k in range(1, 5):  # epoch 0: both publish at its last step
            b.after_step(_north_truth(0.004 * k, 0.5), crashed=False)
            assert a.after_step(_north_truth(0.004 * k, 0.0), crashed=False) == []
        # WHEN drone 1 runs a step ahead into the next epoch and moves 3 m away
        b.after_step(_north_truth(0.020, 3.0), crashed=False)
        b.world.write(1, 0.020, (LAT + 3.0 / M_PER_DEG_LAT, LON, ALT + 3.0), (0.0, 0.0, 0.0), 0.35, False,
                      rest_alt_amsl_m=ALT)  # fmt: skip
        # THEN drone 0's first step of the epoch still sees it where it was at the epoch's end, touching (0.5 m)
        (contact,) = a.after_step(_north_truth(0.020, 0.0), crashed=False)
        assert contact.instance == 1 and contact.distance_m == pytest.approx(0.5, abs=1e-6)
        ids, offsets = others_ned_m(a.world, 0)
        assert list(ids) == [1] and offsets[0][0] == pytest.approx(0.5, abs=1e-6)
        # AND the live table, which paced drones read, has the move
        ids, offsets = others_ned_m(world, 0)
        assert offsets[0][0] == pytest.approx(3.0, abs=1e-6)
        a.close()
        b.close()
    finally:
        world.close()


def test_an_epoch_is_a_whole_number_of_quanta_and_of_publishing_periods() -> None:
    assert [lockstep_epoch_steps(q) for q in (1, 2, 3, 4, 8)] == [4, 4, 12, 4, 8]
