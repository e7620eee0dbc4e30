"""MAVLink 2 message signing, sans-IO: the key, signing of outgoing frames, checking of incoming ones.

A signed frame has bit 0x01 (MAVLINK_IFLAG_SIGNED) set in its incompatibility flags and 13 bytes after the CRC:
the link id (1 byte), a 48-bit timestamp in 10 us units since 2015-01-01 00:00 UTC, and the first 6 bytes of
SHA-256(secret key + header + payload + CRC + link id + timestamp) (mavlink.io, "Message Signing"). The header is
part of the CRC, so signing a packed frame sets the flag and recomputes the CRC before appending the signature.

What a drone does with it follows PX4 (src/modules/mavlink/mavlink_sign_control.cpp and its MAV_SIGN_CFG, which
PX4's current main has since dropped: there a key alone makes signing required, as MAV_SIGN_CFG 2 here):
- with a key, every frame it sends is signed, whatever MAV_SIGN_CFG says;
- MAV_SIGN_CFG 0 accepts unsigned and wrongly signed frames (signing optional); 1 (required except on USB, and a
  simulated drone has only UDP links) and 2 (always required) drop them, except HEARTBEAT, RADIO_STATUS,
  ADSB_VEHICLE and COLLISION, which PX4 always accepts unsigned (radios and traffic receivers cannot sign);
- a correctly signed frame is accepted only if its timestamp is newer than the last one of its stream, a stream
  being one (link id, system id, component id), or, for a stream not heard before, at most one minute behind the
  drone's own timestamp. That is the replay protection.
Two choices go beyond pymavlink's reference code, as the specification asks: a stream's last timestamp, and the
drone's own, move only on a frame whose signature is correct (pymavlink records the stream's timestamp before
checking the signature, so one forged frame with a timestamp far ahead would lock the real sender out); and so a
peer without the key cannot grow the stream table either.

The drone's own timestamp is the wall clock (never the simulated clock: a client stamps its frames with the wall
clock and drops a new stream more than a minute behind its own) and at least one more than the last one used.
The key lives for the process only (a simulated drone has no SD card); SETUP_SIGNING replaces it as PX4 does.
"""

from __future__ import annotations

import hashlib
import re
import struct
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from typing import Final

from pymavlink.dialects.v20 import common as mavlink

from sitl.protocol.core import Identity, MAVLinkMessage, PeerInputError, addressed_to, read_int
from sitl.protocol.framing import IFLAG_SIGNED, SIGNATURE_LEN, crc_x25

KEY_LEN: Final = 32
EPOCH_UNIX_S: Final = 1_420_070_400  # 2015-01-01 00:00:00 UTC, the signing epoch
TICKS_PER_S: Final = 100_000  # timestamp unit: 10 us
NEW_STREAM_WINDOW_TICKS: Final = 6_000_000  # a new stream may start at most one minute behind our timestamp
TIMESTAMP_MAX: Final = (1 << 48) - 1
_FRAME_HEADER_LEN: Final = 10
_CRC: Final = struct.Struct("<H")
_LINK_AND_TIME: Final = struct.Struct("<BQ")  # link id, timestamp (the top two bytes cut off: 48 bits)

# MAV_SIGN_CFG, as PX4's signing support (PX4-Autopilot PR #25284, 2025) added it: MavlinkSignControl::PROTO_SIGN_*.
SIGN_OPTIONAL: Final = 0
SIGN_NON_USB: Final = 1
SIGN_ALWAYS: Final = 2
SIGN_CFG_PARAM: Final = "MAV_SIGN_CFG"

# Accepted unsigned even when signing is required: PX4's allow-list (docs/en/mavlink/message_signing.md).
ACCEPT_UNSIGNED: Final = frozenset(
    {
        mavlink.MAVLINK_MSG_ID_HEARTBEAT,
        mavlink.MAVLINK_MSG_ID_RADIO_STATUS,
        mavlink.MAVLINK_MSG_ID_ADSB_VEHICLE,
        mavlink.MAVLINK_MSG_ID_COLLISION,
    }
)


class SigningKeyError(ValueError):
    """A key file or key text that gives no usable key; the message is one line for the user."""


# ---- keys --------------------------------------------------------------------------------------------------------
_HEX_KEY = re.compile(r"[0-9a-fA-F]{64}")


def key_from_text(text: str) -> bytes:
    """The 32-byte key a key file's text stands for: 64 hex digits are the key itself; any other text is a
    passphrase, and the key is its SHA-256, as MAVProxy's ``signing setup PASSPHRASE`` and QGroundControl's
    signing key field make it, so the same words give the same key everywhere. Surrounding whitespace (a final
    newline) is not part of it."""
    stripped = text.strip()
    if not stripped:
        raise SigningKeyError("the key file is empty (give 64 hex digits or a passphrase)")
    if "\n" in stripped:
        raise SigningKeyError("the key file holds more than one line (give 64 hex digits or a one-line passphrase)")
    key = bytes.fromhex(stripped) if _HEX_KEY.fullmatch(stripped) else hashlib.sha256(stripped.encode()).digest()
    if key == bytes(KEY_LEN):
        raise SigningKeyError("the all-zero key means 'no signing' in MAVLink; give another key")
    return key


def key_from_file_bytes(data: bytes) -> bytes:
    """A key file's content: text (see ``key_from_text``), or PX4's binary mavlink-signing-key.bin (32 key bytes,
    then an 8-byte timestamp, which is ignored here)."""
    if len(data) in (KEY_LEN, KEY_LEN + 8):
        try:
            data.decode("ascii")
        except UnicodeDecodeError:
            key = data[:KEY_LEN]
            if key == bytes(KEY_LEN):
                raise SigningKeyError("the all-zero key means 'no signing' in MAVLink; give another key") from None
            return key
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise SigningKeyError("the key file is neither text nor a 32- or 40-byte binary key") from None
    return key_from_text(text)


def load_key(path: str) -> bytes:
    """The key in the file at ``path``; SigningKeyError with one line when there is none to be had."""
    try:
        with open(path, "rb") as f:
            data = f.read(4096)
    except OSError as exc:
        raise SigningKeyError(f"cannot read signing key file {path}: {exc.strerror}") from None
    try:
        return key_from_file_bytes(data)
    except SigningKeyError as exc:
        raise SigningKeyError(f"signing key file {path}: {exc}") from None


def key_id(key: bytes) -> str:
    """A short name for a key that does not reveal it (the first 8 hex digits of its SHA-256): what logs and
    reports show, so that two sides can see they hold the same key."""
    return hashlib.sha256(key).hexdigest()[:8]


# ---- timestamps and frames ---------------------------------------------------------------------------------------
def timestamp_from_unix(unix_s: float) -> int:
    """Signing ticks (10 us since 2015-01-01) of a Unix time; 0 before the epoch."""
    return max(0, min(TIMESTAMP_MAX, int((unix_s - EPOCH_UNIX_S) * TICKS_PER_S)))


def frame_signature(key: bytes, signed_part: bytes) -> bytes:
    """The 6 signature bytes of a frame whose first ``len - 6`` bytes (flagged header to timestamp) are given."""
    return hashlib.sha256(key + signed_part).digest()[:6]


def append_signature(frame: bytes, key: bytes, link_id: int, timestamp: int) -> bytes:
    """A MAVLink 2 frame packed with the signed flag set, with its 13-byte signature block appended."""
    head = frame + _LINK_AND_TIME.pack(link_id, timestamp)[:7]
    return head + frame_signature(key, head)


def flag_signed(frame: bytes) -> bytes | None:
    """An unsigned MAVLink 2 frame with the signed flag set and its CRC recomputed (the flag is under the CRC):
    for frames packed by a packer that knows nothing of signing. None for a frame that is no MAVLink 2 frame of
    a message this dialect knows (its CRC extra is needed)."""
    if len(frame) < _FRAME_HEADER_LEN + 2 or frame[0] != mavlink.PROTOCOL_MARKER_V2:
        return None
    cls = mavlink.mavlink_map.get(frame[7] | frame[8] << 8 | frame[9] << 16)
    if cls is None:
        return None
    body = bytearray(frame[1:-2])
    body[1] |= IFLAG_SIGNED
    checksum = crc_x25(bytes(body) + bytes((cls.crc_extra,)), 0xFFFF)
    return frame[:1] + bytes(body) + _CRC.pack(checksum)


def signature_fields(frame: bytes) -> tuple[int, int]:
    """(link id, timestamp) of a signed frame."""
    link_id, low, high = struct.unpack_from("<BIH", frame, len(frame) - SIGNATURE_LEN)
    return link_id, low | high << 32


def is_signed(frame: bytes) -> bool:
    return (
        len(frame) >= _FRAME_HEADER_LEN + 2 + SIGNATURE_LEN
        and frame[0] == mavlink.PROTOCOL_MARKER_V2
        and bool(frame[2] & IFLAG_SIGNED)
    )


# ---- the drone's signing state -----------------------------------------------------------------------------------
class Verdict(Enum):
    """What became of one received frame."""

    SIGNED = "signed"  # correct signature, fresh timestamp
    UNSIGNED_ACCEPTED = "unsigned accepted"  # unsigned or wrongly signed, but signing is not required for it
    REJECTED_UNSIGNED = "unsigned"
    REJECTED_BAD_SIGNATURE = "bad signature"  # wrong key, or altered on the way
    REJECTED_REPLAY = "replay"  # correct signature, old timestamp

    @property
    def accepted(self) -> bool:
        return self in (Verdict.SIGNED, Verdict.UNSIGNED_ACCEPTED)


# What a link says once when it first drops a frame for each reason (STATUSTEXT, at most 50 characters each).
REJECTION_TEXT: Final = {
    Verdict.REJECTED_UNSIGNED: "MAVLink signing required: unsigned msgs dropped",
    Verdict.REJECTED_BAD_SIGNATURE: "MAVLink signature invalid (wrong key): dropped",
    Verdict.REJECTED_REPLAY: "MAVLink signed msg replayed: dropped",
}


@dataclass(frozen=True, slots=True, kw_only=True)
class SetupResult:
    """What a SETUP_SIGNING did, and the line the drone says about it."""

    applied: bool
    text: str


@dataclass(slots=True)
class SigningCounters:
    """Frames by fate, for the drone's closing line: bad signatures and replays are counted whether or not
    MAV_SIGN_CFG drops them; ``rejected_unsigned`` counts the unsigned frames dropped."""

    signed_in: int = 0
    unsigned_accepted: int = 0
    rejected_unsigned: int = 0
    bad_signatures: int = 0
    replays: int = 0
    signed_out: int = 0


class SigningState:
    """One drone's key, timestamp and incoming streams, shared by its links (as PX4 keeps one key for all).

    Nothing here reads a clock or a socket: ``sign`` and ``sign_frames`` are given the wall-clock time."""

    def __init__(self, key: bytes | None = None, *, initial_timestamp: int = 0) -> None:
        if key is not None and len(key) != KEY_LEN:
            raise ValueError(f"a signing key is {KEY_LEN} bytes, got {len(key)}")
        self.key = key
        self.timestamp = initial_timestamp
        self._streams: dict[tuple[int, int, int], int] = {}
        self.counters = SigningCounters()

    @property
    def active(self) -> bool:
        return self.key is not None

    def next_timestamp(self, unix_s: float) -> int:
        """The timestamp of the next frame sent: the wall clock, and at least one more than the last."""
        self.timestamp = max(self.timestamp + 1, timestamp_from_unix(unix_s))
        return self.timestamp

    def sign(self, flagged_frame: bytes, link_id: int, unix_s: float) -> bytes:
        """A frame packed with the signed flag set, signed with our key (which must be set)."""
        key = self.key
        assert key is not None, "sign() without a key"
        self.counters.signed_out += 1
        return append_signature(flagged_frame, key, link_id, self.next_timestamp(unix_s))

    def sign_frames(self, frames: list[bytes], link_id: int, unix_s: float) -> list[bytes]:
        """Unsigned MAVLink 2 frames, each signed for ``link_id`` (flag set, CRC recomputed, signature appended);
        the frames unchanged without a key. Re-CRCing a packed frame costs a fraction of a microsecond, a small
        part of the SHA-256, and keeps the packers (framing.py's and pymavlink's) unaware of signing."""
        if self.key is None:
            return frames
        out = []
        for frame in frames:
            flagged = flag_signed(frame)
            out.append(self.sign(flagged, link_id, unix_s) if flagged is not None else frame)
        return out

    def check(self, frame: bytes, msg_id: int, sysid: int, compid: int, sign_cfg: int) -> Verdict:
        """The verdict on one received frame (its full bytes, signature block included) under MAV_SIGN_CFG
        ``sign_cfg``; counts it."""
        if self.key is None:
            return Verdict.UNSIGNED_ACCEPTED  # no key: nothing to check against, everything is accepted (PX4)
        verdict = self._verify(frame, sysid, compid) if is_signed(frame) else Verdict.REJECTED_UNSIGNED
        if verdict is Verdict.SIGNED:
            self.counters.signed_in += 1
            return verdict
        if verdict is Verdict.REJECTED_BAD_SIGNATURE:
            self.counters.bad_signatures += 1
        elif verdict is Verdict.REJECTED_REPLAY:
            self.counters.replays += 1
        if sign_cfg == SIGN_OPTIONAL or msg_id in ACCEPT_UNSIGNED:
            self.counters.unsigned_accepted += 1
            return Verdict.UNSIGNED_ACCEPTED
        if verdict is Verdict.REJECTED_UNSIGNED:
            self.counters.rejected_unsigned += 1
        return verdict

    def _verify(self, frame: bytes, sysid: int, compid: int) -> Verdict:
        key = self.key
        assert key is not None
        if frame_signature(key, frame[:-6]) != frame[-6:]:
            return Verdict.REJECTED_BAD_SIGNATURE
        link_id, timestamp = signature_fields(frame)
        stream = (link_id, sysid, compid)
        last = self._streams.get(stream)
        if last is not None:
            if timestamp <= last:
                return Verdict.REJECTED_REPLAY
        elif timestamp + NEW_STREAM_WINDOW_TICKS < self.timestamp:
            return Verdict.REJECTED_REPLAY
        self._streams[stream] = timestamp
        self.timestamp = max(self.timestamp, timestamp)
        return Verdict.SIGNED

    def setup(self, secret_key: bytes, initial_timestamp: int, *, signed: bool, armed: bool) -> SetupResult:
        """SETUP_SIGNING as PX4 applies it: refused while armed; a drone with a key takes a new key (or the
        all-zero key and timestamp, which turns signing off) only from a message signed with the current one;
        a drone without a key takes the first it is given. The new key's streams start afresh."""
        blank = secret_key == bytes(KEY_LEN) and initial_timestamp == 0
        if len(secret_key) != KEY_LEN:
            return SetupResult(applied=False, text="SETUP_SIGNING refused: key is not 32 bytes")
        if armed:
            return SetupResult(applied=False, text="SETUP_SIGNING refused: disarm first")
        if self.key is not None and not signed:
            return SetupResult(applied=False, text="SETUP_SIGNING refused: not signed with current key")
        if blank:
            if self.key is None:
                return SetupResult(applied=False, text="MAVLink signing already off")
            self.key = None
            self._streams.clear()
            return SetupResult(applied=True, text="MAVLink signing off (key cleared)")
        self.key = bytes(secret_key)
        self.timestamp = max(self.timestamp, min(initial_timestamp, TIMESTAMP_MAX))
        self._streams.clear()
        return SetupResult(applied=True, text=f"MAVLink signing key {key_id(self.key)} installed")


# ---- one drone's gate: the verdict on each received message, SETUP_SIGNING, the warnings -------------------------
class SigningGate:
    """What a drone's links let through. ``admit`` takes each decoded message (its buffer holds the frame as it
    arrived, signature included) and says whether the services may see it, and what the link should say about
    it: one STATUSTEXT per link the first time it drops a message for each reason, and the outcome of a
    SETUP_SIGNING, a refusal again once per link and reason (not one per message: a flooding peer must not make
    the drone flood back); a new key resets what was said. The drone's services never see SETUP_SIGNING, and the
    key never appears in a parameter or a log."""

    def __init__(
        self, state: SigningState, identity_sysid: int, identity_compid: int, *, sign_cfg: Callable[[], int],
        armed: Callable[[], bool],
    ) -> None:  # fmt: skip
        self.state = state
        self._sysid = identity_sysid
        self._compid = identity_compid
        self._sign_cfg = sign_cfg
        self._armed = armed
        self._said: set[tuple[int, str]] = set()  # (link id, warning) said once already

    def admit(self, msg: MAVLinkMessage, link_id: int) -> tuple[bool, list[tuple[int, str]]]:
        """(deliver to the services?, [(severity, text) for the link to send])."""
        try:
            msg_id = int(msg.get_msgId())
            if self.state.key is None and msg_id != mavlink.MAVLINK_MSG_ID_SETUP_SIGNING:
                return True, []  # no key: nothing to check (the common case costs one comparison)
            frame = bytes(msg.get_msgbuf())
            sysid, compid = int(msg.get_srcSystem()), int(msg.get_srcComponent())
        except (AttributeError, TypeError, ValueError):
            return False, []
        verdict = self.state.check(frame, msg_id, sysid, compid, self._sign_cfg())
        if not verdict.accepted:
            return False, self._warn_once(link_id, REJECTION_TEXT[verdict])
        if msg_id == mavlink.MAVLINK_MSG_ID_SETUP_SIGNING:
            return False, self._setup(msg, link_id, signed=verdict is Verdict.SIGNED)
        return True, []

    def _warn_once(self, link_id: int, text: str) -> list[tuple[int, str]]:
        if (link_id, text) in self._said:
            return []
        self._said.add((link_id, text))
        return [(mavlink.MAV_SEVERITY_WARNING, text)]

    def _setup(self, msg: MAVLinkMessage, link_id: int, *, signed: bool) -> list[tuple[int, str]]:
        try:
            if not addressed_to(msg, Identity(sysid=self._sysid, compid=self._compid)):
                return []
            key = bytes(int(b) & 0xFF for b in msg.secret_key)
            initial = read_int(msg, "initial_timestamp", lo=0, hi=2**64 - 1)
        except (PeerInputError, TypeError, ValueError):
            return self._warn_once(link_id, "SETUP_SIGNING refused: malformed")
        result = self.state.setup(key, initial, signed=signed, armed=self._armed())
        if not result.applied:
            return self._warn_once(link_id, result.text)
        self._said.clear()  # a new key (or none): say again why anything is dropped
        return [(mavlink.MAV_SEVERITY_INFO, result.text)]
