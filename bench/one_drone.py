"""Benchmark: simulated seconds per CPU second for one drone, and where the time goes.

Three measurements of the same flight (arm as soon as the pre-arm checks pass, take off to 3 m, hover), unpaced:

1. **total**: ``ClosedLoop.step()`` itself, unmodified, with the process CPU clock read only at the start and the end
   of the run. This is the figure to compare (a swarm drone runs exactly this, plus its MAVLink IO).
2. **breakdown**: the parts of a physics step called one by one, as ``ClosedLoop.step()`` calls them (sensors,
   estimator, autopilot, control cascade, JSBSim, wind and battery), each timed with the process CPU clock. A read
   of that clock is a system call (about 0.4 us, several percent of a part), so its cost is measured first and
   subtracted from every interval; the parts then add up to within a few percent of the total. (The monotonic clock
   is ten times cheaper to read but counts time the process spent descheduled, which on a shared machine swamps
   the parts.) The autopilot/cascade split times ``Cascade.update`` from a wrapper, whose call overhead lands in the
   autopilot's share.
3. **bare JSBSim**: the plant alone with constant hover commands (no control, no sensors, no IO): the floor.

Figures are from one run on the current machine, which is shared: compare ratios, not absolute numbers.

    python bench/one_drone.py [--sim-seconds 30] [--mpc-loop-hz HZ]

``--mpc-loop-hz`` sets the rate of the position and velocity loops (the MPC_LOOP_HZ parameter; 250 = every physics
step, i.e. single-rate) to compare a multi-rate cascade with a single-rate one.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable

from sitl.drone.closed_loop import PHYSICS_RATE_HZ, ClosedLoop, SimConfig
from sitl.dynamics.airframe import load_airframe
from sitl.dynamics.jsbsim_plant import JsbsimPlant

TAKEOFF_ALT_M = 3.0
PARTS = ("jsbsim", "sensors", "estimator", "autopilot", "control cascade", "wind+battery", "other")


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


def _make_sim(mpc_loop_hz: float | None) -> ClosedLoop:
    sim = ClosedLoop(SimConfig(airframe=load_airframe(), seed=0))
    if mpc_loop_hz is not None:
        sim.params.set("MPC_LOOP_HZ", mpc_loop_hz)
    return sim


def arm_and_take_off_when_ready(sim: ClosedLoop) -> bool:
    vehicle = sim.vehicle
    return vehicle.preflight_problem() is None and vehicle.arm().ok and vehicle.takeoff(TAKEOFF_ALT_M).ok


def closed_loop_total(sim_seconds: float, mpc_loop_hz: float | None = None) -> float:
    """CPU seconds per simulated second of ``ClosedLoop.step()`` (arming checks until armed included)."""
    sim = _make_sim(mpc_loop_hz)
    steps = int(sim_seconds / sim.dt_s)
    armed = False
    start = time.process_time()
    for _ in range(steps):
        sim.step()
        if not armed:
            armed = arm_and_take_off_when_ready(sim)
    return (time.process_time() - start) / sim_seconds


def _clock_read_ns(clock: Callable[[], int], reads: int = 20_000) -> float:
    """What one clock read adds to an interval measured with it (the median of five batches)."""
    batches = []
    for _ in range(5):
        start = clock()
        for _ in range(reads):
            clock()
        batches.append((clock() - start) / (reads + 1))
    return sorted(batches)[2]


def closed_loop_breakdown(sim_seconds: float, mpc_loop_hz: float | None = None) -> dict[str, float]:
    """CPU seconds per simulated second of each part of the step, and their sum as "total"."""
    sim = _make_sim(mpc_loop_hz)
    clock = time.process_time_ns
    read_ns = _clock_read_ns(clock)
    plant, sensors, estimator, vehicle, wind, battery = (
        sim.plant,
        sim.sensors,
        sim.estimator,
        sim.vehicle,
        sim.wind,
        sim.battery,
    )
    cascade = vehicle.cascade
    cascade_ns = 0

    def timed(update: Callable[..., object]) -> Callable[..., object]:
        def wrapper(*args: object, **kwargs: object) -> object:
            nonlocal cascade_ns
            t0 = clock()
            out = update(*args, **kwargs)
            cascade_ns += clock() - t0
            return out

        return wrapper

    # Instance attributes shadow the methods for this one simulation only.
    cascade.fly = timed(cascade.fly)  # type: ignore[method-assign,assignment]
    cascade.update_attitude = timed(cascade.update_attitude)  # type: ignore[method-assign,assignment]
    k_q = sim.config.airframe.torque_coeff_nm_per_radps2
    dt_s = sim.dt_s
    totals = dict.fromkeys(PARTS, 0.0)
    steps = int(sim_seconds / dt_s)
    armed = False
    for _ in range(steps):
        # The body of ClosedLoop.step(), part by part.
        t0 = clock()
        readings = sensors.sample(sim.truth)
        if readings.gps is not None:
            sim.last_gps = readings.gps
        t1 = clock()
        est = estimator.update(readings, sim.time_s, dt_s)
        t2 = clock()
        cascade_before = cascade_ns
        motors = vehicle.step(est, sim.time_s, dt_s)
        t3 = clock()
        if not wind.calm:
            plant.set_wind(wind.update(dt_s))
        t4 = clock()
        sim.truth = plant.step(motors)
        t5 = clock()
        sim.time_s = sim.truth.time_s
        battery.update(sum(k_q * w * w * w for w in sim.truth.motor_speeds_radps), dt_s)
        t6 = clock()
        if not armed:
            armed = arm_and_take_off_when_ready(sim)
        t7 = clock()
        totals["sensors"] += t1 - t0
        totals["estimator"] += t2 - t1
        totals["autopilot"] += t3 - t2
        totals["jsbsim"] += t5 - t4
        totals["wind+battery"] += (t4 - t3) + (t6 - t5)
        totals["other"] += t7 - t6
        if cascade_ns != cascade_before:
            # The wrapper's two reads lie inside the autopilot's interval; one read's worth is in its own.
            totals["autopilot"] -= cascade_ns - cascade_before + 2 * read_ns
            totals["control cascade"] += cascade_ns - cascade_before - read_ns
    # One read's worth in every interval (two intervals for wind+battery).
    for part in PARTS:
        totals[part] -= (2 if part == "wind+battery" else 1) * read_ns * steps
    out = {k: v / 1e9 / sim_seconds for k, v in totals.items()}
    out["total"] = sum(out[k] for k in PARTS)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sim-seconds", type=float, default=30.0)
    parser.add_argument("--mpc-loop-hz", type=float, default=None, help="MPC_LOOP_HZ (default: the parameter's)")
    args = parser.parse_args()
    bare = bare_jsbsim(args.sim_seconds)
    total = closed_loop_total(args.sim_seconds, args.mpc_loop_hz)
    parts = closed_loop_breakdown(args.sim_seconds, args.mpc_loop_hz)
    loop_hz = _make_sim(args.mpc_loop_hz).params["MPC_LOOP_HZ"]
    print(
        f"physics {PHYSICS_RATE_HZ:.0f} Hz, position/velocity loops at {loop_hz:.0f} Hz, "
        f"{args.sim_seconds:.0f} simulated seconds each"
    )
    print(f"bare JSBSim plant : {1 / bare:7.1f} sim s per CPU s  ({bare * 1e3:6.1f} ms CPU per sim s)")
    print(
        f"full closed loop  : {1 / total:7.1f} sim s per CPU s  ({total * 1e3:6.1f} ms CPU per sim s,"
        f" {total / bare:.1f}x bare JSBSim)"
    )
    print(f"breakdown (process CPU clock, its reads subtracted; sum {parts['total'] * 1e3:.1f} ms per sim s):")
    for part in PARTS:
        print(f"  {part:<18} {parts[part] * 1e3:6.2f} ms per sim s  {parts[part] / parts['total']:5.1%}")


if __name__ == "__main__":
    main()
