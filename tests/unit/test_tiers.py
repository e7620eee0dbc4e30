"""The suite's tiers (tests/conftest.py): every test has exactly one tier from its folder, the quick tier holds no
test that starts processes, and the heavy tests are the ones that need Ray, a browser, CPU burners, a bench or a
flood."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.timeout(120)


# One collection of the whole suite, in a child: every test's node id and the tier and heavy marks it was given.
_COLLECT = """
import json, sys, pytest

class Marks:
    def __init__(self): self.items = {}
    def pytest_collection_finish(self, session):
        for item in session.items:
            self.items[item.nodeid] = sorted({m.name for m in item.iter_markers()} & TIERS)

TIERS = {"unit", "flight", "integration", "heavy"}
marks = Marks()
code = pytest.main(["--collect-only", "-q", "-p", "no:cacheprovider", "tests"], plugins=[marks])
print("MARKS " + json.dumps(marks.items))
sys.exit(code)
"""


def _marks() -> dict[str, set[str]]:
    out = subprocess.run([sys.executable, "-c", _COLLECT], cwd=ROOT, capture_output=True, text=True, timeout=110)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    line = next(line for line in out.stdout.splitlines() if line.startswith("MARKS "))
    return {nodeid: set(marks) for nodeid, marks in json.loads(line[len("MARKS ") :]).items()}


def test_every_test_has_one_tier_from_its_folder_and_heavy_is_where_it_is_meant() -> None:
    marks = _marks()
    assert len(marks) > 1000
    folders = {"unit": "tests/unit/", "flight": "tests/closed_loop/", "integration": "tests/integration/"}
    for nodeid, names in marks.items():
        tiers = names - {"heavy"}
        assert len(tiers) == 1, (nodeid, names)
        assert nodeid.startswith(folders[tiers.pop()]), (nodeid, names)
    # heavy: a fixture (a Ray head) or the test's own mark, only among the integration tests; the quick tier
    # (-m "unit or flight") therefore starts no process
    heavy = {nodeid for nodeid, names in marks.items() if "heavy" in names}
    assert all(nodeid.startswith("tests/integration/") for nodeid in heavy)
    assert {nodeid.split("::")[0] for nodeid in heavy} == {
        "tests/integration/test_bench.py",
        "tests/integration/test_falsify.py",
        "tests/integration/test_fuzz.py",
        "tests/integration/test_links_fly.py",
        "tests/integration/test_many_drones_ports.py",
        "tests/integration/test_sweep.py",
        "tests/integration/test_view_live.py",
    }
    assert any("ray" in nodeid for nodeid in heavy if nodeid.startswith("tests/integration/test_sweep.py"))
