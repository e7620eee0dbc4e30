"""One drone's closed loop without any IO: plant -> sensors -> estimator -> autopilot -> plant.

Tests fly this directly (no sockets, no clock); the process runtime (sitl/process/runtime.py) wraps it with pacing and
MAVLink. Everything random is drawn from streams spawned from one seed, so a seed fixes the whole flight.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from sitl.autopilot.commander import Commander
from sitl.control.cascade import Cascade
from sitl.drone.param_table import build_param_store
from sitl.dynamics.airframe import Airframe
from sitl.dynamics.battery import Battery, BatteryConfig
from sitl.dynamics.jsbsim_plant import JsbsimPlant
from sitl.dynamics.plant import DEFAULT_HOME, PHYSICS_RATE_HZ, GeoPoint, PlantState
from sitl.dynamics.wind import WindConfig, WindModel
from sitl.estimation.estimator import Estimate, Estimator, EstimatorConfig
from sitl.faults.failures import FaultState
from sitl.kernels import between_ticks as bt
from sitl.params import ParamStore
from sitl.sensors.models import GpsSample, SensorConfig, SensorSuite

# A touchdown faster than this breaks the airframe (gear, arms, props): the vehicle is crashed, as after a collision.
# A normal landing touches down at MPC_LAND_SPEED (0.7 m/s) or slower; 3 m/s is the speed of a drop from 0.46 m, which
# a hobby quadrotor's gear does not survive without damage. A quad that loses a rotor in a 3 m hover lands at ~6 m/s.
GROUND_IMPACT_SPEED_MPS = 3.0


@dataclass(frozen=True, slots=True, kw_only=True)
class SimConfig:
    airframe: Airframe
    seed: int = 0
    home: GeoPoint = DEFAULT_HOME
    initial_yaw_rad: float = 0.0
    physics_rate_hz: float = PHYSICS_RATE_HZ
    sensors: SensorConfig = field(default_factory=SensorConfig)
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)
    wind: WindConfig = field(default_factory=WindConfig)
    battery: BatteryConfig = field(default_factory=BatteryConfig)


class ClosedLoop:
    def __init__(self, config: SimConfig, params: ParamStore | None = None) -> None:
        self.config = config
        self.dt_s = 1.0 / config.physics_rate_hz
        self.params = params if params is not None else build_param_store()
        seeds = np.random.SeedSequence(config.seed).spawn(2)
        self.plant = JsbsimPlant(
            config.airframe, home=config.home, dt_s=self.dt_s, initial_yaw_rad=config.initial_yaw_rad
        )
        self.sensors = SensorSuite(config.sensors, seed=int(seeds[0].generate_state(1)[0]))
        self.wind = WindModel(config.wind, np.random.default_rng(seeds[1]))
        self.estimator = Estimator(config.estimator, origin_alt_amsl_m=self.plant.state().geo.alt_amsl_m)
        self.estimator.set_mag_reference(np.array(config.sensors.mag_field_ned_gauss))
        self.battery = Battery(config.battery)
        self.vehicle = Commander(
            config.airframe,
            self.params,
            Cascade(config.airframe, self.params),
            battery_remaining=lambda: self.battery.remaining,
        )
        self.faults = FaultState()  # injected faults in force (set_faults)
        self.truth: PlantState = self.plant.state()
        self.last_gps: GpsSample | None = None  # the receiver's latest report, for GPS_RAW_INT
        self.estimate: Estimate | None = None
        self.time_s = 0.0
        self.truth_at_boot_ned_m = self.truth.pos_ned_m.copy()
        self._k_q = config.airframe.torque_coeff_nm_per_radps2
        # Steady ticks taken in one kernel (``_compiled_step``); off, every tick runs the Python commander, to the same
        # bits (tests/closed_loop/test_between_ticks.py flies both).
        self.steady_ticks = True
        self.control_ns = 0  # sensors, estimator, autopilot and cascade
        self.physics_ns = 0  # JSBSim, wind, battery
        # The clock the parts are timed with: monotonic by default (a read costs ~40 ns); a drone in a swarm uses its
        # thread's CPU clock instead (~0.4 us a read), because with more drones than cores a monotonic clock also
        # counts the time a drone waits for a CPU, charged to whichever part it was preempted in (sitl/process/app.py).
        self.part_clock_ns: Callable[[], int] = time.perf_counter_ns

    def set_faults(self, faults: FaultState) -> None:
        """Put injected faults in force where they act: the plant's rotors, the GPS receiver, the battery monitor.
        (A link fault acts in the MAVLink endpoint, which reads ``faults.link_off_until_s``.)"""
        self.faults = faults
        self.plant.failed_motors = faults.motors_off
        self.sensors.gps.fault = faults.gps
        self.battery.reported_remaining = faults.battery_remaining

    def step(self) -> PlantState:
        """Advance one physics step (sensors sample at their own rates, the estimator, attitude and rate control
        every step; the autopilot's commander and the position and velocity loops on its ticks,
        sitl/autopilot/commander.py).

        A step without a GPS sample samples the sensors and steps the estimator in one compiled call, which between
        ticks runs the inner loops too (``_compiled_step``); the others go through the parts' shells. The two halves
        are timed (``control_ns``, ``physics_ns``) with ``part_clock_ns`` so benchmarks can say where a drone's time
        goes without a profiler's distortion."""
        clock = self.part_clock_ns
        t0 = clock()
        motors = self._compiled_step()
        if motors is None:
            readings = self.sensors.sample(self.truth)
            if readings.gps is not None:
                self.last_gps = readings.gps
            self.estimate = self.estimator.update(readings, self.time_s, self.dt_s)
            motors = self.vehicle.step(self.estimate, self.time_s, self.dt_s)
        t1 = clock()
        if not self.wind.calm:
            self.plant.set_wind(self.wind.update(self.dt_s))
        before = self.truth
        self.truth = self.plant.step(motors)
        self.time_s = self.truth.time_s
        if self.truth.on_ground and not before.on_ground:
            self._touchdown(before)
        power_w = 0.0
        for w in self.truth.motor_speeds_radps:
            power_w += w * w * w
        power_w *= self._k_q
        self.battery.update(power_w, self.dt_s)
        t2 = clock()
        self.control_ns += t1 - t0
        self.physics_ns += t2 - t1
        return self.truth

    def _compiled_step(self) -> tuple[float, ...] | None:
        """The sensors' sample and the estimator's step as one kernel (sitl/kernels/between_ticks.py ``sense``), then
        the commander's step on that estimate; when the autopilot only runs its inner loops
        (``Commander.holds_inner_loops``) they run in the same call (``step``). The same samples, estimate and motor
        commands as the shells would give. None, having changed nothing, when the sensors cannot be sampled there
        (``SensorSuite.take_kernel_sample``)."""
        estimator, dt_s, time_s = self.estimator, self.dt_s, self.time_s
        sample = self.sensors.take_kernel_sample(self.truth, estimator.attitude_initialised)
        if sample is None:
            return None
        vehicle = self.vehicle
        est_state, est_cfg, est_gps, est_no_vec, est_out = estimator.kernel_rows()
        imu_inputs, row = self.plant.imu_inputs(), self.sensors.row
        if not vehicle.holds_inner_loops(dt_s):
            if self.steady_ticks and vehicle.steady_tick_ready(time_s, dt_s):
                cascade = vehicle.cascade
                plan = vehicle.steady_tick_plan(time_s, dt_s)
                conditions, (fly, due, elapsed_s) = plan[:-3], plan[-3:]
                avoiding = None if fly else vehicle.steady_tick_avoiding_plan(time_s, dt_s)
                sp, pos_cfg, vel_cfg, vel_state, heading, held = cascade.outer_rows()
                att_cfg, rate_cfg, rate_state, alloc_rows, t_max, inner_out = cascade.inner_rows()
                if avoiding is None:
                    taken = bt.steady_tick(imu_inputs, row, *sample, est_state, est_cfg, est_gps, est_no_vec, est_out,
                                           time_s, dt_s, *conditions, fly, sp, due, elapsed_s, pos_cfg, vel_cfg,
                                           vel_state, heading, held, att_cfg, rate_cfg, rate_state, alloc_rows, t_max,
                                           inner_out)  # fmt: skip
                else:  # (mypy cannot line up a third unpacked tuple with the parameters: it is AvoidingPlan's order)
                    taken = bt.steady_tick_avoiding(imu_inputs, row, *sample, est_state, est_cfg, est_gps, est_no_vec,
                                                    est_out, time_s, dt_s, *conditions, sp, *avoiding, pos_cfg,  # type: ignore[arg-type]
                                                    vel_cfg, vel_state, heading, held, att_cfg, rate_cfg, rate_state,
                                                    alloc_rows, t_max, inner_out)  # fmt: skip
                if taken == bt.TICK_STEADY:
                    self.estimate = estimate = estimator.published(time_s)
                    return vehicle.steady_tick_taken(estimate, time_s)
                if taken >= bt.TICK_AVOIDED:
                    self.estimate = estimate = estimator.published(time_s)
                    return vehicle.steady_tick_avoided(estimate, time_s, taken == bt.TICK_AVOIDED_OUTER)
                if taken == bt.TICK_QUIET:
                    self.estimate = estimate = estimator.published_whole(time_s)
                    return vehicle.steady_tick_run(estimate, time_s, dt_s)
            else:
                bt.sense(imu_inputs, row, *sample, est_state, est_cfg, est_gps, est_no_vec, est_out,
                         time_s, dt_s)  # fmt: skip
            self.estimate = estimate = estimator.published_whole(time_s)  # a tick, most likely: it reads every vector
            return vehicle.step(estimate, time_s, dt_s)
        cascade = vehicle.cascade
        att_cfg, rate_cfg, rate_state, alloc_rows, t_max, inner_out = cascade.inner_rows()
        bt.step(imu_inputs, row, *sample, est_state, est_cfg, est_gps, est_no_vec, est_out,
                time_s, dt_s, cascade.held_row, vehicle.landed, att_cfg, rate_cfg, rate_state, alloc_rows, t_max,
                inner_out)  # fmt: skip
        self.estimate = estimate = estimator.published(time_s)
        return vehicle.inner_loops_stepped(estimate, time_s, dt_s)

    def _touchdown(self, before: PlantState) -> None:
        """The first step in contact with the ground: too fast a touchdown is a crash (the speed is the one just
        before contact, as the gear's springs have already begun to slow the body on this step)."""
        vn, ve, vd = before.vel_ned_mps
        speed_mps = math.sqrt(vn * vn + ve * ve + vd * vd)
        if speed_mps > GROUND_IMPACT_SPEED_MPS:
            self.vehicle.crash(f"Ground impact at {speed_mps:.1f} m/s")

    def run_for(self, duration_s: float, on_step: Callable[[ClosedLoop], None] | None = None) -> None:
        for _ in range(round(duration_s / self.dt_s)):
            self.step()
            if on_step is not None:
                on_step(self)

    def run_until(self, condition: Callable[[ClosedLoop], bool], timeout_s: float) -> bool:
        """Step until the condition holds (checked after each step); False if the timeout passes first."""
        end = self.time_s + timeout_s
        while self.time_s < end - 1e-9:
            self.step()
            if condition(self):
                return True
        return False

    def altitude_above_start_m(self) -> float:
        """True CG height above where it rested at boot (for tests and reports; the autopilot never sees it)."""
        return float(self.truth_at_boot_ned_m[2] - self.truth.pos_ned_m[2])
