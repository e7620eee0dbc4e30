"""What the simulation tells a ground station about itself before any drone flies: its limits, the airframe's size,
and the cost of its physics alone (the bench's yardstick).

Imported by the ground station's composition root only; JSBSim is loaded by ``bare_plant_cpu_ms_per_sim_s``
alone, so that starting a swarm does not load it into the ground station.
"""

from __future__ import annotations

import math
import time
from typing import Literal

from sitl.dynamics.airframe import AirframeError, load_airframe
from sitl.dynamics.plant import PHYSICS_RATE_HZ
from sitl.harness.processes import host_groups
from sitl.process.ports import INSTANCES
from sitl.world.shared import MAX_OBSTACLES
from swarmcommon.cpus import usable_cpus

__all__ = [
    "MAX_INSTANCES",
    "MAX_OBSTACLES",
    "PHYSICS_RATE_HZ",
    "AirframeError",
    "bare_plant_cpu_ms_per_sim_s",
    "contact_distance_m",
    "drones_per_host",
    "parameter_value",
]

MAX_INSTANCES = INSTANCES  # instances 0..MAX_INSTANCES-1: sysids 1..254, each on its own ports (sitl/process/ports.py)
BARE_SIM_SECONDS = 10.0
BARE_REPEATS = 3


def contact_distance_m(airframe: str | None) -> float:
    """Centre distance at which two drones of this airframe touch (twice its collision radius); AirframeError (a
    ValueError, one line) for an airframe that does not exist or does not load."""
    frame = load_airframe(airframe) if airframe else load_airframe()
    return 2.0 * frame.collision_radius_m


def check_behaviour(spec: str) -> None:
    """Load an onboard behaviour (``path/file.py:Class``) as every drone will; ValueError (one line) if it cannot be:
    the ground station says so before anything is spawned."""
    from sitl.onboard.loader import load_behaviour  # imports the simulation: only when a behaviour is asked for

    load_behaviour(spec)


def parameter_value(name: str, value: float) -> int | float:
    """``value`` as a drone takes parameter ``name`` (an int for an integer parameter, which goes out as INT32, a
    float for a REAL32 one); ValueError (one line) unless a PARAM_SET of it would be accepted."""
    from sitl.drone.param_table import build_param_store
    from sitl.params import ParamError, ParamType

    store = build_param_store()
    if name not in store:
        raise ValueError(f"{name} is not a parameter of the simulated drones (docs/parameters.md lists them)")
    try:
        store.set(name, value)
    except ParamError as exc:
        raise ValueError(str(exc)) from None
    return int(value) if store.definition(name).type is ParamType.INT else float(value)


def drones_per_host(n_drones: int, drones_per_process: int | Literal["auto"]) -> list[int]:
    """How many drones each process runs for a swarm of ``n_drones`` with this setting (spawn order), on this
    machine (``auto`` counts its usable CPUs)."""
    return [len(group) for group in host_groups(n_drones, drones_per_process, usable_cpus())]


def bare_plant_cpu_ms_per_sim_s(sim_seconds: float = BARE_SIM_SECONDS, repeats: int = BARE_REPEATS) -> float:
    """CPU ms per simulated second of the plant alone, hovering with constant commands (median of ``repeats``).

    Same airframe (the default) and physics rate as the drones; the thread CPU clock, so other processes do not
    count."""
    from sitl.dynamics.jsbsim_plant import JsbsimPlant

    airframe = load_airframe()
    dt_s = 1.0 / PHYSICS_RATE_HZ
    cmds = (math.sqrt(airframe.hover_thrust_fraction),) * len(airframe.rotors)
    steps = round(sim_seconds / dt_s)
    results = []
    for _ in range(repeats):
        plant = JsbsimPlant(airframe, dt_s=dt_s, initial_pos_ned_m=(0.0, 0.0, -10.0), initial_motor_cmds=cmds)
        step = plant.step
        start = time.thread_time()
        for _ in range(steps):
            step(cmds)
        results.append((time.thread_time() - start) / (steps * dt_s) * 1e3)
    return sorted(results)[len(results) // 2]
