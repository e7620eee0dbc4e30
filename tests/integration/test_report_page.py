"""The report page in a headless Chromium, on reports written from recordings without flying: the checks every
flight's page gets (tests/integration/report_page.py), on a swarm its recorder heard come up one drone at a time and
on a flight whose minimum separation is a contact a drone reported."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from gcs.record.recording import EventRecord
from gcs.view.report import METRICS_FILE, write_report
from tests.integration.report_page import check_report_page, is_contact
from tests.unit.test_replay import staggered_flight
from tests.unit.test_report import synthetic_flight

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


def test_the_pages_minimum_separation_holds_a_contact_the_positions_never_showed(tmp_path: Path) -> None:
    # GIVEN the report of two drones whose positions never came within 1.9 m, one of which reported touching the
    # other at 0.31 m at 9.5 s
    rec = synthetic_flight(n_drones=2)
    rec.events = [EventRecord(time_s=9.5, sysid=1, text="Collision with drone 2 at 0.31 m")]
    out = write_report(rec, tmp_path / "report", plots="never")
    metrics = json.loads((out / METRICS_FILE).read_text())
    assert (metrics["min_separation_m"], metrics["min_separation_time_s"]) == (0.31, 9.5) and is_contact(metrics)
    # THEN the page's smallest separation is that contact from 9.5 s, and at the end, as metrics.json's
    check_report_page(out, metrics, marks=("collision",))
