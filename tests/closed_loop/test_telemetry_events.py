"""Telemetry that skips the vehicle snapshot on polls with nothing due sends exactly what it sent before.

A whole mission flight (arm, AUTO.MISSION through four waypoints with MISSION_CURRENT and MISSION_ITEM_REACHED
events, landing, disarm) through SimVehicleApi, polled every 8 physics steps as the drone's loop polls it, by two
schedulers of one link's telemetry: one given the vehicle as it is (``event_state`` lets it skip snapshots), one
given a view of the same vehicle that only offers ``snapshot`` (a snapshot at every poll, as before). Every poll
must emit the same messages, field for field.
"""

from __future__ import annotations

from typing import Any, cast

import pytest

from sitl.autopilot import vehicle_api as api
from sitl.autopilot.px4_modes import Px4Mode
from sitl.drone.sim_vehicle_api import SimVehicleApi
from sitl.protocol import Identity
from sitl.protocol.core import Effect
from sitl.protocol.telemetry import TelemetryScheduler
from tests.closed_loop.test_mav_vehicle import Drone, _waypoint

pytestmark = pytest.mark.timeout(120)

POLL_STEPS = 8  # sitl/process/runtime.py PACED_WAKE_STEPS


class SnapshotOnly:
    """The vehicle as a telemetry scheduler sees it, without ``event_state``."""

    def __init__(self, vehicle: SimVehicleApi) -> None:
        self._vehicle = vehicle

    def snapshot(self) -> api.VehicleSnapshot:
        return self._vehicle.snapshot()


def _wire(effects: list[Effect]) -> list[tuple[str, str]]:
    return [(e.msg.get_type(), repr(e.msg.to_dict())) for e in effects]


def test_skipping_snapshots_changes_no_message_of_a_mission_flight() -> None:
    drone = Drone(seed=39)
    identity = Identity(sysid=1)
    skipping = TelemetryScheduler(identity, drone.api)
    full = TelemetryScheduler(identity, cast(api.VehicleApi, SnapshotOnly(drone.api)))
    polls = skipped = messages = 0
    kinds: set[str] = set()

    def poll() -> None:
        nonlocal polls, skipped, messages
        before = skipping._checked_event_state
        a, b = skipping.poll(drone.sim.time_s), full.poll(drone.sim.time_s)
        assert _wire(a) == _wire(b), drone.sim.time_s
        polls += 1
        messages += len(a)
        kinds.update(e.msg.get_type() for e in a)
        skipped += not a and before is not None and skipping._checked_event_state is before

    def run(seconds: float, until: Any = None) -> None:
        end = drone.sim.time_s + seconds
        while drone.sim.time_s < end and not (until is not None and until()):
            for _ in range(POLL_STEPS):
                drone.sim.step()
            poll()

    run(10.0, until=lambda: drone.snap().prearm_ok)
    legs = [(6.0, 0.0), (6.0, 6.0), (0.0, 6.0), (0.0, 0.0)]
    items = tuple(_waypoint(drone, seq, n, e, 3.0) for seq, (n, e) in enumerate(legs))
    assert drone.command(api.SetMission(items=items)).ok
    assert drone.command(api.Arm()).ok
    assert drone.command(api.SetMode(mode=Px4Mode.AUTO_MISSION)).ok
    run(60.0, until=lambda: drone.snap().mission.state is api.MissionState.COMPLETE)
    assert drone.command(api.SetMode(mode=Px4Mode.AUTO_LAND)).ok
    run(30.0, until=lambda: not drone.snap().armed)
    run(2.0)
    assert not drone.snap().armed
    # The flight produced every kind of event message, and most polls skipped their snapshot.
    assert {"MISSION_CURRENT", "MISSION_ITEM_REACHED", "HOME_POSITION", "EXTENDED_SYS_STATE", "HEARTBEAT"} <= kinds
    assert messages > 1000 and skipped > polls // 3, (polls, skipped)
