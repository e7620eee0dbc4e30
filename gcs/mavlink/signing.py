"""MAVLink 2 signing on the ground station's side: the key file, and pymavlink's signing set up on its encoder.

The ground station signs every frame it packs with pymavlink's own implementation (``MAVLink.signing``): link id
200 (``GCS_LINK_ID``), timestamps from the wall clock in 10 us units since 2015-01-01 (the signing epoch), at least
one more per frame. pymavlink counts its timestamp up by one per frame from where it was set, which after a long
session falls behind the wall clock, and a drone refuses a new stream more than a minute behind its own timestamp;
so before each frame the timestamp is moved up to the wall clock when it lags (``refresh``).

The key file is read by the same rules as the drone's (sitl/protocol/signing.py, kept separate because the ground
station knows the drones only over MAVLink; tests/unit/test_signing.py checks the two agree): 64 hex digits are the
key; any other one-line text is a passphrase whose SHA-256 is the key, as MAVProxy's ``signing setup`` and
QGroundControl derive it; a 32- or 40-byte binary file (PX4's mavlink-signing-key.bin) holds the key in its first
32 bytes. Frames the ground station relays or forwards (drones' positions, another ground station's commands) keep
their own signatures: they are passed on byte for byte.
"""

from __future__ import annotations

import hashlib
import re
import struct
from pathlib import Path
from typing import Any, Final

from pymavlink.dialects.v20 import common as mavlink

KEY_LEN: Final = 32
EPOCH_UNIX_S: Final = 1_420_070_400  # 2015-01-01 00:00:00 UTC
TICKS_PER_S: Final = 100_000  # 10 us
# The supervisor's link id in its signatures. A drone keeps one timestamp per (link id, system, component) stream, and
# the supervisor is system 255, component 190, as QGroundControl is, which numbers its links from 0 (MAVProxy and
# pymavlink do too): a QGroundControl on the forward port signing with link id 0 would share the supervisor's
# stream, and its frames, stamped from another clock, would look like replays. No client starts at 200.
GCS_LINK_ID: Final = 200
SIGNATURE_LEN: Final = mavlink.MAVLINK_SIGNATURE_BLOCK_LEN
_HEADER_LEN: Final = 10  # MAVLink 2
_HEX_KEY = re.compile(r"[0-9a-fA-F]{64}")
_ZERO_KEY = "the all-zero key means 'no signing' in MAVLink; give another key"


class SigningKeyError(ValueError):
    """No usable key in a key file; the message is one line for the user."""


def key_from_file_bytes(data: bytes) -> bytes:
    """The 32-byte key of a key file's content (see the module docstring)."""
    if len(data) in (KEY_LEN, KEY_LEN + 8) and not data.isascii():
        if data[:KEY_LEN] == bytes(KEY_LEN):
            raise SigningKeyError(_ZERO_KEY)
        return data[:KEY_LEN]
    try:
        text = data.decode("utf-8").strip()
    except UnicodeDecodeError:
        raise SigningKeyError("the key file is neither text nor a 32- or 40-byte binary key") from None
    if not text:
        raise SigningKeyError("the key file is empty (give 64 hex digits or a passphrase)")
    if "\n" in text:
        raise SigningKeyError("the key file holds more than one line (give 64 hex digits or a one-line passphrase)")
    key = bytes.fromhex(text) if _HEX_KEY.fullmatch(text) else hashlib.sha256(text.encode()).digest()
    if key == bytes(KEY_LEN):
        raise SigningKeyError(_ZERO_KEY)
    return key


def load_key(path: Path) -> bytes:
    """The key in the file at ``path``; SigningKeyError with one line when there is none to be had."""
    try:
        data = path.read_bytes()[:4096]
    except OSError as exc:
        raise SigningKeyError(f"cannot read signing key file {path}: {exc.strerror}") from None
    try:
        return key_from_file_bytes(data)
    except SigningKeyError as exc:
        raise SigningKeyError(f"signing key file {path}: {exc}") from None


def key_id(key: bytes) -> str:
    """A name for a key that does not give it away (8 hex digits of its SHA-256), for logs and reports."""
    return hashlib.sha256(key).hexdigest()[:8]


def ticks(unix_s: float) -> int:
    """Signing timestamp of a Unix time: 10 us units since 2015-01-01."""
    return max(0, int((unix_s - EPOCH_UNIX_S) * TICKS_PER_S))


def enable(encoder: Any, key: bytes, unix_s: float, link_id: int = GCS_LINK_ID) -> None:
    """Make a pymavlink ``MAVLink`` encoder sign everything it packs with ``key`` from now on."""
    signing = encoder.signing
    signing.secret_key = key
    signing.link_id = link_id
    signing.timestamp = ticks(unix_s)
    signing.sign_outgoing = True


def refresh(encoder: Any, unix_s: float) -> None:
    """Move a signing encoder's timestamp up to the wall clock if it lags (see the module docstring)."""
    signing = encoder.signing
    signing.timestamp = max(signing.timestamp, ticks(unix_s))


def without_signature(packet: bytes) -> bytes:
    """A signed MAVLink 2 packet as it would have been unsigned (flag cleared, CRC recomputed, the 13 signature
    bytes dropped); any other packet unchanged. Logs keep packets this way, as the signing specification asks
    ("Logging"): a log must not hand whoever reads it a collection of signatures to attack the key with, and a
    flight's log then does not depend on the signatures' wall-clock timestamps."""
    if len(packet) < _HEADER_LEN + 2 + SIGNATURE_LEN or packet[0] != mavlink.PROTOCOL_MARKER_V2:
        return packet
    if not packet[2] & mavlink.MAVLINK_IFLAG_SIGNED or len(packet) != _HEADER_LEN + packet[1] + 2 + SIGNATURE_LEN:
        return packet
    cls = mavlink.mavlink_map.get(packet[7] | packet[8] << 8 | packet[9] << 16)
    if cls is None:
        return packet
    body = bytearray(packet[1 : _HEADER_LEN + packet[1]])
    body[1] &= ~mavlink.MAVLINK_IFLAG_SIGNED
    crc = mavlink.x25crc(bytes(body) + bytes((cls.crc_extra,))).crc
    return packet[:1] + bytes(body) + struct.pack("<H", crc)
