"""Benchmark: the cost of one JSBSim physics step, bare and behind the Plant interface.

Separates what JSBSim itself costs (``FGFDMExec.run`` on the generated model) from what our Python plant adds
(writing motor commands, reading properties, unit and frame conversion, building ``PlantState``), and compares
the two ways of touching a property from Python: ``fdm[name]`` and a property node bound once. Other
benchmarks import ``bare_step_us`` and ``plant_step_us`` as reference figures. Numbers are from one run on
this machine; compare ratios, not absolute values.

    python bench/bare_jsbsim.py [--steps 20000]
"""

from __future__ import annotations

import argparse
import math
import time

import jsbsim

from sitl.drone.closed_loop import PHYSICS_RATE_HZ
from sitl.dynamics.airframe import Airframe, load_airframe
from sitl.dynamics.jsbsim_model import model_name, motor_cmd_property
from sitl.dynamics.jsbsim_plant import JsbsimPlant

HOVER_START_NED_M = (0.0, 0.0, -10.0)


def hover_cmd(airframe: Airframe) -> float:
    # Commands are normalised rotor speed, and thrust goes with speed squared.
    return math.sqrt(airframe.hover_thrust_fraction)


def _bare_fdm(airframe: Airframe, dt_s: float, on_ground: bool) -> jsbsim.FGFDMExec:
    # Built through the plant (quiet logging, initial conditions); the bench then drives the executive
    # directly, which only a benchmark has reason to do.
    if on_ground:
        plant = JsbsimPlant(airframe, dt_s=dt_s)
    else:
        cmds = [hover_cmd(airframe)] * len(airframe.rotors)
        plant = JsbsimPlant(airframe, dt_s=dt_s, initial_pos_ned_m=HOVER_START_NED_M, initial_motor_cmds=cmds)
    return plant._fdm


def bare_step_us(steps: int = 20_000, *, on_ground: bool = False, dt_s: float = 1.0 / PHYSICS_RATE_HZ) -> float:
    """Microseconds per ``FGFDMExec.run()`` of the generated model, hovering (or resting on the ground)."""
    fdm = _bare_fdm(load_airframe(), dt_s, on_ground)
    run = fdm.run
    start = time.perf_counter()
    for _ in range(steps):
        run()
    return (time.perf_counter() - start) / steps * 1e6


def plant_step_us(steps: int = 20_000, *, on_ground: bool = False, dt_s: float = 1.0 / PHYSICS_RATE_HZ) -> float:
    """Microseconds per ``JsbsimPlant.step()`` including command writes and the PlantState it returns."""
    airframe = load_airframe()
    cmds = [0.0 if on_ground else hover_cmd(airframe)] * len(airframe.rotors)
    if on_ground:
        plant = JsbsimPlant(airframe, dt_s=dt_s)
    else:
        plant = JsbsimPlant(airframe, dt_s=dt_s, initial_pos_ned_m=HOVER_START_NED_M, initial_motor_cmds=cmds)
    step = plant.step
    start = time.perf_counter()
    for _ in range(steps):
        step(cmds)
    return (time.perf_counter() - start) / steps * 1e6


def property_access_ns(calls: int = 200_000) -> dict[str, float]:
    """Nanoseconds per property read and write, by item access on the executive and by a bound node."""
    airframe = load_airframe()
    fdm = _bare_fdm(airframe, 1.0 / PHYSICS_RATE_HZ, on_ground=True)
    read_name = "velocities/v-north-fps"
    write_name = motor_cmd_property(0)
    manager = fdm.get_property_manager()
    read_node = manager.get_node(read_name)
    write_node = manager.get_node(write_name)
    assert read_node is not None and write_node is not None, model_name(airframe)
    get, set_ = read_node.get_double_value, write_node.set_double_value

    def timed(body: object) -> float:
        start = time.perf_counter()
        for _ in range(calls):
            body()  # type: ignore[operator]
        return (time.perf_counter() - start) / calls * 1e9

    return {
        "fdm[name] read": timed(lambda: fdm[read_name]),
        "node read": timed(get),
        "fdm[name] = v": timed(lambda: fdm.__setitem__(write_name, 0.0)),
        "node write": timed(lambda: set_(0.0)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20_000, help="physics steps per measurement")
    args = parser.parse_args()
    print(f"JSBSim {jsbsim.__version__}, {args.steps} steps at {PHYSICS_RATE_HZ:.0f} Hz")
    for where, on_ground in (("hovering", False), ("on ground", True)):
        bare = bare_step_us(args.steps, on_ground=on_ground)
        full = plant_step_us(args.steps, on_ground=on_ground)
        added = full - bare
        print(f"  {where:9s}: fdm.run {bare:6.2f} us, JsbsimPlant.step {full:6.2f} us (Python adds {added:.2f})")
    for name, ns in property_access_ns().items():
        print(f"  {name:14s}: {ns:6.0f} ns")


if __name__ == "__main__":
    main()
