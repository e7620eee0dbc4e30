"""Parameters and missions on several drones at once: the swarm's parts that drive the MAVLink parameter and mission
clients (gcs/mavlink/params.py, gcs/mavlink/mission_transfer.py), which the pump feeds with what arrives.

Each starts its work on every drone at once and is served until every drone's ends (gcs/fleet/pump.py
``Pump.serve``: pumped, the setpoint stream kept going), with MAVSDK's timeouts and retries: nine drones are nine
transfers in flight at once, not nine in turn.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from gcs.fleet.clock import SwarmClock
from gcs.fleet.errors import SwarmError
from gcs.fleet.pump import Pump
from gcs.mavlink.mission_transfer import MISSION_TYPE_MISSION, MissionClient, MissionProgress, TransferResult, WireItem
from gcs.mavlink.params import ParamClient, ParamResult


class Params:
    def __init__(self, client: ParamClient, pump: Pump, clock: SwarmClock) -> None:
        self.client = client
        self.pump = pump
        self.clock = clock

    def set(self, sysid: int, name: str, value: int | float) -> None:
        """PARAM_SET, confirmed by the drone's PARAM_VALUE echo (as MAVSDK does); SwarmError if refused or silent."""
        result = self.set_all(name, value, [sysid])[0]
        if result.refused:
            raise SwarmError(f"drone {sysid}: parameter {name} = {value:g} refused (kept {result.kept:g})")
        if not result.ok:
            raise SwarmError(f"drone {sysid}: no answer to setting parameter {name}")

    def set_all(self, name: str, value: int | float, sysids: Iterable[int]) -> list[ParamResult]:
        """One parameter on several drones at once, each confirmed by its echo or retried (gcs/mavlink/params.py)."""
        return self.set_each(name, dict.fromkeys(sysids, value))

    def read(self, name: str, sysids: Iterable[int]) -> list[ParamResult]:
        """One parameter read from several drones at once (PARAM_REQUEST_READ, retried as a set); ``kept`` is the
        value, None for a drone that never answered."""
        return self.set_each(name, dict.fromkeys(sysids, None))

    def set_each(self, name: str, values: Mapping[int, int | float | None]) -> list[ParamResult]:
        """One parameter, a value of its own on each drone (sysid -> value; None reads it), all at once as
        ``set_all``."""
        for sysid, value in values.items():
            self.pump.send(self.client.start(sysid, name, value, self.clock.now()), now=False)
        return self.pump.serve(self.client, name, list(values), now=False)


class Missions:
    def __init__(self, client: MissionClient, progress: MissionProgress, pump: Pump, clock: SwarmClock) -> None:
        self.client = client
        self.progress = progress  # each drone's MISSION_CURRENT / MISSION_ITEM_REACHED, fed by the pump
        self.pump = pump
        self.clock = clock

    def upload(
        self, items: dict[int, list[WireItem]], mission_type: int = MISSION_TYPE_MISSION
    ) -> list[TransferResult]:
        """A mission (or fence: ``mission_type`` 1) to several drones at once, each its own list (sysid -> items),
        with MAVSDK's timeouts and retries (gcs/mavlink/mission_transfer.py); the outcomes in the order of ``items``."""
        for sysid, own in items.items():
            self.pump.send(self.client.start_upload(sysid, own, mission_type, self.clock.now()), now=True)
        return self.pump.serve(self.client, mission_type, list(items), now=True)

    def download(self, sysids: Iterable[int], mission_type: int = MISSION_TYPE_MISSION) -> list[TransferResult]:
        """Several drones' missions (or fences) at once; each outcome carries the items downloaded."""
        targets = list(sysids)
        for sysid in targets:
            self.pump.send(self.client.start_download(sysid, mission_type, self.clock.now()), now=True)
        return self.pump.serve(self.client, mission_type, targets, now=True)
