"""First-principles checks of the JSBSim plant: every expectation is computed from the airframe numbers."""

from __future__ import annotations

import dataclasses
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from sitl.dynamics.airframe import Airframe, load_airframe
from sitl.dynamics.geodesy import LocalFrame
from sitl.dynamics.jsbsim_model import contact_count, model_name, write_model
from sitl.dynamics.jsbsim_plant import JsbsimPlant
from sitl.dynamics.plant import DEFAULT_HOME, GeoPoint, PlantState
from sitl.mathutil import GRAVITY_MPS2, quat_to_dcm, quat_to_euler

pytestmark = pytest.mark.timeout(30)

AIRFRAME = load_airframe("quad_x_f450")


def hover_cmd(airframe: Airframe = AIRFRAME) -> float:
    """Normalised command whose rotor speed makes total thrust equal the weight: n k_t w^2 = m g."""
    n = len(airframe.rotors)
    omega = math.sqrt(airframe.mass_kg * GRAVITY_MPS2 / (n * airframe.thrust_coeff_n_per_radps2))
    return omega / airframe.motor_max_speed_radps


def run(plant: JsbsimPlant, cmds: list[float], seconds: float) -> list[PlantState]:
    return [plant.step(cmds) for _ in range(round(seconds / plant.dt_s))]


def assert_finite(state: PlantState) -> None:
    for vector in (
        state.pos_ned_m,
        state.vel_ned_mps,
        state.att_q_frd_to_ned,
        state.rates_frd_radps,
        state.specific_force_frd_mps2,
    ):
        assert np.all(np.isfinite(vector)), state
    assert all(math.isfinite(v) for v in state.motor_speeds_radps), state


def hovering_plant(**kwargs: object) -> JsbsimPlant:
    cmd = hover_cmd()
    return JsbsimPlant(AIRFRAME, initial_pos_ned_m=(0.0, 0.0, -10.0), initial_motor_cmds=[cmd] * 4, **kwargs)  # type: ignore[arg-type]


# --- hover and free fall -----------------------------------------------------------------------------------


def test_thrust_equal_to_weight_holds_altitude_for_one_second() -> None:
    # GIVEN a drone at 10 m with the rotors at the speed whose thrust equals the weight
    cmd = hover_cmd()
    plant = hovering_plant()
    start = plant.state()
    assert start.motor_speeds_radps == pytest.approx([cmd * AIRFRAME.motor_max_speed_radps] * 4)
    # WHEN it holds that command for one second
    states = run(plant, [cmd] * 4, 1.0)
    # THEN it neither climbs nor sinks (the residual is the difference between standard g and local gravity)
    end = states[-1]
    assert abs(end.pos_ned_m[2] - start.pos_ned_m[2]) < 0.005
    assert abs(end.vel_ned_mps[2]) < 0.002
    assert np.linalg.norm(end.pos_ned_m[:2] - start.pos_ned_m[:2]) < 0.001
    assert not end.on_ground
    assert_finite(end)


def test_hover_accelerometer_reads_minus_g_along_body_z() -> None:
    plant = hovering_plant()
    state = run(plant, [hover_cmd()] * 4, 0.5)[-1]
    np.testing.assert_allclose(state.specific_force_frd_mps2, (0.0, 0.0, -GRAVITY_MPS2), atol=2e-3)


def test_spun_up_from_rest_thrust_settles_to_weight() -> None:
    # GIVEN a drone in the air with stopped motors, WHEN commanded to hover speed, THEN after the motor lag
    # has settled (10 time constants) the vertical acceleration is zero
    plant = JsbsimPlant(AIRFRAME, initial_pos_ned_m=(0.0, 0.0, -20.0))
    states = run(plant, [hover_cmd()] * 4, 10 * AIRFRAME.motor_time_constant_s + 0.1)
    a = states[-1].vel_ned_mps[2] - states[-41].vel_ned_mps[2]
    assert abs(a / (40 * plant.dt_s)) < 0.01


def test_free_fall_with_motors_off_accelerates_at_g() -> None:
    # GIVEN a drone at 100 m with motors off, WHEN released for 0.1 s (drag still below 0.5 % of weight)
    plant = JsbsimPlant(AIRFRAME, initial_pos_ned_m=(0.0, 0.0, -100.0))
    states = run(plant, [0.0] * 4, 0.1)
    end = states[-1]
    # THEN it falls with g
    assert end.vel_ned_mps[2] / end.time_s == pytest.approx(GRAVITY_MPS2, rel=2e-3)
    assert end.pos_ned_m[2] - (-100.0) == pytest.approx(0.5 * GRAVITY_MPS2 * end.time_s**2, rel=2e-2)
    # and the accelerometer reads only the airframe drag, c v^2 / m upwards
    drag = AIRFRAME.drag_coeff_frd_n_per_mps2[2] * end.vel_ned_mps[2] ** 2 / AIRFRAME.mass_kg
    np.testing.assert_allclose(end.specific_force_frd_mps2, (0.0, 0.0, -drag), rtol=0.02, atol=1e-9)
    assert np.linalg.norm(end.vel_ned_mps[:2]) < 1e-3


def test_heavier_airframe_sinks_at_the_rate_its_data_file_predicts() -> None:
    # The model is generated from the airframe data, not typed by hand: doubling the mass at the original
    # hover command must give a = g / 2 downwards.
    heavy = dataclasses.replace(AIRFRAME, mass_kg=2.0 * AIRFRAME.mass_kg)
    cmd = hover_cmd(AIRFRAME)
    plant = JsbsimPlant(heavy, initial_pos_ned_m=(0.0, 0.0, -50.0), initial_motor_cmds=[cmd] * 4)
    end = run(plant, [cmd] * 4, 0.1)[-1]
    assert end.vel_ned_mps[2] / end.time_s == pytest.approx(GRAVITY_MPS2 / 2, rel=1e-2)


# --- moments -----------------------------------------------------------------------------------------------


def angular_acceleration(cmds: list[float]) -> np.ndarray:
    plant = JsbsimPlant(AIRFRAME, initial_pos_ned_m=(0.0, 0.0, -10.0), initial_motor_cmds=cmds)
    start = plant.state().rates_frd_radps
    steps = 4
    end = run(plant, cmds, steps * plant.dt_s)[-1].rates_frd_radps
    return (end - start) / (steps * plant.dt_s)


def expected_moment(cmds: list[float]) -> np.ndarray:
    """Sum of r x F for thrust along body -z at each rotor, plus spin_dir * k_q * w^2 about body z."""
    total = np.zeros(3)
    for rotor, cmd in zip(AIRFRAME.rotors, cmds, strict=True):
        omega = cmd * AIRFRAME.motor_max_speed_radps
        thrust = np.array((0.0, 0.0, -AIRFRAME.thrust_coeff_n_per_radps2 * omega**2))
        total += np.cross(np.array(rotor.pos_frd_m), thrust)
        total[2] += rotor.spin_dir * AIRFRAME.torque_coeff_nm_per_radps2 * omega**2
    return total


def rotor_indices(predicate: object) -> list[int]:
    return [i for i, r in enumerate(AIRFRAME.rotors) if predicate(r)]  # type: ignore[operator]


def test_more_thrust_on_the_left_rolls_right_with_torque_over_inertia() -> None:
    left = rotor_indices(lambda r: r.pos_frd_m[1] < 0)
    cmds = [hover_cmd() + (0.05 if i in left else -0.05) for i in range(4)]
    alpha = angular_acceleration(cmds)
    expected = expected_moment(cmds)[0] / AIRFRAME.inertia_diag_kg_m2[0]
    assert expected > 0  # positive roll is right side down
    assert alpha[0] == pytest.approx(expected, rel=0.02)
    assert abs(alpha[1]) < 1e-3 * abs(expected)


def test_more_thrust_in_front_pitches_nose_up_with_torque_over_inertia() -> None:
    front = rotor_indices(lambda r: r.pos_frd_m[0] > 0)
    cmds = [hover_cmd() + (0.05 if i in front else -0.05) for i in range(4)]
    alpha = angular_acceleration(cmds)
    expected = expected_moment(cmds)[1] / AIRFRAME.inertia_diag_kg_m2[1]
    assert expected > 0  # positive pitch is nose up
    assert alpha[1] == pytest.approx(expected, rel=0.02)
    assert abs(alpha[0]) < 1e-3 * abs(expected)


def test_counter_clockwise_rotors_faster_yaws_nose_right() -> None:
    ccw = rotor_indices(lambda r: r.spin_dir > 0)
    cmds = [hover_cmd() + (0.05 if i in ccw else -0.05) for i in range(4)]
    alpha = angular_acceleration(cmds)
    expected = expected_moment(cmds)[2] / AIRFRAME.inertia_diag_kg_m2[2]
    assert expected > 0
    assert alpha[2] == pytest.approx(expected, rel=0.02)
    assert abs(alpha[0]) < 1e-3 * expected and abs(alpha[1]) < 1e-3 * expected


# --- motors ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("dt_s", [1.0 / 400.0, 1.0 / 1000.0, 1.0 / 250.0])
def test_motor_speed_reaches_63_percent_in_one_time_constant(dt_s: float) -> None:
    # GIVEN stopped motors, WHEN commanded to half speed, THEN the speed follows 1 - exp(-t / tau) exactly
    # at every physics rate
    plant = JsbsimPlant(AIRFRAME, dt_s=dt_s, initial_pos_ned_m=(0.0, 0.0, -10.0))
    tau = AIRFRAME.motor_time_constant_s
    target = 0.5 * AIRFRAME.motor_max_speed_radps
    states = run(plant, [0.5] * 4, 5 * tau)
    for state in (states[round(tau / dt_s) - 1], states[-1]):
        expected = (1.0 - math.exp(-state.time_s / tau)) * target
        assert state.motor_speeds_radps == pytest.approx([expected] * 4, rel=1e-9)
    assert states[round(tau / dt_s) - 1].motor_speeds_radps[0] == pytest.approx(0.632 * target, rel=0.03)


def test_motor_commands_are_sanitised() -> None:
    plant = JsbsimPlant(AIRFRAME, initial_pos_ned_m=(0.0, 0.0, -10.0))
    state = run(plant, [float("nan"), -3.0, 7.0, float("inf")], 20 * AIRFRAME.motor_time_constant_s)[-1]
    top = AIRFRAME.motor_max_speed_radps
    assert state.motor_speeds_radps == pytest.approx([0.0, 0.0, top, top], abs=1e-3 * top)
    assert_finite(state)
    with pytest.raises(ValueError):
        plant.step([0.5, 0.5, 0.5])


# --- ground ------------------------------------------------------------------------------------------------


def test_resting_on_the_ground_for_ten_seconds_is_quiet() -> None:
    # GIVEN the default start (resting on the ground at home) and motors off
    plant = JsbsimPlant(AIRFRAME)
    states = run(plant, [0.0] * 4, 10.0)
    for state in states:
        assert_finite(state)
        assert state.on_ground
    end = states[-1]
    # THEN the CG sits at the gear height less the static spring compression m g / (n k)
    compression = AIRFRAME.mass_kg * GRAVITY_MPS2 / (4 * AIRFRAME.gear_spring_n_per_m)
    assert -end.pos_ned_m[2] == pytest.approx(AIRFRAME.gear_height_m - compression, abs=5e-4)
    assert -end.pos_ned_m[2] == pytest.approx(plant.rest_height_m, abs=5e-4)
    assert np.linalg.norm(end.pos_ned_m[:2]) < 1e-3
    assert np.linalg.norm(end.vel_ned_mps) < 1e-4
    np.testing.assert_allclose(end.specific_force_frd_mps2, (0.0, 0.0, -GRAVITY_MPS2), atol=0.01)
    np.testing.assert_allclose(end.rates_frd_radps, 0.0, atol=1e-5)


def test_drop_onto_the_ground_lands_without_wild_bounce_or_penetration() -> None:
    # GIVEN a drone 2 m above the ground with motors off, WHEN it falls and lands
    plant = JsbsimPlant(AIRFRAME, initial_pos_ned_m=(0.0, 0.0, -2.0))
    states = run(plant, [0.0] * 4, 3.0)
    downs = np.array([s.pos_ned_m[2] for s in states])
    first_contact = next(i for i, s in enumerate(states) if s.on_ground)
    # THEN the CG never reaches the ground, the rebound is a few centimetres, and it comes to rest on its gear
    assert downs.max() < 0.0
    assert -downs[first_contact:].min() - plant.rest_height_m < 0.05
    assert -downs[-1] == pytest.approx(plant.rest_height_m, abs=1e-3)
    assert states[-1].on_ground
    assert np.linalg.norm(states[-1].vel_ned_mps) < 1e-3
    assert all(np.all(np.isfinite(s.pos_ned_m)) for s in states)


def test_start_position_below_resting_height_means_resting_on_the_ground() -> None:
    plant = JsbsimPlant(AIRFRAME, initial_pos_ned_m=(3.0, -4.0, 5.0))
    state = plant.state()
    np.testing.assert_allclose(state.pos_ned_m, (3.0, -4.0, -plant.rest_height_m), atol=1e-6)
    assert state.on_ground


# --- wind --------------------------------------------------------------------------------------------------


def test_wind_pushes_a_hovering_drone_downwind_with_quadratic_drag() -> None:
    # GIVEN a hovering drone and a 5 m/s wind blowing towards the north-east
    plant = hovering_plant()
    wind = np.array((4.0, 3.0, 0.0))
    plant.set_wind(wind)
    # WHEN a short time passes
    states = run(plant, [hover_cmd()] * 4, 0.05)
    # THEN it accelerates downwind at c v^2 / m per body axis (level, yaw 0: body x = north, y = east), measured as
    # the slope of the velocity once JSBSim's multi-step integrator has taken up the new force (its first few steps
    # over- and undershoot, by a share of the window that grows with the step: 3 % of v/t at 400 Hz, 4.6 % at 250)
    t = np.array([s.time_s for s in states])
    v = np.array([s.vel_ned_mps for s in states])
    after = t >= 0.02 - 1e-9
    accel = np.polyfit(t[after], v[after], 1)[0]
    cx, cy, _ = AIRFRAME.drag_coeff_frd_n_per_mps2
    expected = np.array((cx * wind[0] ** 2, cy * wind[1] ** 2)) / AIRFRAME.mass_kg
    np.testing.assert_allclose(accel[:2], expected, rtol=0.03)
    # and keeps drifting that way
    later = run(plant, [hover_cmd()] * 4, 2.0)[-1]
    assert later.pos_ned_m[0] > 0.3 and later.pos_ned_m[1] > 0.2
    np.testing.assert_allclose(plant.wind_ned_mps, wind)


def test_wind_does_not_move_a_drone_resting_on_the_ground() -> None:
    plant = JsbsimPlant(AIRFRAME)
    plant.set_wind(np.array((0.0, 8.0, 0.0)))
    end = run(plant, [0.0] * 4, 2.0)[-1]
    assert np.linalg.norm(end.pos_ned_m[:2]) < 0.01
    assert end.on_ground


# --- frames and geodesy ------------------------------------------------------------------------------------


def test_initial_yaw_is_reported_in_the_attitude() -> None:
    plant = JsbsimPlant(AIRFRAME, initial_yaw_rad=-2.0)
    q = plant.state().att_q_frd_to_ned
    assert q[0] >= 0.0
    assert np.linalg.norm(q) == pytest.approx(1.0)
    roll, pitch, yaw = quat_to_euler(q)
    assert yaw == pytest.approx(-2.0, abs=1e-9)
    assert abs(roll) < 1e-9 and abs(pitch) < 1e-9


def test_thrust_in_a_yawed_body_pushes_along_the_rotated_axes() -> None:
    # Tilted drone: the accelerometer is in the body frame, the velocity in NED; they agree through att_q.
    plant = hovering_plant(initial_yaw_rad=math.radians(30.0))
    front = rotor_indices(lambda r: r.pos_frd_m[0] > 0)
    # pitch nose down briefly, then hold level thrust
    cmds = [hover_cmd() + (-0.03 if i in front else 0.03) for i in range(4)]
    run(plant, cmds, 0.1)
    states = run(plant, [hover_cmd()] * 4, 0.2)
    a_ned = (states[-1].vel_ned_mps - states[0].vel_ned_mps) / (0.2 - plant.dt_s)
    mean_sf = np.mean([quat_to_dcm(s.att_q_frd_to_ned) @ s.specific_force_frd_mps2 for s in states], axis=0)
    np.testing.assert_allclose(a_ned[:2], mean_sf[:2], atol=0.02)
    heading = math.atan2(a_ned[1], a_ned[0])
    assert heading == pytest.approx(math.radians(30.0), abs=math.radians(3.0))


def test_geodetic_position_is_consistent_with_ned() -> None:
    home = GeoPoint(lat_deg=-33.8568, lon_deg=151.2153, alt_amsl_m=20.0)
    frame = LocalFrame(home)
    plant = JsbsimPlant(AIRFRAME, home=home, initial_pos_ned_m=(120.0, -80.0, -30.0))
    start = plant.state()
    np.testing.assert_allclose(start.pos_ned_m, (120.0, -80.0, -30.0), atol=1e-6)
    plant.set_wind(np.array((-6.0, 6.0, 0.0)))
    states = run(plant, [hover_cmd()] * 4, 3.0)
    for state in (start, states[-1]):
        np.testing.assert_allclose(frame.ned_from_geo(state.geo), state.pos_ned_m, atol=1e-9)
        assert state.geo.alt_amsl_m == pytest.approx(home.alt_amsl_m - state.pos_ned_m[2], abs=1e-9)
    # integrating the NED velocity reproduces the NED displacement
    travelled = np.sum([s.vel_ned_mps for s in states], axis=0) * plant.dt_s
    np.testing.assert_allclose(states[-1].pos_ned_m - start.pos_ned_m, travelled, atol=0.01)
    assert np.linalg.norm(travelled[:2]) > 1.0


def test_default_home_is_px4_sitl_home() -> None:
    plant = JsbsimPlant(AIRFRAME)
    geo = plant.state().geo
    assert geo.lat_deg == pytest.approx(DEFAULT_HOME.lat_deg, abs=1e-9)
    assert geo.lon_deg == pytest.approx(DEFAULT_HOME.lon_deg, abs=1e-9)
    assert geo.alt_amsl_m == pytest.approx(DEFAULT_HOME.alt_amsl_m + plant.rest_height_m, abs=1e-6)


# --- model generation --------------------------------------------------------------------------------------


def test_model_is_written_in_jsbsim_layout_with_airframe_values(tmp_path: Path) -> None:
    path = write_model(AIRFRAME, tmp_path)
    name = model_name(AIRFRAME)
    assert path == tmp_path / "aircraft" / name / f"{name}.xml"
    root = ET.parse(path).getroot()
    assert root.tag == "fdm_config"
    assert float(root.findtext("mass_balance/emptywt", "nan")) == AIRFRAME.mass_kg
    assert root.find("mass_balance/emptywt").get("unit") == "KG"  # type: ignore[union-attr]
    contacts = root.findall("ground_reactions/contact")
    skids = [c for c in contacts if (c.get("name") or "").startswith("skid")]
    assert len(skids) == len(AIRFRAME.rotors)
    assert len(contacts) == contact_count(AIRFRAME)
    # JSBSim's structural frame has z up: the skids are gear_height below the CG
    assert all(float(c.findtext("location/z", "nan")) == -AIRFRAME.gear_height_m for c in skids)
    assert len(root.findall("external_reactions/force")) == len(AIRFRAME.rotors) + 3
    assert root.find("flight_control") is not None and len(root.find("flight_control")) == 0  # type: ignore[arg-type]


def test_constructor_rejects_bad_arguments() -> None:
    with pytest.raises(ValueError):
        JsbsimPlant(AIRFRAME, dt_s=0.0)
    with pytest.raises(ValueError):
        JsbsimPlant(AIRFRAME, initial_pos_ned_m=(0.0, float("nan"), 0.0))
    with pytest.raises(ValueError):
        hovering_plant().set_wind(np.array((float("nan"), 0.0, 0.0)))


def test_a_vehicle_that_flips_over_rests_on_its_motors_above_the_ground() -> None:
    # GIVEN a drone 3 m up, WHEN two diagonal motors at full power flip it and it falls inverted
    plant = JsbsimPlant(AIRFRAME, initial_pos_ned_m=(0.0, 0.0, -3.0))
    run(plant, [1.0, 0.0, 0.0, 1.0], 0.5)
    states = run(plant, [0.0] * 4, 5.0)
    end = states[-1]
    # THEN it lies upside down on the motor contacts with its CG above the ground, at rest
    body_down_in_ned = quat_to_dcm(end.att_q_frd_to_ned) @ np.array((0.0, 0.0, 1.0))
    assert body_down_in_ned[2] < -0.9
    assert end.on_ground
    assert all(s.pos_ned_m[2] < 0.0 for s in states)
    assert np.linalg.norm(end.vel_ned_mps) < 1e-3
    assert_finite(end)


def test_a_state_read_after_later_steps_is_the_state_of_its_own_step() -> None:
    """A step's vectors are built on first read from the properties read at that step: reading one late, or copying,
    replacing or pickling it, gives what reading it at once gave, as a plain ``PlantState``."""
    import copy
    import pickle

    cmds = [hover_cmd() * 1.2] * len(AIRFRAME.rotors)
    eager, lazy = JsbsimPlant(AIRFRAME), JsbsimPlant(AIRFRAME)
    read_at_once = [dataclasses.replace(eager.step(cmds)) for _ in range(50)]
    kept = [lazy.step(cmds) for _ in range(50)]
    for now, late in zip(read_at_once, kept, strict=True):
        assert type(now) is PlantState
        for f in dataclasses.fields(PlantState):
            a, b = getattr(now, f.name), getattr(late, f.name)
            assert type(a) is type(b)
            if isinstance(a, np.ndarray):
                assert a.tobytes() == b.tobytes(), f.name
            else:
                assert a == b, f.name
        for plain in (dataclasses.replace(late), copy.copy(late), pickle.loads(pickle.dumps(late))):
            assert type(plain) is PlantState
            assert plain.geo == late.geo and plain.pos_ned_m.tobytes() == late.pos_ned_m.tobytes()
    imu = lazy.imu_inputs()
    last = kept[-1]
    assert imu.tobytes() == np.concatenate((last.rates_frd_radps, last.specific_force_frd_mps2)).tobytes()
