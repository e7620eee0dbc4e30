"""Bad input to ``sitl`` ends with one clear line naming the problem and exit code 2, never a traceback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from sitl.dynamics.airframe import AIRFRAMES_DIR

pytestmark = pytest.mark.timeout(60)


def run_sitl(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "sitl.cli", *args], capture_output=True, text=True, timeout=50)


def assert_one_line_error(result: subprocess.CompletedProcess[str], *fragments: str) -> None:
    assert result.returncode == 2, result
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("sitl: error: ")
    assert "Traceback" not in result.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


def test_unknown_airframe_names_the_file() -> None:
    assert_one_line_error(run_sitl("--airframe", "no_such_frame"), "no_such_frame.toml", "no such airframe file")


@pytest.mark.parametrize(
    ("mutate", "expected"),
    [
        (lambda text: text.replace("mass_kg = 1.5", "mass_kg = -1.5"), "body.mass_kg"),
        (lambda text: text.replace("mass_kg = 1.5", ""), "missing field 'body.mass_kg'"),
        (lambda text: text.replace('spin = "cw"', 'spin = "sideways"', 1), "spin"),
        (lambda text: text.replace("[rotor]", "[rotor"), "not valid TOML"),
        (lambda text: text.replace("max_speed_radps = 1100.0", "max_speed_radps = 300.0"), "cannot lift"),
        (
            lambda text: text.replace("inertia_diag_kg_m2 = [", "inertia_diag_kg_m2 = [1, "),
            "inertia_diag_kg_m2",
        ),
    ],
)
def test_malformed_airframe_file_names_file_and_problem(tmp_path: Path, mutate, expected: str) -> None:  # type: ignore[no-untyped-def]
    bad = tmp_path / "bad_frame.toml"
    bad.write_text(mutate((AIRFRAMES_DIR / "quad_x_f450.toml").read_text()))
    assert_one_line_error(run_sitl("--airframe", str(bad)), str(bad), expected)


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (("--speed", "fast"), "--speed must be a number"),
        (("--speed", "-2"), "--speed must be a finite number >= 0"),
        (("--instance", "-1"), "--instance"),
        (("--home", "47.3,8.5"), "--home"),
        (("--bogus",), "unrecognized arguments"),
        (("--duration", "0"), "--duration"),
        (("--instances", "3-1"), "--instances must be ranges"),
        (("--instances", "0-254"), "--instances must be ranges within 0..253"),
        (("--instance", "254"), "--instance must be in 0..253, got 254"),
        (("--instances", "a-b"), "--instances must look like 0-24"),
        (("--instances", "1-3,2"), "names an instance twice"),
        (("--instances", "1-2", "--instance", "1"), "--instance or --instances, not both"),
        (("--instances", "1-2", "--api-port", "15000"), "--api-port is one drone's"),
        (("--instances", "1-3", "--home", "47.3,8.5,400", "--home", "47.3,8.6,400"), "one per instance (3), not 2"),
        (("--instances", "1-2", "--spacing", "0"), "--spacing must be a positive"),
        (("--instances", "1-2", "--demo"), "--demo flies one drone"),
    ],
)
def test_bad_arguments_give_one_line(args: tuple[str, ...], expected: str) -> None:
    assert_one_line_error(run_sitl(*args), expected)


def test_bad_speed_env_is_reported(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PX4_SIM_SPEED_FACTOR", "turbo")
    assert_one_line_error(run_sitl("--duration", "1"), "PX4_SIM_SPEED_FACTOR")
