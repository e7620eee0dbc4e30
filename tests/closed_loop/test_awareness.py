"""Perception renders frames only when something uses them."""

from __future__ import annotations

import pytest

from sitl.airframe import load_airframe
from sitl.awareness import Awareness
from sitl.dynamics.geodesy import LocalFrame
from sitl.simulation import SimConfig, Simulation
from sitl.world import SharedWorld, WorldParticipant

pytestmark = pytest.mark.timeout(60)


@pytest.mark.parametrize(("avoid", "armed", "frames_expected"), [(1, True, True), (1, False, False), (0, True, False)])
def test_the_cameras_render_only_while_avoidance_uses_them(avoid: int, armed: bool, frames_expected: bool) -> None:
    """Collision prevention is the frames' only user, and only in flight: a disarmed drone (a swarm's boot, with
    every neighbour in view on the ground) and a drone with avoidance off render nothing."""
    world = SharedWorld.create()
    try:
        sim = Simulation(SimConfig(airframe=load_airframe(), seed=3))
        sim.params.set("AVOID_ENABLE", avoid)
        part = WorldParticipant(world, 0, 0.35, rest_alt_amsl_m=sim.truth.geo.alt_amsl_m)
        eyes = Awareness(sim, 0, LocalFrame(sim.truth.geo), world=world, neighbours=None)

        def run(seconds: float) -> None:
            for _ in range(round(seconds / sim.dt_s)):
                sim.step()
                part.after_step(sim.truth, sim.vehicle.crashed)
                eyes.update(sim.time_s)

        run(5.0)  # past the estimator's attitude convergence and the pre-arm checks, disarmed
        assert eyes.frames == 0
        if armed:
            assert sim.vehicle.arm().ok
        run(1.0)
        assert (eyes.frames > 0) is frames_expected, eyes.frames
    finally:
        world.close()
