"""A physics step's sensing taken as one compiled call (sitl/kernels/between_ticks.py: the IMU, barometer and
magnetometer samples and the estimator; between two commander ticks the cascade's inner loops too) flies to the bit
what the parts' shells fly, and is taken on every step but the GPS fixes'."""

from __future__ import annotations

import numpy as np
import pytest

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
