"""The Python API (gcs/api) flying real ``sitl`` drones in lockstep: asyncio and blocking, a user's controller, events,
faults, errors, and every process gone at the end, however the session ends.

Policy: loopback only; leased instances (tests/integration/instances.py); a time limit on every test; the drone
processes are children of this test process (started by the session's supervisor thread) and each test checks that
none is left.
"""

from __future__ import annotations

import asyncio
import itertools
import json
import math
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

import pytest

from gcs.api import (
    FLOCKING,
    CircleSpec,
    ControllerError,
    DroneState,
    Event,
    FlockSpec,
    LaunchOptions,
    Setpoint,
    launch,
    launch_blocking,
)
from tests.integration.conftest import child_pids
from tests.integration.instances import Leases
from tests.integration.test_swarm import wait_dead

pytestmark = [pytest.mark.sim_only]

ALT_M = 3.0


def get_json(url: str) -> Any:
    with urllib.request.urlopen(url, timeout=10) as response:
        return json.loads(response.read())


def on_circle(drones: dict[int, DroneState], radius_m: float, tolerance_m: float) -> bool:
    return all(abs(math.hypot(d.pos_ned_m[0], d.pos_ned_m[1]) - radius_m) < tolerance_m for d in drones.values())


@pytest.mark.timeout(180)
def test_an_async_session_flies_a_formation_and_a_users_controller_then_lands_and_reports(
    tmp_path: Path, instances: Leases
) -> None:
    first = instances(3)
    sysids = [first + 1, first + 2, first + 3]
    events: list[Event] = []
    spread: dict[str, float] = {}

    async def fly() -> dict[str, object]:
        async with launch(3, lockstep=True, first_instance=first, drones_per_process="auto",
                          report_dir=tmp_path / "report", view=True, view_port=0) as swarm:  # fmt: skip
            collecting = asyncio.create_task(collect(swarm.events()))
            assert swarm.sysids == sysids
            assert swarm.view_url is not None
            view["url"] = swarm.view_url
            # GIVEN three drones up, WHEN they take off THEN the call returns with every drone at the altitude
            await swarm.takeoff(ALT_M)
            assert all(abs(d.alt_m - ALT_M) < 0.25 and d.armed and d.in_air for d in swarm.drones().values())
            # AND an invariant required from here on (docs/invariants.md) holds through the rest of the flight
            await swarm.require(kind="separation", min_m=1.0, name="apart")
            with pytest.raises(ValueError, match="'apart' is checked already"):
                await swarm.require(kind="contact", name="apart")
            # WHEN they fly a rotating circle THEN they are on it by the time the call said
            arrival_s = await swarm.formation(CircleSpec(radius_m=3.0, alt_m=ALT_M, angular_rate_radps=0.3))
            await swarm.sleep(arrival_s + 2.0)
            assert on_circle(swarm.drones(), 3.0, 0.3), swarm.drones()
            # AND the live view the session serves, asked for its newest frame while the swarm flies, draws them
            # there too (lockstep: the clock, and the view's frames, stand still between calls)
            fetched, _ = await asyncio.gather(asyncio.to_thread(get_json, f"{swarm.view_url}frame"), swarm.sleep(2.0))
            drawn = {d["sysid"]: d["pos_ned_m"] for d in fetched["drones"]}
            assert sorted(drawn) == sysids, fetched
            assert all(abs(math.hypot(n, e) - 3.0) < 0.3 and abs(-d - ALT_M) < 0.3 for n, e, d in drawn.values()), drawn
            # WHEN the user's own function commands them (a wider circle turning the other way, as bare positions)
            seen: list[float] = []

            def widen(t_s: float, drones: dict[int, DroneState]) -> dict[int, tuple[float, float, float]]:
                seen.append(t_s)
                return {s: (5.0 * math.cos(2.0944 * k - 0.2 * t_s), 5.0 * math.sin(2.0944 * k - 0.2 * t_s), -ALT_M)
                        for k, s in enumerate(sorted(drones))}  # fmt: skip

            await swarm.control(widen)
            reached = await swarm.wait_until(lambda drones: on_circle(drones, 5.0, 0.3), timeout_s=30.0)
            assert reached, swarm.drones()
            # THEN it was called every tick, 20 times a simulated second (lockstep frames are 0.02 s, so a tick
            # comes 0.04 or 0.06 s after the last), and they follow it
            steps = [b - a for a, b in itertools.pairwise(seen)]
            assert len(steps) > 20 and max(steps) < 0.061, steps[:20]
            assert abs((seen[-1] - seen[0]) / len(steps) - 0.05) < 0.001, (seen[0], seen[-1], len(steps))
            await swarm.sleep(3.0)
            assert on_circle(swarm.drones(), 5.0, 0.3), swarm.drones()
            spread["time_s"] = swarm.time_s
            await swarm.land()
            assert not any(d.armed for d in swarm.drones().values())
            collecting.cancel()
        assert swarm.result is not None and swarm.result.report_dir == tmp_path / "report"
        return swarm.result.metrics

    async def collect(stream: object) -> None:
        async for event in stream:  # type: ignore[attr-defined]
            events.append(event)

    view: dict[str, str] = {}
    metrics = asyncio.run(fly())
    # AND the live view stopped with the session
    with pytest.raises(urllib.error.URLError):
        get_json(f"{view['url']}frame")
    # AND the report has every step, no collision, and the session's processes are all gone
    assert [s["name"] for s in metrics["steps"]] == ["takeoff", "circle", "control", "land"], metrics["steps"]  # type: ignore[index]
    assert metrics["collisions"] == 0
    assert (metrics["invariants"], metrics["violations"]) == (["apart always"], [])
    assert (tmp_path / "report" / "flight.tlog").stat().st_size > 100_000
    assert any(e.kind == "statustext" and e.sysid in sysids for e in events), events[:5]
    assert wait_dead(sorted(child_pids()), 10) == []


@pytest.mark.timeout(180)
def test_a_controller_that_raises_holds_the_swarm_and_an_exception_in_the_block_still_stops_everything(
    tmp_path: Path, instances: Leases
) -> None:
    first = instances(2)
    sysids = [first + 1, first + 2]
    said: list[str] = []
    events: list[Event] = []

    def broken(t_s: float, drones: dict[int, DroneState]) -> dict[int, Setpoint]:
        if t_s > start_s + 1.0:
            raise ZeroDivisionError("the user's bug")
        return {s: Setpoint(pos_ned_m=d.pos_ned_m, vel_ned_mps=(0.0, 0.0, 0.0), acc_ned_mps2=(0.0, 0.0, 0.0),
                            yaw_rad=math.nan) for s, d in drones.items()}  # fmt: skip

    with pytest.raises(RuntimeError, match="the script's own failure"), \
            launch_blocking(2, lockstep=True, first_instance=first, say=said.append, on_event=events.append,
                            behaviour=FLOCKING) as swarm:  # fmt: skip
        # GIVEN a takeoff to 2 m, below the drones' MIS_TAKEOFF_ALT (2.5 m): they climb to 2.5 m and say so, as PX4,
        # and the call returns once they hold that
        swarm.takeoff(2.0)
        assert all(abs(d.alt_m - 2.5) < 0.25 for d in swarm.drones().values()), swarm.drones()
        assert any("takeoff to 2 m: below the drones' MIS_TAKEOFF_ALT (2.5 m)" in line for line in said), said
        minimum = [e.sysid for e in events if e.text == "Using minimum takeoff altitude: 2.50 m"]
        assert sorted(minimum) == sysids, events
        # GIVEN the two drones flocking by themselves (the shipped onboard behaviour) towards a point 8 m north
        north_before = [d.pos_ned_m[0] for d in swarm.drones().values()]
        swarm.flock(FlockSpec(alt_m=ALT_M, migration_ne_m=((8.0, 0.0),)), onboard=True)
        swarm.sleep(5.0)
        drones = swarm.drones().values()
        assert all(d.mode == "OFFBOARD" for d in drones), drones
        assert all(d.pos_ned_m[0] - n > 2.0 for d, n in zip(drones, north_before, strict=True)), drones
        # WHEN the user's controller takes over THEN their behaviours stop (BHV_EN 0) and it alone feeds them
        start_s = swarm.time_s
        swarm.control(broken)
        swarm.sleep(0.5)
        stopped = [e for e in events if e.kind == "statustext" and e.text == "Behaviour Flocking stopped (BHV_EN 0)"]
        assert sorted(e.sysid for e in stopped) == sysids, events
        # WHEN the controller raises THEN the call in progress raises ControllerError (the cause chained) and every
        # drone holds where it is, still flying
        with pytest.raises(ControllerError) as info:
            swarm.sleep(5.0)
        assert isinstance(info.value.__cause__, ZeroDivisionError)
        swarm.sleep(1.0)
        assert all(d.mode == "AUTO.LOITER" and d.in_air for d in swarm.drones().values()), swarm.drones()
        assert any("the controller raised ZeroDivisionError: the user's bug" in line for line in said), said
        # WHEN the user's script then fails inside the block
        raise RuntimeError("the script's own failure")
    # THEN the session still landed and stopped every drone process
    assert swarm.result is not None and swarm.result.report_dir is None
    assert wait_dead(sorted(child_pids()), 10) == []


def test_bad_launch_options_are_one_line_before_anything_starts() -> None:
    for bad, fragment in (({"drones": 0}, "drones must be in 1..254, got 0"),
                          ({"drones": 255}, "drones must be in 1..254, got 255"),
                          ({"drones": 3, "first_instance": 253}, "first_instance must leave room"),
                          ({"drones": 3, "speed": -1.0}, "speed must be a positive number"),
                          ({"drones": 3, "view_port": 8765}, "view_port needs view=True"),
                          ({"drones": 3, "invariants": [{"kind": "fence"}]}, "missing field 'radius_m'"),
                          ({"drones": 3, "invariants": {"kind": "contact"}}, "invariants takes a list")):  # fmt: skip
        with pytest.raises(ValueError, match=fragment):
            LaunchOptions(**bad)  # type: ignore[arg-type]
    assert child_pids() == set()
