"""Open a flight's report.html in a headless Chromium and check what a person would (shared by the flight tests).

The page is checked against metrics.json, written by other code from the same recording: the page computes its
separations itself from the positions it draws."""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path
from typing import Any

from gcs.mavlink.statustext import parse_contact
from tests.integration.browser import Browser

DOCS_IMAGES = Path(__file__).resolve().parents[2] / "docs" / "images"
REPLAY_TIMEOUT_S = 60.0


@dataclasses.dataclass(frozen=True, slots=True)
class Opening:
    """What the page showed as it opened, and at the timeline's first instant (the first sample)."""

    start_s: float
    opening_s: float
    drawn_at_start: int
    drawn_at_opening: int


def counted(n: int, noun: str) -> str:
    """What a person writes: "1 drone", "2 drones" (written out here, not the page's own code)."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def count_text(browser: Browser) -> str:
    """The header's count with its noun, as read on the page."""
    return str(browser.evaluate("document.getElementById('count').closest('span').textContent")).strip()


def is_contact(metrics: dict[str, Any]) -> bool:
    """Whether metrics.json's minimum separation is a contact a drone reported (docs/metrics.md), not positions."""
    pair = sorted(metrics["min_separation_pair"])
    for event in metrics["collision_events"]:
        contact = parse_contact(event["text"])
        if contact is None or contact.drone is None or sorted((event["sysid"], contact.drone)) != pair:
            continue
        distance = contact.distance_m if contact.distance_m is not None else metrics["collision_radius_m"]
        then = abs(event["time_s"] - metrics["min_separation_time_s"]) < 1e-3
        if then and abs(distance - metrics["min_separation_m"]) < 1e-3:
            return True
    return False


def check_report_page(report: Path, metrics: dict[str, Any], *, lost: tuple[int, ...] = (),
                      marks: tuple[str, ...] = (), screenshot_at_s: float | None = None,
                      external: tuple[int, ...] = ()) -> Opening:  # fmt: skip
    """The page loads from the file alone and opens where every drone of metrics.json's ``sysids`` is drawn (the
    timeline reaching back to the first sample), its header counting the drones it draws in good English ("1 drone",
    "9 drones"); it replays to the end at 32x and then shows metrics.json's minimum separation (the simulated
    drones'); at the metrics' closest instant the closest pair is drawn that far apart (or, when that minimum is a
    contact a drone reported, the page's smallest separation so far is it from there); drones in ``lost`` end drawn
    lost; the attached vehicles ``external`` are drawn beside them, as external (or lost where they fell silent);
    the timeline carries a mark of every kind in ``marks``. Returns what it saw as the page opened."""
    page = report / "report.html"
    with Browser() as browser:
        browser.open(page.as_uri())
        browser.wait_for("window.swarmReplay || window.swarmReplayError", 30)
        assert browser.evaluate("window.swarmReplayError || null") is None
        start, opening, end = browser.evaluate("[swarmReplay.start(), swarmReplay.opening(), swarmReplay.end()]")
        assert start <= opening < end and browser.evaluate("swarmReplay.time()") == opening
        assert browser.evaluate("swarmView.webgl()"), "the page's 3D scene did not start"
        # it opens on the whole swarm, and says how many it draws
        opened_on = {int(s) for s in browser.evaluate("swarmView.drones()")}
        assert set(metrics["sysids"]) <= opened_on <= {*metrics["sysids"], *external}, (opening, opened_on)
        assert count_text(browser) == counted(len(opened_on), "drone")
        # and so at the first sample, when perhaps one drone was known
        at_start = len(browser.evaluate(f"swarmReplay.seek({start}); swarmView.drones()"))
        assert at_start >= 1 and count_text(browser) == counted(at_start, "drone")
        # the closest pair, drawn at the closest instant (or, when the minimum is a contact a drone reported, the
        # page's smallest separation so far from that instant)
        expected = metrics["min_separation_m"]
        a, b = metrics["min_separation_pair"]
        drawn = browser.evaluate(f"swarmReplay.seek({metrics['min_separation_time_s']}); swarmView.drones()")
        if is_contact(metrics):
            assert abs(browser.evaluate("swarmReplay.minSeparation()") - expected) < 2e-3
        else:
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
    return Opening(start_s=start, opening_s=opening, drawn_at_start=at_start, drawn_at_opening=len(opened_on))
