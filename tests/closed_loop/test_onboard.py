"""Onboard behaviours (sitl/onboard) flown in closed loop through JSBSim: a user's class, loaded from its file,
steers a drone through the autopilot's offboard input; its parameters are the drone's; an operator's mode change
stops it; an exception in it stops it and the drone holds, in the air."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from sitl.autopilot.px4_modes import Px4Mode
from sitl.drone.closed_loop import ClosedLoop, SimConfig
from sitl.drone.param_table import build_param_store
from sitl.onboard.loader import ENABLE_PARAM, BehaviourError, load_behaviour
from sitl.onboard.runner import OnboardRunner
from tests.closed_loop.flight import load_airframe, take_off

GOTO = """
from sitl.onboard import OnboardSetpoint, OnboardState


class GoTo:
    RATE_HZ = 10
    PARAMS = {"GOTO_N": (5.0, -50.0, 50.0), "GOTO_E": (0.0, -50.0, 50.0)}

    def step(self, state: OnboardState) -> OnboardSetpoint:
        return OnboardSetpoint(pos_ned_m=(state.params["GOTO_N"], state.params["GOTO_E"], -3.0))
"""

BOOM = """
class Boom:
    RATE_HZ = 20
    PARAMS = {}

    def __init__(self):
        self.steps = 0

    def step(self, state):
        self.steps += 1
        if self.steps > 10:
            return 1 / 0
        return None
"""


def drone_with(tmp_path: Path, name: str, source: str) -> tuple[ClosedLoop, OnboardRunner]:
    path = tmp_path / f"{name.lower()}.py"
    path.write_text(source)
    loaded = load_behaviour(f"{path}:{name}")
    sim = ClosedLoop(SimConfig(airframe=load_airframe(), seed=3), params=build_param_store(loaded.params))
    prevention = sim.vehicle.collision_prevention
    runner = OnboardRunner(loaded, sysid=1, vehicle=sim.vehicle, params=sim.params, estimate=lambda: sim.estimate,
                           relayed=prevention.relayed, camera=prevention.camera)  # fmt: skip
    return sim, runner


def fly(sim: ClosedLoop, runner: OnboardRunner, seconds: float) -> None:
    for _ in range(round(seconds / sim.dt_s)):
        sim.step()
        runner.tick(sim.time_s)


def texts(sim: ClosedLoop) -> list[str]:
    return [e.text for e in sim.vehicle.events]


@pytest.mark.timeout(120)
def test_a_behaviour_flies_the_drone_from_its_own_parameters_until_the_operator_takes_it(tmp_path: Path) -> None:
    sim, runner = drone_with(tmp_path, "GoTo", GOTO)
    # GIVEN a drone hovering at 3 m with the behaviour loaded, its parameters declared on the drone
    take_off(sim, 3.0)
    assert sim.params["GOTO_N"] == 5.0 and sim.params[ENABLE_PARAM] == 0
    fly(sim, runner, 1.0)
    assert runner.steps == 0 and sim.vehicle.status.mode is Px4Mode.AUTO_LOITER  # not enabled: nothing happens
    # WHEN BHV_EN is set to 1 THEN it runs at its rate, the drone goes OFFBOARD and flies where it says
    sim.params.set(ENABLE_PARAM, 1)
    fly(sim, runner, 10.0)
    assert sim.vehicle.status.mode is Px4Mode.OFFBOARD
    assert 95 <= runner.steps <= 101, runner.steps
    pos = sim.estimate.pos_ned_m
    assert math.hypot(pos[0] - 5.0, pos[1]) < 0.3 and abs(pos[2] + 3.0) < 0.3, pos
    # WHEN one of its parameters changes (as PARAM_SET would) THEN it follows
    sim.params.set("GOTO_E", 4.0)
    fly(sim, runner, 8.0)
    pos = sim.estimate.pos_ned_m
    assert math.hypot(pos[0] - 5.0, pos[1] - 4.0) < 0.3, pos
    # WHEN the operator commands Hold THEN the behaviour stops and says so, and BHV_EN reads 0 again
    assert sim.vehicle.hold().ok
    steps = runner.steps
    fly(sim, runner, 2.0)
    assert runner.steps == steps and sim.params[ENABLE_PARAM] == 0
    assert "Behaviour GoTo stopped: the drone left OFFBOARD for AUTO.LOITER" in texts(sim), texts(sim)


@pytest.mark.timeout(120)
def test_a_behaviour_that_raises_is_stopped_and_the_drone_holds_in_the_air(tmp_path: Path) -> None:
    sim, runner = drone_with(tmp_path, "Boom", BOOM)
    take_off(sim, 3.0)
    sim.params.set(ENABLE_PARAM, 1)
    # WHEN its 11th step divides by zero
    fly(sim, runner, 3.0)
    # THEN it stopped there, the drone says why and where in one line, and holds where it is, still flying
    assert runner.steps == 10
    assert "Behaviour Boom stopped: ZeroDivisionError at boom.py:12" in texts(sim), texts(sim)
    assert sim.vehicle.status.mode is Px4Mode.AUTO_LOITER and sim.vehicle.status.armed and not sim.vehicle.landed
    assert sim.params[ENABLE_PARAM] == 0


@pytest.mark.parametrize(
    ("source", "spec_tail", "expected"),
    [
        ("class A:\n    def step(self, s)\n        return None\n", "A", "a.py:2: SyntaxError: expected ':'"),
        ("import math\nx = math.sqrt(-1)\n", "A", "a.py:2: ValueError: math domain error"),
        ("class B:\n    pass\n", "A", "a.py: no class A"),
        ("class A:\n    RATE_HZ = 10\n", "A", "a.py:A: the class has no step(state) method"),
        ("class A:\n    RATE_HZ = 0\n    def step(self, s): ...\n", "A", "RATE_HZ must be a number in (0, 250]"),
        ("class A:\n    RATE_HZ = 5\n    PARAMS = {'bad name': (1, 0, 2)}\n    def step(self, s): ...\n", "A",
         "parameter name 'bad name' must be 1-16 characters"),
        ("class A:\n    RATE_HZ = 5\n    PARAMS = {'MPC_XY_CRUISE': (1, 0, 2)}\n    def step(self, s): ...\n", "A",
         "parameter name 'MPC_XY_CRUISE' must be 1-16 characters A-Z, 0-9, _ and not one of the drone's own"),
        ("class A:\n    RATE_HZ = 5\n    PARAMS = {'GAIN': (5, 0, 2)}\n    def step(self, s): ...\n", "A",
         "PARAMS['GAIN']: default 5 outside [0, 2]"),
        ("class A:\n    RATE_HZ = 5\n    PARAMS = {'GAIN': 1.0}\n    def step(self, s): ...\n", "A",
         "PARAMS['GAIN'] must be (default, min, max), got 1.0"),
    ],
)  # fmt: skip
def test_a_broken_behaviour_is_one_line_naming_its_file_and_the_problem(
    tmp_path: Path, source: str, spec_tail: str, expected: str
) -> None:
    path = tmp_path / "a.py"
    path.write_text(source)
    with pytest.raises(BehaviourError) as info:
        load_behaviour(f"{path}:{spec_tail}")
    message = str(info.value)
    assert "\n" not in message and expected in message.replace(str(tmp_path) + "/", ""), message


def test_a_missing_file_or_a_spec_without_a_class_is_one_line(tmp_path: Path) -> None:
    with pytest.raises(BehaviourError, match="no such file"):
        load_behaviour(f"{tmp_path}/none.py:A")
    with pytest.raises(BehaviourError, match=r"a behaviour is given as path/to/file\.py:ClassName"):
        load_behaviour(f"{tmp_path}/none.py")
