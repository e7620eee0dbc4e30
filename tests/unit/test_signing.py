"""MAVLink 2 signing: the drone's sans-IO signer and verifier against pymavlink's signing (the reference), the
ground station's key file and signing against the drone's, and the drone's gate (MAV_SIGN_CFG, the allow-list,
SETUP_SIGNING, one warning per link and reason)."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink

from gcs.mavlink import signing as gcs_signing
from gcs.mavlink.transport import GcsSocket
from sitl.protocol import framing
from sitl.protocol.signing import (
    ACCEPT_UNSIGNED,
    EPOCH_UNIX_S,
    NEW_STREAM_WINDOW_TICKS,
    REJECTION_TEXT,
    SIGN_ALWAYS,
    SIGN_NON_USB,
    SIGN_OPTIONAL,
    SigningGate,
    SigningKeyError,
    SigningState,
    Verdict,
    key_from_file_bytes,
    key_from_text,
    signature_fields,
    timestamp_from_unix,
)

pytestmark = pytest.mark.timeout(60)

KEY = hashlib.sha256(b"swarm test key").digest()
OTHER_KEY = hashlib.sha256(b"somebody else").digest()
T0 = 348_289_000_000  # a signing timestamp (10 us ticks since 2015): late 2026
NOW_S = EPOCH_UNIX_S + T0 / 100_000  # the wall clock at T0


def _messages() -> list[Any]:
    """Messages packed by both paths of the drone: framing.py's layouts and pymavlink's generic packing."""
    return [
        mavlink.MAVLink_heartbeat_message(2, 12, 81, 0x30000, 3, 3),
        mavlink.MAVLink_global_position_int_message(1234, 473977420, 85455940, 500000, 2500, 10, -20, 5, 9000),
        mavlink.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0),
        mavlink.MAVLink_statustext_message(4, b"Takeoff detected", 0, 0),  # text: pymavlink packs it
        mavlink.MAVLink_param_value_message(b"MAV_SIGN_CFG", 2.0, 6, 300, 290),
    ]


def _pymavlink_signer(key: bytes, link_id: int, timestamp: int, sysid: int = 1, compid: int = 1) -> Any:
    mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    mav.signing.secret_key = key
    mav.signing.link_id = link_id
    mav.signing.timestamp = timestamp
    mav.signing.sign_outgoing = True
    return mav


def _unsigned(msg: Any, seq: int = 0, sysid: int = 1, compid: int = 1) -> bytes:
    layout = framing.layout_of(msg)
    if layout is not None:
        return framing.pack(layout, msg, seq, sysid, compid)
    mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    mav.seq = seq
    return bytes(msg.pack(mav))


def _parse(frame: bytes, key: bytes | None = None) -> Any:
    parser = mavlink.MAVLink(None)
    if key is not None:
        parser.signing.secret_key = key
    messages = parser.parse_buffer(frame)
    assert messages and len(messages) == 1, messages
    return messages[0]


# ---- signatures: byte for byte pymavlink's ----------------------------------------------------------------------
@pytest.mark.parametrize("link_id", [0, 1, 7, 255])
def test_signed_frames_are_byte_identical_to_pymavlinks_for_the_same_key_timestamp_and_link_id(link_id: int) -> None:
    for seq, msg in enumerate(_messages()):
        signer = _pymavlink_signer(KEY, link_id, T0 + seq)
        signer.seq = seq
        reference = bytes(msg.pack(signer))
        state = SigningState(KEY, initial_timestamp=T0 + seq - 1)  # the next frame takes T0 + seq
        (ours,) = state.sign_frames([_unsigned(msg, seq)], link_id, unix_s=0.0)
        assert ours == reference, msg.get_type()
        assert signature_fields(ours) == (link_id, T0 + seq)


def test_pymavlink_with_the_key_accepts_what_the_drone_signs_and_pymavlink_with_another_key_rejects_it() -> None:
    state = SigningState(KEY)
    frames = state.sign_frames([_unsigned(m) for m in _messages()], 1, NOW_S)
    for frame in frames:
        msg = _parse(frame, KEY)
        assert msg.get_type() != "BAD_DATA" and msg._signed, msg
    parser = mavlink.MAVLink(None)
    parser.signing.secret_key = OTHER_KEY
    with pytest.raises(mavlink.MAVError, match="Invalid signature"):
        parser.parse_buffer(frames[0])


def test_the_drones_timestamp_follows_the_wall_clock_and_grows_by_at_least_one_per_frame() -> None:
    state = SigningState(KEY)
    frames = state.sign_frames([_unsigned(m) for m in _messages()], 0, NOW_S)
    stamps = [signature_fields(f)[1] for f in frames]
    assert stamps[0] == timestamp_from_unix(NOW_S) == T0
    assert stamps == list(range(T0, T0 + len(frames)))
    later = state.sign_frames([_unsigned(_messages()[0])], 0, NOW_S + 2.0)
    assert signature_fields(later[0])[1] == T0 + 200_000  # 2 s later on the wall clock, in 10 us ticks


def test_without_a_key_nothing_is_signed() -> None:
    frames = [_unsigned(m) for m in _messages()]
    assert SigningState().sign_frames(frames, 0, NOW_S) is frames


def test_the_fast_parser_reads_signed_frames_as_pymavlinks_parser_without_a_key_does() -> None:
    state = SigningState(KEY)
    msg = _messages()[1]  # GLOBAL_POSITION_INT: a layout the fast parser takes
    (frame,) = state.sign_frames([_unsigned(msg)], 3, NOW_S)
    fast = framing.parse_datagram(frame)
    assert fast is not None and len(fast) == 1
    reference = _parse(frame)
    assert fast[0].to_dict() == reference.to_dict()
    assert bytes(fast[0].get_msgbuf()) == bytes(reference.get_msgbuf()) == frame  # signature kept for the gate
    assert bytes(fast[0].get_payload()) == bytes(reference.get_payload())
    assert fast[0].get_header().incompat_flags == mavlink.MAVLINK_IFLAG_SIGNED


# ---- the verifier: pymavlink-signed frames, wrong keys, replays, unsigned -----------------------------------------
def _signed_by_client(msg: Any, key: bytes = KEY, timestamp: int = T0, link_id: int = 0) -> bytes:
    return bytes(msg.pack(_pymavlink_signer(key, link_id, timestamp, sysid=255, compid=190)))


def _command() -> Any:
    return mavlink.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)


def test_a_frame_pymavlink_signed_with_the_key_is_accepted_and_moves_the_drones_timestamp_up() -> None:
    state = SigningState(KEY, initial_timestamp=T0 - 10)
    frame = _signed_by_client(_command(), timestamp=T0 + 50)
    assert state.check(frame, 76, 255, 190, SIGN_ALWAYS) is Verdict.SIGNED
    assert state.timestamp == T0 + 50
    assert state.counters.signed_in == 1


def test_a_frame_signed_with_another_key_is_rejected_and_counted() -> None:
    state = SigningState(KEY, initial_timestamp=T0)
    frame = _signed_by_client(_command(), key=OTHER_KEY)
    assert state.check(frame, 76, 255, 190, SIGN_ALWAYS) is Verdict.REJECTED_BAD_SIGNATURE
    assert state.counters.bad_signatures == 1


def test_an_altered_frame_is_rejected() -> None:
    frame = bytearray(_signed_by_client(_command()))
    frame[14] ^= 0x01  # a payload bit, CRC fixed up as an attacker would: the signature still fails
    body = bytes(frame[1:-15]) + bytes((mavlink.MAVLink_command_long_message.crc_extra,))
    frame[-15:-13] = framing.crc_x25(body, 0xFFFF).to_bytes(2, "little")
    assert SigningState(KEY).check(bytes(frame), 76, 255, 190, SIGN_ALWAYS) is Verdict.REJECTED_BAD_SIGNATURE


def test_a_replayed_frame_is_rejected_and_so_is_an_older_one_of_the_same_stream() -> None:
    state = SigningState(KEY, initial_timestamp=T0)
    first = _signed_by_client(_command(), timestamp=T0 + 100)
    older = _signed_by_client(_command(), timestamp=T0 + 99)
    newer = _signed_by_client(_command(), timestamp=T0 + 101)
    assert state.check(first, 76, 255, 190, SIGN_ALWAYS) is Verdict.SIGNED
    assert state.check(first, 76, 255, 190, SIGN_ALWAYS) is Verdict.REJECTED_REPLAY
    assert state.check(older, 76, 255, 190, SIGN_ALWAYS) is Verdict.REJECTED_REPLAY
    assert state.check(newer, 76, 255, 190, SIGN_ALWAYS) is Verdict.SIGNED
    assert state.counters.replays == 2
    # the same timestamp on another link id is another stream
    other_link = _signed_by_client(_command(), timestamp=T0 + 100, link_id=1)
    assert state.check(other_link, 76, 255, 190, SIGN_ALWAYS) is Verdict.SIGNED


def test_a_new_stream_more_than_a_minute_behind_the_drones_timestamp_is_a_replay() -> None:
    state = SigningState(KEY, initial_timestamp=T0)
    stale = _signed_by_client(_command(), timestamp=T0 - NEW_STREAM_WINDOW_TICKS - 1)
    recent = _signed_by_client(_command(), timestamp=T0 - NEW_STREAM_WINDOW_TICKS, link_id=2)
    assert state.check(stale, 76, 255, 190, SIGN_ALWAYS) is Verdict.REJECTED_REPLAY
    assert state.check(recent, 76, 255, 190, SIGN_ALWAYS) is Verdict.SIGNED


def test_a_forged_frame_stamped_far_ahead_does_not_lock_the_real_sender_out() -> None:
    """pymavlink records a stream's timestamp before checking the signature; the specification (and this drone)
    move it only for a correct signature, so a forgery cannot make the real sender's frames look like replays."""
    state = SigningState(KEY, initial_timestamp=T0)
    forged = _signed_by_client(_command(), key=OTHER_KEY, timestamp=T0 + 10**9)
    assert state.check(forged, 76, 255, 190, SIGN_ALWAYS) is Verdict.REJECTED_BAD_SIGNATURE
    assert state.timestamp == T0
    assert state.check(_signed_by_client(_command(), timestamp=T0 + 1), 76, 255, 190, SIGN_ALWAYS) is Verdict.SIGNED


@pytest.mark.parametrize("sign_cfg", [SIGN_NON_USB, SIGN_ALWAYS])
def test_unsigned_frames_are_rejected_when_signing_is_required_except_the_allow_list(sign_cfg: int) -> None:
    state = SigningState(KEY)
    command = _unsigned(_command(), sysid=255, compid=190)
    assert state.check(command, 76, 255, 190, sign_cfg) is Verdict.REJECTED_UNSIGNED
    heartbeat = _unsigned(_messages()[0], sysid=255, compid=190)
    assert state.check(heartbeat, 0, 255, 190, sign_cfg) is Verdict.UNSIGNED_ACCEPTED
    for msg_id in (mavlink.MAVLINK_MSG_ID_RADIO_STATUS, mavlink.MAVLINK_MSG_ID_ADSB_VEHICLE):
        assert msg_id in ACCEPT_UNSIGNED
    assert state.counters.rejected_unsigned == 1 and state.counters.unsigned_accepted == 1


def test_with_signing_optional_unsigned_and_wrongly_signed_frames_pass_but_bad_signatures_are_still_counted() -> None:
    state = SigningState(KEY)
    assert state.check(_unsigned(_command()), 76, 255, 190, SIGN_OPTIONAL) is Verdict.UNSIGNED_ACCEPTED
    wrong = _signed_by_client(_command(), key=OTHER_KEY)
    assert state.check(wrong, 76, 255, 190, SIGN_OPTIONAL) is Verdict.UNSIGNED_ACCEPTED
    assert state.counters.bad_signatures == 1


def test_without_a_key_everything_is_accepted() -> None:
    assert SigningState().check(_unsigned(_command()), 76, 255, 190, SIGN_ALWAYS) is Verdict.UNSIGNED_ACCEPTED


# ---- keys -------------------------------------------------------------------------------------------------------
def test_a_passphrase_gives_the_key_mavproxy_and_qgroundcontrol_derive_and_hex_gives_itself() -> None:
    assert key_from_text("correct horse battery staple\n") == hashlib.sha256(b"correct horse battery staple").digest()
    assert key_from_text(KEY.hex().upper() + "\n") == KEY
    assert key_from_file_bytes(KEY + (1234).to_bytes(8, "little")) == KEY  # PX4's mavlink-signing-key.bin


@pytest.mark.parametrize(
    ("content", "reason"),
    [(b"", "empty"), (b"  \n", "empty"), (b"one\ntwo\n", "more than one line"), (b"0" * 64, "all-zero"),
     (b"\xff\xfe" * 3, "neither text")],
)  # fmt: skip
def test_a_key_file_without_a_usable_key_is_one_clear_error_on_both_sides(content: bytes, reason: str) -> None:
    with pytest.raises(SigningKeyError, match=reason):
        key_from_file_bytes(content)
    with pytest.raises(gcs_signing.SigningKeyError, match=reason):
        gcs_signing.key_from_file_bytes(content)


@pytest.mark.parametrize(
    "content", [b"my swarm passphrase\n", KEY.hex().encode(), KEY, KEY + bytes(8), "pässphrase".encode()]
)
def test_the_ground_station_and_the_drone_read_a_key_file_the_same_way(content: bytes, tmp_path: Path) -> None:
    path = tmp_path / "key"
    path.write_bytes(content)
    assert gcs_signing.load_key(path) == key_from_file_bytes(content)


def test_what_the_ground_station_signs_the_drone_accepts_and_the_signatures_are_the_drones_own() -> None:
    link = GcsSocket(signing_key=KEY)
    try:
        frames = [link.pack(_command()) for _ in range(3)]
    finally:
        link.close()
    state = SigningState(KEY)
    for frame in frames:
        assert state.check(frame, 76, 255, 190, SIGN_ALWAYS) is Verdict.SIGNED
        link_id, stamp = signature_fields(frame)
        assert link_id == gcs_signing.GCS_LINK_ID
        # the drone's signer, given the same frame content, key, link id and timestamp, writes the same bytes
        unsigned = _unsigned(_command(), seq=frame[4], sysid=255, compid=190)
        (ours,) = SigningState(KEY, initial_timestamp=stamp - 1).sign_frames([unsigned], link_id, 0.0)
        assert ours == frame


# ---- the gate: what a drone's links let through and say ---------------------------------------------------------
class _Gate:
    def __init__(self, key: bytes | None, sign_cfg: int = SIGN_ALWAYS, armed: bool = False) -> None:
        self.sign_cfg = sign_cfg
        self.armed = armed
        self.state = SigningState(key, initial_timestamp=T0)
        self.gate = SigningGate(self.state, 1, 1, sign_cfg=lambda: self.sign_cfg, armed=lambda: self.armed)

    def admit(self, frame: bytes, link_id: int = 0) -> tuple[bool, list[tuple[int, str]]]:
        return self.gate.admit(_parse(frame), link_id)


def test_the_gate_says_why_it_drops_once_per_link_and_reason_not_once_per_message() -> None:
    gate = _Gate(KEY)
    unsigned = _unsigned(_command(), sysid=255, compid=190)
    first = gate.admit(unsigned)
    assert first == (False, [(mavlink.MAV_SEVERITY_WARNING, REJECTION_TEXT[Verdict.REJECTED_UNSIGNED])])
    assert gate.admit(unsigned) == (False, [])
    assert gate.admit(unsigned, link_id=1)[1] == first[1]  # the other link is told too
    wrong = _signed_by_client(_command(), key=OTHER_KEY)
    assert gate.admit(wrong)[1] == [(mavlink.MAV_SEVERITY_WARNING, REJECTION_TEXT[Verdict.REJECTED_BAD_SIGNATURE])]
    assert gate.admit(_signed_by_client(_command(), key=OTHER_KEY, timestamp=T0 + 1)) == (False, [])
    assert gate.admit(_signed_by_client(_command(), timestamp=T0 + 2)) == (True, [])
    assert all(len(text) <= 50 for text in REJECTION_TEXT.values())  # one STATUSTEXT each, never split


def _setup(key: bytes, timestamp: int = T0 + 500, target: int = 1) -> Any:
    return mavlink.MAVLink_setup_signing_message(target, 1, list(key), timestamp)


def test_setup_signing_installs_a_key_on_a_drone_without_one_and_is_never_handed_to_the_services() -> None:
    gate = _Gate(None)
    admit, texts = gate.admit(_unsigned(_setup(KEY), sysid=255, compid=190))
    assert not admit and gate.state.key == KEY and gate.state.timestamp == T0 + 500
    assert texts == [(mavlink.MAV_SEVERITY_INFO, f"MAVLink signing key {gcs_signing.key_id(KEY)} installed")]
    # from now on unsigned commands are dropped, signed ones pass
    assert not gate.admit(_unsigned(_command(), sysid=255, compid=190))[0]
    assert gate.admit(_signed_by_client(_command(), timestamp=T0 + 501))[0]


def test_setup_signing_for_another_system_is_ignored() -> None:
    gate = _Gate(None)
    assert gate.admit(_unsigned(_setup(KEY, target=7), sysid=255, compid=190)) == (False, [])
    assert gate.state.key is None


def test_setup_signing_must_be_signed_with_the_current_key_to_change_or_clear_it_and_is_refused_when_armed() -> None:
    gate = _Gate(KEY, sign_cfg=SIGN_OPTIONAL)  # even where unsigned messages pass, a key change needs the key
    admit, texts = gate.admit(_unsigned(_setup(OTHER_KEY), sysid=255, compid=190))
    assert not admit and gate.state.key == KEY and "not signed with current key" in texts[0][1]
    gate.armed = True
    _, texts = gate.admit(_signed_by_client(_setup(OTHER_KEY), timestamp=T0 + 1))
    assert gate.state.key == KEY and "disarm first" in texts[0][1]
    # a flood of refused SETUP_SIGNING is answered once, not once per message
    assert gate.admit(_signed_by_client(_setup(OTHER_KEY), timestamp=T0 + 2)) == (False, [])
    assert gate.admit(_unsigned(_setup(OTHER_KEY), sysid=255, compid=190)) == (False, [])
    gate.armed = False
    gate.admit(_signed_by_client(_setup(OTHER_KEY), timestamp=T0 + 3))
    assert gate.state.key == OTHER_KEY
    _, texts = gate.admit(_signed_by_client(_setup(bytes(32), timestamp=0), key=OTHER_KEY, timestamp=T0 + 600))
    assert gate.state.key is None and "off" in texts[0][1]


def test_the_flight_log_keeps_a_signed_packet_as_it_would_have_been_unsigned() -> None:
    for seq, msg in enumerate(_messages()):
        signer = _pymavlink_signer(KEY, 200, T0)
        signer.seq = seq
        signed = bytes(msg.pack(signer))
        assert gcs_signing.without_signature(signed) == _unsigned(msg, seq), msg.get_type()
        unsigned = _unsigned(msg, seq)
        assert gcs_signing.without_signature(unsigned) is unsigned
    assert gcs_signing.without_signature(b"\xfe\x09garbage") == b"\xfe\x09garbage"
