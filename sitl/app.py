"""Composition of one drone process: build the simulation, attach the demo, run the paced loop."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from sitl.airframe import Airframe
from sitl.awareness import Awareness
from sitl.demo import DemoFlight
from sitl.dynamics.plant import GeoPoint
from sitl.lockstep import LockstepMember
from sitl.mav_vehicle import SimVehicleApi
from sitl.mavlink_io import LinkConfig, MavlinkEndpoint
from sitl.protocol import Identity
from sitl.runtime import LockstepSteps, LoopStats, RunOptions, StopFlag, run_loop
from sitl.simulation import SimConfig, Simulation
from sitl.wind import WindConfig
from sitl.world import SharedWorld, WorldParticipant

CPU_REPORT_STEPS = 100  # how often the time spent per part is published in the shared world (for benchmarks)


def _say(text: str) -> None:
    print(text, flush=True)


def run(
    *,
    instance: int,
    airframe: Airframe,
    seed: int,
    speed_factor: float,
    home: GeoPoint,
    wind: WindConfig,
    duration_s: float | None,
    demo: bool,
    links: list[LinkConfig],
    world_name: str | None = None,
    lockstep: bool = False,
    lockstep_quantum: int = 1,
    camera_frames: Path | None = None,
) -> int:
    stop = StopFlag()
    stop.install()
    sim = Simulation(SimConfig(airframe=airframe, seed=seed, home=home, wind=wind))
    speed = "lockstep" if lockstep else "unpaced" if speed_factor == 0 else f"{speed_factor:g}x real time"
    _say(
        f"sitl {instance}: airframe {airframe.name} ({airframe.mass_kg:.2f} kg, hover at "
        f"{airframe.hover_thrust_fraction:.0%} of max thrust), seed {seed}, {speed}, "
        f"physics {1 / sim.dt_s:.0f} Hz, home {home.lat_deg:.6f}, {home.lon_deg:.6f}, {home.alt_amsl_m:.1f} m"
    )
    flight = DemoFlight(sim, _say) if demo else None
    world = SharedWorld.attach(world_name) if world_name else None
    # The body rests with its centre where it rests now, at boot on its gear: that is where it comes to lie if it falls.
    rest_alt = sim.truth.geo.alt_amsl_m
    participant = (
        WorldParticipant(world, instance, airframe.collision_radius_m, rest_alt_amsl_m=rest_alt)
        if world is not None
        else None
    )
    clock = LockstepSteps(LockstepMember(world, instance, lockstep_quantum)) if lockstep and world is not None else None

    api = SimVehicleApi(sim)
    endpoint = MavlinkEndpoint(Identity(sysid=instance + 1), api, sim.params, links) if links else None
    # In a swarm the parts are timed on this thread's CPU clock (Simulation.part_clock_ns), so the split stays true
    # when there are more drones than cores.
    part_clock_ns = time.thread_time_ns if world is not None else time.perf_counter_ns
    sim.part_clock_ns = part_clock_ns
    awareness = Awareness(
        sim,
        instance,
        api.frame,
        world=world,
        neighbours=endpoint.neighbours if endpoint is not None else None,
        frames_dir=camera_frames,
        shared_clock=clock is not None,
        clock_ns=part_clock_ns,
    )

    stats = LoopStats(clock_ns=part_clock_ns)
    steps = 0

    def on_step() -> None:
        nonlocal steps
        if flight is not None:
            flight.tick()
        if participant is not None:
            for contact in participant.after_step(sim.truth, sim.vehicle.crashed):
                sim.vehicle.crash(contact.text())
        awareness.update(sim.time_s)
        steps += 1
        if world is not None and steps % CPU_REPORT_STEPS == 0:
            world.write_cpu(instance, sim.physics_ns * 1e-9, sim.control_ns * 1e-9, awareness.cpu_ns * 1e-9,
                            stats.link_ns * 1e-9)  # fmt: skip

    for link in endpoint.links if endpoint is not None else []:
        remote = link.config.remote
        _say(
            f"sitl {instance}: MAVLink {link.config.name} link on udp {link.config.bind[0]}:{link.port}"
            + (f", streaming to {remote[0]}:{remote[1]}" if remote else "")
        )
    try:
        run_loop(
            sim,
            RunOptions(speed_factor=speed_factor, duration_s=duration_s),
            stop,
            endpoint=endpoint,
            on_step=on_step,
            on_event=(lambda e: flight.event(e.text)) if flight is not None else None,
            finished=(lambda: flight.done) if flight is not None else None,
            clock=clock,
            stats=stats,
            booting=lambda: not sim.vehicle.status.armed and sim.vehicle.preflight_problem() is not None,
        )
    finally:
        if endpoint is not None:
            endpoint.close()
        if participant is not None:
            participant.close()
    if stop.stopped:
        print(f"sitl {instance}: stopped by {stop.signal_name} at t={sim.time_s:.2f} s", file=sys.stderr)
    return 0
