"""Benchmark: simulated seconds per CPU second for one drone, and where the time goes.

Flies the closed loop (takeoff to 3 m and hover) unpaced and times each part of a physics step with
``time.process_time_ns`` -- JSBSim, sensors, estimator, autopilot + control cascade -- then steps the bare JSBSim
plant alone with constant hover commands (no control, no sensors, no IO) as the physical limit. Figures are from
one run on the current machine; compare ratios, not absolute numbers.

    python bench/one_drone.py [--sim-seconds 30]
"""

from __future__ import annotations

import argparse
import math
import time

from sitl.airframe import load_airframe
from sitl.dynamics.jsbsim_plant import JsbsimPlant
from sitl.simulation import SimConfig, Simulation


def bare_jsbsim(sim_seconds: float) -> float:
    """CPU seconds per simulated second of the plant alone."""
    airframe = load_airframe()
    plant = JsbsimPlant(airframe)
    hover_u = math.sqrt(airframe.hover_thrust_fraction)
    cmds = (hover_u,) * len(airframe.rotors)
    steps = int(sim_seconds / plant.dt_s)
    start = time.process_time()
    for _ in range(steps):
        plant.step(cmds)
    return (time.process_time() - start) / sim_seconds


def closed_loop(sim_seconds: float) -> dict[str, float]:
    sim = Simulation(SimConfig(airframe=load_airframe(), seed=0))
    totals = {"jsbsim": 0, "sensors": 0, "estimator": 0, "autopilot+control": 0, "other": 0}
    clock = time.process_time_ns
    plant, sensors, estimator, vehicle = sim.plant, sim.sensors, sim.estimator, sim.vehicle
    steps = int(sim_seconds / sim.dt_s)
    armed = False
    wall_start = clock()
    for _ in range(steps):
        t0 = clock()
        readings = sensors.sample(sim.truth)
        t1 = clock()
        est = estimator.update(readings, sim.time_s, sim.dt_s)
        t2 = clock()
        motors = vehicle.step(est, sim.time_s, sim.dt_s)
        t3 = clock()
        sim.truth = plant.step(motors)
        t4 = clock()
        sim.time_s = sim.truth.time_s
        if not armed and vehicle.preflight_problem() is None:
            armed = vehicle.arm().ok and vehicle.takeoff(3.0).ok
        t5 = clock()
        totals["sensors"] += t1 - t0
        totals["estimator"] += t2 - t1
        totals["autopilot+control"] += t3 - t2
        totals["jsbsim"] += t4 - t3
        totals["other"] += t5 - t4
    total_ns = clock() - wall_start
    out = {k: v / 1e9 / sim_seconds for k, v in totals.items()}
    out["total"] = total_ns / 1e9 / sim_seconds
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sim-seconds", type=float, default=30.0)
    args = parser.parse_args()
    bare = bare_jsbsim(args.sim_seconds)
    loop = closed_loop(args.sim_seconds)
    print(f"physics 400 Hz, {args.sim_seconds:.0f} simulated seconds each")
    print(f"bare JSBSim plant : {1 / bare:7.1f} sim s per CPU s  ({bare * 1e3:6.1f} ms CPU per sim s)")
    print(
        f"full closed loop  : {1 / loop['total']:7.1f} sim s per CPU s  ({loop['total'] * 1e3:6.1f} ms CPU per sim s,"
        f" {loop['total'] / bare:.1f}x bare JSBSim)"
    )
    for part in ("jsbsim", "sensors", "estimator", "autopilot+control", "other"):
        print(f"  {part:<18} {loop[part] * 1e3:6.1f} ms per sim s  {loop[part] / loop['total']:5.1%}")


if __name__ == "__main__":
    main()
