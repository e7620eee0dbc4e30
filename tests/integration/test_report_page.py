"""The report page in a headless Chromium, on a report written from a recording without flying: the checks every
flight's page gets (tests/integration/report_page.py), on a swarm its recorder heard come up one drone at a time."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from gcs.view.report import METRICS_FILE, write_report
from tests.integration.report_page import check_report_page
from tests.unit.test_replay import staggered_flight

pytestmark = pytest.mark.timeout(120)


def test_the_page_opens_on_the_whole_swarm_its_recorder_heard_one_drone_at_a_time(tmp_path: Path) -> None:
    # GIVEN the report of a three-drone flight whose drones were first heard at 0, 0.7 and 2.33 s
    out = write_report(staggered_flight(), tmp_path / "report", plots="never")
    metrics = json.loads((out / METRICS_FILE).read_text())
    assert metrics["sysids"] == [1, 2, 3]
    # WHEN its report.html is opened as a person would, and replayed
    opened = check_report_page(out, metrics, marks=("avoidance", "collision"))
    # THEN it opened at 2.4 s, the first instant with all three drawn ("3 drones"), its timeline from 0 s, where it
    # drew drone 1 alone ("1 drone")
    assert (opened.start_s, opened.opening_s) == (0.0, 2.4)
    assert (opened.drawn_at_start, opened.drawn_at_opening) == (1, 3)
