"""The parameter service: list pacing, reads, sets, PX4 bytewise INT32 encoding and refusals."""

from __future__ import annotations

import struct

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl.params import ParamDef, ParamStore, ParamType
from sitl.protocol.core import Identity, MAVLinkMessage
from sitl.protocol.params import PARAM_LIST_BURST, ParamService, decode_bits, encode_value
from sitl.protocol.testing import Wire, of_type

SYSID = 1
REAL32 = mavlink.MAV_PARAM_TYPE_REAL32
INT32 = mavlink.MAV_PARAM_TYPE_INT32


def table() -> ParamStore:
    defs = [
        ParamDef(name="MIS_TAKEOFF_ALT", default=2.5, min=0.5, max=100.0, unit="m", description="takeoff"),
        ParamDef(name="RTL_RETURN_ALT", default=30.0, min=0.0, max=150.0, unit="m", description="rtl"),
        ParamDef(name="COM_ARM_WO_GPS", default=0, min=0, max=1, unit="", description="gps", type=ParamType.INT),
        ParamDef(
            name="SYS_WIDE_INT", default=0, min=-(2**31), max=2**31 - 1, unit="", description="", type=ParamType.INT
        ),
    ]
    defs += [
        ParamDef(name=f"TEST_P{i:03d}", default=float(i), min=0, max=1000, unit="", description="") for i in range(60)
    ]
    return ParamStore(defs)


class Rig:
    def __init__(self) -> None:
        self.store = table()
        self.service = ParamService(Identity(sysid=SYSID), self.store)
        self.up = Wire(245, 190)
        self.down = Wire(SYSID, 1)
        self.now_s = 0.0

    def send(self, msg: MAVLinkMessage) -> list[MAVLinkMessage]:
        return self.down.carry(self.service.handle(self.up(msg), self.now_s))

    def poll(self, dt_s: float = 0.01) -> list[MAVLinkMessage]:
        self.now_s += dt_s
        return self.down.carry(self.service.poll(self.now_s))


def int_bits_as_float(value: int) -> float:
    return struct.unpack("<f", struct.pack("<i", value))[0]


def raw_value_bits(msg: MAVLinkMessage) -> int:
    """The exact 4 bytes of PARAM_VALUE.param_value as received."""
    payload = bytes(msg.get_msgbuf()[10:])
    return struct.unpack("<I", (payload + bytes(4))[:4])[0]


# ---- list --------------------------------------------------------------------------------------------------
def test_request_list_streams_every_parameter_once_in_index_order_and_paced() -> None:
    # GIVEN 64 parameters  WHEN a client requests the list
    rig = Rig()
    assert rig.send(mavlink.MAVLink_param_request_list_message(SYSID, 1)) == []
    # THEN polls deliver them, never more than a burst per poll
    received: list[MAVLinkMessage] = []
    for _ in range(100):
        batch = rig.poll()
        assert len(batch) <= PARAM_LIST_BURST
        received += batch
    assert [m.param_index for m in received] == list(range(len(rig.store)))
    assert {m.param_count for m in received} == {len(rig.store)}
    assert received[0].param_id == "MIS_TAKEOFF_ALT"
    assert not rig.service.listing


def test_list_rate_is_bounded_in_simulation_time() -> None:
    # GIVEN a list request  WHEN the shell polls very often  THEN no more than the configured rate comes out
    rig = Rig()
    rig.send(mavlink.MAVLink_param_request_list_message(SYSID, 1))
    count = sum(len(rig.poll(0.0005)) for _ in range(40))  # 20 ms of simulated time
    assert count <= PARAM_LIST_BURST + 0.02 * 500 + 1


def test_a_new_list_request_restarts_from_the_beginning() -> None:
    rig = Rig()
    rig.send(mavlink.MAVLink_param_request_list_message(SYSID, 1))
    first = rig.poll()
    rig.send(mavlink.MAVLink_param_request_list_message(SYSID, 0))
    second = rig.poll()
    assert first[0].param_index == second[0].param_index == 0


def test_hash_check_set_stops_the_stream() -> None:
    rig = Rig()
    rig.send(mavlink.MAVLink_param_request_list_message(SYSID, 1))
    rig.poll()
    rig.send(mavlink.MAVLink_param_set_message(SYSID, 1, b"_HASH_CHECK", 0.0, REAL32))
    assert rig.poll(1.0) == []


def test_list_request_for_another_system_is_ignored() -> None:
    rig = Rig()
    rig.send(mavlink.MAVLink_param_request_list_message(9, 1))
    assert rig.poll(1.0) == []


# ---- read --------------------------------------------------------------------------------------------------
def test_read_by_name_with_index_minus_one() -> None:
    rig = Rig()
    (value,) = rig.send(mavlink.MAVLink_param_request_read_message(SYSID, 1, b"RTL_RETURN_ALT", -1))
    assert (value.param_id, value.param_value, value.param_type, value.param_index) == (
        "RTL_RETURN_ALT",
        30.0,
        REAL32,
        1,
    )


def test_read_by_index() -> None:
    rig = Rig()
    (value,) = rig.send(mavlink.MAVLink_param_request_read_message(SYSID, 1, b"", 2))
    assert value.param_id == "COM_ARM_WO_GPS"
    assert value.param_type == INT32


def test_unknown_name_gets_no_value_only_a_statustext() -> None:
    # GIVEN a client asking for a parameter PX4 has but we do not  THEN no PARAM_VALUE (it times out, as on PX4)
    rig = Rig()
    out = rig.send(mavlink.MAVLink_param_request_read_message(SYSID, 1, b"SYS_HITL", -1))
    assert of_type(out, "PARAM_VALUE") == []
    assert of_type(out, "STATUSTEXT")[0].text == "[pm] unknown param: SYS_HITL"


def test_index_out_of_range_gets_a_statustext() -> None:
    rig = Rig()
    out = rig.send(mavlink.MAVLink_param_request_read_message(SYSID, 1, b"", 999))
    assert [m.get_type() for m in out] == ["STATUSTEXT"]


# ---- set ---------------------------------------------------------------------------------------------------
def test_set_float_is_echoed_with_value_and_type() -> None:
    rig = Rig()
    (echo,) = rig.send(mavlink.MAVLink_param_set_message(SYSID, 1, b"MIS_TAKEOFF_ALT", 5.0, REAL32))
    assert (echo.param_id, echo.param_value, echo.param_type) == ("MIS_TAKEOFF_ALT", 5.0, REAL32)
    assert rig.store["MIS_TAKEOFF_ALT"] == 5.0


def test_set_int_bytewise_as_mavsdk_sends_it() -> None:
    # GIVEN MAVSDK setting an INT32 to 1: the int's bytes in the float field
    rig = Rig()
    (echo,) = rig.send(mavlink.MAVLink_param_set_message(SYSID, 1, b"COM_ARM_WO_GPS", int_bits_as_float(1), INT32))
    # THEN stored as 1 and echoed bytewise with type INT32
    assert rig.store["COM_ARM_WO_GPS"] == 1
    assert echo.param_type == INT32
    assert raw_value_bits(echo) == 1


def test_set_int_sent_as_a_plain_float_is_understood() -> None:
    # GIVEN a pymavlink script sending param_set_send("COM_ARM_WO_GPS", 1, INT32) (the float 1.0, not its bytes)
    rig = Rig()
    (echo,) = rig.send(mavlink.MAVLink_param_set_message(SYSID, 1, b"COM_ARM_WO_GPS", 1.0, INT32))
    assert rig.store["COM_ARM_WO_GPS"] == 1
    assert raw_value_bits(echo) == 1


@pytest.mark.parametrize("value", [-5_000_000, -1, 2_139_095_041, -(2**31), 2**31 - 1, 0, 123456])
def test_int32_values_survive_the_wire_bit_exactly(value: int) -> None:
    # GIVEN integers whose bit pattern is a float32 signalling NaN (the first and third) or an extreme
    rig = Rig()
    payload = mavlink.MAVLink_param_set_message(SYSID, 1, b"SYS_WIDE_INT", 0.0, INT32)
    # Pack by hand so the client side does not route the bits through a Python float either.
    payload.pack = lambda mav, force_mavlink1=False: payload._pack(
        mav, payload.crc_extra, struct.pack("<iBB16sB", value, SYSID, 1, b"SYS_WIDE_INT", INT32)
    )
    (echo,) = rig.send(payload)
    # THEN stored exactly and echoed with exactly the same bits
    assert rig.store["SYS_WIDE_INT"] == value
    assert raw_value_bits(echo) == value & 0xFFFFFFFF


def test_refused_set_leaves_the_store_unchanged_and_echoes_the_current_value() -> None:
    # GIVEN a value outside the declared range
    rig = Rig()
    out = rig.send(mavlink.MAVLink_param_set_message(SYSID, 1, b"MIS_TAKEOFF_ALT", 500.0, REAL32))
    # THEN the store is unchanged, the echo carries the old value (MAVSDK then reports failure) and a reason
    assert rig.store["MIS_TAKEOFF_ALT"] == 2.5
    assert [m.get_type() for m in out] == ["PARAM_VALUE", "STATUSTEXT"]
    assert out[0].param_value == 2.5
    assert "MIS_TAKEOFF_ALT" in out[1].text


@pytest.mark.parametrize("value", [float("nan"), float("inf")])
def test_non_finite_set_is_refused(value: float) -> None:
    rig = Rig()
    out = rig.send(mavlink.MAVLink_param_set_message(SYSID, 1, b"RTL_RETURN_ALT", value, REAL32))
    assert rig.store["RTL_RETURN_ALT"] == 30.0
    assert out[0].param_value == 30.0


def test_set_of_an_unknown_name_changes_nothing_and_says_so() -> None:
    rig = Rig()
    out = rig.send(mavlink.MAVLink_param_set_message(SYSID, 1, b"NOPE", 1.0, REAL32))
    assert [m.get_type() for m in out] == ["STATUSTEXT"]


def test_set_for_another_system_is_ignored() -> None:
    rig = Rig()
    assert rig.send(mavlink.MAVLink_param_set_message(4, 1, b"MIS_TAKEOFF_ALT", 5.0, REAL32)) == []
    assert rig.store["MIS_TAKEOFF_ALT"] == 2.5


def test_malformed_set_built_in_code_is_ignored() -> None:
    rig = Rig()
    bad = mavlink.MAVLink_param_set_message(SYSID, 1, b"MIS_TAKEOFF_ALT", 5.0, REAL32)
    bad.param_type = "REAL32"
    assert rig.service.handle(bad, 0.0) == []
    assert rig.store["MIS_TAKEOFF_ALT"] == 2.5


# ---- encoding helpers --------------------------------------------------------------------------------------
def test_bytewise_encoding_round_trip() -> None:
    bits, mav_type = encode_value(-3.0, ParamType.INT)
    assert mav_type == INT32 and decode_bits(bits, INT32) == -3.0
    bits, mav_type = encode_value(2.5, ParamType.FLOAT)
    assert mav_type == REAL32 and decode_bits(bits, REAL32) == 2.5
    assert decode_bits(0xFF, mavlink.MAV_PARAM_TYPE_INT8) == -1.0
    assert decode_bits(0xFF, mavlink.MAV_PARAM_TYPE_UINT8) == 255.0
