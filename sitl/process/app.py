"""Composition of one drone process: build its drones (one, or several hosted together), attach the demo, run the
loop, and end every drone cleanly."""

from __future__ import annotations

import logging
from collections.abc import Sequence

from sitl.process.drone import Drone, DroneLogRouter, HostShare, build_drone, cpu_clock
from sitl.process.runtime import LockstepSteps, RunOptions, StepClock, StopFlag, run_loop
from sitl.process.specs import DroneSpec, ProcessSpec
from sitl.world.lockstep import LockstepMember
from sitl.world.shared import SharedWorld

EXIT_FAILED = 1  # every drone of the process ended by an exception in its own code


def run(specs: Sequence[DroneSpec], common: ProcessSpec) -> int:
    """Run the drones of ``specs`` in this process until stopped; 0, or EXIT_FAILED when every drone failed.

    With several drones, log records go to the log of the drone that wrote them (``DroneLogRouter``)."""
    stop = StopFlag()
    stop.install()
    router = DroneLogRouter()
    root = logging.getLogger()
    root.handlers[:] = [router]
    clock_ns = cpu_clock(common.world_name is not None)
    drones: list[Drone] = []
    world: SharedWorld | None = None
    clock: StepClock | None = None
    try:
        share = HostShare() if len(specs) > 1 else None
        for spec in specs:
            drones.append(build_drone(spec, common, clock_ns=clock_ns, share=share))
        if common.lockstep and common.world_name is not None:
            world = SharedWorld.attach(common.world_name)
            clock = LockstepSteps(LockstepMember(world, [d.instance for d in drones], common.lockstep_quantum))
        run_loop(
            drones,
            RunOptions(speed_factor=common.speed_factor, duration_s=common.duration_s),
            stop,
            clock=clock,
            router=router,
        )
    finally:
        last_words = f"stopped by {stop.signal_name} at t=" if stop.stopped else None
        for drone in drones:
            drone.close(last_words=f"{last_words}{drone.time_s:.2f} s" if last_words else None)
        if world is not None:
            world.close()
    if stop.stopped:
        return 0
    return EXIT_FAILED if drones and all(d.failed for d in drones) else 0
