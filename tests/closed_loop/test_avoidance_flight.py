"""Two drones flown at each other through JSBSim, in one process, seeing each other only through the camera.

Both simulations share one world table, as drone processes do; each renders its camera from it, detects with
OpenCV and lets collision prevention bend its velocity. No relay here (camera only), and the world's contact check
is live: a collision crashes both, so "no crash" is a real outcome. The same run with avoidance off collides.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from gcs.record.metrics import compute_metrics
from gcs.record.recording import DroneSample, EventRecord, FlightRecording
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
TELEMETRY_HZ = 10.0  # LOCAL_POSITION_NED's default rate (sitl/protocol/telemetry.py), what the report samples


@dataclass(frozen=True, slots=True)
class HeadOn:
    """A head-on pass: the world's truth at physics rate, and what the drones reported at their telemetry rate."""

    closest_m: float  # the true centres' minimum distance, every physics step until they touched
    closest_time_s: float
    closing_speed_mps: float  # the true relative speed at that instant
    crashed: list[bool]
    final_m: list[float]  # each drone's distance to its goal at the end
    events: list[str]
    reported: FlightRecording  # each drone's estimate at TELEMETRY_HZ (its own phase), in the swarm frame


def _fly_head_on(avoid: bool) -> HeadOn:
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
    local = [LocalFrame(home) for home in homes]
    reported = FlightRecording(mission_name="head_on", n_drones=2, collision_radius_m=2 * airframe.collision_radius_m)
    closest = (math.inf, 0.0, 0.0)
    previous = None
    told = [0, 0]  # events already put in the recording, per drone

    def step_both() -> None:
        nonlocal closest, previous
        touched = any(sim.vehicle.crashed for sim in sims)  # (after that, two falling bodies: no separation)
        for i, (sim, part, eyes) in enumerate(zip(sims, participants, seen, strict=True)):
            sim.step()
            for contact in part.after_step(sim.truth, sim.vehicle.crashed):
                sim.vehicle.crash(contact.text())
            eyes.update(sim.time_s)
            reported.events += [EventRecord(time_s=sim.time_s, sysid=i + 1, text=e.text)
                                for e in sim.vehicle.events[told[i]:]]  # fmt: skip
            told[i] = len(sim.vehicle.events)
            # telemetry as the ground station records it: the estimate, at the drone's rate, each drone its own phase
            tick = sim.time_s * TELEMETRY_HZ + 0.5 * i
            # (a drone that crashed is lost to the ground station: its report ends there, as flying_samples cuts it)
            if math.floor(tick) != math.floor(tick - sim.dt_s * TELEMETRY_HZ) and not sim.vehicle.crashed:
                est = sim.vehicle.estimate
                assert est is not None
                reported.samples.append(DroneSample(
                    time_s=sim.time_s, sysid=i + 1, armed=True, mode="OFFBOARD",
                    pos_ned_m=frame.ned_from_geo(local[i].geo_from_ned(est.pos_ned_m)), vel_ned_mps=est.vel_ned_mps,
                ))  # fmt: skip
        a = np.array(frame.ned_from_geo(sims[0].truth.geo))
        b = np.array(frame.ned_from_geo(sims[1].truth.geo))
        if previous is not None and not touched and math.dist(a, b) < closest[0]:
            closing = float(np.linalg.norm((a - b) - previous) / sims[0].dt_s)
            closest = (math.dist(a, b), sims[0].time_s, closing)
        previous = a - b

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
        return HeadOn(closest_m=closest[0], closest_time_s=closest[1], closing_speed_mps=closest[2],
                      crashed=[s.vehicle.crashed for s in sims], final_m=final, events=events,
                      reported=reported)  # fmt: skip
    finally:
        for part in participants:
            part.world.mark_ended(part.instance)
        world.close()


def test_a_head_on_pair_seeing_only_with_cameras_passes_without_touching() -> None:
    flown = _fly_head_on(avoid=True)
    assert flown.crashed == [False, False], flown.events
    assert flown.closest_m >= 0.8, flown.closest_m
    assert max(flown.final_m) < 0.5, flown.final_m  # both arrive where they were sent
    assert any(e.startswith("Avoidance:") for e in flown.events), flown.events
    # AND the flight report's minimum separation, from the drones' 10 Hz estimates, is the true minimum to within
    # one sample's travel at the closing speed (docs/metrics.md), found at the true instant to within one sample
    metrics = compute_metrics(flown.reported)
    one_sample_m = flown.closing_speed_mps / TELEMETRY_HZ
    assert metrics.min_separation_m is not None and metrics.min_separation_time_s is not None
    assert abs(metrics.min_separation_m - flown.closest_m) <= one_sample_m, (metrics.min_separation_m, flown)
    assert abs(metrics.min_separation_time_s - flown.closest_time_s) <= 1.0 / TELEMETRY_HZ, flown.closest_time_s


def test_the_same_pass_without_avoidance_collides() -> None:
    flown = _fly_head_on(avoid=False)
    assert flown.closest_m < 0.7 and flown.crashed == [True, True], (flown.closest_m, flown.events)
    # AND the report's minimum separation, its instant and its pair are the contact's, though no sample caught it
    metrics = compute_metrics(flown.reported)
    # (each drone reports it, from its own world's check: the two distances may differ by a step's travel)
    reports = [e for e in flown.reported.events if e.text.startswith("Collision with drone")]
    contact = min(reports, key=lambda e: float(e.text.split(" at ")[1].removesuffix(" m")))
    assert metrics.min_separation_m is not None and metrics.min_separation_m <= flown.reported.collision_radius_m
    assert f"at {metrics.min_separation_m:.2f} m" in contact.text  # the distance the world measured
    assert (metrics.min_separation_time_s, metrics.min_separation_pair) == (contact.time_s, (1, 2))


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
