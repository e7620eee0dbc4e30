"""The drone's neighbour table and the ground station's relay plan (pure)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from gcs.fleet.relay import RELAY_REACH_HORIZON_S, RELAY_REACH_M, NeighbourRelay, RelayScope, relay_matrix
from gcs.fleet.telemetry import Fleet
from sitl.drone.param_table import build_param_store
from sitl.dynamics.geodesy import LocalFrame
from sitl.dynamics.plant import GeoPoint
from sitl.kernels import neighbours as nk
from sitl.kernels.avoidance import NEIGHBOUR_SIZE
from sitl.protocol import Identity, LinkServices
from sitl.protocol.framing import FRAME_MEMO_SIZE, FrameMemo, parse_datagram
from sitl.protocol.neighbours import (
    LINK,
    MESH,
    NEIGHBOUR_TIMEOUT_S,
    RELAY,
    NeighbourFeed,
    NeighbourTable,
    SharedReports,
)
from sitl.protocol.testing import FakeVehicle


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
    relay = NeighbourRelay(rate_hz=10.0, scope=RelayScope(kind="all"))
    assert relay.targets(1, 0.0, fleet) == [2, 3]
    assert relay.targets(1, 0.05, fleet) == []  # a second report within 0.1 s is not forwarded
    assert relay.targets(1, 0.1, fleet) == [2, 3]
    near = NeighbourRelay(rate_hz=10.0, scope=RelayScope(kind="within", radius_m=50.0))
    assert near.targets(1, 0.0, fleet) == [2]
    assert relay.targets(2, 5.0, fleet) == []  # everyone else went silent: nobody to forward to


def test_a_relay_scope_is_spelled_as_on_the_command_line_and_a_bad_one_is_one_line() -> None:
    assert RelayScope.parse("reach") == RelayScope()
    assert RelayScope.parse("all").kind == "all"
    assert RelayScope.parse("within:12.5") == RelayScope(kind="within", radius_m=12.5)
    assert RelayScope.parse("nearest:8") == RelayScope(kind="nearest", count=8)
    for scope in ("reach", "all", "within:12.5", "nearest:8"):
        assert RelayScope.parse(scope).text() == scope
    for bad, says in (("near", "must be reach, all, within:METRES or nearest:COUNT, got 'near'"),
                      ("within", "must be reach"), ("within:-3", "positive number of metres"),
                      ("within:nan", "positive number"), ("nearest:0", "whole number of drones >= 1"),
                      ("nearest:2.5", "'2.5' is not a number"), ("all:3", "must be reach")):  # fmt: skip
        with pytest.raises(ValueError, match=says):
            RelayScope.parse(bad)


def _matrix(
    scope: str, pos: list[tuple[float, float, float]], vel: list[tuple[float, float, float]]
) -> list[list[int]]:
    matrix = relay_matrix(RelayScope.parse(scope), np.array(pos, dtype=float), np.array(vel, dtype=float))
    return [np.flatnonzero(row).tolist() for row in matrix]


def test_reach_relays_to_drones_near_or_closing_in_and_not_to_far_ones_moving_alongside() -> None:
    far = RELAY_REACH_M + 20.0
    pos = [(0.0, 0.0, -5.0), (RELAY_REACH_M - 0.1, 0.0, -5.0), (far, 0.0, -5.0), (0.0, far, -5.0),
           (math.nan, math.nan, math.nan)]  # fmt: skip
    # 2 comes straight at 0 fast enough to be within reach inside the horizon; 3 flies alongside at the same speed
    closing = 20.0 / RELAY_REACH_HORIZON_S + 0.5
    vel = [(0.0, 5.0, 0.0), (0.0, 0.0, 0.0), (-closing, 5.0, 0.0), (0.0, 5.0, 0.0), (0.0, 0.0, 0.0)]
    rows = _matrix("reach", pos, vel)
    assert rows[0] == [1, 2, 4]  # near, closing, and one whose position is not known yet
    assert rows[3] == [4]  # nobody near, nobody closing in (0 and 2 are 35 m away and not closing)
    assert rows[4] == [0, 1, 2, 3]  # not known: sent everyone's
    # the same drone flying away is not closing in
    vel[2] = (closing, 5.0, 0.0)
    assert _matrix("reach", pos, vel)[0] == [1, 4]


def test_a_rotating_circle_relays_within_reach_only_and_all_relays_everything() -> None:
    n, radius, rate = 60, 40.0, 0.2
    angles = [2 * math.pi * k / n for k in range(n)]
    pos = [(radius * math.cos(a), radius * math.sin(a), -5.0) for a in angles]
    vel = [(-radius * rate * math.sin(a), radius * rate * math.cos(a), 0.0) for a in angles]
    rows = _matrix("reach", pos, vel)
    chord = [2 * radius * math.sin(abs(k) * math.pi / n) for k in range(1, n)]
    within = sum(c <= RELAY_REACH_M for c in chord)
    assert all(len(row) == within for row in rows)  # a rigid rotation closes in on nobody
    assert within < n - 1
    assert all(len(row) == n - 1 for row in _matrix("all", pos, vel))
    assert all(len(row) == 4 for row in _matrix("nearest:4", pos, vel))
    assert _matrix("nearest:2", pos, vel)[0] == [1, n - 1]
    assert _matrix("within:5", pos, vel)[0] == [1, n - 1]  # neighbours on the circle are 4.2 m apart


def test_the_relay_works_out_its_targets_once_a_period_and_reports_look_them_up() -> None:
    fleet = Fleet()
    for sysid, lat in ((1, 473977420), (2, 473977520), (3, 473987420)):  # 3 is about 111 m north
        heartbeat(fleet, sysid, 0.0, lat)
    relay = NeighbourRelay(rate_hz=10.0)  # reach
    assert relay.targets(1, 0.0, fleet) == [2] and relay.targets(3, 0.0, fleet) == []
    heartbeat(fleet, 3, 0.05, 473977620)  # 3 comes near; the plan of 0.0 still holds until 0.1 s
    assert relay.targets(2, 0.05, fleet) == [1]
    assert relay.targets(2, 0.15, fleet) == [1, 3]
    assert relay.targets(99, 0.15, fleet) == [1, 2, 3]  # a system the plan has not placed: to everyone


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


def test_a_hosts_drones_parse_a_relayed_frame_once_and_each_table_still_judges_it_alone() -> None:
    """The relay forwards a report byte for byte to every drone of a host: their links parse it into one message, the
    record is made once, and each table takes it or not as if it were alone (its own report, an older one)."""
    memo, shared = FrameMemo(), SharedReports()
    encoder = mavlink.MAVLink(None, srcSystem=2, srcComponent=1)
    newer = position(473977520, 492000, boot_ms=1100).pack(encoder)
    older = position(473977420, 491000, boot_ms=1000).pack(encoder)
    hosted = [NeighbourTable(own_sysid=s, shared=shared) for s in (1, 2, 3)]
    alone = [NeighbourTable(own_sysid=s) for s in (1, 2, 3)]
    hosted[2].receive(parse_datagram(newer, memo)[0], 0.5, RELAY)  # the third has the newer report already
    alone[2].receive(parse_datagram(newer)[0], 0.5, RELAY)
    parsed = [parse_datagram(older, memo) for _ in hosted]
    assert all(p is not None and p[0] is parsed[0][0] for p in parsed) and memo.hits == 2
    for table, messages in zip(hosted, parsed, strict=True):
        table.receive(messages[0], 1.0, RELAY)
    for table in alone:
        table.receive(parse_datagram(older)[0], 1.0, RELAY)
    assert shared.hits == 2
    assert [t.entries(1.0) for t in hosted] == [t.entries(1.0) for t in alone]
    assert [n.sender_time_s for n in hosted[0].entries(1.0)] == [1.0]  # sysid 2's own table skipped its report
    assert hosted[1].entries(1.0) == [] and hosted[2].entries(1.0)[0].sender_time_s == 1.1
    assert [t.stale for t in hosted] == [t.stale for t in alone] == [0, 0, 1]
    # A frame that differs in any byte (here the sequence number) is parsed again.
    encoder.seq = 200
    assert parse_datagram(position(473977420, 491000).pack(encoder), memo)[0] is not parsed[0][0]


def test_the_memos_start_again_when_full() -> None:
    memo, shared = FrameMemo(), SharedReports()
    encoder = mavlink.MAVLink(None, srcSystem=2, srcComponent=1)
    frames = [position(473977420, 491000, boot_ms=k).pack(encoder) for k in range(FRAME_MEMO_SIZE + 1)]
    first = parse_datagram(frames[0], memo)[0]
    shared.record(first, 0.0, RELAY)
    for frame in frames[1:]:
        shared.record(parse_datagram(frame, memo)[0], 0.0, RELAY)
    assert parse_datagram(frames[0], memo)[0] is not first and memo.hits == 0
    assert shared.record(first, 0.0, RELAY) is not None and shared.hits == 0


def test_a_position_taken_without_the_routing_leaves_the_table_as_the_routing_does() -> None:
    """``LinkServices.take_position`` (the drone's path for a GLOBAL_POSITION_INT when no signing key is set) against
    ``handle``: the same reports taken, our own echo (same sysid and component) left out, a same-sysid report from
    another component taken by neither table as a neighbour (it is our own sysid), and nothing answered."""
    reports = [
        wire(position(473977420, 491000), 2),
        wire(position(473977520, 492000, 1100), 3),
        wire(position(473977620, 493000, 1200), 1),  # our sysid from another component: not a neighbour
        wire(position(473977720, 494000, 900), 2),  # sent before sysid 2's first: stale
    ]
    echo = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
    reports.append(mavlink.MAVLink(None).parse_char(position(473977820, 495000, 1400).pack(echo)))
    tables = []
    for way in ("handle", "take_position"):
        table = NeighbourTable(own_sysid=1)
        services = LinkServices(Identity(sysid=1, compid=191), FakeVehicle(), build_param_store(()),
                                neighbours=NeighbourFeed(table, RELAY))  # fmt: skip
        for k, msg in enumerate(reports):
            if way == "handle":
                assert services.handle(msg, 1.0 + 0.01 * k) == []
            else:
                services.take_position(msg, 1.0 + 0.01 * k)
        tables.append(table)
    assert tables[0].entries(1.1) == tables[1].entries(1.1)
    assert [n.sysid for n in tables[1].entries(1.1)] == [2, 3]
    assert (tables[0].updates, tables[0].stale) == (tables[1].updates, tables[1].stale) == (2, 1)


def test_the_tables_rows_convert_in_one_call_to_the_bits_of_the_python_conversion_and_count_the_same_ages() -> None:
    """sitl/kernels/neighbours.py ``relay_rows`` against the record path it replaced (``entries`` and
    ``LocalFrame.ned_from_geodetic_rad``): every figure to the bit, expired entries left out, the ages counted per
    source in the same order, in both clocks."""
    rng = np.random.default_rng(7)
    frame = LocalFrame(GeoPoint(lat_deg=47.397742, lon_deg=8.545594, alt_amsl_m=488.0))
    conversion = np.array(frame.conversion)
    tables = [NeighbourTable(own_sysid=1), NeighbourTable(own_sysid=1)]
    for sysid in rng.permutation(np.arange(2, 40)).tolist():
        lat, lon = 473977420 + int(rng.integers(-20000, 20000)), 85455940 + int(rng.integers(-30000, 30000))
        alt, received = 488000 + int(rng.integers(-2000, 60000)), float(rng.uniform(0.0, 5.0))
        vel = [int(v) for v in rng.integers(-800, 800, 3)]
        msg = wire(mavlink.MAVLink_global_position_int_message(int(received * 900), lat, lon, alt, 0, *vel, 0), sysid)
        for table in tables:
            table.receive(msg, received, (RELAY, LINK, MESH)[sysid % 3])
    traffic = mavlink.MAVLink_adsb_vehicle_message(  # flags 0x1FF: where it is and how it moves
        4000, 473979000, 85457000, 0, 530000, 9000, 250, -40, b"INTRUDER", 0, 7, 0x1FF, 0
    )  # fmt: skip
    for table in tables:
        table.receive(wire(traffic, 200), 4.5, RELAY)
    kernel_table, record_table = tables
    for now_s, shared_clock in ((5.0, True), (6.5, False), (7.4, True)):
        entries = kernel_table.entry_rows()
        out = np.empty((len(entries), NEIGHBOUR_SIZE))
        n = nk.relay_rows(entries, now_s, NEIGHBOUR_TIMEOUT_S, conversion, shared_clock, kernel_table.ages, out)
        expected = [
            (*frame.ned_from_geodetic_rad(math.radians(e.lat_deg), math.radians(e.lon_deg), e.alt_amsl_m),
             *e.vel_ned_mps, e.sender_time_s if shared_clock else e.received_s, e.stale_s,
             1.0 if e.cooperative else 0.0, float(e.sysid))
            for e in record_table.entries(now_s)
        ]  # fmt: skip
        assert 0 < n < len(entries)  # some have expired
        assert out[:n].tolist() == [list(row) for row in expected]
        assert kernel_table.ages.tolist() == record_table.ages.tolist()
    assert kernel_table.counts() == record_table.counts()
    assert kernel_table.counts()[MESH].age_samples > 0
