"""The ground station's mission client against a drone's own mission server, with no socket.

Two real protocol objects joined by a fake link that can lose chosen messages: ``MissionClient``
(gcs/mavlink/mission_transfer.py) on one side, the drone's link services (sitl/protocol, a recording fake vehicle) on
the other, every message packed and parsed by pymavlink on the way. Both sides are given the same number as the time
and their timers are run by advancing it, so retries and timeouts take no wall time.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink

from gcs.mavlink.commands import Send
from gcs.mavlink.mission_transfer import (
    MISSION_RETRIES,
    MISSION_TIMEOUT_S,
    MISSION_TYPE_FENCE,
    MISSION_TYPE_MISSION,
    Direction,
    MissionClient,
    MissionProgress,
    TransferInFlight,
    TransferResult,
    WireItem,
)
from gcs.missions.qgc_plan import fence_items, load_plan, mission_items
from sitl.params import ParamDef, ParamStore
from sitl.protocol import Identity, LinkServices
from sitl.protocol.testing import FakeVehicle, Wire

SYSIDS = (14, 15)
BOX_PLAN = Path(__file__).resolve().parents[2] / "missions" / "box.plan"


class Drones:
    """Drones ``SYSIDS``, each its link services behind a wire each way; ``lose_up``/``lose_down`` drop messages."""

    def __init__(self) -> None:
        store = ParamStore([ParamDef(name="MIS_TAKEOFF_ALT", default=2.5, min=0.5, max=100, unit="m",
                                     description="")])  # fmt: skip
        self.vehicles = {s: FakeVehicle() for s in SYSIDS}
        self.services = {s: LinkServices(Identity(sysid=s), self.vehicles[s], store) for s in SYSIDS}
        self.up = Wire()  # the ground station's ids (255/190)
        self.down = {s: Wire(s, 1) for s in SYSIDS}
        self.lose_up: Callable[[Any], bool] = lambda _msg: False
        self.lose_down: Callable[[Any], bool] = lambda _msg: False
        self.sent_up: list[Any] = []

    def exchange(self, effects: list[Send], now_s: float) -> list[Any]:
        answers: list[Any] = []
        for effect in effects:
            msg = self.up(effect.message)
            self.sent_up.append(msg)
            if self.lose_up(msg):
                continue
            drone = self.services[effect.sysid]
            answers += [m for m in self.down[effect.sysid].carry(drone.handle(msg, now_s)) if not self.lose_down(m)]
        return answers

    def poll(self, now_s: float) -> list[Any]:
        """The drones' own timers (their mission server re-requests lost items)."""
        out: list[Any] = []
        for sysid, drone in self.services.items():
            out += [m for m in self.down[sysid].carry(drone.poll(now_s)) if not self.lose_down(m)]
        return out


class Run:
    ended_s = 0.0  # when the last transfer ended


def run(drones: Drones, client: MissionClient, first: list[Send], mission_type: int) -> list[TransferResult]:
    """Serve the transfers as the swarm does until each has ended: every message handled at once, each answer fed
    back until the link is quiet at that instant, then both sides' timers run as the time moves on by 50 ms."""
    now = 0.0
    pending = drones.exchange(first, now)
    results: dict[int, TransferResult] = {}
    while len(results) < len(SYSIDS):
        assert now < 60.0, "the transfer never ended"
        while pending:
            msg = pending.pop(0)
            pending += drones.exchange(client.handle(msg, now), now)
        for sysid in SYSIDS:
            if sysid not in results and (result := client.take(sysid, mission_type)) is not None:
                results[sysid] = result
        now = round(now + 0.05, 9)
        pending = drones.exchange(client.poll(now), now) + drones.poll(now)
    Run.ended_s = now
    return [results[s] for s in SYSIDS]


def upload(drones: Drones, client: MissionClient, items: list[WireItem], mission_type: int) -> list[TransferResult]:
    first = [e for s in SYSIDS for e in client.start_upload(s, items, mission_type, 0.0)]
    return run(drones, client, first, mission_type)


def download(drones: Drones, client: MissionClient, mission_type: int) -> list[TransferResult]:
    first = [e for s in SYSIDS for e in client.start_download(s, mission_type, 0.0)]
    return run(drones, client, first, mission_type)


def same_items(a: list[WireItem] | tuple[WireItem, ...], b: list[WireItem] | tuple[WireItem, ...]) -> bool:
    def key(item: WireItem) -> tuple[Any, ...]:
        params = tuple("nan" if math.isnan(p) else p for p in (item.param1, item.param2, item.param3, item.param4))
        return (item.seq, item.frame, item.command, item.autocontinue, params, item.x, item.y, item.z,
                item.mission_type)  # fmt: skip

    return [key(i) for i in a] == [key(i) for i in b]


def test_a_plan_uploads_to_two_drones_at_once_and_downloads_back_the_same() -> None:
    # GIVEN two drones and the committed QGroundControl plan's mission and fence
    plan = load_plan(BOX_PLAN)
    drones, client = Drones(), MissionClient()
    # WHEN the mission and then the fence are uploaded to both at once
    assert all(r.ok for r in upload(drones, client, mission_items(plan), MISSION_TYPE_MISSION))
    assert all(r.ok for r in upload(drones, client, fence_items(plan), MISSION_TYPE_FENCE))
    # THEN each vehicle holds them, and a download gives back exactly what was sent
    for vehicle in drones.vehicles.values():
        assert [i.command for i in vehicle.mission] == [22, 16, 16, 16, 21]
        assert [i.command for i in vehicle.fence] == [5001] * 4 + [5004]
    for result in download(drones, client, MISSION_TYPE_MISSION):
        assert result.direction is Direction.DOWNLOAD and same_items(result.items, mission_items(plan))
    for result in download(drones, client, MISSION_TYPE_FENCE):
        assert same_items(result.items, fence_items(plan))


def test_lost_items_and_requests_are_recovered_by_the_vehicles_re_requests() -> None:
    # GIVEN a link that loses the first copy of item 2 up and the first request for item 3 down
    drones, client = Drones(), MissionClient()
    lost: set[tuple[str, int, int]] = set()

    def once(kind: str) -> Callable[[Any], bool]:
        def lose(msg: Any) -> bool:
            key = (msg.get_type(), msg.seq if hasattr(msg, "seq") else -1, msg.get_srcSystem())
            if msg.get_type() == kind and key[1] in (2, 3) and key not in lost:
                lost.add(key)
                return True
            return False

        return lose

    drones.lose_up = once("MISSION_ITEM_INT")
    drones.lose_down = once("MISSION_REQUEST_INT")
    items = mission_items(load_plan(BOX_PLAN))
    # WHEN the mission is uploaded
    results = upload(drones, client, items, MISSION_TYPE_MISSION)
    # THEN it arrives whole on both drones, after the vehicles' re-requests
    assert all(r.ok for r in results), results
    assert lost, "nothing was lost: the test did not test recovery"
    for vehicle in drones.vehicles.values():
        assert len(vehicle.mission) == len(items)


def test_a_lost_final_ack_is_recovered_by_sending_the_last_item_again() -> None:
    # GIVEN a link that loses the first MISSION_ACK each drone sends, and the first copy of the last item to one
    drones, client = Drones(), MissionClient()
    items = mission_items(load_plan(BOX_PLAN))
    acked: set[int] = set()
    last_sent: set[int] = set()

    def lose_down(msg: Any) -> bool:
        if msg.get_type() == "MISSION_ACK" and msg.get_srcSystem() not in acked:
            acked.add(msg.get_srcSystem())
            return True
        return False

    def lose_up(msg: Any) -> bool:
        last = msg.get_type() == "MISSION_ITEM_INT" and msg.seq == len(items) - 1 and msg.target_system == SYSIDS[1]
        if last and not last_sent:
            last_sent.add(msg.target_system)
            return True
        return False

    drones.lose_down, drones.lose_up = lose_down, lose_up
    # WHEN the mission is uploaded
    results = upload(drones, client, items, MISSION_TYPE_MISSION)
    # THEN both uploads succeed, each after the last item was sent again once its ACK (or the item) went missing
    assert all(r.ok for r in results), results
    assert acked == set(SYSIDS) and last_sent == {SYSIDS[1]}
    for sysid in SYSIDS:
        lasts = [m for m in drones.sent_up if m.get_type() == "MISSION_ITEM_INT" and m.target_system == sysid
                 and m.seq == len(items) - 1]  # fmt: skip
        assert len(lasts) >= 2
        assert len(drones.vehicles[sysid].mission) == len(items)


def test_a_silent_drone_ends_the_upload_with_no_answer_after_the_retries_and_a_cancel() -> None:
    # GIVEN a drone that hears nothing
    drones, client = Drones(), MissionClient()
    drones.lose_up = lambda msg: msg.get_srcSystem() == 255 and getattr(msg, "target_system", 0) == SYSIDS[1]
    items = mission_items(load_plan(BOX_PLAN))
    # WHEN the mission is uploaded to both
    results = upload(drones, client, items, MISSION_TYPE_MISSION)
    # THEN the first succeeds, the second ends with no answer after MISSION_RETRIES resends of MISSION_COUNT
    assert results[0].ok
    assert results[1].error == f"sysid {SYSIDS[1]}: mission upload no answer after {MISSION_RETRIES + 1} tries"
    counts = [m for m in drones.sent_up if m.get_type() == "MISSION_COUNT" and m.target_system == SYSIDS[1]]
    assert len(counts) == MISSION_RETRIES + 1
    cancels = [m for m in drones.sent_up if m.get_type() == "MISSION_ACK" and m.target_system == SYSIDS[1]]
    assert [m.type for m in cancels] == [mavlink.MAV_MISSION_OPERATION_CANCELLED]
    assert Run.ended_s == pytest.approx((MISSION_RETRIES + 1) * MISSION_TIMEOUT_S, abs=0.06)


def test_an_item_the_vehicle_refuses_ends_the_upload_with_its_result_named() -> None:
    # GIVEN a mission whose item 1 is a waypoint in a local frame, which PX4 refuses
    items = mission_items(load_plan(BOX_PLAN))
    items[1] = WireItem(seq=1, frame=mavlink.MAV_FRAME_LOCAL_NED, command=16, z=-3.0)
    drones, client = Drones(), MissionClient()
    # WHEN it is uploaded
    results = upload(drones, client, items, MISSION_TYPE_MISSION)
    # THEN each drone's refusal says which item and why, and no drone took a half mission
    assert [r.error for r in results] == [
        f"sysid {s}: mission upload refused (item 1): MAV_MISSION_UNSUPPORTED_FRAME" for s in SYSIDS
    ]
    assert [r.result for r in results] == [mavlink.MAV_MISSION_UNSUPPORTED_FRAME] * 2
    assert all(v.mission == [] for v in drones.vehicles.values())


def test_a_lost_count_and_lost_items_on_download_are_asked_for_again() -> None:
    # GIVEN two drones holding the plan, and a link losing the first MISSION_COUNT and item 1 on their way down
    plan_items = mission_items(load_plan(BOX_PLAN))
    drones, client = Drones(), MissionClient()
    assert all(r.ok for r in upload(drones, client, plan_items, MISSION_TYPE_MISSION))
    lost: set[tuple[int, str]] = set()

    def lose_down(msg: Any) -> bool:
        kind = msg.get_type()
        key = (msg.get_srcSystem(), kind)
        if (kind == "MISSION_COUNT" or (kind == "MISSION_ITEM_INT" and msg.seq == 1)) and key not in lost:
            lost.add(key)
            return True
        return False

    drones.lose_down = lose_down
    # WHEN both are downloaded
    results = download(drones, client, MISSION_TYPE_MISSION)
    # THEN both come back whole
    assert len(lost) == 4
    assert all(r.ok and same_items(r.items, plan_items) for r in results)


def test_an_empty_download_and_a_second_transfer_while_one_runs() -> None:
    drones, client = Drones(), MissionClient()
    # a drone without a mission answers with a count of 0: an empty, successful download
    assert [(r.ok, r.items) for r in download(drones, client, MISSION_TYPE_MISSION)] == [(True, ())] * 2
    # one transfer per drone at a time (the vehicle runs one): a second is our own misuse
    client.start_download(SYSIDS[0], MISSION_TYPE_MISSION, 0.0)
    with pytest.raises(TransferInFlight):
        client.start_upload(SYSIDS[0], [], MISSION_TYPE_FENCE, 0.0)
    client.cancel(SYSIDS[0], MISSION_TYPE_MISSION)
    assert not client.in_flight(SYSIDS[0]) and client.next_due_s() == math.inf


def test_progress_follows_mission_current_and_item_reached() -> None:
    progress = MissionProgress()
    wire = Wire(14, 1)
    progress.handle(wire(mavlink.MAVLink_mission_current_message(1, 5, 3, 0)))
    for seq in (0, 1, 1, 2):  # PX4 may repeat a report
        progress.handle(wire(mavlink.MAVLink_mission_item_reached_message(seq)))
    assert progress.drones[14].reached == [0, 1, 2] and progress.drones[14].current_seq == 1
    assert not progress.finished(14, 4)
    progress.handle(wire(mavlink.MAVLink_mission_item_reached_message(4)))
    assert progress.finished(14, 4)
    progress.reset(14)
    assert not progress.finished(14, 4)
    progress.handle(wire(mavlink.MAVLink_mission_current_message(4, 5, 5, 0)))  # state 5: complete
    assert progress.finished(14, 4)
