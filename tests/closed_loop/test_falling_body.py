"""A dead drone's body falls through the shared world onto a drone hovering below it, which crashes.

One ClosedLoop hovers with its camera and collision prevention running, as in a drone process; the dead drone is a
row of the same world, written once above it and marked ended as the supervisor marks a killed process. Nothing
moves that row afterwards: the body falls because every reader computes it from the row at its own time.
"""

from __future__ import annotations

import math

import pytest

from sitl.drone.awareness import Awareness
from sitl.drone.closed_loop import ClosedLoop, SimConfig
from sitl.dynamics.airframe import load_airframe
from sitl.dynamics.geodesy import LocalFrame
from sitl.mathutil import GRAVITY_MPS2
from sitl.world.shared import SharedWorld
from sitl.world.view import WorldParticipant
from tests.closed_loop.flight import take_off

pytestmark = pytest.mark.timeout(120)

HOVER_M = 2.0
DROP_ABOVE_M = 3.0


def test_a_body_falling_from_3_m_above_a_hovering_drone_hits_it_and_it_crashes() -> None:
    airframe = load_airframe()
    world = SharedWorld.create()
    try:
        sim = ClosedLoop(SimConfig(airframe=airframe, seed=5))
        rest_alt = sim.truth.geo.alt_amsl_m
        part = WorldParticipant(world, 0, airframe.collision_radius_m, rest_alt_amsl_m=rest_alt)
        eyes = Awareness(sim, 0, LocalFrame(sim.truth.geo), world=world, neighbours=None)
        take_off(sim, HOVER_M)
        # GIVEN drone 2's last state 3 m straight above the hovering drone, at rest, and its process gone
        geo = sim.truth.geo
        world.write(1, sim.time_s, (geo.lat_deg, geo.lon_deg, geo.alt_amsl_m + DROP_ABOVE_M), (0.0, 0.0, 0.0),
                    airframe.collision_radius_m, False, rest_alt_amsl_m=rest_alt)  # fmt: skip
        world.mark_ended(1)
        ended_at_s = sim.time_s
        crashed_at_s = math.nan
        # WHEN the drone flies on for 2 s
        for _ in range(round(2.0 / sim.dt_s)):
            sim.step()
            for contact in part.after_step(sim.truth, sim.vehicle.crashed):
                sim.vehicle.crash(contact.text())
                crashed_at_s = sim.time_s
            eyes.update(sim.time_s)
        # THEN it was hit when the body had fallen to within two radii: after (3 - 0.7) m of free fall, 0.68 s
        events = [e.text for e in sim.vehicle.events]
        assert sim.vehicle.crashed and any(e.startswith("Collision with drone 2") for e in events), events
        expected_s = math.sqrt(2.0 * (DROP_ABOVE_M - 2.0 * airframe.collision_radius_m) / GRAVITY_MPS2)
        assert crashed_at_s - ended_at_s == pytest.approx(expected_s, abs=0.05)
        # AND the body lies on the ground where it fell
        lat, lon, alt = world.body_geo(1, sim.time_s)  # type: ignore[misc]
        assert alt == pytest.approx(rest_alt, abs=1e-6)
        assert math.dist(LocalFrame(geo).ned_from_geo(type(geo)(lat_deg=lat, lon_deg=lon, alt_amsl_m=alt))[:2],
                         (0.0, 0.0)) < 1e-6  # fmt: skip
    finally:
        world.close()
