"""The drone's neighbour table and the ground station's relay plan (pure)."""

from __future__ import annotations

from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink

from gcs.fleet.relay import NeighbourRelay
from gcs.fleet.telemetry import Fleet
from sitl.protocol.neighbours import NEIGHBOUR_TIMEOUT_S, NeighbourTable


def wire(msg: Any, sysid: int) -> Any:
    return mavlink.MAVLink(None).parse_char(msg.pack(mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)))


def position(lat_e7: int, alt_mm: int, boot_ms: int = 1000) -> Any:
    return mavlink.MAVLink_global_position_int_message(boot_ms, lat_e7, 85455940, alt_mm, 3000, 120, 0, -50, 0)


def test_the_table_keeps_other_systems_with_their_ages_and_forgets_silent_ones() -> None:
    table = NeighbourTable(own_sysid=1)
    table.handle(wire(position(473977420, 491000), 1), 0.0)  # our own report is not a neighbour
    table.handle(wire(position(473977420, 491000), 2), 1.0)
    table.handle(wire(position(473977520, 492000, 1100), 2), 1.1)  # a newer report replaces the old one
    table.handle(wire(position(473977000, 490000), 3), 1.1)
    entries = table.entries(1.2)
    assert [n.sysid for n in entries] == [2, 3]
    two = entries[0]
    assert two.lat_deg == pytest.approx(47.397752) and two.alt_amsl_m == pytest.approx(492.0)
    assert two.vel_ned_mps == pytest.approx((1.2, 0.0, -0.5)) and two.sender_time_s == pytest.approx(1.1)
    assert two.age_s(1.2) == pytest.approx(0.1)
    table.poll(1.1 + NEIGHBOUR_TIMEOUT_S + 0.01)
    assert table.entries(1.1 + NEIGHBOUR_TIMEOUT_S + 0.01) == []


def heartbeat(fleet: Fleet, sysid: int, now: float, lat_e7: int) -> None:
    fleet.handle(wire(mavlink.MAVLink_heartbeat_message(2, 12, 1, 0, 3, 3), sysid), now)
    fleet.handle(wire(position(lat_e7, 491000), sysid), now)


def test_the_relay_forwards_to_every_other_live_system_rate_limited_and_within_radius() -> None:
    fleet = Fleet()
    for sysid, lat in ((1, 473977420), (2, 473977520), (3, 473987420)):  # 3 is about 111 m north
        heartbeat(fleet, sysid, 0.0, lat)
    relay = NeighbourRelay(rate_hz=10.0)
    assert relay.targets(1, 0.0, fleet) == [2, 3]
    assert relay.targets(1, 0.05, fleet) == []  # a second report within 0.1 s is not forwarded
    assert relay.targets(1, 0.1, fleet) == [2, 3]
    near = NeighbourRelay(rate_hz=10.0, radius_m=50.0)
    assert near.targets(1, 0.0, fleet) == [2]
    assert relay.targets(2, 5.0, fleet) == []  # everyone else went silent: nobody to forward to


def test_the_relay_forwards_reports_a_late_pump_reads_together_but_holds_a_fast_source_to_its_rate() -> None:
    fleet = Fleet()
    for sysid, lat in ((1, 473977420), (2, 473977520)):
        heartbeat(fleet, sysid, 0.0, lat)
    relay = NeighbourRelay(rate_hz=10.0)
    # GIVEN a source reporting at 10 Hz, read on time for 0.0-0.2 s WHEN the supervisor is late and reads the
    # reports of 0.3 and 0.4 s together at 0.42 s THEN both are forwarded: the source kept its rate
    assert [relay.targets(1, t, fleet) for t in (0.0, 0.1, 0.2)] == [[2], [2], [2]]
    assert [relay.targets(1, 0.42, fleet), relay.targets(1, 0.42, fleet)] == [[2], [2]]
    # GIVEN a source reporting at 40 Hz for 2.5 s THEN about 10 a second are forwarded (1 / 0.9 of the rate at most)
    forwarded = sum(1 for k in range(1, 101) if relay.targets(1, 0.42 + k * 0.025, fleet))
    assert 25 <= forwarded <= 28, forwarded


def test_the_one_pass_field_check_accepts_and_refuses_exactly_what_the_field_by_field_check_does() -> None:
    from sitl.protocol.core import PeerInputError
    from sitl.protocol.neighbours import _checked_fields, _plain_fields

    def fields(**overrides: Any) -> Any:
        msg = mavlink.MAVLink_global_position_int_message(5, 473977420, 85455940, 490000, 3000, -10, 20, 0, 9000)
        for name, value in overrides.items():
            setattr(msg, name, value)
        return msg

    extremes = {"lat": (-900_000_000, 900_000_000), "lon": (-1_800_000_000, 1_800_000_000),
                "alt": (-(2**31), 2**31 - 1), "vx": (-32768, 32767), "vy": (-32768, 32767),
                "vz": (-32768, 32767), "time_boot_ms": (0, 2**32 - 1)}  # fmt: skip
    cases = [fields()]
    for name, (lo, hi) in extremes.items():
        cases += [fields(**{name: v}) for v in (lo, hi, lo - 1, hi + 1, True, 1.0, None, "1", 2**70)]
    for msg in cases:
        try:
            expected: Any = _checked_fields(msg)
        except PeerInputError:
            expected = None
        plain = _plain_fields(msg)
        assert plain is None or plain == expected  # the fast path never accepts what the checks refuse
        if expected is not None and all(type(v) is int for v in expected):
            assert plain == expected  # and takes every well-formed report


def test_a_poll_forgets_each_silent_neighbour_as_soon_as_it_is_too_old_and_not_before() -> None:
    # GIVEN three neighbours heard at 0, 1 and 2 s, the first heard again at 2.5 s (a newer report)
    table = NeighbourTable(own_sysid=1)
    for sysid, now in ((2, 0.0), (3, 1.0), (4, 2.0), (2, 2.5)):
        table.handle(wire(position(473977420, 491000, boot_ms=1000 + int(now * 1000)), sysid), now)
    # WHEN polled as time passes, THEN each goes once it is older than the timeout, in the order it fell silent
    remaining = []
    for now in (3.9, 4.0, 4.01, 5.0, 5.01, 5.5, 5.51):
        table.poll(now)
        remaining.append(sorted(table._entries))
    assert remaining == [[2, 3, 4], [2, 3, 4], [2, 4], [2, 4], [2], [2], []]
    # AND an entry stamped earlier than any before (a clock that restarted) is still forgotten on time
    table.handle(wire(position(473977420, 491000), 5), 0.5)
    table.poll(3.5)
    assert sorted(table._entries) == [5]
    table.poll(3.51)
    assert table._entries == {}
