"""What fuzzing a flying drone found in the autopilot (bench/fuzz.py, docs/reliability.md), pinned closed-loop.

Policy: a ClosedLoop stepped directly (JSBSim, sensor noise on) behind the MAVLink adapter, driven with the request
objects the MAVLink services send; ground truth only checks where the vehicle really went.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from bench.fuzz import run_in_process
from sitl.autopilot import vehicle_api as api
from sitl.autopilot.px4_modes import Px4Mode
from sitl.drone.closed_loop import ClosedLoop
from sitl.drone.sim_vehicle_api import SimVehicleApi
from tests.closed_loop.flight import boot_position, make_sim

pytestmark = pytest.mark.timeout(120)


def _hovering(seed: int) -> tuple[ClosedLoop, SimVehicleApi, npt.NDArray[np.float64]]:
    """A drone hovering in Hold at the takeoff altitude (2.5 m), and where it booted."""
    sim = make_sim(seed=seed)
    vehicle = SimVehicleApi(sim)
    home = boot_position(sim)
    assert sim.run_until(lambda _s: vehicle.snapshot().prearm_ok, 10.0)
    assert vehicle.command(api.Arm(), sim.time_s).ok
    assert vehicle.command(api.Takeoff(), sim.time_s).ok
    assert sim.run_until(lambda _s: vehicle.snapshot().mode is Px4Mode.AUTO_LOITER, 15.0)
    return sim, vehicle, home


def _assert_flies_there_then_lands(sim: ClosedLoop, vehicle: SimVehicleApi, home: npt.NDArray[np.float64],
                                   north_m: float) -> None:  # fmt: skip
    lowest_m = [sim.altitude_above_start_m()]

    def watch(_s: ClosedLoop) -> None:
        if (sim.truth.pos_ned_m[0] - home[0]) < north_m - 5.0:
            lowest_m[0] = min(lowest_m[0], sim.altitude_above_start_m())

    sim.run_for(north_m / 2.0 + 15.0, on_step=watch)
    # it kept its altitude until it was there, and touched down there, unbroken, and disarmed
    assert lowest_m[0] > 2.0, f"descended to {lowest_m[0]:.2f} m on the way"
    assert not sim.vehicle.crashed
    assert sim.truth.on_ground and not vehicle.snapshot().armed
    assert (sim.truth.pos_ned_m - home)[:2] == pytest.approx((north_m, 0.0), abs=0.5)


@pytest.mark.parametrize("north_m", [30.0, 100.0])
def test_land_at_a_point_far_away_flies_there_first_and_touches_down_gently(north_m: float) -> None:
    # GIVEN a drone hovering in Hold WHEN it is told to land at a point tens of metres away (NAV_LAND with a
    # latitude and longitude) THEN it flies there at its altitude and lands there
    sim, vehicle, home = _hovering(seed=61)
    spot = vehicle.frame.geo_from_ned((north_m, 0.0, 0.0))
    assert vehicle.command(api.Land(lat_deg=spot.lat_deg, lon_deg=spot.lon_deg), sim.time_s).ok
    _assert_flies_there_then_lands(sim, vehicle, home, north_m)


def test_hostile_commands_and_setpoints_into_a_flying_drone_raise_nothing_and_keep_its_state_finite() -> None:
    # GIVEN a flying drone behind its MAVLink services WHEN 4,000 seeded hostile frames arrive, most of them commands
    # and setpoints addressed to it (bench/fuzz.py --in-process)
    report = run_in_process(4_000, seed=20261125)

    # THEN no handler, reply or step raised, and its position, velocity and attitude stayed finite
    assert report.frames == 4_000 and report.messages_handled > 2_000
    assert report.errors == {}, report.text()
    assert report.nonfinite == 0, report.text()
