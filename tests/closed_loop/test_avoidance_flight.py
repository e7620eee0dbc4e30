"""Two drones flown at each other through JSBSim, in one process, seeing each other only through the camera.

Both simulations share one world table, as drone processes do; each renders its camera from it, detects with
OpenCV and lets collision prevention bend its velocity. No relay here (camera only), and the world's contact check
is live: a collision crashes both, so "no crash" is a real outcome. The same run with avoidance off collides.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sitl.drone.awareness import Awareness
from sitl.drone.closed_loop import ClosedLoop, SimConfig
from sitl.dynamics.airframe import load_airframe
from sitl.dynamics.geodesy import LocalFrame
from sitl.dynamics.plant import DEFAULT_HOME
from sitl.world.shared import SharedWorld
from sitl.world.view import WorldParticipant
from tests.closed_loop.flight import take_off

pytestmark = pytest.mark.timeout(240)

GAP_M = 12.0


def _fly_head_on(avoid: bool) -> tuple[float, list[bool], list[float], list[str]]:
    """(minimum true centre distance, crashed flags, final distance to goal, events) of a head-on pass."""
    airframe = load_airframe()
    world = SharedWorld.create()
    frame = LocalFrame(DEFAULT_HOME)
    homes = [frame.geo_from_ned((0.0, 0.0, 0.0)), frame.geo_from_ned((GAP_M, 0.0, 0.0))]
    sims = [
        ClosedLoop(SimConfig(airframe=airframe, seed=11 + i, home=home, initial_yaw_rad=yaw))
        for i, (home, yaw) in enumerate(zip(homes, (0.0, math.pi), strict=True))
    ]
    participants = [
        WorldParticipant(world, i, airframe.collision_radius_m, rest_alt_amsl_m=s.truth.geo.alt_amsl_m)
        for i, s in enumerate(sims)
    ]
    seen = [Awareness(s, i, LocalFrame(s.truth.geo), world=world, neighbours=None) for i, s in enumerate(sims)]
    closest = math.inf

    def step_both() -> None:
        nonlocal closest
        for i, (sim, part, eyes) in enumerate(zip(sims, participants, seen, strict=True)):
            sim.step()
            for contact in part.after_step(sim.truth, sim.vehicle.crashed):
                sim.vehicle.crash(f"Collision with drone {contact.instance + 1}")
            eyes.update(sim.time_s)
            del i
        a = frame.ned_from_geo(sims[0].truth.geo)
        b = frame.ned_from_geo(sims[1].truth.geo)
        closest = min(closest, math.dist(a, b))

    try:
        for sim in sims:
            sim.params.set("AVOID_ENABLE", 1 if avoid else 0)
            take_off(sim, 3.0)  # one after the other: each waits on the ground, far apart, while the other climbs
        for sim, sign in zip(sims, (1.0, -1.0), strict=True):
            start = sim.vehicle.estimate.pos_ned_m  # type: ignore[union-attr]
            assert sim.vehicle.set_speed(2.0).ok
            assert sim.vehicle.goto(np.array([start[0] + sign * GAP_M, start[1], start[2]])).ok
        for _ in range(round(15.0 / sims[0].dt_s)):
            step_both()
        goals = [frame.ned_from_geo(homes[1]), frame.ned_from_geo(homes[0])]
        final = [math.dist(frame.ned_from_geo(s.truth.geo)[:2], g[:2]) for s, g in zip(sims, goals, strict=True)]
        events = [e.text for s in sims for e in s.vehicle.events]
        return closest, [s.vehicle.crashed for s in sims], final, events
    finally:
        for part in participants:
            part.world.mark_ended(part.instance)
        world.close()


def test_a_head_on_pair_seeing_only_with_cameras_passes_without_touching() -> None:
    closest, crashed, final, events = _fly_head_on(avoid=True)
    assert crashed == [False, False], events
    assert closest >= 0.8, closest
    assert max(final) < 0.5, final  # both arrive where they were sent
    assert any(e.startswith("Avoidance:") for e in events), events


def test_the_same_pass_without_avoidance_collides() -> None:
    closest, crashed, _final, events = _fly_head_on(avoid=False)
    assert closest < 0.7 and crashed == [True, True], (closest, events)


def _fly_past_pole(avoid: bool) -> tuple[bool, float, list[str]]:
    """(crashed, final distance to the goal, events) of one drone sent straight through a pole, camera only."""
    airframe = load_airframe()
    world = SharedWorld.create()
    try:
        frame = LocalFrame(DEFAULT_HOME)
        sim = ClosedLoop(SimConfig(airframe=airframe, seed=21))
        pole = frame.geo_from_ned((GAP_M / 2, 0.0, -5.0))  # 0.25 m radius, 10 m tall, halfway along the path
        world.add_obstacle(cylinder=True, centre=(pole.lat_deg, pole.lon_deg, pole.alt_amsl_m), radius_m=0.25,
                           height_m=10.0)  # fmt: skip
        part = WorldParticipant(world, 0, airframe.collision_radius_m, rest_alt_amsl_m=sim.truth.geo.alt_amsl_m)
        eyes = Awareness(sim, 0, LocalFrame(sim.truth.geo), world=world, neighbours=None)
        sim.params.set("AVOID_ENABLE", 1 if avoid else 0)

        def step() -> None:
            sim.step()
            for contact in part.after_step(sim.truth, sim.vehicle.crashed):
                sim.vehicle.crash(contact.text())
            eyes.update(sim.time_s)

        take_off(sim, 3.0)
        start = sim.vehicle.estimate.pos_ned_m  # type: ignore[union-attr]
        assert sim.vehicle.set_speed(2.0).ok
        assert sim.vehicle.goto(np.array([start[0] + GAP_M, start[1], start[2]])).ok
        for _ in range(round(15.0 / sim.dt_s)):
            step()
        final = math.dist(frame.ned_from_geo(sim.truth.geo)[:2], (GAP_M, 0.0))
        return sim.vehicle.crashed, final, [e.text for e in sim.vehicle.events]
    finally:
        world.close()


def test_a_drone_sees_a_declared_pole_with_its_camera_and_flies_round_it() -> None:
    crashed, final, events = _fly_past_pole(avoid=True)
    assert not crashed, events
    assert final < 0.5, final
    assert any(e.startswith("Avoidance:") for e in events), events


def test_without_avoidance_the_drone_hits_the_pole() -> None:
    crashed, _final, events = _fly_past_pole(avoid=False)
    assert crashed and any(e.startswith("Collision with obstacle 1") for e in events), events
