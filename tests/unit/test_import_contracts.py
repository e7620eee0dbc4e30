"""The boundary between the ground station and the simulation holds: ``lint-imports`` with the contracts in
pyproject.toml ([tool.importlinter]): gcs imports nothing from sitl except through its composition root, which
only the swarm entry point uses, sitl imports nothing from gcs, the harness never reaches the drones' compiled
kernels, on each side a folder imports only the folders below it, what both sides share imports neither, and no part
imports the facade that holds it (the swarm's, the flight session's, the commander's) (docs/architecture.md)."""

from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
LINT_IMPORTS = Path(sys.executable).parent / "lint-imports"

pytestmark = pytest.mark.timeout(120)


def _lint_imports(root: Path) -> subprocess.CompletedProcess[str]:
    if not LINT_IMPORTS.exists():
        pytest.fail(f"{LINT_IMPORTS} is missing: install the test extra (pip install -e '.[test]')")
    env = {**os.environ, "PYTHONPATH": str(root)}
    return subprocess.run([str(LINT_IMPORTS), "--no-cache"], cwd=root, env=env, capture_output=True, text=True,
                          timeout=100)  # fmt: skip


def test_the_ground_station_and_the_simulation_keep_to_their_import_contracts() -> None:
    result = _lint_imports(ROOT)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "10 kept, 0 broken" in result.stdout, result.stdout


@pytest.mark.parametrize(
    ("module", "line", "complaint"),
    [
        ("gcs/flight/formation.py", "import sitl.world.shared", "gcs.flight.formation -> sitl.world.shared"),
        ("gcs/bench/scaling.py", "import gcs.composition", "gcs.bench.scaling -> gcs.composition"),
        ("sitl/harness/harness.py", "import gcs.fleet.harness", "sitl.harness.harness -> gcs.fleet.harness"),
        ("sitl/world/shared.py", "import sitl.world.view", "sitl.world.shared -> sitl.world.view"),
        ("gcs/flight/formation.py", "import gcs.fleet.swarm", "gcs.flight.formation -> gcs.fleet.swarm"),
        ("gcs/mavlink/transport.py", "import gcs.flight.geodesy", "gcs.mavlink.transport -> gcs.flight.geodesy"),
        ("sitl/autopilot/commander.py", "import sitl.protocol.link", "sitl.autopilot.commander -> sitl.protocol.link"),
        ("sitl/dynamics/wind.py", "import sitl.sensors.models", "sitl.dynamics.wind -> sitl.sensors.models"),
        ("swarmcommon/links.py", "import gcs.fleet.links", "swarmcommon.links -> gcs.fleet.links"),
        ("gcs/sweep/child.py", "import gcs.cli", "gcs.sweep.child -> gcs.cli"),
        ("gcs/fleet/attachments.py", "import gcs.fleet.swarm", "gcs.fleet.attachments -> gcs.fleet.swarm"),
        ("gcs/fleet/picture.py", "import gcs.fleet.swarm", "gcs.fleet.picture -> gcs.fleet.swarm"),
        (
            "gcs/supervisor/invariant_watch.py",
            "import gcs.supervisor.session",
            "gcs.supervisor.invariant_watch -> gcs.supervisor.session",
        ),
        ("gcs/record/recorder.py", "import gcs.supervisor.session", "gcs.record.recorder -> gcs.supervisor.session"),
        (
            "sitl/autopilot/modes.py",
            "import sitl.autopilot.commander",
            "sitl.autopilot.modes -> sitl.autopilot.commander",
        ),
    ],
)
def test_a_crossing_import_breaks_the_build(tmp_path: Path, module: str, line: str, complaint: str) -> None:
    # GIVEN a copy of both packages with one import that crosses a boundary or runs up a layer
    for package in ("gcs", "sitl", "swarmcommon"):
        shutil.copytree(ROOT / package, tmp_path / package, ignore=shutil.ignore_patterns("__pycache__", "*.xml"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    target = tmp_path / module
    target.write_text(target.read_text() + f"\n{line}  # noqa\n")
    # WHEN the contracts are checked THEN the check fails and names the import
    result = _lint_imports(tmp_path)
    assert result.returncode != 0, result.stdout
    assert complaint in result.stdout, result.stdout


def test_a_swarm_command_that_does_not_fly_starts_without_numba() -> None:
    # status, down, --help: the ground station's whole import graph, and not the compiled kernels (they load in the
    # drones' processes, and importing numba costs a command like these about half a second)
    code = "import sys, gcs.cli, gcs.api; print(sorted(m for m in sys.modules if m.startswith(('numba', 'llvmlite'))))"
    result = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]", result.stdout


def test_checking_a_mission_s_parameters_loads_no_numba_either() -> None:
    # swarm fly checks every parameter a mission sets against the drones' table before it spawns them: the check alone
    # once loaded the whole flight code and its kernels, about two seconds of every flight with parameters
    code = ("import sys; from gcs.composition import SITL; assert SITL.parameter_value('AVOID_ENABLE', 0) == 0; "
            "print(sorted(m for m in sys.modules if m.startswith(('numba', 'llvmlite', 'sitl.kernels'))))")  # fmt: skip
    result = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]", result.stdout


MAX_CLASS_LINES = 350  # docs/architecture.md: a class that grows past this is doing more than one part's job


def test_no_class_of_the_drone_or_the_ground_station_outgrows_one_part() -> None:
    """A signal, not a proof: a facade that takes on its parts' work grows; its parts are classes of their own (never
    mixins, nor helpers handed the facade), which the import contracts keep from importing it."""
    grown = []
    for root in ("gcs", "sitl"):
        for path in sorted((ROOT / root).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ClassDef) and node.end_lineno is not None:
                    lines = node.end_lineno - node.lineno + 1
                    if lines > MAX_CLASS_LINES:
                        grown.append(f"{path.relative_to(ROOT)}: {node.name} ({lines} lines)")
    assert not grown, grown
