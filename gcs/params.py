"""PARAM_SET and PARAM_VALUE as PX4 expects them (pure): integers travel bytewise in the float field."""

from __future__ import annotations

import struct
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

_INT_PARAM_TYPES = {
    mavlink.MAV_PARAM_TYPE_UINT8: "<B",
    mavlink.MAV_PARAM_TYPE_INT8: "<b",
    mavlink.MAV_PARAM_TYPE_UINT16: "<H",
    mavlink.MAV_PARAM_TYPE_INT16: "<h",
    mavlink.MAV_PARAM_TYPE_UINT32: "<I",
    mavlink.MAV_PARAM_TYPE_INT32: "<i",
}


def param_set_message(sysid: int, name: str, value: int | float) -> Any:
    """PARAM_SET as PX4 expects it: an int bytewise in the float field as INT32, a float as REAL32."""
    if isinstance(value, int):
        bits = struct.unpack("<f", struct.pack("<i", value))[0]
        return mavlink.MAVLink_param_set_message(sysid, 1, name.encode("ascii"), bits, mavlink.MAV_PARAM_TYPE_INT32)
    return mavlink.MAVLink_param_set_message(sysid, 1, name.encode("ascii"), value, mavlink.MAV_PARAM_TYPE_REAL32)


def param_value(msg: Any) -> float:
    """The number a PARAM_VALUE carries (integer types bytewise)."""
    fmt = _INT_PARAM_TYPES.get(msg.param_type)
    if fmt is None:
        return float(msg.param_value)
    raw = struct.pack("<f", msg.param_value)
    return float(struct.unpack(fmt, raw[: struct.calcsize(fmt)])[0])
