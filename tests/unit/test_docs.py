"""Generated documentation stays in step with the code."""

from __future__ import annotations

import re
from pathlib import Path

from sitl.drone.closed_loop import build_param_store
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
