"""The suite's three tiers, and the kind of every test (docs/testing.md).

Every test has a **kind** from its folder: ``unit`` (tests/unit: a part on its own, in this process), ``flight``
(tests/closed_loop: closed-loop flights through JSBSim, every drone in this process) or ``integration``
(tests/integration: real ``sitl`` and ``swarm`` processes on 127.0.0.1 driven by real clients).

And a **tier**, which says when it runs:

- ``quick``: the unit tests and the in-process flights, <= 3 minutes on two cores; while working on the code.
- ``suite``: the quick tier, the integration tests and the few unit or flight tests marked ``suite`` (those that
  compile the kernels cold); <= 10 minutes on two cores. The README's test command; every push.
- ``acceptance``: campaigns, Ray, the long attach flights, scale flights, long floods: every test marked
  ``acceptance``, at most 15 minutes on two cores. CI runs it after the suite.

``pytest`` runs the suite, ``pytest --tier quick`` the quick tier, ``pytest --tier acceptance`` the acceptance tier,
``pytest --tier all`` everything. Each test is also marked with its kind and its tier, so ``-m`` selects among them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Final

import pytest

KIND_OF_FOLDER: Final = {"unit": "unit", "closed_loop": "flight", "integration": "integration"}
TIERS: Final = ("quick", "suite", "acceptance")
SELECTIONS: Final = {
    "quick": frozenset({"quick"}),
    "suite": frozenset({"quick", "suite"}),
    "acceptance": frozenset({"acceptance"}),
    "all": frozenset(TIERS),
}
DEFAULT_SELECTION: Final = "suite"
ACCEPTANCE_FIXTURES: Final = frozenset({"ray_head"})  # a local Ray head: sweeps and campaigns on Ray
_TESTS: Final = Path(__file__).resolve().parent


def file_of(nodeid: str) -> str:
    """The test file a node id belongs to (the unit the workers are dealt, and the summary's row)."""
    return nodeid.split("::")[0]


def kind_of(path: Path) -> str | None:
    """The kind of a test module from its folder under tests/ (None outside the three)."""
    try:
        folder = path.resolve().relative_to(_TESTS).parts[0]
    except (ValueError, IndexError):
        return None
    return KIND_OF_FOLDER.get(folder)


def tier_of(item: pytest.Item) -> str:
    """The tier ``item`` runs in: acceptance when marked so or when it needs a Ray head; suite when marked so or when
    it starts processes (an integration test); quick otherwise."""
    fixtures = getattr(item, "fixturenames", ())
    if item.get_closest_marker("acceptance") is not None or ACCEPTANCE_FIXTURES.intersection(fixtures):
        return "acceptance"
    if item.get_closest_marker("suite") is not None or kind_of(item.path) == "integration":
        return "suite"
    return "quick"


def add_options(parser: pytest.Parser) -> None:
    parser.addoption(
        "--tier",
        choices=sorted(SELECTIONS),
        default=DEFAULT_SELECTION,
        help="which tests to run: quick (unit and in-process flights), suite (quick and the integration tests: the "
        "default), acceptance (campaigns, Ray, long and scale flights), all (tests/tiers.py)",
    )


def mark_and_select(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark every item with its kind and tier, and deselect those outside ``--tier``."""
    wanted = SELECTIONS[config.getoption("--tier")]
    kept: list[pytest.Item] = []
    dropped: list[pytest.Item] = []
    for item in items:
        kind = kind_of(item.path)
        if kind is not None:
            item.add_marker(getattr(pytest.mark, kind))
        tier = tier_of(item)
        item.add_marker(getattr(pytest.mark, tier))
        (kept if tier in wanted else dropped).append(item)
    if dropped:
        config.hook.pytest_deselected(items=dropped)
        items[:] = kept
