"""The shared world table: rows written by one process are seen by another; contacts use both radii."""

from __future__ import annotations

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


def test_a_participant_publishes_every_n_steps_and_reports_no_contact_once_crashed() -> None:
    world = SharedWorld.create()
    try:
        world.write(1, 0.0, (LAT, LON, ALT), (0.0, 0.0, 0.0), 0.35, False)
        participant = WorldParticipant(SharedWorld.attach(world.name), 0, 0.35, every_n_steps=4)
        results = [participant.update(0.01 * k, (LAT, LON, ALT + 0.2), (0.0, 0.0, 0.0), False) for k in range(8)]
        assert [len(r) for r in results] == [0, 0, 0, 1, 0, 0, 0, 1]
        assert participant.update(0.1, (LAT, LON, ALT), (0.0, 0.0, 0.0), True) == []
        participant.close()
        assert world.table[0, 0] == 0.0  # its row is cleared when it leaves
    finally:
        world.close()
