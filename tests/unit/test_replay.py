"""The flight report page: its replay document (gcs/view/replay.py) and the self-contained report.html."""

from __future__ import annotations

import base64
import dataclasses
import gzip
import json
import math
import re
from pathlib import Path

import numpy as np

from gcs.fleet.losses import DroneLoss
from gcs.record.metrics import compute_metrics
from gcs.record.recording import DroneSample, EventRecord, FaultRecord, FlightRecording, ObstacleShape
from gcs.view.replay import replay_document
from gcs.view.report import write_report
from gcs.view.report_page import PAYLOADS, REPORT_PAGE_FILE
from gcs.view.server import STATIC
from tests.unit.test_report import synthetic_flight


def positions(document: dict, k: int) -> np.ndarray:
    d = document["drones"][k]
    return np.array([d["north_m"], d["east_m"], d["down_m"]], dtype=float).T  # None -> NaN


def page_min_separation(document: dict, *, contacts: bool = True) -> float:
    """What the page computes (static/replay.js), in numpy: every grid instant's distance between pairs airborne
    then, and the closest approach of their linear relative motion between consecutive instants both airborne; and
    (``contacts``) the contacts the document lists."""
    pos = [positions(document, k) for k in range(len(document["drones"]))]
    air = [
        np.array(d["airborne"], dtype=bool) & ~np.isnan(p[:, 0]) for d, p in zip(document["drones"], pos, strict=True)
    ]
    best = math.inf
    for a in range(len(pos)):
        for b in range(a + 1, len(pos)):
            both = air[a] & air[b]
            rel = pos[a] - pos[b]
            dist = np.linalg.norm(rel, axis=1)
            if both.any():
                best = min(best, float(dist[both].min()))
            ok = both[:-1] & both[1:]
            r0, dr = rel[:-1][ok], (rel[1:] - rel[:-1])[ok]
            dr2 = np.einsum("ij,ij->i", dr, dr)
            s = np.clip(np.divide(-np.einsum("ij,ij->i", r0, dr), dr2, out=np.zeros_like(dr2), where=dr2 > 0), 0, 1)
            if ok.any():
                best = min(best, float(np.linalg.norm(r0 + s[:, None] * dr, axis=1).min()))
    return min([best, *(c["distance_m"] for c in document["contacts"])]) if contacts else best


def flight_with_everything() -> FlightRecording:
    """The synthetic three-drone flight with a loss and return, a failsafe, avoidance, a fault and an obstacle."""
    rec = synthetic_flight()
    rec.events.append(EventRecord(time_s=9.8, sysid=2, text="Avoidance ended: closest approach 0.80 m"))
    rec.losses = [DroneLoss(sysid=3, time_s=12.0, cause="link lost", silent=True, regained_s=14.0)]
    rec.regained = list(rec.losses)
    rec.failsafes = [EventRecord(time_s=21.0, sysid=1, text="Failsafe: battery critical")]
    rec.faults = [FaultRecord(time_s=11.5, sysid=3, fault="comms", result="accepted")]
    rec.obstacles = [ObstacleShape(kind="cylinder", north_m=5.0, east_m=5.0, radius_m=0.5, height_m=8.0)]
    return rec


def staggered_flight() -> FlightRecording:
    """The synthetic three-drone flight as the recorder hears a swarm come up: drone 1 from the start, drone 2 from
    0.7 s, drone 3 from 2.33 s (its samples off the grid, 0.03 s after each tenth)."""
    rec = synthetic_flight()
    first_s = {1: 0.0, 2: 0.7, 3: 2.33}
    rec.samples = [
        dataclasses.replace(s, time_s=s.time_s + 0.03) if s.sysid == 3 else s
        for s in rec.samples
        if s.time_s + (0.03 if s.sysid == 3 else 0.0) >= first_s[s.sysid] - 1e-9
    ]
    return rec


def test_the_pages_minimum_separation_from_the_drawn_positions_is_the_metrics_one() -> None:
    rec = flight_with_everything()
    document = replay_document(rec)
    metrics = compute_metrics(rec)
    assert metrics.min_separation_m is not None
    assert abs(page_min_separation(document) - metrics.min_separation_m) < 1e-3
    # and the document is plain JSON (no NaN), on the metrics' grid
    json.dumps(document, allow_nan=False)
    assert np.allclose(document["time_s"][:3], [0.0, 0.1, 0.2])


def test_a_reported_contact_is_in_the_pages_minimum_separation_as_in_the_metrics() -> None:
    # GIVEN two drones whose positions never came within 1.9 m, one of which reported touching the other at 0.31 m,
    # and a contact with an attached vehicle (the metrics count it apart)
    rec = synthetic_flight(n_drones=2)
    rec.attached = {250: ("member", "udpin:0.0.0.0:14560")}
    rec.events = [EventRecord(time_s=9.5, sysid=1, text="Collision with drone 2 at 0.31 m"),
                  EventRecord(time_s=9.7, sysid=2, text="Collision with drone 250 at 0.2 m")]  # fmt: skip
    document = replay_document(rec)
    # THEN the document lists the drones' contact, and the page's minimum is the metrics' minimum, the contact
    assert document["contacts"] == [{"time_s": 9.5, "pair": [1, 2], "distance_m": 0.31}]
    metrics = compute_metrics(rec)
    assert (metrics.min_separation_m, metrics.min_separation_pair) == (0.31, (1, 2))
    assert page_min_separation(document, contacts=False) > 1.9
    assert page_min_separation(document) == 0.31


def test_the_replay_opens_where_every_drone_is_known_its_timeline_from_the_first_sample() -> None:
    # GIVEN a flight whose drones were first heard at 0, 0.7 and 2.33 s
    rec = staggered_flight()
    document = replay_document(rec)
    grid = document["time_s"]
    # THEN the timeline starts at the first sample, when one drone was known
    assert grid[0] == 0.0
    known = [[d["north_m"][k] is not None for d in document["drones"]] for k in range(len(grid))]
    assert known[0] == [True, False, False]
    # AND the page opens at the first grid instant with every drone drawn (drone 3's first: between 2.33 and 2.43 s)
    assert document["open_s"] == 2.4
    assert all(known[grid.index(2.4)]) and not all(known[grid.index(2.3)])
    # AND the page's minimum separation over the whole timeline is still the metrics'
    metrics = compute_metrics(rec)
    assert metrics.min_separation_m is not None
    assert abs(page_min_separation(document) - metrics.min_separation_m) < 1e-3


def test_a_swarm_heard_at_once_opens_at_its_first_sample_and_an_empty_one_nowhere() -> None:
    assert replay_document(flight_with_everything())["open_s"] == 0.0
    empty = FlightRecording(mission_name="aborted", n_drones=2, collision_radius_m=0.7)
    assert replay_document(empty)["open_s"] is None


def test_states_follow_losses_failsafes_and_avoidance_as_the_live_view_colours_them() -> None:
    document = replay_document(flight_with_everything())
    states = {d["sysid"]: d["states"] for d in document["drones"]}
    # drone 1: disarmed until it arms at 1 s, failsafe from 21 s until it disarms at 25 s
    assert states[1] == [[0.0, "disarmed"], [1.0, "armed"], [21.0, "failsafe"], [25.0, "disarmed"]]
    # drone 2: avoiding from its "Avoidance:" text until "Avoidance ended"
    assert [9.0, "avoiding"] in states[2] and [9.8, "armed"] in states[2]
    # drone 3: lost while silent, taken back when heard again
    assert [12.0, "lost"] in states[3] and [14.0, "armed"] in states[3]
    # a lost drone is no separation: airborne only while flying
    drone3 = document["drones"][2]
    lost_instants = [a for t, a in zip(document["time_s"], drone3["airborne"], strict=True) if 12.0 <= t < 14.0]
    assert lost_instants and not any(lost_instants)


def test_marks_are_every_event_kind_in_time_order() -> None:
    document = replay_document(flight_with_everything())
    kinds = [(m["time_s"], m["kind"]) for m in document["marks"]]
    assert kinds == [(9.0, "avoidance"), (9.5, "collision"), (11.5, "fault"), (12.0, "loss"), (14.0, "regained"),
                     (21.0, "failsafe")]  # fmt: skip
    assert document["obstacles"] == [{"kind": "cylinder", "north_m": 5.0, "east_m": 5.0, "radius_m": 0.5,
                                      "height_m": 8.0}]  # fmt: skip
    assert [s["name"] for s in document["steps"]] == ["takeoff", "circle", "land"]


def unpack(page: str, element_id: str) -> bytes:
    match = re.search(rf'<script type="application/octet-stream" id="{element_id}">\s*([A-Za-z0-9+/=]+)\s*</script>',
                      page)  # fmt: skip
    assert match is not None, element_id
    return gzip.decompress(base64.b64decode(match.group(1)))


def test_report_html_is_one_self_contained_file_the_same_for_the_same_flight(tmp_path: Path) -> None:
    first = (write_report(flight_with_everything(), tmp_path / "a") / REPORT_PAGE_FILE).read_text()
    second = (write_report(flight_with_everything(), tmp_path / "b") / REPORT_PAGE_FILE).read_text()
    assert first == second
    # nothing is fetched: every src and href is inline data, and there is no address to go to
    assert re.findall(r'(?:src|href)="(?!data:)', first) == []
    assert "http://" not in first.split("<script")[0] and "https://" not in first.split("<script")[0]
    # the scripts are the package's own, unchanged, and the flight is the replay document
    for element_id, name in PAYLOADS.items():
        assert unpack(first, element_id) == (STATIC / name).read_bytes()
    assert json.loads(unpack(first, "flight")) == json.loads(json.dumps(replay_document(flight_with_everything())))
    # the plots and the summary are in it
    assert first.count('src="data:image/png;base64,') == 3
    assert "circle_demo" in first and "min separation" in first


def test_an_empty_flight_still_gets_a_page(tmp_path: Path) -> None:
    out = write_report(FlightRecording(mission_name="aborted", n_drones=2, collision_radius_m=0.7), tmp_path)
    page = (out / REPORT_PAGE_FILE).read_text()
    document = json.loads(unpack(page, "flight"))
    assert document["drones"] == [] and document["time_s"] == []


def test_an_attached_vehicle_is_drawn_apart_where_it_said_it_was_and_lost_while_silent() -> None:
    # GIVEN the synthetic flight with an attached member reporting from 2 s to 10 s, then from 16 s (silent between)
    rec = flight_with_everything()
    rec.attached = {250: ("member", "udpin:0.0.0.0:14560")}
    for k in range(20, 250):
        t = k * 0.1
        if 10.0 < t < 16.0:
            continue
        rec.attached_samples.append(DroneSample(time_s=t, sysid=250, pos_ned_m=(3.0, 1.0 + 0.1 * t, -3.0),
                                                vel_ned_mps=(0.0, 1.0, 0.0), armed=True, mode="GUIDED",
                                                target_ned_m=(3.0, 1.0 + 0.1 * t, -3.0)))  # fmt: skip
    document = replay_document(rec)
    json.dumps(document, allow_nan=False)
    (vehicle,) = document["external"]
    # THEN it comes apart from the drones, with its role, link, positions on the grid and its slot
    assert (vehicle["sysid"], vehicle["role"], vehicle["link"]) == (250, "member", "udpin:0.0.0.0:14560")
    assert [d["sysid"] for d in document["drones"]] == [1, 2, 3]
    grid = document["time_s"]
    at5 = grid.index(5.0)
    assert (vehicle["north_m"][at5], vehicle["east_m"][at5], vehicle["slot_east_m"][at5]) == (3.0, 1.5, 1.5)
    assert "GUIDED" in document["modes"] and not any(vehicle["airborne"])  # not in the page's drone separation
    # AND it is external while heard, lost while silent (null positions: the page keeps it where it was last known)
    states = [s for _t, s in vehicle["states"]]
    assert states[:4] == ["lost", "external", "lost", "external"] and states[4:] in ([], ["lost"])  # (after 24.9 s)
    assert vehicle["north_m"][grid.index(13.0)] is None
    # AND the page's separation is still the metrics' drone separation
    assert abs(page_min_separation(document) - compute_metrics(rec).min_separation_m) < 1e-3
