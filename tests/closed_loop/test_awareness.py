"""Perception renders frames only when something uses them."""

from __future__ import annotations

import pytest

from sitl.airframe import load_airframe
from sitl.awareness import Awareness
from sitl.dynamics.geodesy import LocalFrame
from sitl.simulation import SimConfig, Simulation
from sitl.world import SharedWorld, WorldParticipant

pytestmark = pytest.mark.timeout(60)


@pytest.mark.parametrize(("avoid", "frames_expected"), [(1, True), (0, False)])
def test_the_cameras_render_only_while_avoidance_uses_them(avoid: int, frames_expected: bool) -> None:
    world = SharedWorld.create()
    try:
        sim = Simulation(SimConfig(airframe=load_airframe(), seed=3))
        sim.params.set("AVOID_ENABLE", avoid)
        part = WorldParticipant(world, 0, 0.35, rest_alt_amsl_m=sim.truth.geo.alt_amsl_m)
        eyes = Awareness(sim, 0, LocalFrame(sim.truth.geo), world=world, neighbours=None)
        for _ in range(round(4.0 / sim.dt_s)):  # past the estimator's attitude convergence
            sim.step()
            part.after_step(sim.truth, sim.vehicle.crashed)
            eyes.update(sim.time_s)
        assert (eyes.frames > 0) is frames_expected, eyes.frames
    finally:
        world.close()
