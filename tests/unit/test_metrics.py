"""Flight metrics on synthetic recordings whose answers are known in closed form."""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable

import numpy as np
import pytest

from gcs.record.metrics import (
    ALIGNMENT_CONVERGED,
    ALIGNMENT_MIN_SPEED_MPS,
    FORMATION_SETTLED_RMS_M,
    MAX_GAP_S,
    TAKEOFF_TOLERANCE_M,
    LiveMetrics,
    alignment_order_parameter,
    compute_metrics,
    settle_time,
)
from gcs.record.recording import DroneSample, EventRecord, FlightRecording, StepRecord, Vec3
from gcs.view.report import summary_text

RATE_HZ = 50.0


def sample(
    time_s: float,
    sysid: int,
    pos: Vec3,
    *,
    armed: bool = True,
    target: Vec3 | None = None,
    vel: Vec3 = (0.0, 0.0, 0.0),
) -> DroneSample:
    return DroneSample(
        time_s=time_s, sysid=sysid, pos_ned_m=pos, vel_ned_mps=vel, armed=armed, mode="OFFBOARD", target_ned_m=target
    )


def recording(
    n_drones: int = 2, *, steps: list[StepRecord] | None = None, events: list[EventRecord] | None = None
) -> FlightRecording:
    return FlightRecording(
        mission_name="test", n_drones=n_drones, collision_radius_m=0.3, steps=steps or [], events=events or []
    )


def flight(
    sysid: int,
    start_s: float,
    end_s: float,
    pos_at: Callable[[float], Vec3],
    *,
    offset_s: float = 0.0,
    target_at: Callable[[float], Vec3 | None] = lambda t: None,
) -> list[DroneSample]:
    """Samples at RATE_HZ (shifted by offset_s, as real telemetry of different drones is not simultaneous)."""
    times = np.arange(start_s, end_s + 1e-9, 1.0 / RATE_HZ) + offset_s
    return [sample(float(t), sysid, pos_at(float(t)), target=target_at(float(t))) for t in times]


# --- separation -------------------------------------------------------------------------------------------------


def test_two_drones_approaching_to_0_8_m_give_min_separation_0_8_at_the_closest_instant() -> None:
    # GIVEN drone 1 hovering at 3 m and drone 2 flying past it at 2 m/s on a line 0.8 m to its side, closest at
    # t = 5.03 s (between grid instants), with telemetry of the two drones 13 ms apart
    rec = recording()
    rec.samples += flight(1, 0.0, 10.0, lambda t: (0.0, 0.0, -3.0))
    rec.samples += flight(2, 0.0, 10.0, lambda t: (2.0 * (5.03 - t), 0.8, -3.0), offset_s=0.013)

    # WHEN the metrics are computed
    metrics = compute_metrics(rec)

    # THEN the minimum separation is the miss distance, at the closest instant, between drones 1 and 2
    assert metrics.min_separation_m == pytest.approx(0.8, abs=1e-6)
    assert metrics.min_separation_time_s == pytest.approx(5.03, abs=1e-6)
    assert metrics.min_separation_pair == (1, 2)
    # AND the plotted series on the 10 Hz grid never dips below it
    assert np.nanmin(metrics.separation.min_separation_m) >= 0.8 - 1e-9
    assert np.nanmin(metrics.separation.min_separation_m) == pytest.approx(0.8, abs=0.02)


def test_a_contact_the_telemetry_never_sampled_is_the_minimum_separation_everywhere_it_shows() -> None:
    # GIVEN two drones head-on at 2 m/s each whose telemetry ends 1.08 m apart (both crash on touching, so no sample
    # of the contact itself arrives), and both drones' reports of the contact 0.15 s later, at 0.61 m
    rec = recording()
    rec.samples += flight(1, 0.0, 11.0, lambda t: (2.0 * (t - 11.0) - 0.54, 0.0, -3.0))
    rec.samples += flight(2, 0.0, 11.0, lambda t: (0.54 - 2.0 * (t - 11.0), 0.0, -3.0))
    rec.events += [
        EventRecord(time_s=11.15, sysid=2, text="Collision with drone 1 at 0.61 m"),
        EventRecord(time_s=11.15, sysid=1, text="Collision with drone 2 at 0.61 m"),
    ]

    # WHEN the metrics are computed
    metrics = compute_metrics(rec)

    # THEN the minimum is the contact, not the last sampled distance
    assert np.nanmin(metrics.separation.min_separation_m) == pytest.approx(1.08, abs=1e-6)  # the telemetry alone
    assert (metrics.min_separation_m, metrics.min_separation_time_s) == (0.61, 11.15)
    assert metrics.min_separation_pair == (1, 2)
    # AND so it is in metrics.json and in the summary
    data = metrics.to_dict()
    assert (data["min_separation_m"], data["min_separation_pair"]) == (0.61, [1, 2])
    assert "min separation: 0.61 m at 11.2 s (drones 1 and 2" in summary_text(metrics)
    # AND in the live status line
    live = LiveMetrics()
    for s in rec.samples:
        live.observe(s)
    assert live.status().min_separation_m == pytest.approx(1.08, abs=0.05)
    for event in rec.events:
        live.observe_event(event, rec.collision_radius_m, attached=(2,))  # drone 2 attached: not the swarm's figure
    assert live.status().min_separation_m == pytest.approx(1.08, abs=0.05)
    for event in rec.events:
        live.observe_event(event, rec.collision_radius_m)
    assert live.status().min_separation_m == 0.61


def test_a_contact_whose_text_gives_no_distance_counts_at_the_contact_distance() -> None:
    rec = recording(events=[EventRecord(time_s=3.0, sysid=2, text="Collision with drone 3")])
    rec.samples += flight(2, 0.0, 2.0, lambda t: (0.0, 0.0, -3.0))
    rec.samples += flight(3, 0.0, 2.0, lambda t: (5.0, 0.0, -3.0))

    metrics = compute_metrics(rec)

    assert (metrics.min_separation_m, metrics.min_separation_time_s) == (rec.collision_radius_m, 3.0)
    assert metrics.min_separation_pair == (2, 3)
    # a contact with an obstacle is no separation between drones
    rec.events[:] = [EventRecord(time_s=3.0, sysid=2, text="Collision with obstacle 1 at 0.40 m")]
    assert compute_metrics(rec).min_separation_m == pytest.approx(5.0)


def test_the_closest_pair_of_three_drones_is_reported() -> None:
    rec = recording(n_drones=3)
    rec.samples += flight(1, 0.0, 4.0, lambda t: (0.0, 0.0, -3.0))
    rec.samples += flight(2, 0.0, 4.0, lambda t: (5.0, 0.0, -3.0))
    rec.samples += flight(3, 0.0, 4.0, lambda t: (5.0, 1.5, -4.0))

    metrics = compute_metrics(rec)

    assert metrics.min_separation_m == pytest.approx(math.hypot(1.5, 1.0))
    assert metrics.min_separation_pair == (2, 3)


def test_drones_on_the_ground_or_disarmed_do_not_count_for_separation() -> None:
    # GIVEN two drones 0.3 m apart: first disarmed on the ground, then armed but only 0.3 m up
    rec = recording()
    for k in range(100):
        t = k / 10
        height = 0.0 if t < 5 else 0.3
        rec.samples.append(sample(t, 1, (0.0, 0.0, -height), armed=t >= 5))
        rec.samples.append(sample(t, 2, (0.0, 0.3, -height), armed=t >= 5))

    # WHEN the metrics are computed
    metrics = compute_metrics(rec)

    # THEN there is no separation to report, and the series is undefined everywhere
    assert metrics.min_separation_m is None
    assert metrics.min_separation_pair is None
    assert np.all(np.isnan(metrics.separation.min_separation_m))
    assert metrics.to_dict()["separation"]["min_separation_m"][0] is None


def test_ground_level_is_taken_from_where_each_drone_stood_disarmed() -> None:
    # GIVEN a drone standing disarmed 2 m below the swarm origin (lower terrain), then 0.6 m above that ground
    rec = recording()
    rec.samples += [sample(t / 10, 1, (0.0, 0.0, 2.0), armed=False) for t in range(10)]
    rec.samples += [sample(1 + t / 10, 1, (0.0, 0.0, 1.4)) for t in range(10)]
    rec.samples += [sample(t / 10, 2, (0.0, 1.0, 1.4)) for t in range(20)]  # armed since its first sample

    metrics = compute_metrics(rec)

    # THEN drone 1 is airborne at 0.6 m over its ground; drone 2, never seen disarmed, is measured from the origin
    # (1.4 m below it), so it is on the ground and there is no pair
    assert metrics.min_separation_m is None


def test_no_position_is_invented_across_a_telemetry_gap() -> None:
    # GIVEN drone 2 reports at 10 m north, falls silent for longer than MAX_GAP_S, and reappears 10 m south; a straight
    # line between the two reports would pass right through hovering drone 1
    gap = MAX_GAP_S + 1.0
    rec = recording()
    rec.samples += flight(1, 0.0, 10.0, lambda t: (0.0, 0.0, -3.0))
    rec.samples += flight(2, 0.0, 4.0, lambda t: (10.0, 0.0, -3.0))
    rec.samples += flight(2, 4.0 + gap, 10.0, lambda t: (-10.0, 0.0, -3.0))

    metrics = compute_metrics(rec)

    assert metrics.min_separation_m == pytest.approx(10.0)


# --- formation --------------------------------------------------------------------------------------------------


def test_time_to_formation_of_an_exponentially_decaying_error() -> None:
    # GIVEN two drones whose distance to their slots decays as 4 m * exp(-t/2 s) from the start of a 20 s step
    e0, tau, start, end = 4.0, 2.0, 10.0, 30.0
    rec = recording(steps=[StepRecord(index=0, name="circle", kind="formation", start_s=start, end_s=end)])
    slots: dict[int, Vec3] = {1: (5.0, 0.0, -3.0), 2: (-5.0, 0.0, -3.0)}
    directions = {1: np.array([0.0, 1.0, 0.0]), 2: np.array([0.6, 0.0, 0.8])}

    def pos(sysid: int) -> Callable[[float], Vec3]:
        def at(t: float) -> Vec3:
            error = e0 * math.exp(-(max(t, start) - start) / tau)
            x, y, z = np.array(slots[sysid]) + error * directions[sysid]
            return (float(x), float(y), float(z))

        return at

    def slot(sysid: int) -> Callable[[float], Vec3 | None]:
        return lambda t: slots[sysid] if t >= start else None

    for sysid, offset in ((1, 0.0), (2, 0.007)):
        rec.samples += flight(sysid, start, end, pos(sysid), offset_s=offset, target_at=slot(sysid))

    # WHEN the metrics are computed
    step = compute_metrics(rec).steps[0]

    # THEN the formation is reached when the error falls to the threshold: t = tau * ln(e0 / threshold)
    settle = tau * math.log(e0 / FORMATION_SETTLED_RMS_M)
    assert step.time_to_formation_s == pytest.approx(settle, abs=0.02)
    # AND the settled RMS is that of 0.5 m * exp(-s/tau) over the rest of the step
    rest = end - start - settle
    expected_rms = math.sqrt(FORMATION_SETTLED_RMS_M**2 * tau / 2 * (1 - math.exp(-2 * rest / tau)) / rest)
    assert step.formation_rms_m == pytest.approx(expected_rms, rel=0.05)
    # AND the largest single error once settled is the threshold itself (both drones share the error)
    assert step.max_error_m == pytest.approx(FORMATION_SETTLED_RMS_M, abs=0.03)
    assert step.step_rms_m is not None and step.step_rms_m > expected_rms


def test_formation_that_drifts_out_again_before_the_step_ends_is_not_settled_until_it_returns() -> None:
    # GIVEN an error that is small at first, grows to 1 m mid-step, and is small again from t = 14 s
    rec = recording(n_drones=1, steps=[StepRecord(index=0, name="line", kind="formation", start_s=0.0, end_s=20.0)])

    def error(t: float) -> float:
        return 1.0 if 6.0 <= t < 14.0 else 0.1

    rec.samples += flight(1, 0.0, 20.0, lambda t: (error(t), 0.0, -3.0), target_at=lambda t: (0.0, 0.0, -3.0))

    step = compute_metrics(rec).steps[0]

    assert step.time_to_formation_s == pytest.approx(14.0, abs=0.1)
    assert step.formation_rms_m == pytest.approx(0.1, abs=0.01)


def test_a_formation_is_not_settled_before_its_planned_transition_arrives() -> None:
    # GIVEN nine drones, eight on their slots from the start and one whose setpoint travels 3 m to its slot in a
    # transition planned to arrive at 6 s (it follows 0.3 m behind): the swarm RMS error is below 0.5 m from 2.4 s on
    arrival_s = 6.0
    rec = recording(n_drones=9, steps=[StepRecord(index=0, name="circle", kind="formation", start_s=0.0, end_s=12.0,
                                                  arrival_s=arrival_s)])  # fmt: skip
    for sysid in range(1, 9):
        rec.samples += flight(sysid, 0.0, 12.0, lambda t, k=sysid: (3.0 * k, 0.0, -3.0),
                              target_at=lambda t, k=sysid: (3.0 * k, 0.0, -3.0))  # fmt: skip

    def late(t: float) -> Vec3:
        return (max(0.0, 3.0 * (1.0 - t / arrival_s) - 0.3 * (t < arrival_s)) + 0.0, 40.0, -3.0)

    rec.samples += flight(9, 0.0, 12.0, late, target_at=lambda t: (0.0, 40.0, -3.0))
    # WHEN the metrics are computed
    step = compute_metrics(rec).steps[0]
    # THEN the formation settles when the plan arrives, and its largest error once settled is the drone's on its slot
    assert step.time_to_formation_s == pytest.approx(arrival_s, abs=0.01)
    assert step.max_error_m == pytest.approx(0.0, abs=1e-9)
    assert compute_metrics(rec).to_dict()["steps"][0]["arrival_s"] == arrival_s
    # AND without the plan's arrival the RMS bound alone would have called it settled while the drone was 1.5 m away
    rec.steps[0] = dataclasses.replace(rec.steps[0], arrival_s=None)
    early = compute_metrics(rec).steps[0]
    assert early.time_to_formation_s is not None and early.time_to_formation_s < 2.5
    assert early.max_error_m is not None and early.max_error_m > 1.0
    # AND a step that ends before its plan arrives never settled
    rec.steps[0] = dataclasses.replace(rec.steps[0], arrival_s=13.0)
    assert compute_metrics(rec).steps[0].time_to_formation_s is None


def test_a_formation_never_reached_has_null_settled_metrics() -> None:
    rec = recording(n_drones=1, steps=[StepRecord(index=0, name="v", kind="formation", start_s=0.0, end_s=10.0)])
    rec.samples += flight(1, 0.0, 10.0, lambda t: (2.0, 0.0, -3.0), target_at=lambda t: (0.0, 0.0, -3.0))

    step = compute_metrics(rec).steps[0]

    assert step.time_to_formation_s is None
    assert step.formation_rms_m is None
    assert step.max_error_m is None
    assert step.step_rms_m == pytest.approx(2.0)


def test_slots_of_the_previous_step_do_not_leak_into_the_next() -> None:
    # GIVEN a formation step ending at 10 s and a land step without slots; telemetry arrives 7 ms after each grid
    # instant, so at the boundary the newest sample still carries the old slot
    rec = recording(
        n_drones=1,
        steps=[
            StepRecord(index=0, name="circle", kind="formation", start_s=0.0, end_s=10.0),
            StepRecord(index=1, name="land", kind="land", start_s=10.0, end_s=20.0),
        ],
    )
    rec.samples += flight(
        1,
        0.0,
        20.0,
        lambda t: (0.0, 0.0, -3.0),
        offset_s=0.007,
        target_at=lambda t: (0.0, 0.0, -3.0) if t < 10 else None,
    )

    circle, land = compute_metrics(rec).steps

    assert circle.time_to_formation_s == pytest.approx(0.1, abs=0.11)  # first grid instant with a slot
    assert land.step_rms_m is None
    assert land.time_to_formation_s is None


# --- takeoff ----------------------------------------------------------------------------------------------------


def climb(target_m: float, tau_s: float, start_s: float) -> Callable[[float], Vec3]:
    def at(t: float) -> Vec3:
        altitude = 0.0 if t < start_s else target_m * (1.0 - math.exp(-(t - start_s) / tau_s))
        return (0.0, 0.0, -altitude)

    return at


def test_takeoff_time_is_when_the_slowest_drone_settles_within_the_tolerance() -> None:
    # GIVEN a takeoff command to 3 m at t = 2 s and two drones climbing as first-order lags of 1 s and 1.5 s
    target, start = 3.0, 2.0
    step = StepRecord(index=0, name="takeoff", kind="takeoff", start_s=start, end_s=12.0, target_alt_m=target)
    rec = recording(steps=[step])
    rec.samples += flight(1, 0.0, 14.0, climb(target, 1.0, start))
    rec.samples += flight(2, 0.0, 14.0, climb(target, 1.5, start), offset_s=0.011)

    # WHEN the metrics are computed
    metrics = compute_metrics(rec)

    # THEN each drone settles when 3 m * exp(-t/tau) = 0.2 m, and the swarm when the slower one does
    expected = {1: 1.0 * math.log(target / TAKEOFF_TOLERANCE_M), 2: 1.5 * math.log(target / TAKEOFF_TOLERANCE_M)}
    assert metrics.takeoff_time_per_drone_s == pytest.approx(expected, abs=1e-3)
    assert metrics.takeoff_time_s == pytest.approx(expected[2], abs=1e-3)
    assert metrics.steps[0].takeoff_time_s == metrics.takeoff_time_s


def test_takeoff_overshoot_counts_from_the_return_into_the_band() -> None:
    # GIVEN a climb to 3.5 m at t = 3 s (passing through the 3 m +- 0.2 m band), then back down to 3 m at t = 4 s
    step = StepRecord(index=0, name="takeoff", kind="takeoff", start_s=0.0, end_s=8.0, target_alt_m=3.0)
    rec = recording(n_drones=1, steps=[step])

    def altitude(t: float) -> float:
        return float(np.interp(t, [0.0, 3.0, 4.0], [0.0, 3.5, 3.0]))

    rec.samples += flight(1, 0.0, 8.0, lambda t: (0.0, 0.0, -altitude(t)))

    metrics = compute_metrics(rec)

    # THEN it settles when coming back down through 3.2 m: 3 s + (0.3 / 0.5) * 1 s
    assert metrics.takeoff_time_s == pytest.approx(3.6, abs=1e-6)


def test_takeoff_time_is_null_if_a_drone_is_not_at_altitude_when_the_step_ends() -> None:
    step = StepRecord(index=0, name="takeoff", kind="takeoff", start_s=0.0, end_s=5.0, target_alt_m=3.0)
    rec = recording(steps=[step])
    rec.samples += flight(1, 0.0, 5.0, climb(3.0, 0.5, 0.0))
    rec.samples += flight(2, 0.0, 5.0, climb(2.5, 0.5, 0.0))  # stuck 0.5 m low

    metrics = compute_metrics(rec)

    assert metrics.takeoff_time_per_drone_s[1] is not None
    assert metrics.takeoff_time_per_drone_s[2] is None
    assert metrics.takeoff_time_s is None


def test_settle_time_of_a_series_inside_the_band_from_the_start_is_its_first_instant() -> None:
    times = np.array([1.0, 2.0, 3.0])
    assert settle_time(times, np.array([0.1, -0.1, 0.0]), 0.2) == 1.0
    assert settle_time(times, np.array([0.1, -0.1, 0.3]), 0.2) is None
    assert settle_time(times, np.array([-1.0, -0.1, 0.0]), 0.2) == pytest.approx(1.0 + 0.8 / 0.9)


# --- events, distance, totals -----------------------------------------------------------------------------------


def test_collisions_count_events_whose_text_starts_with_collision() -> None:
    rec = recording(
        events=[
            EventRecord(time_s=3.0, sysid=2, text="Collision with drone 3"),
            EventRecord(time_s=3.0, sysid=3, text="Collision with drone 2"),
            EventRecord(time_s=4.0, sysid=1, text="Avoidance: climbing over drone 2"),
            EventRecord(time_s=5.0, sysid=None, text="no collision risk"),
        ]
    )

    metrics = compute_metrics(rec)

    assert metrics.collisions == 2
    assert [e.sysid for e in metrics.collision_events] == [2, 3]
    assert metrics.avoidance_events == 1
    assert metrics.avoidance_closest_approach_m is None


def test_avoidance_episodes_are_counted_once_and_the_closest_reported_approach_kept() -> None:
    rec = recording(
        events=[
            EventRecord(time_s=4.0, sysid=1, text="Avoidance: correcting for 1 neighbour(s), closest 3.10 m"),
            EventRecord(time_s=6.0, sysid=1, text="Avoidance ended: closest approach 1.42 m"),
            EventRecord(time_s=4.1, sysid=2, text="Avoidance: correcting for 2 neighbour(s), closest 2.90 m"),
            EventRecord(time_s=6.5, sysid=2, text="Avoidance ended: closest approach 1.38 m"),
        ]
    )

    metrics = compute_metrics(rec)

    assert metrics.avoidance_events == 2
    assert metrics.avoidance_closest_approach_m == 1.38
    assert metrics.to_dict()["avoidance_closest_approach_m"] == 1.38
    # AND each episode's first text, which says why it started, is listed in metrics.json and in the summary
    assert [e["sysid"] for e in metrics.to_dict()["avoidance_starts"]] == [1, 2]
    assert "      4.1 s  drone 2: Avoidance: correcting for 2 neighbour(s)" in summary_text(metrics)


def test_distance_flown_is_the_path_while_armed_without_jitter_on_the_ground() -> None:
    # GIVEN a drone jittering disarmed on the ground, armed at 2 s, climbing 3 m, flying 4 m north, descending,
    # disarmed at 12 s and jittering again
    rec = recording(n_drones=1)
    path_t = [0.0, 2.0, 5.0, 9.0, 12.0, 14.0]
    path_n = [0.0, 0.0, 0.0, 4.0, 4.0, 4.0]
    path_d = [0.0, 0.0, -3.0, -3.0, 0.0, 0.0]
    for k in range(int(14 * RATE_HZ) + 1):
        t = k / RATE_HZ
        armed = 2.0 <= t <= 12.0
        jitter = 0.0 if armed else 0.01 * (-1) ** k
        pos = (float(np.interp(t, path_t, path_n)) + jitter, 0.0, float(np.interp(t, path_t, path_d)))
        rec.samples.append(sample(t, 1, pos, armed=armed))

    metrics = compute_metrics(rec)

    # THEN it is the 3 + 4 + 3 m path
    assert metrics.distance_flown_m[1] == pytest.approx(10.0, abs=1e-6)


def test_duration_spans_samples_and_steps_and_drone_count_is_the_configured_one() -> None:
    rec = recording(n_drones=3, steps=[StepRecord(index=0, name="hold", kind="hold", start_s=1.0, end_s=12.5)])
    rec.samples += flight(1, 0.5, 10.0, lambda t: (0.0, 0.0, 0.0))

    metrics = compute_metrics(rec)

    assert metrics.duration_s == pytest.approx(12.0)
    assert metrics.n_drones == 3
    assert metrics.sysids == (1,)


def test_an_empty_recording_has_metrics_too() -> None:
    metrics = compute_metrics(recording())

    assert metrics.duration_s == 0.0
    assert metrics.min_separation_m is None
    assert metrics.takeoff_time_s is None
    assert metrics.separation.time_s.size == 0


def test_metrics_dict_is_strict_json_with_the_documented_keys_in_a_fixed_order() -> None:
    step = StepRecord(index=0, name="takeoff", kind="takeoff", start_s=0.0, end_s=6.0, target_alt_m=3.0)
    rec = recording(steps=[step])
    rec.samples += flight(1, 0.0, 6.0, climb(3.0, 1.0, 0.0))
    rec.samples += flight(2, 0.0, 6.0, lambda t: (3.0, 0.0, climb(3.0, 1.0, 0.0)(t)[2]))

    data = compute_metrics(rec).to_dict()
    text = json.dumps(data, allow_nan=False)

    assert list(json.loads(text))[:10] == [
        "mission",
        "n_drones",
        "sysids",
        "duration_s",
        "collision_radius_m",
        "min_separation_m",
        "min_separation_time_s",
        "min_separation_pair",
        "collisions",
        "collision_events",
    ]
    assert data["min_separation_m"] == pytest.approx(3.0)
    assert data["takeoff_time_per_drone_s"].keys() == {"1", "2"}
    assert data["steps"][0]["takeoff_time_s"] == data["takeoff_time_s"]
    assert len(data["separation"]["time_s"]) == len(data["separation"]["min_separation_m"])


def test_the_pace_of_a_paced_flight_is_reported_and_a_flight_that_fell_behind_says_so() -> None:
    # GIVEN a paced flight at 2x whose drones kept the pace, then fell to 1.2x for a while
    rec = recording()
    rec.requested_speed = 2.0
    rec.realtime_factors = [2.0, 1.99, 1.2, 1.97]
    metrics = compute_metrics(rec)
    # THEN the slowest and the mean are in the metrics and the JSON, and the summary flags it
    assert metrics.realtime_factor_min == pytest.approx(1.2)
    assert metrics.realtime_factor_mean == pytest.approx(1.79)
    data = metrics.to_dict()
    assert (data["requested_speed"], data["realtime_factor_min"]) == (2.0, 1.2)
    pace = [ln for ln in summary_text(metrics).splitlines() if ln.startswith("pace:")]
    assert pace == ["pace: 1.79x real time on average, 1.20x at the slowest, 2x requested - BEHIND: the mission's "
                    "timing ran ahead of the drones (see docs/benchmarks.md)"]  # fmt: skip
    # AND a flight that kept its pace gets the line without the flag, a lockstep flight none
    rec.realtime_factors = [2.0, 1.95]
    assert "BEHIND" not in summary_text(compute_metrics(rec))
    assert "pace:" in summary_text(compute_metrics(rec))
    assert "pace:" not in summary_text(compute_metrics(recording()))
    assert compute_metrics(recording()).to_dict()["realtime_factor_min"] is None


# --- alignment --------------------------------------------------------------------------------------------------


def test_alignment_order_parameter_is_one_aligned_zero_opposed_and_undefined_when_hovering() -> None:
    assert float(alignment_order_parameter([[1.0, 0.0], [2.0, 0.0], [0.5, 0.0]])) == pytest.approx(1.0)
    assert float(alignment_order_parameter([[1.0, 0.0], [-1.0, 0.0]])) == pytest.approx(0.0)
    # four drones at right angles: no common direction
    assert float(alignment_order_parameter([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])) == pytest.approx(0.0)
    # one north, one east at the same speed: |(1, 1)| / 2
    assert float(alignment_order_parameter([[1.0, 0.0], [0.0, 1.0]])) == pytest.approx(math.sqrt(2) / 2)
    slow = 0.5 * ALIGNMENT_MIN_SPEED_MPS
    assert math.isnan(float(alignment_order_parameter([[slow, 0.0], [slow, 0.0]])))
    assert math.isnan(float(alignment_order_parameter([[1.0, 0.0], [math.nan, math.nan]])))  # one drone present
    # over time: shape (T, n, 2) -> (T,)
    assert alignment_order_parameter(np.zeros((7, 3, 2))).shape == (7,)


def test_a_flock_step_reports_when_the_drones_aligned_and_how_well_from_then_on() -> None:
    # GIVEN three airborne drones flying north, east and south-west until t = 4 s, then all north-east at 1 m/s,
    # in a flock step from 1 s to 9 s (and a hold step after it)
    steps = [
        StepRecord(index=0, name="flock", kind="flock", start_s=1.0, end_s=9.0),
        StepRecord(index=1, name="hold", kind="hold", start_s=9.0, end_s=10.0),
    ]
    rec = recording(n_drones=3, steps=steps)
    before = [(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (-0.7, -0.7, 0.0)]
    after = (0.7, 0.7, 0.0)
    for k in range(3):
        times = np.arange(0.0, 10.0 + 1e-9, 1.0 / RATE_HZ) + 0.007 * k
        rec.samples += [
            sample(float(t), k + 1, (5.0 * k, 0.0, -3.0), vel=before[k] if t < 4.0 else after) for t in times
        ]

    # WHEN the metrics are computed
    data = compute_metrics(rec).to_dict()
    flock = data["steps"][0]["alignment"]

    # THEN alignment converged 3 s into the step, and was perfect from then on
    assert flock["converged_time_s"] == pytest.approx(3.0, abs=1.0 / 10.0 + 1e-9)
    assert flock["mean"] == pytest.approx(1.0, abs=1e-9) and flock["min"] == pytest.approx(1.0, abs=1e-9)
    # AND the series covers the step, low before the switch
    assert len(flock["time_s"]) == len(flock["phi"]) == 80
    assert flock["phi"][0] < ALIGNMENT_CONVERGED
    # AND steps of other kinds carry no alignment; the parameters are stated
    assert "alignment" not in data["steps"][1]
    assert data["parameters"]["alignment_converged"] == ALIGNMENT_CONVERGED


def test_a_hovering_flock_has_no_alignment_and_a_late_dip_counts() -> None:
    # GIVEN two drones that hover (undefined) for a flock step's first half, then fly together, then split
    step = StepRecord(index=0, name="flock", kind="flock", start_s=0.0, end_s=10.0)
    rec = recording(n_drones=2, steps=[step])

    def vel(k: int, t: float) -> tuple[float, float, float]:
        if t < 5.0:
            return (0.0, 0.0, 0.0)
        if t < 8.0:
            return (1.0, 0.0, 0.0)
        return (1.0, 0.0, 0.0) if k == 0 else (0.0, 1.0, 0.0)

    for k in range(2):
        times = np.arange(0.0, 10.0 + 1e-9, 1.0 / RATE_HZ)
        rec.samples += [sample(float(t), k + 1, (0.0, 5.0 * k, -3.0), vel=vel(k, float(t))) for t in times]

    alignment = compute_metrics(rec).steps[0].alignment

    # THEN it converged at 5 s; the split at 8 s (phi = 0.71) is in the mean and is the minimum
    assert alignment is not None
    assert alignment.converged_time_s == pytest.approx(5.0, abs=0.1)
    assert alignment.min == pytest.approx(math.sqrt(2) / 2, abs=1e-6)
    assert alignment.mean == pytest.approx((30 * 1.0 + 20 * math.sqrt(2) / 2) / 50, abs=0.02)
    assert np.all(np.isnan(alignment.phi[alignment.time_s < 4.9]))


# --- live status ------------------------------------------------------------------------------------------------


def test_live_metrics_track_current_error_and_the_smallest_separation_so_far() -> None:
    # GIVEN two drones that take off from the ground, pass 1.2 m apart, then separate to 4 m while holding 0.3 m
    # from their slots
    live = LiveMetrics()
    live.observe(sample(0.0, 1, (0.0, 0.0, 0.0), armed=False))
    live.observe(sample(0.0, 2, (0.0, 0.5, 0.0), armed=False))
    assert live.status().separation_m is None  # on the ground: not counted
    live.observe(sample(1.0, 1, (0.0, 0.0, -3.0)))
    live.observe(sample(1.0, 2, (0.0, 1.2, -3.0)))
    live.observe(sample(2.0, 1, (0.0, 0.0, -3.0), target=(0.3, 0.0, -3.0)))
    live.observe(sample(2.0, 2, (0.0, 4.0, -3.0), target=(0.0, 4.0, -3.3)))

    # WHEN the status is read
    status = live.status()

    # THEN it shows the current values and the minimum so far
    assert status.time_s == 2.0
    assert status.rms_error_m == pytest.approx(0.3)
    assert status.separation_m == pytest.approx(4.0)
    assert status.min_separation_m == pytest.approx(1.2)
    assert status.line() == "t 2.00 s  rms 0.30 m  sep 4.00 m (min 1.20 m)"


def test_live_metrics_compare_drones_at_the_same_instant_using_their_velocity() -> None:
    # GIVEN drone 2's last report is 0.2 s older than drone 1's, and it was flying towards drone 1 at 5 m/s
    live = LiveMetrics()
    live.observe(sample(0.8, 2, (0.0, 3.0, -3.0), vel=(0.0, -5.0, 0.0)))
    live.observe(sample(1.0, 1, (0.0, 0.0, -3.0)))

    # THEN the separation now is 3 m less the 1 m it has flown since
    assert live.status().separation_m == pytest.approx(2.0)
    assert live.status().min_separation_m == pytest.approx(2.0)


def test_live_metrics_leave_out_drones_whose_telemetry_is_stale() -> None:
    live = LiveMetrics()
    live.observe(sample(0.0, 1, (0.0, 0.0, -3.0), target=(1.0, 0.0, -3.0)))
    live.observe(sample(MAX_GAP_S + 1.0, 2, (0.0, 1.0, -3.0), target=(0.0, 1.0, -3.0)))

    status = live.status()

    assert status.separation_m is None
    assert status.rms_error_m == 0.0
    assert LiveMetrics().status().line() == "t -  rms -  sep - (min -)"


def test_live_status_shows_alignment_once_the_drones_move() -> None:
    live = LiveMetrics()
    live.observe(sample(1.0, 1, (0.0, 0.0, -3.0), vel=(1.0, 0.0, 0.0)))
    live.observe(sample(1.0, 2, (0.0, 3.0, -3.0), vel=(0.0, 1.0, 0.0)))
    assert live.status().alignment == pytest.approx(math.sqrt(2) / 2)
    assert live.status().line().endswith("  phi 0.71")


def test_an_attached_vehicles_closest_approach_is_found_between_grid_instants_and_said_in_the_summary() -> None:
    # GIVEN two drones hovering 3 m up, 6 m apart, and an attached vehicle (reporting at 10 Hz, flying or not) that
    # passes drone 2 at 1.25 m, at 4 m/s: the closest instant falls between the metrics' 10 Hz grid instants
    rec = recording()
    rec.samples += flight(1, 0.0, 10.0, lambda t: (0.0, 0.0, -3.0)) + flight(2, 0.0, 10.0, lambda t: (6.0, 0.0, -3.0))
    rec.attached[250] = ("intruder", "udpin:0.0.0.0:14560")
    rec.attached_samples += [
        sample(k / 10.0 + 0.013, 250, (6.0 + 1.25, -20.2 + 4.0 * (k / 10.0 + 0.013), -3.0)) for k in range(100)
    ]
    metrics = compute_metrics(rec)
    # THEN its closest approach is 1.25 m when it passes drone 2 (t = 5.05 s), not the grid instants' 1.27 m
    attached = metrics.attached[250]
    assert (attached.role, attached.link, attached.closest_drone) == ("intruder", "udpin:0.0.0.0:14560", 2)
    assert attached.min_separation_m == pytest.approx(1.25, abs=1e-6)
    assert attached.min_separation_time_s == pytest.approx(5.05, abs=1e-6)
    # AND the drones' own separation does not count it, metrics.json and the summary carry it
    assert metrics.min_separation_m == pytest.approx(6.0)
    assert json.loads(json.dumps(metrics.to_dict()))["attached"]["250"]["min_separation_m"] == pytest.approx(1.25)
    assert "attached vehicle 250 (intruder on udpin:0.0.0.0:14560): closest to a drone 1.25 m at 5.0 s (drone 2)" in (
        summary_text(metrics)
    )
