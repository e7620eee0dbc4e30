"""The drone-to-drone mesh (sitl/world/mesh.py): the medium in a real shared world, the path-loss rule, what a radio
hears and when, and the neighbour table's sources (sitl/protocol/neighbours.py)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl.dynamics.geodesy import geo_from_ned
from sitl.dynamics.plant import DEFAULT_HOME
from sitl.params import ParamStore
from sitl.process.mavlink_io import MavlinkEndpoint
from sitl.protocol import Identity
from sitl.protocol.neighbours import LINK, MESH, RELAY, NeighbourFeed, NeighbourTable
from sitl.protocol.signing import SIGN_ALWAYS, SIGN_CFG_PARAM
from sitl.protocol.signing_params import SIGNING_PARAMS
from sitl.protocol.testing import FakeVehicle
from sitl.world.linkmodel import LinkImpairment
from sitl.world.mesh import MESH_RATE_HZ, MeshCounters, MeshMedium, MeshRadio, MeshSettings, mesh_problem
from sitl.world.shared import MESH_SLOT_BYTES, MESH_SLOTS, SharedWorld

pytestmark = pytest.mark.timeout(60)


@pytest.fixture
def world() -> Iterator[SharedWorld]:
    created = SharedWorld.create()
    try:
        yield created
    finally:
        created.close()


def report(sysid: int, boot_ms: int, lat_e7: int = 473977420) -> bytes:
    """A GLOBAL_POSITION_INT frame as drone ``sysid`` sends it (MAVLink 2, as pymavlink packs it)."""
    msg = mavlink.MAVLink_global_position_int_message(boot_ms, lat_e7, 85455940, 491000, 3000, 120, 0, -50, 0)
    return bytes(msg.pack(mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)))


def place(world: SharedWorld, instance: int, north_m: float, east_m: float = 0.0) -> None:
    """Put drone ``instance``'s body ``north_m``/``east_m`` from the default home, 3 m up."""
    geo = geo_from_ned((north_m, east_m, -3.0), DEFAULT_HOME)
    world.write(instance, 0.0, (geo.lat_deg, geo.lon_deg, geo.alt_amsl_m), (0.0, 0.0, 0.0), 0.35, False,
                rest_alt_amsl_m=DEFAULT_HOME.alt_amsl_m)  # fmt: skip


def counted(c: MeshCounters) -> bool:
    """Every post offered is delivered or lost for one reason."""
    return c.frames_offered == c.frames_delivered + c.frames_lost


# ---- the path-loss rule ------------------------------------------------------------------------------------------


def test_the_path_loss_grows_with_distance_to_certain_loss_at_the_range() -> None:
    rule = MeshSettings(range_m=20.0)  # exponent 4 by default
    assert rule.loss_probability(0.0) == 0.0
    assert rule.loss_probability(10.0) == pytest.approx(0.0625)  # half range loses about 6 %
    assert rule.loss_probability(15.0) == pytest.approx(0.31640625)
    assert rule.loss_probability(20.0) == 1.0 and rule.loss_probability(25.0) == 1.0
    losses = [rule.loss_probability(d) for d in np.linspace(0.0, 20.0, 41)]
    assert losses == sorted(losses)
    assert MeshSettings(range_m=20.0, exponent=2.0).loss_probability(10.0) == pytest.approx(0.25)


@pytest.mark.parametrize(
    ("range_m", "exponent", "message"),
    [
        (0.0, 4.0, "range_m must be > 0, got 0"),
        (-15.0, 4.0, "range_m must be > 0, got -15"),
        (math.inf, 4.0, "range_m must be a finite number, got inf"),
        (15.0, 0.0, "exponent must be in (0, 20], got 0"),
        (15.0, 25.0, "exponent must be in (0, 20], got 25"),
        (15.0, math.nan, "exponent must be a finite number, got nan"),
    ],
)
def test_bad_mesh_settings_are_refused_in_one_line(range_m: float, exponent: float, message: str) -> None:
    assert mesh_problem(range_m, exponent) == message
    with pytest.raises(ValueError, match=None) as caught:
        MeshSettings(range_m=range_m, exponent=exponent)
    assert str(caught.value) == message


# ---- the medium ------------------------------------------------------------------------------------------------------


def test_a_post_is_read_by_every_other_drone_once_in_time_then_sender_order(world: SharedWorld) -> None:
    # GIVEN three drones on one medium, two of them posting at the same simulated times
    a, b, c = (MeshMedium(world, i) for i in (0, 1, 2))
    a.post(report(1, 100), step=25, time_s=0.1)
    c.post(report(3, 100), step=25, time_s=0.1)
    a.post(report(1, 200), step=50, time_s=0.2)
    # WHEN drone 1 (b) reads what is due up to step 25, then everything
    first = b.take(until_step=25)
    second = b.take(until_step=None)
    # THEN it gets the step-25 posts in sender order, then the later one, each once and byte for byte
    assert [(t, s) for t, s, _ in first] == [(0.1, 0), (0.1, 2)]
    assert first[0][2] == report(1, 100) and first[1][2] == report(3, 100)
    assert [(t, s, f) for t, s, f in second] == [(0.2, 0, report(1, 200))]
    assert b.take(until_step=None) == []
    # AND a drone never hears itself
    assert [s for _, s, _ in a.take(until_step=None)] == [2]


def test_a_reader_a_whole_ring_behind_skips_what_was_overwritten_and_counts_it(world: SharedWorld) -> None:
    sender, reader = MeshMedium(world, 5), MeshMedium(world, 6)
    for k in range(MESH_SLOTS + 10):
        sender.post(report(6, k), step=k, time_s=k * 0.1)
    taken = reader.take(until_step=None)
    assert len(taken) == MESH_SLOTS and reader.overruns == 10
    assert taken[0][2] == report(6, 10) and taken[-1][2] == report(6, MESH_SLOTS + 9)


def test_a_frame_larger_than_a_slot_is_not_posted(world: SharedWorld) -> None:
    medium = MeshMedium(world, 0)
    assert not medium.post(bytes(MESH_SLOT_BYTES + 1), step=1, time_s=0.0)
    assert world.mesh_posts[0] == 0


# ---- what a radio hears ----------------------------------------------------------------------------------------------


def radio(world: SharedWorld, instance: int, *, range_m: float = 15.0, quantum: int | None = 1,
          impairment: LinkImpairment | None = None, seed: int | None = None) -> MeshRadio:  # fmt: skip
    """Drone ``instance``'s radio; its seed is 7 + instance unless given (a swarm's drones have seeds of their own)."""
    return MeshRadio(MeshMedium(world, instance), MeshSettings(range_m=range_m), impairment,
                     seed=7 + instance if seed is None else seed, quantum_steps=quantum)  # fmt: skip


def run(radios: list[MeshRadio], steps: int, dt_s: float = 0.004) -> dict[int, list[tuple[int, bytes]]]:
    """Step every radio ``steps`` times; each posts a report every 25 steps (10 Hz at 250 Hz), as a drone's
    telemetry poll does after its step; what each heard, as (step, frame)."""
    heard: dict[int, list[tuple[int, bytes]]] = {i: [] for i in range(len(radios))}
    for step in range(1, steps + 1):
        now_s = step * dt_s
        for i, r in enumerate(radios):
            heard[i] += [(step, f) for f in r.after_step(now_s)]
        if step % 25 == 0:
            for i, r in enumerate(radios):
                r.broadcast(report(i + 1, int(now_s * 1000)), now_s)
    return heard


def test_in_lockstep_a_post_is_heard_exactly_a_quantum_after_it_was_made(world: SharedWorld) -> None:
    # GIVEN two drones 3 m apart with a path loss too small to matter over a long range, a quantum of 4 steps
    place(world, 0, 0.0)
    place(world, 1, 3.0)
    radios = [radio(world, i, range_m=1e6, quantum=4) for i in (0, 1)]
    # WHEN they post every 25 steps for 1 s
    heard = run(radios, 250)
    # THEN each hears every report of the other at its post step + 4, never earlier
    assert [step for step, _ in heard[1]] == [25 * k + 4 for k in range(1, 10)]
    assert [f for _, f in heard[1]] == [report(1, 100 * k) for k in range(1, 10)]
    assert radios[1].counters() == MeshCounters(frames_offered=9, frames_delivered=9)


def test_beyond_the_range_nothing_is_heard_and_within_it_the_path_loss_takes_its_share(world: SharedWorld) -> None:
    # GIVEN drone 0 with one neighbour at 10 m (half of a 20 m range: 6.25 % path loss) and one at 25 m
    place(world, 0, 0.0)
    place(world, 1, 10.0)
    place(world, 2, -25.0)
    radios = [radio(world, i, range_m=20.0) for i in range(3)]
    # WHEN they post for 200 s
    run(radios, 50_001)  # the last post, made at step 50 000, is heard at the next
    # THEN drone 0 heard none of drone 2's 2000 reports and lost about 6.25 % of drone 1's
    c = radios[0].counters()
    assert c.frames_offered == 4000 and counted(c)
    assert c.lost_range == 2000
    assert 0.05 < c.lost_path / 2000 < 0.075
    assert c.lost_model == 0 and c.lost_overrun == 0
    # AND drone 2, out of range of both, hears nothing at all
    assert radios[2].counters() == MeshCounters(frames_offered=4000, lost_range=4000)


def test_the_link_model_loses_and_delays_mesh_reports_on_top_of_the_path_loss(world: SharedWorld) -> None:
    # GIVEN two drones side by side with a 10 % lossy, 40 ms late neighbour link
    place(world, 0, 0.0)
    place(world, 1, 0.5)
    impairment = LinkImpairment(loss=0.1, latency_ms=40.0)
    radios = [radio(world, i, impairment=impairment) for i in (0, 1)]
    heard = run(radios, 25_001)
    c = radios[1].counters()
    # THEN about a tenth is lost to the model, none to range, and what is heard comes 40 ms (10 steps) after posting
    assert c.frames_offered == 1000 and counted(c) and c.lost_range == 0
    assert 0.07 < c.lost_model / 1000 < 0.13
    assert {step % 25 for step, _ in heard[1]} == {10}
    assert c.delayed == c.frames_delivered and c.total_delay_s / c.frames_delivered == pytest.approx(0.04)


def test_the_same_seeds_hear_the_same_and_another_seed_differs(world: SharedWorld) -> None:
    def flight(seed: int) -> list[tuple[int, bytes]]:
        world.mesh_posts[:] = 0.0
        place(world, 0, 0.0)
        place(world, 1, 12.0)
        radios = [radio(world, i, impairment=LinkImpairment(loss=0.2, jitter_ms=30.0), seed=seed) for i in (0, 1)]
        return run(radios, 5000)[1]

    first, again, other = flight(1), flight(1), flight(2)
    assert first == again
    assert first != other


def test_a_drone_posts_at_most_at_the_mesh_rate(world: SharedWorld) -> None:
    r = radio(world, 0)
    for k in range(100):  # a stream raised to 50 Hz for 2 s
        r.broadcast(report(1, 20 * k), k * 0.02)
    assert r.posted == pytest.approx(2.0 * MESH_RATE_HZ, abs=1)


# ---- the neighbour table's sources ---------------------------------------------------------------------------------


def decoded(frame: bytes) -> Any:
    return mavlink.MAVLink(None).parse_char(frame)


def test_each_entry_says_its_source_and_a_late_relayed_copy_does_not_replace_a_newer_mesh_report() -> None:
    table = NeighbourTable(own_sysid=1)
    # GIVEN drone 2's report of t=1.0 s heard over the mesh, and drone 3's relayed
    table.receive(decoded(report(2, 1000)), 1.01, MESH)
    table.handle(decoded(report(3, 1000)), 1.02)
    assert [(n.sysid, n.source) for n in table.entries(1.05)] == [(2, MESH), (3, RELAY)]
    # WHEN drone 2's t=1.1 s report comes over the mesh and then its t=1.0 s one late through the relay
    table.receive(decoded(report(2, 1100, lat_e7=473977999)), 1.11, MESH)
    table.handle(decoded(report(2, 1000)), 1.15)
    # THEN the entry is still the newer mesh one, and the relay's copy is counted as an older copy
    two = table.entries(1.2)[0]
    assert (two.source, two.sender_time_s, two.received_s) == (MESH, 1.1, 1.11)
    assert two.lat_deg == pytest.approx(47.3977999)
    assert table.stale == 1
    # AND a newer report replaces it whichever way it comes
    table.handle(decoded(report(2, 1200)), 1.25)
    assert table.entries(1.3)[0].source == RELAY
    counts = table.counts()
    assert (counts[MESH].updates, counts[RELAY].updates) == (2, 2)


def test_the_table_counts_the_age_of_each_source_s_entries_where_they_are_read() -> None:
    table = NeighbourTable(own_sysid=1)
    table.receive(decoded(report(2, 1000)), 1.0, MESH)
    table.handle(decoded(report(3, 900)), 1.0)
    table.entries(1.1)
    table.entries(1.3)
    counts = table.counts()
    assert counts[MESH].mean_age_s == pytest.approx(0.2) and counts[RELAY].mean_age_s == pytest.approx(0.2)
    assert counts[MESH].age_samples == 2
    assert counts[MESH].mean_sent_age_s == pytest.approx(0.2)  # sent at 1.0 s (time_boot_ms 1000)
    assert counts[RELAY].mean_sent_age_s == pytest.approx(0.3)  # sent at 0.9 s: 0.1 s on the way


def test_each_link_feeds_the_one_table_as_its_own_source() -> None:
    table = NeighbourTable(own_sysid=1)
    relay, client = NeighbourFeed(table, RELAY), NeighbourFeed(table, LINK)
    assert relay.handles == client.handles == NeighbourTable.handles
    relay.handle(decoded(report(2, 1000)), 1.0)
    client.handle(decoded(report(3, 1000)), 1.0)
    assert [(n.sysid, n.source) for n in table.entries(1.0)] == [(2, RELAY), (3, LINK)]
    assert {s: c.updates for s, c in table.counts().items()} == {RELAY: 1, LINK: 1, MESH: 0}
    client.poll(5.0)  # any feed's poll expires the shared table's stale entries
    assert table.entries(5.0) == []


# ---- through a drone's MAVLink endpoint ----------------------------------------------------------------------------


def endpoint_with_radio(world: SharedWorld, instance: int, *, key: bytes | None, required: bool) -> MavlinkEndpoint:
    """A drone's MAVLink side (no links: the mesh alone) with a mesh radio on ``world``."""
    params = ParamStore(SIGNING_PARAMS)
    if required:
        params.set(SIGN_CFG_PARAM, SIGN_ALWAYS)
    endpoint = MavlinkEndpoint(Identity(sysid=instance + 1), FakeVehicle(), params, [], signing_key=key)
    endpoint.attach_mesh(radio(world, instance))
    return endpoint


def hear(receiver: MavlinkEndpoint, steps: int = 2) -> None:
    for step in range(1, steps + 1):
        receiver.hear_mesh(step * 0.004)


@pytest.mark.parametrize(
    ("sender_key", "receiver_key", "heard"),
    [(None, None, True), (b"k" * 32, b"k" * 32, True), (None, b"k" * 32, False), (b"x" * 32, b"k" * 32, False)],
)
def test_a_drone_that_requires_signing_takes_only_correctly_signed_mesh_reports(
    world: SharedWorld, sender_key: bytes | None, receiver_key: bytes | None, heard: bool
) -> None:
    # GIVEN two drones side by side, the receiver requiring signatures when it has a key
    place(world, 0, 0.0)
    place(world, 1, 1.0)
    sender = endpoint_with_radio(world, 0, key=sender_key, required=False)
    receiver = endpoint_with_radio(world, 1, key=receiver_key, required=receiver_key is not None)
    try:
        # WHEN the sender broadcasts its position report (its poll, as after a step) and the receiver steps
        msg = mavlink.MAVLink_global_position_int_message(100, 473977420, 85455940, 491000, 3000, 0, 0, 0, 0)
        sender._broadcast(msg, 0.0)
        hear(receiver)
        # THEN the report is in the receiver's table as heard over the mesh, or not at all
        entries = receiver.neighbours.entries(0.01)
        assert [(n.sysid, n.source) for n in entries] == ([(1, MESH)] if heard else [])
        assert receiver.mesh is not None and receiver.mesh.counters().frames_delivered == 1  # the radio heard it
        assert (receiver.signing.counters.signed_in == 1) == (heard and receiver_key is not None)
    finally:
        sender.close()
        receiver.close()
