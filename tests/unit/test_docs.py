"""Generated documentation stays in step with the code."""

from __future__ import annotations

import re
from pathlib import Path

from sitl.drone.param_table import build_param_store
from sitl.drone.paramdoc import render

DOCS = Path(__file__).resolve().parents[2] / "docs"


def test_parameter_table_in_docs_is_current() -> None:
    assert (DOCS / "parameters.md").read_text() == render(build_param_store()), (
        "docs/parameters.md is stale: run `python -m sitl.drone.paramdoc > docs/parameters.md`"
    )


def test_the_docs_index_names_every_page_once() -> None:
    # docs/README.md is where a newcomer finds a page: a page it does not name is a page nobody finds
    index = (DOCS / "README.md").read_text()
    pages = sorted(p.name for p in DOCS.glob("*.md") if p.name != "README.md")
    linked = re.findall(r"\]\(([\w.-]+\.md)\)", index)
    assert sorted(set(linked)) == pages, set(pages) ^ set(linked)
    assert len(linked) == len(set(linked)), "a page is named twice"


def test_the_architecture_page_names_every_folder_and_the_sides_stay_foldered() -> None:
    # docs/architecture.md's tree is where a newcomer learns what each folder is for: a folder it does not name is
    # one they must read the code to place; and a side that grows loose modules again stops showing its architecture
    page = (DOCS / "architecture.md").read_text()
    tree = page[page.index("## The tree") : page.index("## One drone, one process")]
    root = DOCS.parent
    for side in ("gcs", "sitl"):
        folders = sorted(p.name for p in (root / side).iterdir() if (p / "__init__.py").exists())
        missing = [f for f in folders if f"`{side}/{f}/`" not in tree or f"{f}/" not in tree.split("```")[1]]
        assert not missing, f"docs/architecture.md's tree does not name {side}/{missing}"
        modules = sorted(p.name for p in (root / side).glob("*.py"))
        assert len(modules) <= 6, f"{side}/ has {len(modules)} top-level modules: {modules}"
        loose = [m for m in modules if m != "__init__.py" and f"{side}/{m}" not in tree]
        assert not loose, f"docs/architecture.md's tree does not name {side}/{loose}"
