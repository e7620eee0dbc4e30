"""A rotating circle of drones and one silent drone hovering in its path, flown in one process on one shared world.

The shape of ``swarm formation circle --rate`` with a drone that says nothing: every ClosedLoop steps once per tick
(the lockstep order of a real swarm), each with its world participant (contacts crash) and its perception (camera
rendered from the world; relayed neighbours). The circle's drones hear one another through the relay, at 20 Hz
from their estimates, as the ground station relays them; nobody hears the silent drone, which can only be seen.
The circle is streamed as offboard position + velocity setpoints with yaw left free, as gcs/command/streamer.py streams
it.

The silent drone takes off outside the circle and, once the circle has turned for ``settle_s``, flies at 1 m/s
onto the circle's path (arriving about halfway between two drones) and holds there: a drone that went quiet in a
failsafe hold. Starting it on the path instead would put the first drone of the circle 1.6 m behind it at the start,
a test of the first second and of nothing after.

Used by tests/closed_loop/test_silent_drone.py and bench/silent_drone.py (which compares the camera options).
"""

from __future__ import annotations

import hashlib
import math
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sitl.autopilot.px4_modes import Px4Mode
from sitl.avoidance.collision_prevention import RelayedNeighbour
from sitl.control.cascade import TrajectorySetpoint
from sitl.drone.awareness import Awareness
from sitl.drone.closed_loop import ClosedLoop, SimConfig
from sitl.dynamics.airframe import load_airframe
from sitl.dynamics.geodesy import LocalFrame
from sitl.dynamics.plant import DEFAULT_HOME
from sitl.world.shared import SharedWorld
from sitl.world.view import WorldParticipant

RELAY_PERIOD_S = 0.05  # gcs/fleet/relay.py relays each drone at most 10 Hz; 20 Hz here costs nothing and errs safe
SETPOINT_PERIOD_S = 0.05  # gcs/flight/formation.py SETPOINT_STREAM_HZ
TAKEOFF_TIMEOUT_S = 15.0


@dataclass(frozen=True, slots=True, kw_only=True)
class CircleScenario:
    drones: int = 8
    radius_m: float = 4.0
    rate_radps: float = 0.3  # clockwise seen from above: slot speed 1.2 m/s on a 4 m circle
    alt_m: float = 3.0
    settle_s: float = 5.0  # the circle turns this long before the silent drone moves onto its path
    rotate_s: float = 30.0  # a turn takes 21 s: every drone of the circle passes the silent one once it is there
    silent_start_out_m: float = 3.0  # how far outside the circle the silent drone waits
    silent_speed_mps: float = 1.0
    seed: int = 1
    yaw_follow: int | None = None  # MPC_YAW_FOLLOW (None: the default)
    cam_rig: int | None = None  # CAM_RIG (None: the default)
    avoid: bool = True
    stop_at_collision: bool = False  # end the flight at the first contact (a test that expects one)


@dataclass(frozen=True, slots=True, kw_only=True)
class CircleOutcome:
    collisions: int  # drones that crashed (a contact crashes both of a pair)
    events: tuple[str, ...]  # every collision STATUSTEXT
    min_silent_distance_m: float  # closest approach of any circle drone to the silent one (centres), once it moved
    silent_hold_error_m: float  # how far the silent drone ended from where it was sent (it avoids too)
    avoidance_episodes: int
    cpu_ms_per_drone_sim_s: float  # whole step (physics, control, perception) on this thread's CPU clock
    perception_ms_per_drone_sim_s: float
    control_ms_per_drone_sim_s: float
    sim_s: float


def _slot_ne(scenario: CircleScenario, index: int, tau_s: float) -> tuple[float, float, float, float]:
    """North, east and the velocity of circle slot ``index`` ``tau_s`` after the circle started turning."""
    angle = 2.0 * math.pi * index / scenario.drones + scenario.rate_radps * tau_s
    r, w = scenario.radius_m, scenario.rate_radps
    return r * math.cos(angle), r * math.sin(angle), -r * w * math.sin(angle), r * w * math.cos(angle)


def fly_circle_past_a_silent_drone(
    scenario: CircleScenario, on_tick: Callable[[list[ClosedLoop], float], None] | None = None
) -> CircleOutcome:
    """Fly the scenario; ``on_tick(sims, now)`` is called after every step of all drones (to trace a run)."""
    airframe = load_airframe()
    common = LocalFrame(DEFAULT_HOME)
    n = scenario.drones
    # The circle's drones take off at their slots; the silent one outside the circle, radially out from where it will
    # hold: halfway between two slots when it arrives (about settle_s + its flight time after the circle started).
    arrive_s = scenario.settle_s + scenario.silent_start_out_m / scenario.silent_speed_mps + 1.0
    silent_angle = math.pi / n + scenario.rate_radps * arrive_s
    homes_ne = [_slot_ne(scenario, i, 0.0)[:2] for i in range(n)]
    out_m = scenario.radius_m + scenario.silent_start_out_m
    homes_ne.append((out_m * math.cos(silent_angle), out_m * math.sin(silent_angle)))
    hold_ne = (scenario.radius_m * math.cos(silent_angle), scenario.radius_m * math.sin(silent_angle))
    world = SharedWorld.create()
    try:
        sims: list[ClosedLoop] = []
        parts: list[WorldParticipant] = []
        eyes: list[Awareness] = []
        for i, (north, east) in enumerate(homes_ne):
            sim = ClosedLoop(SimConfig(airframe=airframe, seed=scenario.seed * 100 + i,
                                       home=common.geo_from_ned((north, east, 0.0))))  # fmt: skip
            sim.part_clock_ns = time.thread_time_ns
            if scenario.yaw_follow is not None:
                sim.params.set("MPC_YAW_FOLLOW", scenario.yaw_follow)
            if scenario.cam_rig is not None:
                sim.params.set("CAM_RIG", scenario.cam_rig)
            sim.params.set("AVOID_ENABLE", 1 if scenario.avoid else 0)
            sims.append(sim)
            parts.append(WorldParticipant(world, i, airframe.collision_radius_m,
                                          rest_alt_amsl_m=sim.truth.geo.alt_amsl_m))  # fmt: skip
            eyes.append(Awareness(sim, i, LocalFrame(sim.truth.geo), world=world, neighbours=None,
                                  clock_ns=time.thread_time_ns))  # fmt: skip
        circle = sims[:n]
        silent = sims[n]
        home_offsets = [np.array((north, east, 0.0)) for north, east in homes_ne]
        events: list[str] = []
        closest = math.inf
        next_relay_s = 0.0
        next_setpoint_s = 0.0
        circle_start_s: float | None = None
        silent_sent = False
        launched: set[int] = set()  # Hold is also the mode on the ground: taken off = launched and back in Hold
        t0_cpu = time.thread_time()

        def step_all() -> None:
            nonlocal closest
            for i, (sim, part, eye) in enumerate(zip(sims, parts, eyes, strict=True)):
                sim.step()
                for contact in part.after_step(sim.truth, sim.vehicle.crashed):
                    sim.vehicle.crash(contact.text())
                    events.append(f"drone {i + 1}: {contact.text()}")
                eye.update(sim.time_s)
            if silent_sent:
                silent_ned = common.ned_from_geo(silent.truth.geo)
                for sim in circle:
                    closest = min(closest, math.dist(common.ned_from_geo(sim.truth.geo), silent_ned))

        def relay(now_s: float) -> None:
            """Each circle drone hears the others' estimates, in its own frame (the silent one is never heard)."""
            reports = []
            for j, sim in enumerate(circle):
                est = sim.estimate
                if est is not None and est.position_valid:
                    reports.append((j, home_offsets[j] + est.pos_ned_m, est.vel_ned_mps))
            for i, sim in enumerate(circle):
                sim.vehicle.collision_prevention.set_relay([
                    RelayedNeighbour(sysid=j + 1, pos_ned_m=tuple(float(v) for v in pos - home_offsets[i]),  # type: ignore[arg-type]
                                     vel_ned_mps=tuple(float(v) for v in vel), received_s=now_s)  # type: ignore[arg-type]
                    for j, pos, vel in reports if j != i
                ])  # fmt: skip

        def stream(now_s: float, tau_s: float) -> None:
            for i, sim in enumerate(circle):
                north, east, vn, ve = _slot_ne(scenario, i, tau_s)
                sim.vehicle.set_offboard_setpoint(
                    TrajectorySetpoint(pos_ned_m=(north - homes_ne[i][0], east - homes_ne[i][1], -scenario.alt_m),
                                       vel_ned_mps=(vn, ve, 0.0)),
                    now_s,
                )  # fmt: skip

        end_s = math.inf
        while (now := sims[0].time_s) < end_s and not (scenario.stop_at_collision and events):
            step_all()
            if on_tick is not None:
                on_tick(sims, now)
            if now >= next_relay_s:
                next_relay_s = now + RELAY_PERIOD_S
                relay(now)
            if circle_start_s is None:
                for k, sim in enumerate(sims):
                    v = sim.vehicle
                    if k not in launched and v.preflight_problem() is None:
                        assert v.arm().ok and v.takeoff(scenario.alt_m).ok
                        launched.add(k)
                if len(launched) == len(sims) and all(s.vehicle.status.mode is Px4Mode.AUTO_LOITER for s in sims):
                    circle_start_s = now
                    end_s = now + scenario.rotate_s
                    stream(now, 0.0)
                    for sim in circle:
                        assert sim.vehicle.start_offboard(now).ok
                elif now > TAKEOFF_TIMEOUT_S + 10.0:
                    raise AssertionError(f"takeoff did not complete: {[s.vehicle.status.mode for s in sims]}")
            elif now >= next_setpoint_s:
                next_setpoint_s = now + SETPOINT_PERIOD_S
                stream(now, now - circle_start_s)
                if not silent_sent and now - circle_start_s >= scenario.settle_s:
                    silent_sent = True
                    v = silent.vehicle
                    here = v.estimate.pos_ned_m  # type: ignore[union-attr]
                    target = (hold_ne[0] - homes_ne[n][0], hold_ne[1] - homes_ne[n][1], float(here[2]))
                    assert v.set_speed(scenario.silent_speed_mps).ok and v.goto(np.array(target)).ok
        cpu_s = time.thread_time() - t0_cpu
        drone_sim_s = len(sims) * sims[0].time_s
        return CircleOutcome(
            collisions=sum(s.vehicle.crashed for s in sims),
            events=tuple(events),
            min_silent_distance_m=closest,
            silent_hold_error_m=math.dist(common.ned_from_geo(silent.truth.geo)[:2], hold_ne),
            avoidance_episodes=sum(s.vehicle.collision_prevention.episodes for s in sims),
            cpu_ms_per_drone_sim_s=1e3 * cpu_s / drone_sim_s,
            perception_ms_per_drone_sim_s=1e-6 * sum(e.cpu_ns for e in eyes) / drone_sim_s,
            control_ms_per_drone_sim_s=1e-6 * sum(s.control_ns for s in sims) / drone_sim_s,
            sim_s=sims[0].time_s,
        )
    finally:
        world.close()


# The two flights whose digests tests/closed_loop/test_reference_flight.py holds (beside the reference flight) and
# bench/drone_parts.py prints: the 9-drone circle and the dense circle, 24 drones on the radius ``swarm bench`` gives
# 24 slots (2 m apart), turning at half the rate so the rim keeps the 9-drone circle's pace.
CIRCLE = CircleScenario(rotate_s=5.0)
DENSE = CircleScenario(drones=24, radius_m=8.0, rate_radps=0.15, rotate_s=5.0)


def fly_with_digest(scenario: CircleScenario) -> tuple[str, CircleOutcome, list[ClosedLoop]]:
    """Fly ``scenario`` and hash every drone's true position, velocity and attitude at every step (SHA-256 of the
    float64 bytes): a single bit anywhere in any drone's flight changes it. Returns the hex digest, the outcome and
    the drones, so a caller can read their parts' clocks."""
    digest = hashlib.sha256()
    flown: list[ClosedLoop] = []

    def trace(sims: list[ClosedLoop], _now: float) -> None:
        if not flown:
            flown.extend(sims)
        for sim in sims:
            t = sim.truth
            digest.update(struct.pack("<3d3d4d", *t.pos_ned_m, *t.vel_ned_mps, *t.att_q_frd_to_ned))

    outcome = fly_circle_past_a_silent_drone(scenario, on_tick=trace)
    return digest.hexdigest(), outcome, flown
