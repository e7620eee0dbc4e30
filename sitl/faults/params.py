"""Parameters of fault injection (sitl/faults/failures.py), with PX4's names and defaults."""

from __future__ import annotations

from sitl.params import ParamDef, ParamType

FAULT_PARAMS: tuple[ParamDef, ...] = (
    ParamDef(
        name="SYS_FAILURE_EN",
        default=0,
        min=0,
        max=1,
        unit="",
        type=ParamType.INT,
        description="Failure injection: 1 honours MAV_CMD_INJECT_FAILURE, 0 refuses it (DENIED)",
    ),
    ParamDef(
        name="SYS_FAIL_BAT_LVL",
        default=2,
        min=1,
        max=3,
        unit="",
        type=ParamType.INT,
        description="Injected battery failure (wrong) reads below 1 BAT_LOW_THR, 2 BAT_CRIT_THR, 3 BAT_EMERGEN_THR",
    ),
)
