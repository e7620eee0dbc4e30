"""One request type per verb (gcs/supervisor/requests.py), and every front-end a decoder into them.

Each front-end's decoder is driven to its request for every verb it offers: the CLI's arguments (argparse, then the
JSON it sends), the control channel's JSON (old keys included), a mission file's steps (every file in missions/), and
the Python API (both faces). Each front-end declares what its entries offer (``CLI_VERBS``, ``CHANNEL_VERBS``,
``STEP_VERBS`` and ``MISSION_ALSO``, ``API_VERBS``) and the verbs it leaves out, each with its reason: together they
are every verb in ``VERBS``. A new request type no front-end offers or leaves out, an entry without its verbs or its
case, a default that differs from the request's, or a front-end that reaches past the verbs to what a verb does fails
here."""

from __future__ import annotations

import argparse
import ast
import asyncio
import inspect
import json
import math
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import pytest

from gcs.api.blocking import BlockingSession
from gcs.api.session import Session
from gcs.cli import UsageError, build_parser, client_command
from gcs.fleet.attach import parse_attach
from gcs.fleet.faults import FaultRequest
from gcs.flight.behaviours import FlockSpec, FollowAttachedSpec, FollowSpec
from gcs.flight.formation import CircleSpec, FieldError, GridSpec, LineSpec, VSpec
from gcs.missions import mission_file
from gcs.missions.mission_file import build_formation, load_mission
from gcs.supervisor import requests as rq
from gcs.supervisor.commands import DECODERS, decode
from gcs.supervisor.mission_runner import step_requests
from gcs.supervisor.plan_cli import plan_commands
from gcs.supervisor.verbs import VERBS

ROOT = Path(__file__).resolve().parents[2]
REQUESTS = typing.get_args(rq.Request)
ALL_VERBS = frozenset(r.verb for r in VERBS)


def _offers_every_verb(offered: Mapping[Any, Iterable[str]], left_out: Mapping[str, str]) -> None:
    """What a front-end's entries offer (entry -> its verbs), with the verbs it leaves out on purpose (verb -> why),
    are every verb, each once: a new request type fails here until each front-end offers it or says why not, and an
    entry that offers no verb fails too."""
    verbs = set().union(*offered.values())
    assert all(offered.values()), f"an entry that offers no verb: {[k for k, v in offered.items() if not v]}"
    assert not verbs & set(left_out), f"offered and said to be left out: {sorted(verbs & set(left_out))}"
    assert verbs <= ALL_VERBS, f"not a verb: {sorted(verbs - ALL_VERBS)}"
    assert verbs | set(left_out) == ALL_VERBS, (
        f"neither offered nor left out: {sorted(ALL_VERBS - verbs - set(left_out))}"
    )


def test_every_request_type_has_its_verb_and_its_own_name() -> None:
    assert set(REQUESTS) == set(VERBS), "a request type without a verb, or a verb without a request type"
    names = [r.verb for r in REQUESTS]
    assert len(names) == len(set(names)), names
    for request in REQUESTS:
        assert request.__dataclass_params__.frozen, request  # type: ignore[attr-defined]


def test_one_set_of_defaults_the_mission_file_s() -> None:
    """A takeoff climbs 3 m and waits 30 s, a landing 60 s, a return 120 s, a swap as a mission's swap step."""
    assert (rq.Takeoff().alt_m, rq.Takeoff().timeout_s) == (mission_file.TAKEOFF_ALT_M, mission_file.TAKEOFF_TIMEOUT_S)
    assert (mission_file.TAKEOFF_ALT_M, mission_file.TAKEOFF_TIMEOUT_S, mission_file.LAND_TIMEOUT_S) == (
        3.0,
        30.0,
        60.0,
    )
    assert rq.Land().timeout_s == mission_file.LAND_TIMEOUT_S
    assert rq.ReturnToLaunch().timeout_s == mission_file.RTL_TIMEOUT_S
    swap, step = rq.Swap(speed_mps=1.0), mission_file.SwapStep(speed_mps=1.0)
    assert (swap.accel_mps2, swap.tolerance_m, swap.timeout_s) == (step.accel_mps2, step.tolerance_m, step.timeout_s)
    # a mission's steps wait as long as the requests they make (a takeoff step must say its altitude)
    assert mission_file.TakeoffStep(alt_m=rq.Takeoff().alt_m).timeout_s == rq.Takeoff().timeout_s
    assert mission_file.LandStep().timeout_s == rq.Land().timeout_s
    assert mission_file.RtlStep().timeout_s == rq.ReturnToLaunch().timeout_s


@pytest.mark.parametrize(
    ("make", "field", "fragment"),
    [
        (lambda: rq.Takeoff(alt_m=500.0), "alt_m", "takeoff altitude must be between"),
        (lambda: rq.Takeoff(timeout_s=-1.0), "timeout_s", "positive number of seconds"),
        (lambda: rq.Goto(north_m=math.nan, east_m=0.0), "north_m", "finite"),
        (lambda: rq.Hold(duration_s=-1.0), "duration_s", ">= 0"),
        (lambda: rq.Swap(speed_mps=0.0), "speed_mps", "positive"),
        (lambda: rq.Land(timeout_s=0.0), "timeout_s", "positive"),
        (lambda: rq.SetParam(name="MPC_XY_VEL_MAX", value=math.inf), "value", "finite"),
        (lambda: rq.SetParam(name="MPC_XY_VEL_MAX", value=1.0, sysids=(0,)), "sysids", "1..255"),
        (lambda: rq.Kill(sysid=0), "sysid", "1..255"),
        (lambda: rq.InjectFault(sysid=256, fault=FaultRequest(kind="gps")), "sysid", "1..255"),
        (lambda: rq.Detach(sysid=None), "sysid", "1..255"),
        (lambda: rq.PlanDownload(sysid="2"), "sysid", "1..255"),
        (
            lambda: rq.Follow(spec=FollowSpec(waypoints_ne_m=((5.0, 0.0),), alt_m=3.0, leader_sysid=300)),
            "leader_sysid",
            "1..255",
        ),
        (
            lambda: rq.FollowAttached(spec=FollowAttachedSpec(alt_m=3.0, duration_s=5.0, leader_sysid=0)),
            "leader_sysid",
            "1..255",
        ),
    ],
)
def test_a_request_refuses_a_field_in_one_line_naming_it(make: Any, field: str, fragment: str) -> None:
    with pytest.raises(FieldError) as info:
        make()
    assert info.value.field == field and fragment in info.value.problem and "\n" not in str(info.value)


# ---- the CLI: argparse, then the JSON it sends, decoded as the station decodes it ---------------------------------
CLI_CASES: list[tuple[list[str], rq.Request]] = [
    (["takeoff"], rq.Takeoff()),
    (["takeoff", "--alt", "5"], rq.Takeoff(alt_m=5.0)),
    (["formation", "grid"], rq.FlyFormation(formation=rq.SquareGrid(spacing_m=2.0, alt_m=3.0, heading_deg=0.0))),
    (["formation", "grid", "--rows", "2", "--cols", "3"],
     rq.FlyFormation(formation=GridSpec(rows=2, cols=3, spacing_m=2.0, alt_m=3.0))),
    (["formation", "circle", "--radius", "4", "--rate", "0.2"],
     rq.FlyFormation(formation=CircleSpec(radius_m=4.0, alt_m=3.0, angular_rate_radps=0.2))),
    (["formation", "line"], rq.FlyFormation(formation=LineSpec(spacing_m=2.0, alt_m=3.0))),
    (["formation", "v"], rq.FlyFormation(formation=build_formation("v", {"spacing_m": 2.0, "alt_m": 3.0,
                                                                          "angle_deg": 90.0, "heading_deg": 0.0}))),
    (["flock"], rq.Flock(spec=FlockSpec(alt_m=3.0))),
    (["flock", "--goals", "10,0 10,10", "--speed", "2"],
     rq.Flock(spec=FlockSpec(alt_m=3.0, migration_ne_m=((10.0, 0.0), (10.0, 10.0)), max_speed_mps=2.0))),
    (["follow", "--waypoints", "10,0", "--leader", "2"],
     rq.Follow(spec=FollowSpec(waypoints_ne_m=((10.0, 0.0),), alt_m=3.0, leader_sysid=2))),
    (["follow", "--attached"], rq.FollowAttached(spec=FollowAttachedSpec(alt_m=3.0, duration_s=86400.0))),
    (["goto", "4", "-2"], rq.Goto(north_m=4.0, east_m=-2.0)),
    (["goto", "4", "-2", "--alt", "6"], rq.Goto(north_m=4.0, east_m=-2.0, alt_m=6.0)),
    (["pause"], rq.Pause()),
    (["land"], rq.Land()),
    (["rtl"], rq.ReturnToLaunch()),
    (["behaviour", "start"], rq.Behaviours(run=True)),
    (["behaviour", "stop"], rq.Behaviours(run=False)),
    (["fault", "3", "gps"], rq.InjectFault(sysid=3, fault=FaultRequest(kind="gps"))),
    (["fault", "3", "link", "--for", "2"], rq.InjectFault(sysid=3, fault=FaultRequest(kind="link", for_s=2.0))),
    (["fault", "3", "crash"], rq.Kill(sysid=3)),
    (["kill", "3"], rq.Kill(sysid=3)),
    (["attach", "intruder=udpin://127.0.0.1:14560"],
     rq.Attach(spec=parse_attach("intruder=udpin://127.0.0.1:14560"))),
    (["detach", "200"], rq.Detach(sysid=200)),
    (["require", "separation", "min_m=1.0"], rq.Require(invariants=({"kind": "separation", "min_m": 1.0},))),
]  # fmt: skip
# Each subcommand and the verbs it offers; the subcommands that are not verbs; the verbs the CLI leaves out, and why.
CLI_VERBS: dict[str, set[str]] = {
    "takeoff": {"takeoff"},
    "formation": {"formation"},
    "goto": {"goto"},
    "flock": {"flock"},
    "follow": {"follow", "follow_attached"},  # --attached: the drones follow an attached leader that flies itself
    "pause": {"pause"},
    "land": {"land"},
    "rtl": {"rtl"},
    "behaviour": {"behaviour"},
    "fault": {"fault", "kill"},  # fault N crash: a kill, as every earlier swarm fault sent it
    "kill": {"kill"},
    "attach": {"attach"},
    "detach": {"detach"},
    "require": {"require"},
    "plan": {"plan_upload", "plan_start", "plan_download"},  # gcs/supervisor/plan_cli.py
}
NOT_VERBS = {"up", "fly", "bench", "sweep", "falsify", "status", "down"}  # runs and the session's own
CLI_LEAVES_OUT = {
    "arm": "swarm takeoff arms the drones on the ground first",
    "swap": "the avoidance stress test, flown from a mission file (swarm fly missions/antipodal_swap.toml)",
    "hold": "a wait, for a front-end that waits: the command line answers at once and flies on until told",
    "param": "drone parameters are set before the flight (swarm up --param NAME=VALUE)",
    "control": "a user's controller is Python code: the API's control()",
}


def _subcommands() -> set[str]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return set(sub.choices)


@pytest.mark.parametrize(("argv", "expected"), CLI_CASES, ids=[" ".join(a) for a, _ in CLI_CASES])
def test_the_cli_decodes_each_command_to_its_request(argv: list[str], expected: rq.Request) -> None:
    command = client_command(build_parser().parse_args(argv))
    assert decode(command, None) == expected


@pytest.mark.parametrize(
    ("argv", "line"),
    [(["goto", "nan", "0"], "argument north: must be a finite number, got nan"),
     (["takeoff", "--alt", "500"], "argument --alt: takeoff altitude must be between 0.5 and 100 m, got 500"),
     (["formation", "circle", "--rate", "inf"], "argument --rate: must be a number, got inf")],
)  # fmt: skip
def test_a_cli_mistake_names_the_argument_that_gave_it(argv: list[str], line: str) -> None:
    with pytest.raises(UsageError) as info:
        client_command(build_parser().parse_args(argv))
    assert str(info.value) == line


PLAN_CASES: list[tuple[list[str], list[str]]] = [
    (["plan", "upload", str(ROOT / "missions" / "box.plan")], ["plan_upload"]),
    (["plan", "upload", str(ROOT / "missions" / "box.plan"), "--start"], ["plan_upload", "plan_start"]),
    (["plan", "start", "--drones", "1,2"], ["plan_start"]),
    (["plan", "download", "2", "back.plan"], ["plan_download"]),
]  # decoded against the running swarm but a download (tests/integration/test_qgc_plan_fly.py sends them)


def test_every_cli_command_that_flies_offers_its_verbs_and_the_cli_every_verb_but_those_it_leaves_out() -> None:
    assert _subcommands() - NOT_VERBS == set(CLI_VERBS), "a CLI command not in CLI_VERBS, or one there too many"
    _offers_every_verb(CLI_VERBS, CLI_LEAVES_OUT)
    decoded: dict[str, set[str]] = {}
    for argv, expected in CLI_CASES:
        assert expected.verb in CLI_VERBS[argv[0]], argv
        decoded.setdefault(argv[0], set()).add(expected.verb)
    for argv, verbs in PLAN_CASES:
        commands = plan_commands(build_parser().parse_args(argv))
        assert [c["cmd"] for c in commands] == verbs, argv
        decoded.setdefault(argv[0], set()).update(verbs)
    assert decoded == CLI_VERBS, "a verb a CLI command offers without a case above"


def test_swarm_plan_builds_its_commands_through_the_decoder(tmp_path: Path) -> None:
    """``swarm plan`` sends what the station decodes, checked by the same decoder first: the file, the offsets, a
    plan to start without mission items, a sysid (what needs the swarm, which drones, is left to the station)."""
    box = ROOT / "missions" / "box.plan"
    upload = plan_commands(build_parser().parse_args(["plan", "upload", str(box), "--start", "--offsets", "none"]))
    assert upload == [{"cmd": "plan_upload", "path": str(box.resolve()), "drones": "all", "offsets": "none",
                       "start": True}, {"cmd": "plan_start", "drones": "all"}]  # fmt: skip
    download = plan_commands(build_parser().parse_args(["plan", "download", "2", "back.plan"]))
    assert [decode(c, None) for c in download] == [rq.PlanDownload(sysid=2)]
    fence = tmp_path / "fence.plan"
    data = json.loads(box.read_text())
    data["mission"]["items"] = []
    fence.write_text(json.dumps(data))
    for argv, line in [
        (["upload", str(fence), "--start"],
         f"{fence}: the plan has no mission items to start (upload its fence alone without --start)"),
        (["upload", str(box), "--offsets", "north"], "offsets: 'north' is not N,E (metres north, east)"),
        (["download", "0", "back.plan"], "argument sysid: must be a sysid in 1..255, got 0"),
    ]:  # fmt: skip
        with pytest.raises(ValueError) as info:
            plan_commands(build_parser().parse_args(["plan", *argv]))
        assert str(info.value) == line
    assert plan_commands(build_parser().parse_args(["plan", "upload", str(fence)]))[0]["start"] is False


# ---- the control channel's JSON ------------------------------------------------------------------------------------
JSON_CASES: list[tuple[dict[str, Any], rq.Request]] = [
    ({"cmd": "takeoff"}, rq.Takeoff()),
    ({"cmd": "takeoff", "alt": 4}, rq.Takeoff(alt_m=4.0)),  # the key every earlier swarm takeoff sent
    ({"cmd": "takeoff", "alt_m": 4, "timeout_s": 12}, rq.Takeoff(alt_m=4.0, timeout_s=12.0)),
    ({"cmd": "formation", "shape": "grid", "fields": {"rows": 0, "cols": 0, "spacing_m": 2, "alt_m": 3}},
     rq.FlyFormation(formation=rq.SquareGrid(spacing_m=2, alt_m=3))),
    ({"cmd": "formation", "shape": "v", "fields": {"spacing_m": 2, "alt_m": 3}},
     rq.FlyFormation(formation=VSpec(spacing_m=2.0, alt_m=3.0))),
    ({"cmd": "flock", "fields": {"alt_m": 3}}, rq.Flock(spec=FlockSpec(alt_m=3.0))),
    ({"cmd": "flock", "fields": {"alt_m": 3}, "onboard": True}, rq.Flock(spec=FlockSpec(alt_m=3.0), onboard=True)),
    ({"cmd": "follow", "fields": {"waypoints_ne_m": [[5, 0]], "alt_m": 3}},
     rq.Follow(spec=FollowSpec(waypoints_ne_m=((5.0, 0.0),), alt_m=3.0))),
    ({"cmd": "follow_attached", "fields": {"alt_m": 3, "duration_s": 10}},
     rq.FollowAttached(spec=FollowAttachedSpec(alt_m=3.0, duration_s=10.0))),
    ({"cmd": "goto", "north_m": 1, "east_m": 2, "alt_m": None}, rq.Goto(north_m=1.0, east_m=2.0)),
    ({"cmd": "pause"}, rq.Pause()),
    ({"cmd": "land"}, rq.Land()),
    ({"cmd": "land", "timeout_s": 90}, rq.Land(timeout_s=90.0)),
    ({"cmd": "rtl"}, rq.ReturnToLaunch()),
    ({"cmd": "behaviour", "action": "start"}, rq.Behaviours(run=True)),
    ({"cmd": "fault", "sysid": 2, "kind": "motor", "motor": 1, "for_s": None},
     rq.InjectFault(sysid=2, fault=FaultRequest(kind="motor", motor=1))),
    ({"cmd": "fault", "sysid": 2, "kind": "crash"}, rq.Kill(sysid=2)),  # what every earlier swarm kill sent
    ({"cmd": "kill", "sysid": 2}, rq.Kill(sysid=2)),
    ({"cmd": "plan_download", "sysid": 2}, rq.PlanDownload(sysid=2)),
    ({"cmd": "param", "name": "MPC_XY_VEL_MAX", "value": 2}, rq.SetParam(name="MPC_XY_VEL_MAX", value=2.0)),
    ({"cmd": "attach", "url": "udpin://127.0.0.1:14560"}, rq.Attach(spec=parse_attach("udpin://127.0.0.1:14560"))),
    ({"cmd": "detach", "sysid": 200}, rq.Detach(sysid=200)),
    ({"cmd": "require", "fields": {"kind": "contact"}, "cwd": "/tmp"},
     rq.Require(invariants=({"kind": "contact"},), base=Path("/tmp"))),
]  # fmt: skip


@pytest.mark.parametrize(("command", "expected"), JSON_CASES, ids=[str(c) for c, _ in JSON_CASES])
def test_the_control_channel_decodes_each_command_to_its_request(command: dict[str, Any], expected: Any) -> None:
    assert decode(command, None) == expected


# Each command of the control channel and the verbs it makes; the verbs it leaves out, and why.
CHANNEL_VERBS: dict[str, set[str]] = {
    "takeoff": {"takeoff"},
    "formation": {"formation"},
    "goto": {"goto"},
    "flock": {"flock"},
    "follow": {"follow"},
    "follow_attached": {"follow_attached"},
    "pause": {"pause"},
    "land": {"land"},
    "rtl": {"rtl"},
    "behaviour": {"behaviour"},
    "fault": {"fault", "kill"},  # kind crash: a kill, as every earlier swarm kill sent it
    "kill": {"kill"},
    "plan_upload": {"plan_upload"},
    "plan_start": {"plan_start"},
    "plan_download": {"plan_download"},
    "param": {"param"},
    "attach": {"attach"},
    "detach": {"detach"},
    "require": {"require"},
}
CHANNEL_LEAVES_OUT = {
    "arm": "a takeoff arms the drones on the ground first",
    "swap": "the avoidance stress test, flown from a mission file",
    "hold": "a wait, for a front-end that waits: the channel answers at once",
    "control": "a user's controller is Python code, which JSON cannot carry: the API's control()",
}


def test_the_control_channel_offers_every_verb_but_those_it_leaves_out() -> None:
    assert set(DECODERS) == set(CHANNEL_VERBS), "a command not in CHANNEL_VERBS, or one there too many"
    _offers_every_verb(CHANNEL_VERBS, CHANNEL_LEAVES_OUT)
    decoded: dict[str, set[str]] = {"plan_upload": {"plan_upload"}, "plan_start": {"plan_start"}}  # need the swarm
    for command, expected in JSON_CASES:
        assert expected.verb in CHANNEL_VERBS[command["cmd"]], command
        decoded.setdefault(command["cmd"], set()).add(expected.verb)
    assert decoded == CHANNEL_VERBS, "a verb a command offers without a case above"
    with pytest.raises(ValueError, match="needs the running swarm"):
        decode({"cmd": "plan_start", "drones": "all"}, None)


@pytest.mark.parametrize(
    ("command", "field"),
    [({"cmd": "takeoff", "alt": "high"}, "alt"), ({"cmd": "goto", "north_m": 1}, "east_m"),
     ({"cmd": "flock", "fields": {"alt_m": -3}}, "alt_m"), ({"cmd": "behaviour", "action": "go"}, "action"),
     ({"cmd": "flock", "fields": {"alt_m": 3}, "onboard": "yes"}, "onboard")],
)  # fmt: skip
def test_a_bad_control_command_names_its_key(command: dict[str, Any], field: str) -> None:
    with pytest.raises(FieldError) as info:
        decode(command, None)
    assert info.value.field == field


# ---- mission files --------------------------------------------------------------------------------------------------
MISSIONS = sorted((ROOT / "missions").glob("*.toml"))


@pytest.mark.parametrize("path", MISSIONS, ids=[p.name for p in MISSIONS])
def test_every_shipped_mission_decodes_into_requests(path: Path) -> None:
    mission = load_mission(path)
    sysids = list(range(1, mission.swarm.drones + 1))
    for step in mission.steps:
        if isinstance(step, mission_file.PlanStep | mission_file.FaultStep):
            continue  # decoded when reached (the swarm's spawn points and losses); flown in test_qgc_plan_fly.py
        planned = step_requests(step, sysids)
        assert planned and all(type(p.request) in VERBS for p in planned)


# Each kind of step and the verbs it makes, what else a mission asks and how, and the verbs a mission leaves out.
STEP_VERBS: dict[type, set[str]] = {
    mission_file.TakeoffStep: {"takeoff"},
    mission_file.FormationStep: {"formation", "hold"},
    mission_file.FlockStep: {"flock", "hold", "behaviour"},  # onboard: the drones' behaviours stopped after it
    mission_file.FollowStep: {"follow", "hold", "behaviour"},
    mission_file.FollowAttachedStep: {"follow_attached", "hold"},
    mission_file.SwapStep: {"swap"},
    mission_file.HoldStep: {"hold"},
    mission_file.BehaviourStep: {"behaviour", "hold"},
    mission_file.PauseStep: {"pause", "hold"},
    mission_file.LandStep: {"land"},
    mission_file.RtlStep: {"rtl"},
    mission_file.PlanStep: {"plan_upload", "plan_start"},  # decoded when reached (where each drone spawned)
    mission_file.FaultStep: {"fault"},  # decoded when due (fault = "crash" too: the fault verb's crash)
}
MISSION_ALSO: dict[str, set[str]] = {
    "before the first step": {"arm"},
    "[swarm] params, [swarm.drone.N] params": {"param"},
    "[[invariants]]": {"require"},
    "--attach": {"attach"},  # verbs.attach_all, before the drones start
}
MISSION_LEAVES_OUT = {
    "goto": "a formation step says where the formation is (its centre)",
    "kill": "a fault step of kind crash is the kill (the fault verb's crash)",
    "plan_download": "a mission flies plans; swarm plan download reads one back",
    "detach": "an attached vehicle stays for the mission",
    "control": "a user's controller is Python code: the API's control()",
}


def test_a_mission_offers_every_verb_but_those_it_leaves_out() -> None:
    assert set(STEP_VERBS) == set(typing.get_args(mission_file.Step)), "a kind of step not in STEP_VERBS"
    _offers_every_verb({**STEP_VERBS, **MISSION_ALSO}, MISSION_LEAVES_OUT)
    # and the runner makes exactly those requests (gcs/supervisor/mission_runner.py, step_requests and its own)
    tree = ast.parse((ROOT / "gcs/supervisor/mission_runner.py").read_text())
    made = {getattr(rq, call.func.attr).verb for call in ast.walk(tree) if isinstance(call, ast.Call)
            and isinstance(call.func, ast.Attribute) and isinstance(call.func.value, ast.Name)
            and call.func.value.id == "rq"}  # fmt: skip
    attaches = any(isinstance(n, ast.Name) and n.id == "attach_all" for n in ast.walk(tree))
    assert made | ({"attach"} if attaches else set()) == set().union(*STEP_VERBS.values(), *MISSION_ALSO.values())


def test_each_kind_of_step_decodes_to_its_verbs() -> None:
    """Every kind of step a mission file has, with the verbs it makes; a new kind without its decoding fails."""
    formation = GridSpec(rows=1, cols=2, spacing_m=2.0, alt_m=3.0)
    follow = FollowSpec(waypoints_ne_m=((5.0, 0.0),), alt_m=3.0)
    cases: dict[type, tuple[Any, list[tuple[str, bool]]]] = {
        mission_file.TakeoffStep: (mission_file.TakeoffStep(alt_m=3.0), [("takeoff", True)]),
        mission_file.FormationStep: (mission_file.FormationStep(name="g", formation=formation, hold_s=5.0),
                                     [("formation", True), ("hold", True)]),
        mission_file.FlockStep: (mission_file.FlockStep(name="f", spec=FlockSpec(alt_m=3.0), duration_s=5.0,
                                                        onboard=True),
                                 [("flock", True), ("hold", True), ("behaviour", True)]),
        mission_file.FollowStep: (mission_file.FollowStep(name="f", spec=follow, leader_drone=2, duration_s=None),
                                  [("follow", True)]),
        mission_file.FollowAttachedStep: (
            mission_file.FollowAttachedStep(name="a", spec=FollowAttachedSpec(alt_m=3.0, duration_s=5.0)),
            [("follow_attached", True), ("hold", True)]),
        mission_file.SwapStep: (mission_file.SwapStep(speed_mps=1.0), [("swap", True)]),
        mission_file.HoldStep: (mission_file.HoldStep(duration_s=1.0), [("hold", True)]),
        mission_file.BehaviourStep: (mission_file.BehaviourStep(duration_s=1.0),
                                     [("behaviour", True), ("hold", True), ("behaviour", True)]),
        mission_file.PauseStep: (mission_file.PauseStep(duration_s=2.0), [("pause", True), ("hold", True)]),
        mission_file.LandStep: (mission_file.LandStep(), [("land", True)]),
        mission_file.RtlStep: (mission_file.RtlStep(), [("rtl", True)]),
    }  # fmt: skip
    reached = {mission_file.PlanStep, mission_file.FaultStep}  # decoded when reached, by the runner
    assert set(cases) | reached == set(typing.get_args(mission_file.Step))
    for kind, (step, verbs) in cases.items():
        planned = step_requests(step, [7, 8, 9])
        assert [(p.request.verb, p.wait) for p in planned] == verbs, kind
        assert {verb for verb, _ in verbs} <= STEP_VERBS[kind], kind
    timed = step_requests(mission_file.FollowStep(name="f", spec=follow, leader_drone=2, duration_s=4.0), [7, 8, 9])
    assert [(p.request.verb, p.wait) for p in timed] == [("follow", False), ("hold", True)]
    assert typing.cast(rq.Follow, timed[0].request).spec.leader_sysid == 8  # drone 2 of the swarm
    step = mission_file.TakeoffStep(alt_m=4.0)
    assert step_requests(step, [1])[0].request == rq.Takeoff(alt_m=4.0, timeout_s=step.timeout_s)


# ---- the Python API, both faces ------------------------------------------------------------------------------------
class _Recorder:
    """Stands in for the engine's thread: what a face asks of it, as requests."""

    def __init__(self) -> None:
        self.asked: list[tuple[rq.Request, bool]] = []

    def do(self, request: rq.Request, *, wait: bool = True) -> Any:
        self.asked.append((request, wait))
        return "answer"

    def sleep(self, hold: rq.Hold) -> None:
        self.asked.append((hold, True))

    def control(self, controller: Any) -> rq.Control:
        return rq.Control(controller=controller)

    def submit(self, work: Any) -> Any:
        import concurrent.futures

        future: concurrent.futures.Future[Any] = concurrent.futures.Future()
        future.set_result(work())
        return future


API_CASES: list[tuple[str, tuple[Any, ...], dict[str, Any], rq.Request, bool]] = [
    ("takeoff", (), {}, rq.Takeoff(), True),
    ("takeoff", (6.0,), {}, rq.Takeoff(alt_m=6.0), True),
    ("formation", (LineSpec(spacing_m=2.0, alt_m=3.0),), {}, rq.FlyFormation(formation=LineSpec(spacing_m=2.0,
                                                                                             alt_m=3.0)), True),
    ("flock", (FlockSpec(alt_m=3.0),), {"onboard": True}, rq.Flock(spec=FlockSpec(alt_m=3.0), onboard=True), True),
    ("follow", (FollowSpec(waypoints_ne_m=((5.0, 0.0),), alt_m=3.0),), {},
     rq.Follow(spec=FollowSpec(waypoints_ne_m=((5.0, 0.0),), alt_m=3.0)), False),
    ("control", (print,), {}, rq.Control(controller=print), True),  # type: ignore[arg-type]
    ("start_behaviours", (), {}, rq.Behaviours(run=True), True),
    ("stop_behaviours", (), {}, rq.Behaviours(run=False), True),
    ("require", (), {"kind": "contact"}, rq.Require(invariants=({"kind": "contact"},)), True),
    ("sleep", (2.0,), {}, rq.Hold(duration_s=2.0), True),
    ("pause", (), {}, rq.Pause(), True),
    ("land", (), {}, rq.Land(), True),
    ("return_to_launch", (), {}, rq.ReturnToLaunch(), True),
    ("set_param", ("MPC_XY_VEL_MAX", 2.0), {"sysids": [1, 2]},
     rq.SetParam(name="MPC_XY_VEL_MAX", value=2.0, sysids=(1, 2)), True),
    ("inject_fault", (3, "gps"), {}, rq.InjectFault(sysid=3, fault=FaultRequest(kind="gps")), True),
    ("kill", (3,), {}, rq.Kill(sysid=3), True),
]  # fmt: skip


@pytest.mark.parametrize("face", [Session, BlockingSession])
@pytest.mark.parametrize(("method", "args", "kwargs", "expected", "wait"), API_CASES,
                         ids=[f"{c[0]}{c[1]}" for c in API_CASES])  # fmt: skip
def test_the_api_decodes_each_call_to_its_request(
    face: type, method: str, args: tuple[Any, ...], kwargs: dict[str, Any], expected: Any, wait: bool
) -> None:
    session = face.__new__(face)
    engine = _Recorder()
    session._engine = engine
    if face is Session:
        session._loop = asyncio.new_event_loop()  # _run awaits the future on the caller's loop
        try:
            session._loop.run_until_complete(getattr(session, method)(*args, **kwargs))
        finally:
            session._loop.close()
    else:
        getattr(session, method)(*args, **kwargs)
    assert engine.asked == [(expected, wait)]


# Each public method of both faces and the verb it asks; the methods that are not verbs; the verbs left out, and why.
API_VERBS: dict[str, set[str]] = {
    "takeoff": {"takeoff"},
    "formation": {"formation"},
    "flock": {"flock"},
    "follow": {"follow"},
    "control": {"control"},
    "start_behaviours": {"behaviour"},
    "stop_behaviours": {"behaviour"},
    "require": {"require"},
    "sleep": {"hold"},
    "pause": {"pause"},
    "land": {"land"},
    "return_to_launch": {"rtl"},
    "set_param": {"param"},
    "inject_fault": {"fault"},
    "kill": {"kill"},
}
API_NOT_VERBS = {"start", "close", "events", "wait_until", "drones"}  # the session's own, and reading the drones
API_LEAVES_OUT = {
    "arm": "takeoff() arms the drones on the ground first",
    "goto": "formation() flies a formation anew wherever its spec centres it",
    "swap": "the avoidance stress test, flown from a mission file",
    "follow_attached": "an attached leader is followed by a controller of the user's own (control()) or a mission",
    "attach": "LaunchOptions.attach, before the drones start",
    "detach": "an attached vehicle stays for the session",
    "plan_upload": "QGroundControl plans are flown from a mission or swarm plan; a script flies its own path",
    "plan_start": "as plan_upload",
    "plan_download": "as plan_upload",
}


def test_every_api_call_that_flies_offers_its_verb_and_the_api_every_verb_but_those_it_leaves_out() -> None:
    for face in (Session, BlockingSession):
        public = {n for n, f in inspect.getmembers(face, inspect.isfunction) if not n.startswith("_")}
        assert public - API_NOT_VERBS == set(API_VERBS), (face, public - API_NOT_VERBS ^ set(API_VERBS))
    _offers_every_verb(API_VERBS, API_LEAVES_OUT)
    decoded: dict[str, set[str]] = {}
    for method, _args, _kwargs, expected, _wait in API_CASES:
        assert expected.verb in API_VERBS[method], method
        decoded.setdefault(method, set()).add(expected.verb)
    assert decoded == API_VERBS, "a verb an API call offers without a case above"


# ---- nothing written beside the verbs ------------------------------------------------------------------------------
FRONT_ENDS = ("gcs/supervisor/station.py", "gcs/supervisor/mission_runner.py", "gcs/api/engine.py",
              "gcs/supervisor/commands.py", "gcs/cli.py", "gcs/bench/scaling.py")  # fmt: skip
# What only a verb may do: the calls that change what the swarm flies or what a drone is.
VERBS_OWN = frozenset({
    "command", "command_flock", "command_follow", "command_swap", "command_behaviour", "takeoff_all", "land_all",
    "hold_all", "kill", "inject_fault", "set_params", "start_missions", "upload_plan", "download_plan",
    "start_onboard_behaviours", "stop_onboard_behaviours", "start_onboard_flock", "start_onboard_follow",
    "start_takeoff", "arm_all",
})  # fmt: skip
# Where a front-end does one of those itself, and why it is not a verb.
NOT_VERBS_OWN = {
    # a loss policy's own ending of the mission: the survivors land after holding (docs/drone-loss.md)
    ("gcs/supervisor/mission_runner.py", "_finish_after_policy", "land_all"),
    # a user's controller that raised: the API's failsafe holds every drone where it is
    ("gcs/api/engine.py", "_tick", "hold_all"),
    # the bench's relay probe, a process of its own (gcs/bench/probe.py), ended when it overstays
    ("gcs/bench/scaling.py", "relay_latency", "kill"),
}


@pytest.mark.parametrize("path", FRONT_ENDS)
def test_a_front_end_does_not_reach_past_the_verbs(path: str) -> None:
    tree = ast.parse((ROOT / path).read_text())
    functions = {node.name: node for node in ast.walk(tree) if isinstance(node, ast.FunctionDef)}
    past = set()
    for name, function in functions.items():
        for call in ast.walk(function):
            if isinstance(call, ast.Call) and isinstance(call.func, ast.Attribute) and call.func.attr in VERBS_OWN:
                past.add((path, name, call.func.attr))
    assert past <= NOT_VERBS_OWN, f"written beside the verbs: {sorted(past - NOT_VERBS_OWN)}"
