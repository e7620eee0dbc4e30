"""MAVSDK (``mavsdk.asyncio``, v4) flying several simulated drones at once, each through its own PX4-style API link,
as one would fly several PX4 SITL instances: one ``Mavsdk`` ground station, one connection per drone, every drone
armed, taken off, held and landed concurrently with ``asyncio.gather``. The swarm is launched with the Python API,
paced (MAVSDK's timeouts are wall-clock), and MAVSDK never talks to the ground station, only to the drones.

    python examples/mavsdk_several_drones.py [--drones 3]

Exits 1 unless every drone reached its takeoff altitude and landed and disarmed.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import sys
import time
from collections.abc import AsyncGenerator, Callable
from typing import Any

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk, System
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

from gcs.api import launch
from sitl.process.ports import instance_ports  # a drone's API link streams to 127.0.0.1:14540+i, as PX4 SITL's (i < 40)


async def first(
    subscription: Callable[[], AsyncGenerator[Any, None]], ok: Callable[[Any], bool], timeout_s: float
) -> Any:
    async def scan() -> Any:
        async with contextlib.aclosing(subscription()) as values:
            async for value in values:
                if ok(value):
                    return value
        return None

    return await asyncio.wait_for(scan(), timeout_s)


async def discover(mavsdk: Mavsdk, count: int, timeout_s: float) -> dict[int, System]:
    """Every autopilot MAVSDK has connected, by sysid, once there are ``count``."""
    deadline = time.monotonic() + timeout_s
    while True:
        found = {}
        for system in await mavsdk.get_systems():
            if await system.has_autopilot() and await system.is_connected():
                found[await system.get_system_id()] = system
        if len(found) >= count or time.monotonic() > deadline:
            return found
        await asyncio.sleep(0.2)


async def fly_one(sysid: int, system: System) -> bool:
    action, telemetry = ActionAsync(system), TelemetryAsync(system)
    await first(telemetry.subscribe_health_all_ok, bool, 30.0)
    alt_m = float(await action.get_takeoff_altitude())
    await action.arm()
    await action.takeoff()
    position = await first(telemetry.subscribe_position, lambda p: abs(p.relative_altitude_m - alt_m) < 0.3, 30.0)
    print(f"sysid {sysid}: at {position.relative_altitude_m:.2f} m")
    await asyncio.sleep(3.0)
    await action.land()
    await first(telemetry.subscribe_in_air, lambda in_air: not in_air, 60.0)
    await first(telemetry.subscribe_armed, lambda armed: not armed, 10.0)
    print(f"sysid {sysid}: landed and disarmed")
    return True


async def main(drones: int, first_instance: int) -> bool:
    async with launch(drones, lockstep=False, first_instance=first_instance, say=print):
        loop = asyncio.get_running_loop()
        mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        try:
            for k in range(drones):
                await mavsdk.add_any_connection(f"udpin://127.0.0.1:{instance_ports(first_instance + k).api_remote}")
            systems = await discover(mavsdk, drones, 30.0)
            print(f"MAVSDK found sysid {sorted(systems)}")
            results = await asyncio.gather(*(fly_one(s, system) for s, system in sorted(systems.items())))
            return len(results) == drones and all(results)
        finally:
            await loop.shutdown_default_executor()  # MAVSDK's blocking calls must end before the library goes
            mavsdk.destroy()


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--drones", type=int, default=3)
    parser.add_argument("--first-instance", type=int, default=0)
    args = parser.parse_args()
    sys.exit(0 if asyncio.run(main(args.drones, args.first_instance)) else 1)
