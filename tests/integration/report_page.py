"""Open a flight's report.html in a headless Chromium and check what a person would (shared by the flight tests).

The page is checked against metrics.json, written by other code from the same recording: the page computes its
separations itself from the positions it draws."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

from tests.integration.browser import Browser

DOCS_IMAGES = Path(__file__).resolve().parents[2] / "docs" / "images"
REPLAY_TIMEOUT_S = 60.0


def check_report_page(report: Path, metrics: dict[str, Any], *, lost: tuple[int, ...] = (),
                      marks: tuple[str, ...] = (), screenshot_at_s: float | None = None,
                      external: tuple[int, ...] = ()) -> None:  # fmt: skip
    """The page loads from the file alone, replays to the end at 32x and then shows metrics.json's minimum
    separation (the simulated drones'); at the metrics' closest instant the closest pair is drawn that far apart;
    drones in ``lost`` end drawn lost; the attached vehicles ``external`` are drawn beside them, as external (or lost
    where they fell silent); the timeline carries a mark of every kind in ``marks``."""
    page = report / "report.html"
    with Browser() as browser:
        browser.open(page.as_uri())
        browser.wait_for("window.swarmReplay || window.swarmReplayError", 30)
        assert browser.evaluate("window.swarmReplayError || null") is None
        start, end = browser.evaluate("[swarmReplay.start(), swarmReplay.end()]")
        assert start < end and browser.evaluate("swarmReplay.time()") == start
        assert browser.evaluate("swarmView.webgl()"), "the page's 3D scene did not start"
        # the closest pair, drawn at the closest instant
        expected = metrics["min_separation_m"]
        a, b = metrics["min_separation_pair"]
        drawn = browser.evaluate(f"swarmReplay.seek({metrics['min_separation_time_s']}); swarmView.drones()")
        assert abs(math.dist(drawn[str(a)]["pos_ned_m"], drawn[str(b)]["pos_ned_m"]) - expected) < 2e-3, drawn
        # replayed from the start to the end
        browser.evaluate(f"swarmReplay.seek({start}); swarmReplay.setSpeed(32); swarmReplay.play()")
        browser.wait_for("swarmReplay.ended()", REPLAY_TIMEOUT_S)
        assert browser.evaluate("swarmReplay.time()") == end
        assert abs(browser.evaluate("swarmReplay.minSeparation()") - expected) < 2e-3
        shown = float(browser.evaluate("document.getElementById('min-separation').textContent"))
        assert abs(shown - expected) <= 0.005 + 2e-3, (shown, expected)
        drones = browser.evaluate("swarmView.drones()")
        assert sorted(int(s) for s in drones) == sorted([*metrics["sysids"], *external])
        for sysid in external:
            assert drones[str(sysid)]["state"] in ("external", "lost"), drones[str(sysid)]
        for sysid in lost:
            assert drones[str(sysid)]["state"] == "lost", drones
        kinds = set(browser.evaluate("[...document.querySelectorAll('#events tr')].map((r) => r.cells[1].textContent)"))
        assert kinds >= set(marks), kinds
        if screenshot_at_s is not None and os.environ.get("SWARM_DOCS_SCREENSHOTS"):
            browser.evaluate(f"swarmReplay.seek({screenshot_at_s})")
            browser.screenshot(DOCS_IMAGES / "report-page.png")
