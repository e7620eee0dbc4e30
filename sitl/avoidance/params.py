"""Parameters of onboard collision avoidance and the synthetic camera (docs/avoidance.md, docs/perception.md).

PX4's own collision prevention (CP_DIST and friends) works on a distance sensor's obstacle map and only brakes; this
avoidance steers around moving neighbours, so it has parameters of its own, named in PX4's style.
"""

from __future__ import annotations

from sitl.params import ParamDef, ParamType

AVOIDANCE_PARAMS: tuple[ParamDef, ...] = (
    ParamDef(
        name="AVOID_ENABLE",
        default=1,
        min=0,
        max=1,
        unit="",
        description="Onboard collision avoidance: 1 on (offboard, mission, hold and goto setpoints), 0 off",
        type=ParamType.INT,
    ),
    ParamDef(
        name="AVOID_MIN_DIST",
        default=1.5,
        min=0.8,
        max=20.0,
        unit="m",
        description="Centre-to-centre separation avoidance keeps from another drone",
    ),
    ParamDef(
        name="AVOID_HORIZON",
        default=2.5,
        min=0.5,
        max=10.0,
        unit="s",
        description="Time horizon of the velocity obstacles: encounters further ahead are ignored",
    ),
    ParamDef(
        name="AVOID_MAX_CORR",
        default=5.0,
        min=0.5,
        max=20.0,
        unit="m/s",
        description="Largest horizontal velocity correction avoidance may apply (keep it above the cruise speed)",
    ),
    ParamDef(
        name="AVOID_STALE_RATE",
        default=0.25,
        min=0.0,
        max=5.0,
        unit="m/s",
        description="Keep-out growth around traffic the ground station reports from old knowledge (its tslc: a "
        "vehicle it no longer hears), per second of age",
    ),
    ParamDef(
        name="AVOID_STALE_MAX",
        default=3.0,
        min=0.0,
        max=20.0,
        unit="m",
        description="Largest keep-out growth around traffic reported from old knowledge",
    ),
    ParamDef(
        name="CAM_ENABLE",
        default=1,
        min=0,
        max=1,
        unit="",
        description="Synthetic camera for avoidance: 1 on, 0 off (relayed neighbours only)",
        type=ParamType.INT,
    ),
    ParamDef(
        name="CAM_RIG",
        # Omnidirectional by default: a silent drone (no relay) beside or behind a drone is seen too; with one
        # forward camera a rotating circle flew into one (docs/avoidance.md, "A silent drone").
        default=1,
        min=0,
        max=1,
        unit="",
        description="Camera rig: 0 one forward camera, 1 omnidirectional (four cameras)",
        type=ParamType.INT,
    ),
    ParamDef(name="CAM_RATE", default=15.0, min=1.0, max=60.0, unit="Hz", description="Camera frame rate"),
    ParamDef(name="CAM_HFOV", default=90.0, min=20.0, max=150.0, unit="deg", description="Horizontal field of view"),
    ParamDef(name="CAM_RANGE", default=15.0, min=2.0, max=100.0, unit="m", description="Camera detection range"),
)
