"""Several drones hosted in one process (sitl/process/runtime.py's loop over ``Drone``s): they advance together, and an
exception in one drone's own code ends that drone alone, as a crashed process would end it.

The exception is injected by replacing one drone's ``step`` with one that raises after a while: no real input
should make a drone raise (the fuzz tests hunt for those), so the fault is put there by hand, as a fault-injection
test does. Everything else is the real loop, the real drones and the real shared world.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import pytest

from sitl.dynamics.airframe import load_airframe
from sitl.dynamics.geodesy import geo_from_ned
from sitl.dynamics.plant import DEFAULT_HOME
from sitl.dynamics.wind import WindConfig
from sitl.process.drone import Drone, DroneLogRouter, build_drone, cpu_clock
from sitl.process.runtime import RunOptions, StopFlag, run_loop
from sitl.process.specs import DroneSpec, ProcessSpec
from sitl.world.shared import END_FAILED, END_STOPPED, SharedWorld

pytestmark = pytest.mark.timeout(120)
DURATION_S = 3.0


@pytest.fixture
def world() -> Iterator[SharedWorld]:
    world = SharedWorld.create()
    yield world
    world.close()


def host(world: SharedWorld, tmp_path: Path, count: int) -> list[Drone]:
    common = ProcessSpec(
        airframe=load_airframe("quad_x_f450"),
        speed_factor=0.0,
        wind=WindConfig(),
        duration_s=DURATION_S,
        world_name=world.name,
    )
    specs = [
        DroneSpec(
            instance=i,
            seed=i,
            home=geo_from_ned((0.0, 3.0 * i, 0.0), DEFAULT_HOME),
            links=(),
            log_path=tmp_path / f"drone-{i}.log",
        )
        for i in range(count)
    ]
    return [build_drone(spec, common, clock_ns=cpu_clock(True)) for spec in specs]


def test_an_exception_in_one_hosted_drone_ends_it_alone(world: SharedWorld, tmp_path: Path) -> None:
    drones = host(world, tmp_path, 3)
    victim = drones[1]
    real_step = victim.step

    def failing_step() -> None:
        if victim.time_s >= 1.0:
            raise ZeroDivisionError("injected failure in the drone's own code")
        real_step()

    victim.step = failing_step  # type: ignore[method-assign]
    try:
        run_loop(drones, RunOptions(speed_factor=0.0, duration_s=DURATION_S), StopFlag(), router=DroneLogRouter())
    finally:
        for drone in drones:
            drone.close()
    assert victim.failed and victim.ended
    assert math.isclose(victim.time_s, 1.0, abs_tol=0.01)
    for survivor in (drones[0], drones[2]):
        assert not survivor.failed
        assert survivor.time_s == pytest.approx(DURATION_S, abs=1e-6)  # the others flew on to the end
    log = (tmp_path / "drone-1.log").read_text()
    assert "drone software failed at t=1.000 s" in log and "ZeroDivisionError: injected failure" in log
    assert "Traceback" not in (tmp_path / "drone-0.log").read_text()
    assert world.ended(1) and world.end_cause(1) == END_FAILED
    assert world.body_geo(1, math.inf) is not None  # its body stays in the world (falls, then rests): an obstacle


def test_a_stop_request_ends_one_hosted_drone_as_a_kill_would(world: SharedWorld, tmp_path: Path) -> None:
    drones = host(world, tmp_path, 2)
    world.request_stop(0)
    try:
        run_loop(drones, RunOptions(speed_factor=0.0, duration_s=DURATION_S), StopFlag(), router=DroneLogRouter())
    finally:
        for drone in drones:
            drone.close()
    assert drones[0].ended and not drones[0].failed and drones[0].time_s == 0.0
    assert drones[1].time_s == pytest.approx(DURATION_S, abs=1e-6)
    assert world.end_cause(0) == END_STOPPED
    assert "stopped on request" in (tmp_path / "drone-0.log").read_text()


def test_hosted_drones_fly_exactly_as_lone_ones(world: SharedWorld, tmp_path: Path) -> None:
    """Without a world that couples them, a drone hosted with others computes exactly what it computes alone."""
    common = ProcessSpec(airframe=load_airframe("quad_x_f450"), speed_factor=0.0, wind=WindConfig(), duration_s=2.0)

    def fly(instances: list[int]) -> dict[int, tuple[float, ...]]:
        drones = [
            build_drone(
                DroneSpec(instance=i, seed=i, home=DEFAULT_HOME, links=(), log_path=tmp_path / f"d{i}.log"),
                common,
                clock_ns=cpu_clock(False),
            )
            for i in instances
        ]
        try:
            run_loop(drones, RunOptions(speed_factor=0.0, duration_s=2.0), StopFlag())
        finally:
            for drone in drones:
                drone.close()
        return {d.instance: (*d.sim.truth.pos_ned_m, *d.sim.truth.vel_ned_mps, d.time_s) for d in drones}

    together = fly([0, 1, 2])
    for i in (0, 2):
        assert fly([i])[i] == together[i]
