"""``swarm sweep`` end to end: real runs side by side, two sweeps at once, a run flown again on other instances, the
same runs on a local Ray head, a sweep killed halfway and resumed, and bad input.

Policy: loopback only (Ray too: RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0 keeps a single-machine Ray on 127.0.0.1); a
mission of two drones; the sweeps' runs on instances 20 up, from the machine's sweep locks, and a run flown again
here on instances leased from the same locks (tests/integration/instances.py); every process started here is stopped
by PID (a sweep and the Ray head by their process groups); time limits.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from gcs.sweep.child import RUN_MODULE
from tests.integration.instances import Leases
from tests.integration.mission_flight import mission_drones
from tests.integration.test_swarm import alive, wait_dead

pytestmark = [pytest.mark.sim_only]

SWARM = [sys.executable, "-m", "gcs.cli"]
MISSION = """\
name = "sweep_swap"
[swarm]
drones = 2
layout = "line"
spacing_m = 4.0

[[steps]]
action = "takeoff"
alt_m = 2.5

[[steps]]
action = "formation"
shape = "line"
spacing_m = 4.0
alt_m = 2.5
hold_s = 1.0

[[steps]]
action = "swap"
speed_mps = 2.0
timeout_s = 20.0

[[steps]]
action = "land"
"""
SETTINGS = ["--param", "AVOID_MIN_DIST=1.0,1.5"]


@pytest.fixture(scope="module")
def sweep_env() -> dict[str, str]:
    """The sweeps' environment: Ray on loopback, reporting nothing home. Their instance locks are the machine's, so
    they keep clear of any other sweep running here."""
    return {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"}


@pytest.fixture(scope="module")
def mission(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("mission") / "sweep_swap.toml"
    path.write_text(MISSION)
    return path


def _as_in_a_terminal() -> None:
    """Ctrl-C interrupts, as for a command typed in a terminal. A shell that starts a job in the background has it
    ignore SIGINT, and the tests may be run from such a job: the sweep would inherit that and never be interrupted."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def sweep(mission: Path, out: Path, env: dict[str, str], *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([*SWARM, "sweep", str(mission), "--out", str(out), *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, start_new_session=True,
                            preexec_fn=_as_in_a_terminal)  # fmt: skip


def finish(proc: subprocess.Popen[str], timeout_s: float) -> tuple[int, str, str]:
    try:
        out, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
        pytest.fail(f"sweep did not finish within {timeout_s:g} s: {out[-2000:]} {err[-2000:]}")
    return proc.returncode, out, err


def stopped(proc: subprocess.Popen[str]) -> None:
    """A sweep the test is done with, also after a failed assertion: stopped (its process group) if it still runs,
    and reaped."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
    proc.communicate()


def run_files(out: Path) -> dict[str, dict[str, Any]]:
    """Every complete run's run.json, by run name."""
    return {data["name"]: data for data in (json.loads(p.read_text()) for p in sorted(out.glob("runs/*/*/run.json")))}


@pytest.fixture(scope="module")
def two_sweeps_at_once(mission: Path, sweep_env: dict[str, str],
                       tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:  # fmt: skip
    """Sweep A (2 settings x 2 seeds, two runs at a time) and sweep B (one run) started together on this machine."""
    base = tmp_path_factory.mktemp("sweeps")
    a = sweep(mission, base / "a", sweep_env, "--seeds", "1-2", *SETTINGS, "--jobs", "2")
    b = sweep(mission, base / "b", sweep_env, "--seeds", "7")
    return {"a": (base / "a", *finish(a, 400)), "b": (base / "b", *finish(b, 400))}


@pytest.mark.timeout(600)
def test_two_sweeps_at_once_both_complete_with_every_report_and_a_summary(two_sweeps_at_once: dict[str, Any]) -> None:
    out, code, stdout, stderr = two_sweeps_at_once["a"]
    assert code == 0, stdout[-3000:] + stderr[-3000:]
    runs = run_files(out)
    assert sorted(runs) == sorted(f"AVOID_MIN_DIST={v}/seed-000{s}" for v in ("1", "1.5") for s in (1, 2))
    assert all(r["ok"] for r in runs.values())
    for name in runs:
        assert (out / "runs" / name / "report" / "report.html").exists()
    summary = json.loads((out / "summary.json").read_text())
    assert {k: v["runs"] for k, v in summary["settings"].items()} == {"AVOID_MIN_DIST=1": 2, "AVOID_MIN_DIST=1.5": 2}
    assert summary["worst_runs"] and summary["slowest_runs"]
    assert len((out / "runs.csv").read_text().splitlines()) == 5
    assert (out / "plots" / "min_separation_m.png").exists()
    assert "AVOID_MIN_DIST=1.5" in stdout and "worst runs" in stdout
    # AND sweep B, flown at the same time, completed too, and no two runs that flew at once shared instances
    out_b, code_b, stdout_b, stderr_b = two_sweeps_at_once["b"]
    assert code_b == 0, stdout_b[-3000:] + stderr_b[-3000:]
    assert sorted(run_files(out_b)) == ["default/seed-0007"]
    firsts = [int(r["command"][r["command"].index("--first-instance") + 1])
              for o in (out, out_b) for r in run_files(o).values()]  # fmt: skip
    # B's run flew beside A's first two: three runs at once, three blocks of instances
    assert len(set(firsts)) >= 3, firsts


@pytest.mark.timeout(600)
def test_a_run_gives_the_same_metrics_on_other_instances(
    two_sweeps_at_once: dict[str, Any], mission: Path, sweep_env: dict[str, str], tmp_path: Path, instances: Leases
) -> None:
    """Reproducible from its seed and setting alone: one run of sweep A flown again, alone, on other instances."""
    out = two_sweeps_at_once["a"][0]
    run = run_files(out)["AVOID_MIN_DIST=1.5/seed-0002"]
    command = list(run["command"][1:])
    flown_on = int(command[command.index("--first-instance") + 1])
    first = instances(mission_drones(mission))
    if first == flown_on:  # the sweep has given its instances back: take the next block (this one stays held)
        first = instances(mission_drones(mission))
    command[command.index("--first-instance") + 1] = str(first)
    command[command.index("--report") + 1] = str(tmp_path / "again")
    result = subprocess.run([*SWARM, *command], capture_output=True, text=True, env=sweep_env, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    again = json.loads((tmp_path / "again" / "metrics.json").read_text())
    original = json.loads((out / "runs" / "AVOID_MIN_DIST=1.5" / "seed-0002" / "report" / "metrics.json").read_text())
    assert again["sysids"] == [first + 1, first + 2] and again["sysids"] != original["sysids"]
    assert by_drone_index(again) == by_drone_index(original)  # every figure, each drone named by its place


def by_drone_index(metrics: dict[str, Any]) -> Any:
    """metrics.json with each sysid replaced by the drone's place in the swarm (0, 1, ...), in the drones' texts too
    ("Avoidance: drone 26 predicted ...")."""
    place = {sysid: k for k, sysid in enumerate(metrics["sysids"])}

    def named(text: str) -> str:
        return re.sub(r"drone (\d+)", lambda m: f"drone #{place.get(int(m.group(1)), m.group(1))}", text)

    def walk(value: Any, key: str = "") -> Any:
        if isinstance(value, dict):
            renamed = {k: str(place[int(k)]) if k.isdigit() and int(k) in place else k for k in value}
            return {renamed[k]: walk(v, k) for k, v in value.items()}
        if isinstance(value, list):
            return [walk(v, key) for v in value]
        if key in ("sysids", "min_separation_pair", "sysid") and isinstance(value, int):
            return place.get(value, value)
        if key == "text" and isinstance(value, str):
            return named(value)
        return value

    return walk(metrics)


HEADS: dict[str, int] = {}  # the Ray heads started here: address -> the session (process group) of ray start


def all_children(pid: int) -> list[int]:
    """Children of every thread of ``pid`` (a Ray worker starts processes from a thread of its own)."""
    out: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        with contextlib.suppress(OSError):
            out += [int(c) for c in (task / "children").read_text().split()]
    return out


def ray_head_session(address: str) -> int:
    return HEADS[address]


def busy_worker(session: int, timeout_s: float) -> tuple[int, int]:
    """A Ray worker of the head's session flying a run: its PID and its run's (the swarm's supervisor)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for stat in Path("/proc").glob("[0-9]*/stat"):
            with contextlib.suppress(OSError, ValueError, IndexError):
                pid = int(stat.parent.name)
                if int(stat.read_text().rsplit(")", 1)[1].split()[3]) != session:
                    continue
                if not (stat.parent / "cmdline").read_bytes().startswith(b"ray::fly_on_node"):
                    continue
                runs = [c for c in all_children(pid) if RUN_MODULE.encode() in Path(f"/proc/{c}/cmdline").read_bytes()]
                if runs:
                    return pid, runs[0]
        time.sleep(0.1)
    raise AssertionError("no Ray worker was flying a run")


@pytest.fixture
def ray_head(sweep_env: dict[str, str]) -> Iterator[str]:
    """A local Ray head on loopback with two CPUs, stopped (its whole process group) at the end."""
    pytest.importorskip("ray")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    temp = tempfile.mkdtemp(prefix="ray-", dir="/tmp")  # Ray's socket paths must stay short
    ray = Path(sys.executable).with_name("ray")
    head = subprocess.Popen([str(ray), "start", "--head", "--port", str(port), "--num-cpus", "2",
                             "--include-dashboard", "false", "--disable-usage-stats", "--temp-dir", temp, "--block"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=sweep_env,
                            start_new_session=True)  # fmt: skip
    HEADS[f"127.0.0.1:{port}"] = head.pid
    try:
        yield f"127.0.0.1:{port}"
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(head.pid, signal.SIGTERM)
        with contextlib.suppress(subprocess.TimeoutExpired):
            head.wait(5)  # its servers take their time over SIGTERM: what is left after 5 s is killed
        with contextlib.suppress(ProcessLookupError):
            os.killpg(head.pid, signal.SIGKILL)
        head.wait(10)
        subprocess.run(["rm", "-rf", temp], check=False)


@pytest.mark.timeout(600)
def test_the_same_sweep_on_a_local_ray_head_gives_the_same_runs_and_summary(
    two_sweeps_at_once: dict[str, Any], mission: Path, sweep_env: dict[str, str], ray_head: str, tmp_path: Path
) -> None:
    local = two_sweeps_at_once["a"][0]
    proc = sweep(mission, tmp_path / "ray", sweep_env, "--seeds", "1-2", *SETTINGS, "--ray", ray_head)
    try:
        # WHEN the Ray worker flying a run dies (SIGKILL, as with its node) THEN its run's swarm ends with it, and
        # Ray flies the run again
        worker, flight = busy_worker(ray_head_session(ray_head), 120)
        os.kill(worker, signal.SIGKILL)
        assert wait_dead([flight], 30) == [], "the killed worker's run outlived it"
        code, stdout, stderr = finish(proc, 500)
    finally:
        stopped(proc)
    assert code == 0, stdout[-3000:] + stderr[-3000:]
    assert "Ray cluster at" in stdout
    on_ray, here = run_files(tmp_path / "ray"), run_files(local)
    assert sorted(on_ray) == sorted(here)
    assert {n: r["metrics"] for n, r in on_ray.items()} == {n: r["metrics"] for n, r in here.items()}
    for name in on_ray:
        assert (tmp_path / "ray" / "runs" / name / "report" / "report.html").exists()
    summary_ray = json.loads((tmp_path / "ray" / "summary.json").read_text())
    summary_here = json.loads((local / "summary.json").read_text())
    assert summary_ray["settings"] == summary_here["settings"]


# Starts a run as gcs/sweep/runs.py does, naming itself its parent (gcs/sweep/child.py), and dies at once; the run's
# process waits until the starter is gone and only then becomes the run (exec: the same process, parent and
# environment): a Ray worker killed the moment its run's process exists, before the run could ask the kernel to end
# it with its parent, made certain.
STARTER = """\
import os, subprocess, sys
from gcs.sweep.child import RUN_MODULE, parent_named
wait = ("import os, sys, time\\nwhile os.getppid() == int(sys.argv[1]):\\n    time.sleep(0.01)\\n"
        f"os.execv(sys.executable, [sys.executable, '-m', {RUN_MODULE!r}, *sys.argv[2:]])")
with open(sys.argv[1], "w") as log:
    run = subprocess.Popen([sys.executable, "-c", wait, str(os.getpid()), *sys.argv[2:]], stdout=log,
                           stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True,
                           env={**os.environ, **parent_named()})
print(run.pid)
"""


@pytest.mark.timeout(120)
def test_a_run_whose_parent_died_before_it_could_ask_to_end_with_it_ends_at_once_starting_nothing(
    mission: Path, sweep_env: dict[str, str], tmp_path: Path, instances: Leases
) -> None:
    log, report = tmp_path / "fly.log", tmp_path / "report"
    args = ["fly", str(mission), "--lockstep", "--report", str(report), "--no-forward", "--no-view",
            "--first-instance", str(instances(mission_drones(mission)))]  # fmt: skip
    starter = subprocess.run([sys.executable, "-c", STARTER, str(log), *args], capture_output=True, text=True,
                             env=sweep_env, timeout=60)  # fmt: skip
    assert starter.returncode == 0, starter.stderr
    run = int(starter.stdout)
    try:
        assert wait_dead([run], 10) == [], "the run flew on without its parent"
    finally:
        if alive(run):  # its drone factory and drones end with it
            os.killpg(run, signal.SIGKILL)
    assert "spawning" not in log.read_text() and not report.exists(), log.read_text()[-2000:]


# Paced runs: a run's lockstep clock goes no faster than PACE x the wall clock, so a run cannot end sooner than its
# flight's simulated time / PACE after it starts, however fast the drones compute. This mission's take-off,
# formation, swap and landing take 14 simulated seconds (its metrics' duration_s), so a run lasts over 4.7 s at
# PACE 3: RUN_FLOOR_S, with a margin. The run's results do not depend on the pace (lockstep).
PACE = 3.0
RUN_FLOOR_S = 4.0


def complete_run_names(out: Path) -> list[str]:
    """The runs whose run.json is there and whole (a poll may meet one half written)."""
    names = []
    for path in sorted(out.glob("runs/*/*/run.json")):
        with contextlib.suppress(OSError, ValueError):
            names.append(json.loads(path.read_text())["name"])
    return names


@pytest.mark.timeout(600)
def test_a_sweep_killed_halfway_finishes_only_the_missing_runs_when_run_again(
    mission: Path, sweep_env: dict[str, str], tmp_path: Path
) -> None:
    """Ctrl-C lands while the second of two runs flies, whatever the drones' speed: with one job the second run
    starts only once the first has written its run.json, and, paced, it flies for at least RUN_FLOOR_S after that;
    the test interrupts as soon as it sees that run.json."""
    out = tmp_path / "sweep"
    args = ["--seeds", "1-2", "--jobs", "1", "--speed", f"{PACE:g}"]
    proc = sweep(mission, out, sweep_env, *args)
    deadline = time.monotonic() + 300
    while not complete_run_names(out) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    seen = time.monotonic()
    assert complete_run_names(out) == ["default/seed-0001"], proc.communicate(timeout=5)
    os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C, as a terminal sends it to the whole group
    assert time.monotonic() - seen < RUN_FLOOR_S / 2  # well within the second run's flight
    code, _stdout, stderr = finish(proc, 120)
    assert code == 130 and "interrupted" in stderr and "Traceback" not in stderr, stderr
    done = run_files(out)
    assert sorted(done) == ["default/seed-0001"]  # the second run was under way: stopped, not complete
    assert done["default/seed-0001"]["wall_s"] >= RUN_FLOOR_S  # the pace held the first run that long too
    before = {name: (out / "runs" / name / "run.json").stat().st_mtime_ns for name in done}
    # WHEN run again with the same folder
    code, stdout, stderr = finish(sweep(mission, out, sweep_env, *args), 400)
    assert code == 0, stdout[-3000:] + stderr[-3000:]
    # THEN it flies only the missing run, and keeps the complete one as it was
    assert "1 complete already, 1 to fly" in stdout
    assert sorted(run_files(out)) == ["default/seed-0001", "default/seed-0002"]
    assert all(r["ok"] for r in run_files(out).values())
    assert {name: (out / "runs" / name / "run.json").stat().st_mtime_ns for name in done} == before
    assert "--speed" in run_files(out)["default/seed-0002"]["command"]


@pytest.mark.timeout(120)
@pytest.mark.parametrize(
    ("args", "line"),
    [
        (["--seeds", "1-2", "--param", "NOT_A_PARAM=1,2"], "NOT_A_PARAM is not a parameter of the simulated drones"),
        (["--seeds", "1-2", "--param", "AVOID_MIN_DIST=0.1,1"], "AVOID_MIN_DIST: 0.1 outside"),
        (["--seeds", "5-1"], "must be a range from low to high"),
        (["--seeds", "1-2", "--link-loss", "0,1.5"], "every probability must be in [0, 1)"),
        (["--seeds", "1-2", "--jobs", "0"], "--jobs must be at least 1"),
        (["--seeds", "1-2", "--speed", "0"], "--speed must be a positive number, got 0"),
    ],
)
def test_bad_input_is_one_line_and_exit_code_2(mission: Path, sweep_env: dict[str, str], tmp_path: Path,
                                               args: list[str], line: str) -> None:  # fmt: skip
    result = subprocess.run([*SWARM, "sweep", str(mission), "--out", str(tmp_path / "o"), *args],
                            capture_output=True, text=True, env=sweep_env, timeout=60)  # fmt: skip
    assert result.returncode == 2, result.stderr
    assert result.stderr.count("\n") == 1 and line in result.stderr, result.stderr
    assert not (tmp_path / "o").exists()  # nothing flown, nothing written


@pytest.mark.timeout(120)
def test_ray_missing_is_one_line_and_exit_code_2(mission: Path, sweep_env: dict[str, str], tmp_path: Path) -> None:
    """As on a machine without the [cluster] extra: ``import ray`` fails."""
    code = "import sys; sys.modules['ray'] = None; from gcs.cli import main; sys.exit(main(sys.argv[1:]))"
    result = subprocess.run([sys.executable, "-c", code, "sweep", str(mission), "--seeds", "1", "--ray", "auto",
                             "--out", str(tmp_path / "o")], capture_output=True, text=True, env=sweep_env,
                            timeout=60)  # fmt: skip
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert "--ray needs Ray" in result.stderr and "pip install" in result.stderr


SPACE = """
[[invariants]]
kind = "contact"

[falsify]
params = { AVOID_ENABLE = [0] }
max_perturbations = 2
"""


def falsify_swap(sweep_env: dict[str, str], tmp_path: Path, where: str, *args: str) -> dict[str, Any]:
    """The budget-6 campaign on the swap with a space where both drones' avoidance off makes them touch: found, exit 3;
    its summary."""
    path = tmp_path / "swap_space.toml"
    path.write_text(MISSION + SPACE)
    run = subprocess.run([*SWARM, "falsify", str(path), "--budget", "6", "--shrink-budget", "6", "--seed", "2",
                          "--out", str(tmp_path / where), *args], capture_output=True, text=True, env=sweep_env,
                         timeout=500)  # fmt: skip
    assert run.returncode == 3, run.stdout[-3000:] + run.stderr[-3000:]
    if "--ray" in args:
        assert "Ray cluster at" in run.stdout
    return dict(json.loads((tmp_path / where / "summary.json").read_text()))


FOUND_KEYS = ("invariant", "drones", "first_flight", "scenario", "perturbations", "detail")


@pytest.mark.timeout(300)
def test_a_small_falsification_finds_the_contact_and_shrinks_it_to_both_drones_avoidance_off(
    sweep_env: dict[str, str], tmp_path: Path
) -> None:
    # GIVEN the swap WHEN a budget-6 campaign searches it on this machine (its Ray twin: the acceptance tier, below)
    summary = falsify_swap(sweep_env, tmp_path, "here", "--jobs", "1")
    # THEN it found the contact and shrank it to the two perturbations that make it: both drones' avoidance off
    found = [{k: f[k] for k in FOUND_KEYS} for f in summary["failures"]]
    assert found and found[0]["invariant"] == "contact", found
    assert found[0]["perturbations"] == 2 and found[0]["drones"] == [1, 2], found
    assert summary["search_flights"] <= 6
    for failure in summary["failures"]:
        assert (Path(failure["report"]) / "report.html").is_file()


@pytest.mark.timeout(600)
def test_a_falsification_on_a_local_ray_head_finds_and_shrinks_what_it_does_here(
    sweep_env: dict[str, str], ray_head: str, tmp_path: Path
) -> None:
    # GIVEN the swap with a space where both drones' avoidance off makes them touch
    # WHEN the same campaign runs on this machine and on the Ray head
    summaries = {where: falsify_swap(sweep_env, tmp_path, where, *args)
                 for where, args in (("here", ("--jobs", "1")), ("ray", ("--ray", ray_head)))}  # fmt: skip
    # THEN both found the same contact and shrank it to the same two perturbations, in as many flights to search
    found = {where: [{k: f[k] for k in FOUND_KEYS} for f in s["failures"]] for where, s in summaries.items()}
    assert found["ray"] == found["here"] and found["here"], found
    assert found["here"][0]["perturbations"] == 2 and found["here"][0]["drones"] == [1, 2], found
    assert summaries["ray"]["search_flights"] == summaries["here"]["search_flights"]
    # AND the Ray flights' folders came back whole: each shrunk failure's report is here
    for failure in summaries["ray"]["failures"]:
        assert (Path(failure["report"]) / "report.html").is_file()
