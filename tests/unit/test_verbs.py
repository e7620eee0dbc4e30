"""The swarm's verbs are written once (gcs/supervisor/verbs.py) and every front-end uses them: the control channel of
``swarm up`` (station.py), a mission's steps (mission_runner.py) and the Python API (api/engine.py).

Read from the front-ends' source: every verb they name is in the table, none of them reaches past it to what a
verb does (streaming a formation, landing, injecting a fault...), every kind of mission step and every API call
that flies is carried out through a verb. A new front-end command written beside the table fails here."""

from __future__ import annotations

import ast
import inspect
import typing
from pathlib import Path

import pytest

from gcs.missions import mission_file
from gcs.supervisor.verbs import VERBS

ROOT = Path(__file__).resolve().parents[2]
FRONT_ENDS = ("gcs/supervisor/station.py", "gcs/supervisor/mission_runner.py", "gcs/api/engine.py")

# What only a verb may do: the calls that change what the swarm flies or what a drone is.
VERBS_OWN = frozenset({
    "command", "command_flock", "command_follow", "command_swap", "command_behaviour", "takeoff_all", "land_all",
    "hold_all", "kill", "inject_fault", "set_params", "start_missions", "upload_plan", "download_plan",
    "start_onboard_behaviours", "stop_onboard_behaviours", "start_onboard_flock", "start_onboard_follow",
    "take_off_and_hold", "start_takeoff",
})  # fmt: skip
# Where a front-end does one of those itself, and why it is not a verb.
NOT_VERBS = {
    # a loss policy's own ending of the mission: the survivors land after holding (docs/drone-loss.md)
    ("gcs/supervisor/mission_runner.py", "_finish_after_policy", "land_all"),
    # a user's controller that raised: the API's failsafe holds every drone where it is
    ("gcs/api/engine.py", "_tick", "hold_all"),
}


def _functions(path: str) -> dict[str, ast.FunctionDef]:
    tree = ast.parse((ROOT / path).read_text())
    return {node.name: node for node in ast.walk(tree) if isinstance(node, ast.FunctionDef)}


def _called_names(node: ast.AST) -> set[str]:
    names = set()
    for call in ast.walk(node):
        if isinstance(call, ast.Call):
            func = call.func
            names.add(func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else "")
    return names


def _verbs_named(node: ast.AST) -> set[str]:
    """``VERBS["x"]``, ``self._verb(request, "x", ...)`` and ``self._start("x", ...)`` in a piece of source."""
    named = set()
    for sub in ast.walk(node):
        if isinstance(sub, ast.Subscript) and isinstance(sub.value, ast.Name) and sub.value.id == "VERBS":
            if isinstance(sub.slice, ast.Constant):
                named.add(sub.slice.value)
            elif isinstance(sub.slice, ast.IfExp):  # VERBS["rtl" if ... else "land"]
                named |= {b.value for b in (sub.slice.body, sub.slice.orelse) if isinstance(b, ast.Constant)}
        if isinstance(sub, ast.Call) and isinstance(sub.func, ast.Attribute) and sub.func.attr in ("_verb", "_start"):
            for arg in sub.args:
                if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                    named.add(arg.value)
                elif isinstance(arg, ast.IfExp):
                    named |= {b.value for b in (arg.body, arg.orelse) if isinstance(b, ast.Constant) and b.value}
    return named


@pytest.mark.parametrize("path", FRONT_ENDS)
def test_a_front_end_names_only_verbs_of_the_table_and_does_not_reach_past_it(path: str) -> None:
    functions = _functions(path)
    named = set().union(*(_verbs_named(f) for f in functions.values()))
    assert named, f"{path} uses no verb"
    assert named <= set(VERBS), f"{path} names verbs the table does not have: {named - set(VERBS)}"
    past = {(path, name, call) for name, f in functions.items() for call in _called_names(f) & VERBS_OWN}
    assert past <= NOT_VERBS, f"written beside the verbs: {sorted(past - NOT_VERBS)}"


def test_every_kind_of_mission_step_is_flown_and_every_api_call_that_flies_is_a_verb() -> None:
    runner = _functions("gcs/supervisor/mission_runner.py")
    dispatch = ast.unparse(runner["_run_step"])
    kinds = [t.__name__ for t in typing.get_args(mission_file.Step)]
    assert len(kinds) >= 10
    assert not [k for k in kinds if f"isinstance(step, {k})" not in dispatch and k not in ("LandStep",)]
    engine = _functions("gcs/api/engine.py")
    calls = {name: f for name, f in engine.items() if name.startswith("do_") and name != "do_wait_until"}
    assert not [name for name, f in calls.items() if not _verbs_named(f)], "an API call that flies without a verb"


def test_the_control_channel_answers_only_with_verbs_and_the_session_s_own_commands() -> None:
    init = _functions("gcs/supervisor/station.py")["__init__"]
    table = next(
        node.value for node in ast.walk(init)
        if isinstance(node, ast.AnnAssign | ast.Assign) and "self.commands" in ast.unparse(node)
    )  # fmt: skip
    assert isinstance(table, ast.Dict)
    commands = {k.value for k in table.keys if isinstance(k, ast.Constant)}
    assert commands - set(VERBS) == {"ping", "status", "down"}
    flown = {"takeoff", "formation", "flock", "follow", "goto", "land", "rtl", "behaviour", "fault", "plan_start"}
    assert flown <= commands


def test_every_front_end_takes_off_and_lands_with_the_mission_file_s_defaults() -> None:
    """One set of defaults (gcs/missions/mission_file.py): a takeoff climbs 3 m and waits 30 s, a landing 60 s, a
    return to launch 120 s, whether a mission file, ``swarm takeoff``, the control channel or the API asks."""
    from gcs.api.blocking import BlockingSession
    from gcs.api.session import Session
    from gcs.cli import build_parser

    defaults = {"takeoff": {"alt_m": mission_file.TAKEOFF_ALT_M, "timeout_s": mission_file.TAKEOFF_TIMEOUT_S},
                "land": {"timeout_s": mission_file.LAND_TIMEOUT_S},
                "return_to_launch": {"timeout_s": mission_file.RTL_TIMEOUT_S}}  # fmt: skip
    documented = (mission_file.TAKEOFF_ALT_M, mission_file.TAKEOFF_TIMEOUT_S, mission_file.LAND_TIMEOUT_S)
    assert documented == (3.0, 30.0, 60.0)
    for api in (Session, BlockingSession):
        for method, expected in defaults.items():
            signature = inspect.signature(getattr(api, method))
            got = {name: signature.parameters[name].default for name in expected}
            assert got == expected, (api.__name__, method, got)
    verbs = {name: inspect.signature(VERBS[name]).parameters for name in ("takeoff", "land", "rtl")}
    assert verbs["takeoff"]["timeout_s"].default == mission_file.TAKEOFF_TIMEOUT_S
    assert verbs["land"]["timeout_s"].default == mission_file.LAND_TIMEOUT_S
    assert verbs["rtl"]["timeout_s"].default == mission_file.RTL_TIMEOUT_S
    assert build_parser().parse_args(["takeoff"]).alt == mission_file.TAKEOFF_ALT_M
    assert "TAKEOFF_ALT_M" in ast.unparse(_functions("gcs/supervisor/station.py")["__init__"])
