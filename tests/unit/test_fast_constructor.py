"""fast_constructor: the cheap way the physics loop builds its frozen records must build exactly what the class does."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sitl.autopilot.guidance import Reference
from sitl.control.allocation import AllocationResult
from sitl.control.cascade import CascadeOutput, TrajectorySetpoint
from sitl.dynamics.plant import GeoPoint, PlantState
from sitl.estimation.estimator import Estimate
from sitl.mathutil import fast_constructor
from sitl.sensors.models import ImuSample, SensorReadings

pytestmark = pytest.mark.timeout(30)


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class _Record:
    name: str
    value_m: float
    scale: float = 2.0


def test_builds_an_equal_object_of_the_same_class_that_stays_frozen() -> None:
    new = fast_constructor(_Record)
    built = new(name="a", value_m=1.5, scale=3.0)
    assert type(built) is _Record
    assert built == _Record(name="a", value_m=1.5, scale=3.0)
    assert repr(built) == repr(_Record(name="a", value_m=1.5, scale=3.0))
    assert hash(built) == hash(_Record(name="a", value_m=1.5, scale=3.0))
    with pytest.raises(dataclasses.FrozenInstanceError):
        built.value_m = 2.0  # type: ignore[misc]


def test_defaults_apply_and_the_signature_is_the_classes() -> None:
    new = fast_constructor(_Record)
    assert new(name="b", value_m=0.0).scale == 2.0
    with pytest.raises(TypeError):
        new(name="b")  # type: ignore[call-arg]
    with pytest.raises(TypeError):
        new(name="b", value_m=0.0, unknown=1.0)  # type: ignore[call-arg]
    with pytest.raises(TypeError):
        new("b", 0.0)  # type: ignore[call-arg]


def test_classes_whose_init_does_more_than_assign_are_refused() -> None:
    @dataclasses.dataclass(frozen=True, slots=True)
    class Checked:
        x: float

        def __post_init__(self) -> None:
            assert self.x >= 0.0

    @dataclasses.dataclass(frozen=True, slots=True)
    class Factory:
        items: list[float] = dataclasses.field(default_factory=list)

    @dataclasses.dataclass(frozen=True)
    class NoSlots:
        x: float

    for cls in (Checked, Factory, NoSlots):
        with pytest.raises(TypeError):
            fast_constructor(cls)


def test_the_records_of_the_physics_loop_build_equal_objects() -> None:
    # Every record the loop builds with a fast constructor, field for field, against the class's own __init__.
    v = np.array((1.0, 2.0, 3.0))
    q = np.array((1.0, 0.0, 0.0, 0.0))
    geo = GeoPoint(lat_deg=47.0, lon_deg=8.0, alt_amsl_m=500.0)
    imu = ImuSample(gyro_frd_radps=v, accel_frd_mps2=v)
    alloc = AllocationResult(
        motor_cmds=(0.5,) * 4,
        rotor_thrusts_n=(4.0,) * 4,
        saturated_pos=(False, True, False),
        saturated_neg=(False, False, True),
        thrust_saturation=1,
    )
    samples: list[object] = [
        geo,
        imu,
        alloc,
        PlantState(
            time_s=1.0,
            pos_ned_m=v,
            vel_ned_mps=v,
            att_q_frd_to_ned=q,
            rates_frd_radps=v,
            specific_force_frd_mps2=v,
            geo=geo,
            on_ground=False,
            motor_speeds_radps=(1.0, 2.0, 3.0, 4.0),
        ),
        SensorReadings(imu=imu, gps=None, baro=None, mag=None),
        Estimate(
            time_s=1.0,
            pos_ned_m=v,
            vel_ned_mps=v,
            att_q_frd_to_ned=q,
            rates_frd_radps=v,
            roll_rad=0.1,
            pitch_rad=0.2,
            yaw_rad=0.3,
            attitude_valid=True,
            position_valid=False,
            altitude_valid=True,
        ),
        Reference(pos_ned_m=v, vel_ned_mps=v, acc_ned_mps2=v),
        CascadeOutput(
            motor_cmds=(0.5,) * 4,
            vel_sp_ned_mps=(1.0, 2.0, math.nan),
            acc_sp_ned_mps2=(0.0, 0.0, 0.0),
            thrust_sp_ned_n=(0.0, 0.0, -15.0),
            att_sp_q=(1.0, 0.0, 0.0, 0.0),
            rates_sp_frd_radps=(0.0, 0.0, 0.0),
            torque_sp_frd_nm=(0.0, 0.0, 0.0),
            collective_sp_n=15.0,
            allocation=alloc,
        ),
        TrajectorySetpoint(pos_ned_m=(1.0, 2.0, 3.0), yaw_rad=0.5),
    ]
    for sample in samples:
        cls = type(sample)
        fields = {f.name: getattr(sample, f.name) for f in dataclasses.fields(sample)}  # type: ignore[arg-type]
        built = fast_constructor(cls)(**fields)
        assert type(built) is cls
        for name, value in fields.items():
            assert getattr(built, name) is value, (cls.__name__, name)
