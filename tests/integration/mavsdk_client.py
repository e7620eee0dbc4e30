"""A MAVSDK (``mavsdk.asyncio``, the native binding) client for the flight tests, opened and closed in one place.

Why a module: MAVSDK runs native threads and hands blocking calls to the event loop's default executor. Shutting
it down in the wrong order (destroying the library while an executor thread is still inside a C call, or leaving
a subscription open) crashes or leaks threads, so every test goes through ``connect`` below, which
- adds one connection per URL to a single ``Mavsdk`` instance configured as a ground station,
- waits for the expected autopilot systems (by sysid when known, else the first autopilot),
- on exit waits for the executor threads to finish before destroying the library, which stops MAVSDK's threads.

Waits take a wall-clock limit and fail with what was expected and what was last seen, rather than hanging until
the test's global timeout. Subscriptions are always closed (``aclosing``) so their native callbacks are released.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections.abc import AsyncGenerator, AsyncIterator, Awaitable, Callable, Sequence
from typing import Any, Final, TypeVar

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk, System
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.mission import MissionAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync

T = TypeVar("T")

DISCOVERY_TIMEOUT_S: Final = 20.0


class Drone:
    """One discovered system and its plugins, created on first use."""

    def __init__(self, system: System, sysid: int) -> None:
        self.system = system
        self.sysid = sysid
        self._action: ActionAsync | None = None
        self._telemetry: TelemetryAsync | None = None
        self._mission: MissionAsync | None = None
        self._offboard: OffboardAsync | None = None
        self._param: ParamAsync | None = None

    @property
    def action(self) -> ActionAsync:
        if self._action is None:
            self._action = ActionAsync(self.system)
        return self._action

    @property
    def telemetry(self) -> TelemetryAsync:
        if self._telemetry is None:
            self._telemetry = TelemetryAsync(self.system)
        return self._telemetry

    @property
    def mission(self) -> MissionAsync:
        if self._mission is None:
            self._mission = MissionAsync(self.system)
        return self._mission

    @property
    def offboard(self) -> OffboardAsync:
        if self._offboard is None:
            self._offboard = OffboardAsync(self.system)
        return self._offboard

    @property
    def param(self) -> ParamAsync:
        if self._param is None:
            self._param = ParamAsync(self.system)
        return self._param


async def _discover(mavsdk: Mavsdk, sysids: Sequence[int | None], timeout_s: float) -> list[Drone]:
    """Wait until an autopilot is connected for every wanted sysid (None: any one autopilot)."""
    deadline = time.monotonic() + timeout_s
    seen: dict[int, System] = {}
    while True:
        for system in await mavsdk.get_systems():
            if await system.has_autopilot() and await system.is_connected():
                seen.setdefault(await system.get_system_id(), system)
        drones: list[Drone] = []
        remaining = dict(seen)
        for wanted in sysids:
            if wanted is None:
                if remaining:
                    sysid = min(remaining)
                    drones.append(Drone(remaining.pop(sysid), sysid))
            elif wanted in remaining:
                drones.append(Drone(remaining.pop(wanted), wanted))
        if len(drones) == len(sysids):
            return drones
        if time.monotonic() > deadline:
            raise AssertionError(
                f"MAVSDK discovered autopilots {sorted(seen)} within {timeout_s:.0f} s, expected {list(sysids)}"
            )
        await asyncio.sleep(0.1)


@contextlib.asynccontextmanager
async def connect_many(
    urls_and_sysids: Sequence[tuple[str, int | None]], timeout_s: float = DISCOVERY_TIMEOUT_S
) -> AsyncIterator[list[Drone]]:
    """One MAVSDK instance with one connection per URL; yields the drones in the order asked for.

    Use once per event loop: closing shuts the loop's default executor down (see the module docstring).
    """
    loop = asyncio.get_running_loop()
    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    try:
        for url, _ in urls_and_sysids:
            await mavsdk.add_any_connection(url)
        yield await _discover(mavsdk, [sysid for _, sysid in urls_and_sysids], timeout_s)
    finally:
        # A blocking MAVSDK call abandoned by a timeout may still run in an executor thread; it must return
        # before the library goes away.
        await loop.shutdown_default_executor()
        mavsdk.destroy()


@contextlib.asynccontextmanager
async def connect(url: str, sysid: int | None, timeout_s: float = DISCOVERY_TIMEOUT_S) -> AsyncIterator[Drone]:
    async with connect_many([(url, sysid)], timeout_s) as drones:
        yield drones[0]


async def first_matching(
    subscription: Callable[[], AsyncGenerator[Any, None]],
    predicate: Callable[[Any], bool],
    timeout_s: float,
    what: str,
) -> Any:
    """Return the first value of a MAVSDK subscription that satisfies ``predicate``, or fail after ``timeout_s``."""
    last: list[Any] = []

    async def scan() -> Any:
        async with contextlib.aclosing(subscription()) as values:
            async for value in values:
                last[:] = [value]
                if predicate(value):
                    return value
        raise AssertionError(f"subscription for {what} ended")

    try:
        return await asyncio.wait_for(scan(), timeout_s)
    except TimeoutError:
        seen = f"last value {describe(last[0])}" if last else "no value at all"
        raise AssertionError(f"{what}: not within {timeout_s:.1f} s ({seen})") from None


def describe(value: object) -> str:
    """A readable one-line form of a MAVSDK value object (they have no useful repr)."""
    if isinstance(value, bool | int | float | str) or value is None:
        return repr(value)
    fields = getattr(value, "__dict__", None)
    if not fields:
        return repr(value)
    return "{" + ", ".join(f"{k}={describe(v)}" for k, v in fields.items() if not k.startswith("_")) + "}"


@contextlib.asynccontextmanager
async def recording(subscription: Callable[[], AsyncGenerator[Any, None]]) -> AsyncIterator[list[Any]]:
    """Collect every value of a MAVSDK subscription while the block runs (in the background)."""
    values: list[Any] = []

    async def collect() -> None:
        async with contextlib.aclosing(subscription()) as stream:
            async for value in stream:
                values.append(value)

    task = asyncio.create_task(collect())
    try:
        yield values
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


async def call_within(call: Awaitable[T], timeout_s: float, what: str) -> T:
    try:
        return await asyncio.wait_for(call, timeout_s)
    except TimeoutError:
        raise AssertionError(f"{what}: no answer within {timeout_s:.1f} s") from None


async def wait_ready_to_arm(drone: Drone, timeout_s: float) -> None:
    await first_matching(drone.telemetry.subscribe_health_all_ok, bool, timeout_s, "telemetry health all OK")


async def wait_relative_altitude(drone: Drone, target_m: float, tolerance_m: float, timeout_s: float) -> float:
    position = await first_matching(
        drone.telemetry.subscribe_position,
        lambda p: abs(p.relative_altitude_m - target_m) <= tolerance_m,
        timeout_s,
        f"relative altitude {target_m:.1f} ± {tolerance_m:.2f} m",
    )
    return float(position.relative_altitude_m)


async def wait_flight_mode(drone: Drone, mode: FlightMode, timeout_s: float) -> None:
    await first_matching(
        drone.telemetry.subscribe_flight_mode, lambda m: m == mode, timeout_s, f"flight mode {mode.name}"
    )


async def wait_landed_and_disarmed(drone: Drone, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    await first_matching(
        drone.telemetry.subscribe_in_air, lambda in_air: not in_air, timeout_s, "landed (in_air False)"
    )
    await first_matching(
        drone.telemetry.subscribe_armed,
        lambda armed: not armed,
        max(deadline - time.monotonic(), 1.0),
        "disarmed after touchdown",
    )


async def take_off(drone: Drone, timeout_s: float) -> float:
    """Arm and take off to MIS_TAKEOFF_ALT; returns the relative altitude once within 0.3 m of it and in Hold."""
    deadline = time.monotonic() + timeout_s
    takeoff_alt_m = float(await drone.action.get_takeoff_altitude())
    await drone.action.arm()
    await drone.action.takeoff()
    reached_m = await wait_relative_altitude(drone, takeoff_alt_m, 0.3, timeout_s)
    await wait_flight_mode(drone, FlightMode.HOLD, max(deadline - time.monotonic(), 1.0))
    return reached_m


def distance_m(a: tuple[float, float, float], b: tuple[float, float, float]) -> float:
    return math.dist(a, b)
