"""The battery model (drain, voltage sag and recovery, empty pack) and the wind model (steady part, seeded gusts)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from sitl.dynamics.airframe import load_airframe
from sitl.dynamics.battery import _SOC_POINTS, Battery, BatteryConfig, _cell_ocv_v, _current_for_power, _segment
from sitl.dynamics.wind import WindConfig, WindModel
from sitl.mathutil import GRAVITY_MPS2

pytestmark = pytest.mark.timeout(30)

CONFIG = BatteryConfig()  # 3S 5000 mAh


def _drain(battery: Battery, mechanical_power_w: float, duration_s: float, dt_s: float = 0.1) -> None:
    for _ in range(round(duration_s / dt_s)):
        battery.update(mechanical_power_w, dt_s)


def _hover_mechanical_power_w() -> float:
    airframe = load_airframe()
    thrust_per_rotor_n = airframe.mass_kg * GRAVITY_MPS2 / len(airframe.rotors)
    omega = math.sqrt(thrust_per_rotor_n / airframe.thrust_coeff_n_per_radps2)
    return len(airframe.rotors) * airframe.torque_coeff_nm_per_radps2 * omega**3


# ---- battery -------------------------------------------------------------------------------------------------------
def test_a_full_pack_at_rest_reads_its_full_charge_voltage() -> None:
    state = Battery(CONFIG).state()
    assert state.remaining == 1.0
    assert state.consumed_mah == 0.0
    assert state.voltage_v == pytest.approx(4.2 * CONFIG.cells)


def test_the_pack_delivers_the_electrical_power_at_its_terminal_voltage() -> None:
    # GIVEN a full pack
    battery = Battery(CONFIG)
    # WHEN the motors draw 200 W of mechanical power
    battery.update(200.0, 0.01)
    state = battery.state()
    # THEN terminal voltage times current is the electrical power: mechanical over efficiency, plus avionics
    electrical_w = 200.0 / CONFIG.efficiency + CONFIG.avionics_w
    assert state.voltage_v * state.current_a == pytest.approx(electrical_w, rel=1e-3)


def test_charge_drawn_is_the_current_integrated_over_time() -> None:
    battery = Battery(CONFIG)
    charge_as = 0.0
    for _ in range(600):
        battery.update(200.0, 0.1)
        charge_as += battery.state().current_a * 0.1
    state = battery.state()
    assert state.consumed_mah == pytest.approx(charge_as / 3.6, rel=1e-3)  # 1 mAh = 3.6 A s
    assert state.remaining == pytest.approx(1.0 - state.consumed_mah / CONFIG.capacity_mah)


def test_more_power_drains_faster() -> None:
    light, heavy = Battery(CONFIG), Battery(CONFIG)
    _drain(light, 100.0, 60.0)
    _drain(heavy, 300.0, 60.0)
    assert heavy.state().consumed_mah > 2.5 * light.state().consumed_mah


def test_an_f450_hovers_for_about_a_quarter_of_an_hour() -> None:
    # The class figure the module docstring claims: a 1.5 kg F450 on a 3S 5000 mAh pack hovers about 15 minutes.
    battery = Battery(CONFIG)
    hover_w = _hover_mechanical_power_w()
    minutes = 0.0
    while battery.state().remaining > 0.0 and minutes < 60.0:
        _drain(battery, hover_w, 60.0, dt_s=1.0)
        minutes += 1.0
    assert 12.0 <= minutes <= 18.0


def test_voltage_sags_under_load_by_the_internal_resistance_drop_and_recovers_at_rest() -> None:
    battery = Battery(CONFIG)
    _drain(battery, 0.0, 1.0)
    at_rest = battery.state()
    # WHEN a 400 W load comes on
    battery.update(400.0, 0.01)
    loaded = battery.state()
    # THEN the voltage drops by I * R at once
    assert loaded.current_a > 30.0
    assert at_rest.voltage_v - loaded.voltage_v == pytest.approx(
        (loaded.current_a - at_rest.current_a) * CONFIG.internal_resistance_ohm, rel=0.01
    )
    # and when the load goes away it recovers (to the open-circuit voltage less the avionics' small drop)
    battery.update(0.0, 0.01)
    recovered = battery.state()
    assert recovered.voltage_v > loaded.voltage_v + 0.5
    assert recovered.voltage_v == pytest.approx(at_rest.voltage_v, abs=0.01)


def test_resting_voltage_falls_as_the_pack_drains() -> None:
    battery = Battery(CONFIG)
    voltages = []
    for _ in range(12):
        _drain(battery, 300.0, 60.0, dt_s=1.0)
        battery.update(0.0, 0.001)
        voltages.append(battery.state().voltage_v)
    assert all(b <= a for a, b in itertools.pairwise(voltages))
    assert voltages[0] - voltages[-1] > 1.0


def test_remaining_never_goes_negative_when_drained_past_empty() -> None:
    # GIVEN a pack with 5 % left
    battery = Battery(CONFIG, initial_remaining=0.05)
    assert battery.state().remaining == pytest.approx(0.05)
    # WHEN far more than that is drawn
    _drain(battery, 300.0, 600.0)
    state = battery.state()
    # THEN remaining stops at zero and the voltage stays finite at the empty-cell level less the load drop
    assert state.remaining == 0.0
    assert state.consumed_mah > CONFIG.capacity_mah
    assert math.isfinite(state.voltage_v)
    assert state.voltage_v == pytest.approx(3.27 * CONFIG.cells - state.current_a * CONFIG.internal_resistance_ohm)


# ---- wind ----------------------------------------------------------------------------------------------------------
def _samples(config: WindConfig, seed: int, duration_s: float, dt_s: float = 0.05) -> np.ndarray:
    model = WindModel(config, np.random.default_rng(seed))
    return np.array([model.update(dt_s).copy() for _ in range(round(duration_s / dt_s))])


def test_calm_air_is_calm() -> None:
    model = WindModel(WindConfig(), np.random.default_rng(0))
    assert model.calm
    assert not model.update(0.01).any()


def test_steady_wind_without_gusts_is_exactly_the_steady_component() -> None:
    config = WindConfig(steady_ned_mps=(5.0, -2.0, 0.5))
    model = WindModel(config, np.random.default_rng(0))
    assert not model.calm
    for _ in range(100):
        np.testing.assert_array_equal(model.update(0.01), (5.0, -2.0, 0.5))


def test_gusts_have_the_configured_rms_around_the_steady_component() -> None:
    # GIVEN 5 m/s north wind with 1.5 m/s RMS gusts, correlation time 2 s
    config = WindConfig(steady_ned_mps=(5.0, 0.0, 0.0), gust_rms_mps=1.5, gust_time_s=2.0)
    # WHEN sampled for 2000 s (about 500 correlation times per axis)
    wind = _samples(config, seed=11, duration_s=2000.0)
    gust = wind - np.array(config.steady_ned_mps)
    # THEN each axis has the configured RMS and the mean is the steady component
    rms = np.sqrt(np.mean(gust**2, axis=0))
    np.testing.assert_allclose(rms, 1.5, rtol=0.1)
    np.testing.assert_allclose(gust.mean(axis=0), 0.0, atol=0.25)


def test_gusts_are_correlated_over_the_configured_time() -> None:
    config = WindConfig(gust_rms_mps=1.0, gust_time_s=2.0)
    dt_s = 0.05
    gust = _samples(config, seed=5, duration_s=2000.0, dt_s=dt_s)[:, 0]
    lag = round(config.gust_time_s / dt_s)
    correlation = float(np.corrcoef(gust[:-lag], gust[lag:])[0, 1])
    assert correlation == pytest.approx(math.exp(-1.0), abs=0.1)  # first-order Gauss-Markov: e^-1 at one tau


def test_the_same_seed_gives_the_same_gusts_and_another_seed_different_ones() -> None:
    config = WindConfig(steady_ned_mps=(3.0, 0.0, 0.0), gust_rms_mps=1.0)
    a = _samples(config, seed=7, duration_s=300.0)
    b = _samples(config, seed=7, duration_s=300.0)
    c = _samples(config, seed=8, duration_s=300.0)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_each_step_draws_the_current_the_whole_curve_gives_across_every_segment() -> None:
    """A step looks only at the curve's segment of the last one (``Battery.update``): across a whole drain, at
    every step, the current is the one the curve searched from its first point gives, to the bit."""
    battery = Battery(CONFIG)
    segments = set()
    for step in itertools.count():
        remaining = battery.true_remaining
        if remaining <= 0.0:
            break
        power_w = 2500.0 if step % 7 else 40.0  # loads that change from step to step
        ocv = _cell_ocv_v(remaining) * CONFIG.cells
        expected_a = _current_for_power(power_w / CONFIG.efficiency + CONFIG.avionics_w, max(ocv, 1.0),
                                        CONFIG.internal_resistance_ohm)  # fmt: skip
        battery.update(power_w, 0.05)
        assert battery.state().current_a == expected_a
        segments.add(_segment(remaining))
    assert segments == set(range(1, len(_SOC_POINTS)))  # every segment of the curve was flown through
