"""The MAVLink signing parameter (sitl/protocol/signing.py), with PX4's name, values and default."""

from __future__ import annotations

from sitl.params import ParamDef, ParamType
from sitl.protocol.signing import SIGN_ALWAYS, SIGN_CFG_PARAM, SIGN_OPTIONAL

SIGNING_PARAMS: tuple[ParamDef, ...] = (
    ParamDef(
        name=SIGN_CFG_PARAM,
        default=SIGN_OPTIONAL,
        min=SIGN_OPTIONAL,
        max=SIGN_ALWAYS,
        unit="",
        type=ParamType.INT,
        description="MAVLink signing with a key: 0 optional (unsigned accepted), 1 required except on USB (every "
        "link here is UDP), 2 always required; HEARTBEAT, RADIO_STATUS, ADSB_VEHICLE, COLLISION pass unsigned",
    ),
)
