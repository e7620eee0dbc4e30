"""A physics step's sensing taken as one compiled call (sitl/kernels/between_ticks.py: the IMU, barometer and
magnetometer samples and the estimator; between two commander ticks the cascade's inner loops too) flies to the bit
what the parts' shells fly, and is taken on every step but the GPS fixes'."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from sitl.avoidance.collision_prevention import RelayedNeighbour
from sitl.control.cascade import TrajectorySetpoint
from sitl.drone.closed_loop import ClosedLoop
from tests.closed_loop.flight import make_sim

pytestmark = pytest.mark.timeout(60)


def _flown(shells_only: bool) -> tuple[ClosedLoop, list[np.ndarray], int]:
    """Take off, fly offboard to a point 3 m away while the setpoint streams at 20 Hz, and record every step's truth
    and estimate; with ``shells_only`` every step goes through the shells. Returns how many steps took the call."""
    sim = make_sim(seed=5)
    taken = 0
    if shells_only:
        sim._compiled_step = lambda: None  # type: ignore[method-assign]
    else:
        between = sim._compiled_step

        def counted() -> tuple[float, ...] | None:
            nonlocal taken
            motors = between()
            taken += motors is not None
            return motors

        sim._compiled_step = counted  # type: ignore[method-assign]
    trace: list[np.ndarray] = []

    def record(s: ClosedLoop) -> None:
        est = s.estimate
        assert est is not None
        trace.append(np.concatenate((s.truth.pos_ned_m, s.truth.att_q_frd_to_ned, est.pos_ned_m, est.att_q_frd_to_ned)))

    v = sim.vehicle
    assert sim.run_until(lambda s: s.vehicle.preflight_problem() is None, 10.0)
    assert v.arm().ok and v.takeoff(3.0).ok
    sim.run_for(6.0, record)
    setpoint = TrajectorySetpoint(pos_ned_m=(3.0, 0.0, -3.0), vel_ned_mps=(0.0, 0.0, 0.0))
    v.set_offboard_setpoint(setpoint, sim.time_s)
    assert v.start_offboard(sim.time_s).ok

    def stream(s: ClosedLoop) -> None:  # a setpoint every 12 steps (about 20 Hz), as the streamer sends them
        if round(s.time_s / s.dt_s) % 12 == 0:
            s.vehicle.set_offboard_setpoint(setpoint, s.time_s)
        record(s)

    sim.run_for(4.0, stream)
    return sim, trace, taken


def test_steps_between_ticks_fly_to_the_bit_what_the_shells_fly() -> None:
    # GIVEN the same flight flown with steps between ticks as one call, and through the shells alone
    fast, fast_trace, taken = _flown(shells_only=False)
    slow, slow_trace, _ = _flown(shells_only=True)
    # THEN all but the steps with a GPS fix (10 Hz of 250 Hz) and a noise block's refill took the call ...
    assert taken > 0.9 * len(fast_trace), taken
    # ... and every step's truth and estimate have the same bits
    assert len(fast_trace) == len(slow_trace)
    for k, (a, b) in enumerate(zip(fast_trace, slow_trace, strict=True)):
        assert np.array_equal(a, b), f"step {k}: {a - b}"
    assert fast.battery.remaining == slow.battery.remaining
    assert np.array_equal(fast.vehicle.cascade.rate.state, slow.vehicle.cascade.rate.state)


def _offboard_flight(steady: bool) -> tuple[list[np.ndarray], list[str], dict[str, int]]:
    """Take off, then in OFFBOARD: fly 3 m north with the setpoint streamed at 20 Hz and a ground station heard at
    1 Hz, lose the stream (the offboard-loss failsafe: Hold), stream again and re-enter OFFBOARD, reposition and
    re-enter OFFBOARD, lose the ground
    station (the datalink-loss failsafe), hear it again, then descend into the ground (the land detector's touchdown
    on a tick), with a neighbour hovering beside the way (collision prevention's runs and corrections). Every step's
    truth, estimate and held control output, the commander's texts, and how many steady ticks were flown in the kernel
    (``taken``), with collision prevention's run in the kernel too (``avoided``) or after it in Python (``run``);
    with ``steady`` off every tick runs the Python commander."""
    sim = make_sim(seed=5)
    sim.steady_ticks = steady
    v = sim.vehicle
    counts = {"taken": 0, "avoided": 0, "run": 0}

    def counted(name: str, method: Callable[..., tuple[float, ...]]) -> Callable[..., tuple[float, ...]]:
        def call(*args: object) -> tuple[float, ...]:
            counts[name] += 1
            return method(*args)

        return call

    v.steady_tick_taken = counted("taken", v.steady_tick_taken)  # type: ignore[method-assign]
    v.steady_tick_avoided = counted("avoided", v.steady_tick_avoided)  # type: ignore[method-assign]
    v.steady_tick_run = counted("run", v.steady_tick_run)  # type: ignore[method-assign]
    trace: list[np.ndarray] = []
    texts: list[str] = []
    setpoint = TrajectorySetpoint(pos_ned_m=(3.0, 0.0, -3.0), vel_ned_mps=(0.0, 0.0, 0.0))
    streaming, hearing, relaying = True, True, True

    def record(s: ClosedLoop) -> None:
        est = s.estimate
        assert est is not None
        trace.append(np.concatenate((s.truth.pos_ned_m, s.truth.att_q_frd_to_ned, est.pos_ned_m, est.att_q_frd_to_ned,
                                     s.vehicle.cascade.held_row)))  # fmt: skip
        texts.extend(e.text for e in s.vehicle.events)
        s.vehicle.events.clear()
        step = round(s.time_s / s.dt_s)
        if streaming and step % 12 == 0:  # about 20 Hz, as the streamer sends them
            s.vehicle.set_offboard_setpoint(setpoint, s.time_s)
        if hearing and step % 250 == 0:
            s.vehicle.note_gcs_heartbeat(s.time_s)
        if step % 5 == 0:  # a hovering neighbour beside the way north, relayed at 50 Hz (while it is heard)
            s.vehicle.collision_prevention.set_relay([RelayedNeighbour(
                sysid=7, pos_ned_m=(1.5, 0.6, -3.0), vel_ned_mps=(0.0, 0.0, 0.0), received_s=s.time_s)]
                if relaying else [])  # fmt: skip

    assert sim.run_until(lambda s: s.vehicle.preflight_problem() is None, 10.0)
    assert v.arm().ok and v.takeoff(3.0).ok
    sim.run_for(6.0, record)
    v.params.set("COM_DL_LOSS_T", 5.0)
    v.params.set("NAV_DLL_ACT", 1)  # Hold
    v.note_gcs_heartbeat(sim.time_s)
    v.set_offboard_setpoint(setpoint, sim.time_s)
    assert v.start_offboard(sim.time_s).ok
    sim.run_for(1.5, record)
    relaying = False  # in the middle of a correction: nothing left to avoid, the episode ends a second later
    sim.run_for(0.5, record)
    relaying = True
    sim.run_for(2.0, record)
    streaming = False
    sim.run_for(2.0, record)  # past COM_OF_LOSS_T: Hold
    streaming = True
    sim.run_for(0.2, record)
    assert v.start_offboard(sim.time_s).ok
    sim.run_for(2.0, record)
    assert v.goto(np.array((0.0, 2.0, -4.0))).ok  # a reposition starts from the reference OFFBOARD kept
    sim.run_for(2.0, record)
    assert v.start_offboard(sim.time_s).ok
    sim.run_for(1.0, record)
    hearing = False
    sim.run_for(6.0, record)  # past COM_DL_LOSS_T
    hearing = True
    sim.run_for(1.5, record)
    assert v.start_offboard(sim.time_s).ok
    setpoint = TrajectorySetpoint(pos_ned_m=(3.0, 0.0, 0.5), vel_ned_mps=(0.0, 0.0, 0.3))
    sim.run_for(10.0, record)
    return trace, texts, counts


def test_steady_ticks_fly_to_the_bit_what_the_python_tick_flies() -> None:
    # GIVEN one OFFBOARD flight through two failsafes and a touchdown, flown with steady ticks in one kernel and
    # with the Python commander on every tick
    fast_trace, fast_texts, counts = _offboard_flight(steady=True)
    slow_trace, slow_texts, none = _offboard_flight(steady=False)
    # THEN steady ticks were taken, the avoiding ones with collision prevention's run in the kernel, and the few it
    # cannot make there (an episode ending with nothing left to avoid) after it, in Python; none when switched off ...
    assert counts["taken"] > 500, counts
    assert counts["avoided"] > 200, counts
    assert counts["run"] > 0, counts
    assert none == {"taken": 0, "avoided": 0, "run": 0}
    # ... the failsafes and the touchdown happened, in the same words ...
    assert any("offboard setpoints lost" in t for t in fast_texts), fast_texts
    assert any("no connection to the ground control station" in t for t in fast_texts), fast_texts
    assert "Landing detected" in fast_texts, fast_texts
    assert any(t.startswith("Avoidance: drone 7") for t in fast_texts), fast_texts
    assert fast_texts == slow_texts
    # ... and every step's truth, estimate and held control output have the same bits
    assert len(fast_trace) == len(slow_trace)
    for k, (a, b) in enumerate(zip(fast_trace, slow_trace, strict=True)):
        assert np.array_equal(a, b, equal_nan=True), f"step {k}: {a - b}"
