"""The composition root: the one ground-station module that sees both sides and wires the simulation in.

Every other module of ``gcs`` depends on the interfaces of gcs/fleet/harness.py only (the import-linter contract in
pyproject.toml fails the build otherwise). Here the ground station's spawn plan becomes the simulation's launch
plan: the same origin and layout offsets, which the simulation turns into each drone's home with its own geodesy
(the simulation decides where bodies really are), and ``SITL`` hands out ``SitlHarness`` instances. The ``swarm``
entry point (gcs/cli.py) passes ``SITL`` to whatever builds swarms: ``swarm up``, the mission runner, the bench.
"""

from __future__ import annotations

from typing import Literal

from gcs.fleet.harness import SimulationHarness, SpawnPlan
from gcs.fleet.links import LinkPlan
from sitl.harness import GeoPoint, LaunchPlan, LinkImpairment, LinkProfile, MeshSettings, SitlHarness
from sitl.harness import simulation as sim


def launch_plan(plan: SpawnPlan) -> LaunchPlan:
    """The simulation's launch plan for the ground station's spawn plan."""
    origin = GeoPoint(lat_deg=plan.origin.lat_deg, lon_deg=plan.origin.lon_deg, alt_amsl_m=plan.origin.alt_amsl_m)
    return LaunchPlan(
        origin=origin,
        offsets_ne_m=tuple(plan.offsets_ne_m()),
        speed_factor=plan.speed_factor,
        lockstep=plan.lockstep,
        lockstep_quantum=plan.lockstep_quantum,
        first_instance=plan.first_instance,
        airframe=plan.airframe,
        seed=plan.seed,
        log_dir=plan.log_dir,
        camera_drones=plan.camera_drones,
        camera_dir=plan.camera_dir,
        drones_per_process=plan.drones_per_process,
        signing_key_file=plan.signing_key_file,
        links=link_profile(plan.links),
        mesh=MeshSettings(range_m=plan.mesh.range_m, exponent=plan.mesh.exponent) if plan.mesh is not None else None,
        behaviour=plan.behaviour,
        wind_ned_mps=plan.wind_ned_mps,
        gust_mps=plan.gust_mps,
    )


def link_profile(plan: LinkPlan) -> LinkProfile:
    """The simulation's link profile for the ground station's link settings (the same keys on both sides)."""
    return LinkProfile(
        gcs=LinkImpairment(**plan.gcs.values()),
        api=LinkImpairment(**plan.api.values()),
        neighbour=LinkImpairment(**plan.neighbour.values()),
    )


class SitlSimulation:
    """The simulation of this project (``sitl`` drones) as the ground station's ``Simulation``."""

    @property
    def max_instances(self) -> int:
        return sim.MAX_INSTANCES

    @property
    def max_obstacles(self) -> int:
        return sim.MAX_OBSTACLES

    @property
    def physics_rate_hz(self) -> float:
        return sim.PHYSICS_RATE_HZ

    def harness(self, plan: SpawnPlan) -> SimulationHarness:
        return SitlHarness(launch_plan(plan))

    def contact_distance_m(self, airframe: str | None) -> float:
        return sim.contact_distance_m(airframe)

    def bare_plant_cpu_ms_per_sim_s(self) -> float:
        return sim.bare_plant_cpu_ms_per_sim_s()

    def check_behaviour(self, spec: str) -> None:
        sim.check_behaviour(spec)

    def drones_per_host(self, n_drones: int, drones_per_process: int | Literal["auto"]) -> list[int]:
        return sim.drones_per_host(n_drones, drones_per_process)

    def parameter_value(self, name: str, value: float) -> int | float:
        return sim.parameter_value(name, value)


SITL = SitlSimulation()
