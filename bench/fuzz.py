"""Fuzzing in flight: hostile MAVLink into a hovering drone, which must not crash, print a traceback or fall silent.

The tool starts a real ``sitl`` drone (paced, in real time: lockstep needs a swarm supervisor to open the barrier) or
attaches to a running one, takes off and hovers through pymavlink on the drone's API link as any client would, then
sends it ``--frames`` frames from a seeded generator at ``--rate`` frames a second on the same link:

- well-formed MAVLink 2 frames (CRC extra right, packed by pymavlink) of every message of the common dialect, with
  hostile field values: NaN, +-inf, -0, the float32 extremes, denormals, the extremes of every integer type, random
  values, valid enum values, empty, random, non-ASCII and unterminated strings, real parameter names, random arrays,
  and every target (the drone's own system, 0 broadcast, other systems; every component) and source address;
- valid MAVLink 1 frames, signed MAVLink 2 frames with a random signature, several frames in one datagram with a
  broken one among them;
- broken frames: a wrong CRC, a wrong length byte, truncated frames, frames split over two datagrams, raw random
  bytes (some starting with a MAVLink magic byte).

``--commands-to-drone no`` (mode a): nothing the drone acts on is addressed to it. Every message the drone handles
(the union of its services' ``handles``) that carries a target goes to another system, except the read-only
requests listed in ``READ_ONLY_REQUESTS`` (PARAM_REQUEST_READ, a mission download...), which the drone only answers;
neighbour reports (GLOBAL_POSITION_INT from another system), the one untargeted message that can move a drone, lie
at least ``NEIGHBOUR_KEEP_AWAY_DEG`` from it. The hovering drone must stay within ``HOVER_TOLERANCE_M``.
``--commands-to-drone yes`` (mode b): anything goes, commands to the drone included (it may land, disarm, change
mode...). In both modes the drone must stay up, answer and log no traceback.

The report: frames sent by kind and by message, datagrams, the drone's HEARTBEAT rate and longest gap during the
run, a PARAM_REQUEST_READ and a COMMAND_LONG round trip afterwards, the largest horizontal and vertical distance from
the hover point (the true position from the shared world when the tool started the drone, else LOCAL_POSITION_NED),
and whether the drone's log holds a traceback. Exit code 0 when every check of the mode passed, 1 otherwise, 2 for
bad arguments.

    python bench/fuzz.py --frames 1000000 --seed 1 --commands-to-drone no --rate 2000
    python bench/fuzz.py --attach 127.0.0.1:14580 --listen 14540 --frames 100000 --commands-to-drone yes
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import importlib
import itertools
import json
import math
import os
import pkgutil
import random
import signal
import socket
import struct
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import IO, Any, Final

from pymavlink import mavutil
from pymavlink.dialects.v10 import common as mavlink1
from pymavlink.dialects.v20 import common as mavlink

import sitl.protocol
from sitl.autopilot.vehicle_api import Arm, LandedState
from sitl.drone.param_table import build_param_store
from sitl.drone.sim_vehicle_api import SimVehicleApi
from sitl.process.ports import MAX_INSTANCE, InstancePorts, instance_ports
from sitl.protocol import Identity, LinkServices
from sitl.protocol.framing import crc_x25, parse_datagram
from sitl.protocol.neighbours import NeighbourTable
from sitl.world.shared import ALT, LAT, LON, VALID, SharedWorld
from tests.closed_loop.flight import make_sim

LOOPBACK: Final = "127.0.0.1"
# With --port-base B the drone's ports are set explicitly, PX4 SITL's numbers for B (B may lie beyond the instances):
API_REMOTE_BASE_PORT: Final = 14540  # it streams to 14540+B
API_BIND_BASE_PORT: Final = 14580  # and listens on 14580+B
GCS_BIND_BASE_PORT: Final = 18570  # and its ground-station link on 18570+B
CLIENT_SYSID, CLIENT_COMPID = 255, 190  # a ground station, as QGroundControl identifies itself
PX4_AUTO_LOITER: Final = 50593792  # custom_mode of AUTO.LOITER (Hold)
HOVER_TOLERANCE_M: Final = 0.5  # mode (a): the hovering drone stays this close to its hover point
NEIGHBOUR_KEEP_AWAY_DEG: Final = 1.0  # mode (a): fuzzed neighbour reports lie at least this far from the drone
HOVER_SETTLE_S: Final = 4.0  # after reaching Hold, before the hover point is taken (the takeoff overshoot decays)
HOVER_POINT_S: Final = 1.0  # the hover point is the mean position over this long
AFTER_SETTLE_S: Final = 2.0  # drift is still watched this long after the last frame
ROUND_TRIP_TRIES: Final = 5
ROUND_TRIP_TIMEOUT_S: Final = 1.0
MAX_HEARTBEAT_GAP_S: Final = 3.0  # MAVSDK calls a system lost after 3 s without a heartbeat
READY_TIMEOUT_S: Final = 40.0
TAKEOFF_TIMEOUT_S: Final = 60.0
STOP_GRACE_S: Final = 10.0
EARTH_RADIUS_M: Final = 6_371_000.0
PR_SET_PDEATHSIG: Final = 1
SEND_CHUNK: Final = 64  # frames sent between two looks at the drone's telemetry

FLOAT32_MAX: Final = 3.4028234663852886e38
FLOAT32_MIN_NORMAL: Final = 1.1754943508222875e-38
FLOAT32_DENORMAL: Final = 1.401298464324817e-45
HOSTILE_FLOATS: Final = (
    math.nan, math.inf, -math.inf, 0.0, -0.0, 1.0, -1.0, FLOAT32_MAX, -FLOAT32_MAX,
    FLOAT32_MIN_NORMAL, FLOAT32_DENORMAL, -FLOAT32_DENORMAL, 16777217.0, 1e-7, 1e7,
)  # fmt: skip
HOSTILE_DOUBLES: Final = (*HOSTILE_FLOATS, sys.float_info.max, -sys.float_info.max, 5e-324, 2.0**53 + 1)
INT_RANGES: Final[dict[str, tuple[int, int]]] = {
    "uint8_t": (0, 0xFF),
    "int8_t": (-0x80, 0x7F),
    "uint16_t": (0, 0xFFFF),
    "int16_t": (-0x8000, 0x7FFF),
    "uint32_t": (0, 0xFFFF_FFFF),
    "int32_t": (-0x8000_0000, 0x7FFF_FFFF),
    "uint64_t": (0, 0xFFFF_FFFF_FFFF_FFFF),
    "int64_t": (-0x8000_0000_0000_0000, 0x7FFF_FFFF_FFFF_FFFF),
}
SYSTEM_TARGET_FIELDS: Final = frozenset({"target_system", "target"})
COMPONENT_TARGET_FIELDS: Final = frozenset({"target_component"})

# Messages the drone acts on only by answering: mode (a) may address them to it.
READ_ONLY_REQUESTS: Final = frozenset(
    {
        mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_READ,
        mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_LIST,
        mavlink.MAVLINK_MSG_ID_MISSION_REQUEST_LIST,
        mavlink.MAVLINK_MSG_ID_MISSION_REQUEST_INT,
        mavlink.MAVLINK_MSG_ID_MISSION_REQUEST,
        mavlink.MAVLINK_MSG_ID_PING,
        mavlink.MAVLINK_MSG_ID_TIMESYNC,
    }
)
# A simulated dead radio is, by design, a drone that stops answering: the fuzzer never enables failure injection.
NEVER_SET_PARAMS: Final = frozenset({"SYS_FAILURE_EN"})
# Taken by the link's signing gate before any service sees it (sitl/protocol/signing.py).
GATE_MESSAGES: Final = frozenset({mavlink.MAVLINK_MSG_ID_SETUP_SIGNING})
# Never addressed to the drone, even in mode b: a key from SETUP_SIGNING makes the drone require signing, and an
# unsigned client, this tool's included, is then refused by design (as by PX4).
NEVER_TO_DRONE: Final = frozenset({mavlink.MAVLINK_MSG_ID_SETUP_SIGNING})

# Kinds of frame and their weights: mostly well-formed messages, the rest every way a frame can be broken.
KIND_WEIGHTS: Final[dict[str, float]] = {
    "mavlink2": 0.55,
    "mavlink1": 0.08,
    "signed": 0.04,
    "glued": 0.05,
    "bad_crc": 0.06,
    "bad_length": 0.05,
    "truncated": 0.06,
    "split": 0.05,
    "random_bytes": 0.06,
}
DRONE_VOCABULARY_SHARE: Final = 0.3  # of the well-formed messages, this share is of a type the drone handles


def drone_handled_ids() -> frozenset[int]:
    """Every message id the drone acts on: the union of the ``handles`` of the service classes in sitl.protocol,
    read from the code so that a service added later is fuzzed (and protected) too, and what the link's signing
    gate takes before them."""
    ids: set[int] = set(GATE_MESSAGES)
    for module_info in pkgutil.iter_modules(sitl.protocol.__path__):
        module = importlib.import_module(f"sitl.protocol.{module_info.name}")
        for obj in vars(module).values():
            handles = getattr(obj, "handles", None)
            if isinstance(obj, type) and isinstance(handles, frozenset):
                ids.update(i for i in handles if isinstance(i, int))
    return frozenset(ids)


# ---------------------------------------------------------------------------------------------------------------
# The generator


def _frame_crc(frame: bytearray, crc_extra: int, header_len: int) -> None:
    """Recompute a frame's CRC in place (header after the magic byte, payload, CRC extra)."""
    payload_len = frame[1]
    end = header_len + payload_len
    crc = crc_x25(bytes(frame[1:end]) + bytes([crc_extra]), 0xFFFF)
    frame[end : end + 2] = struct.pack("<H", crc)


class FrameFactory:
    """Seeded frames for one target drone. ``next()`` gives a kind, the message name (or the kind) and the
    datagrams that carry the frame."""

    def __init__(self, rng: random.Random, *, drone_sysid: int, commands_to_drone: bool, drone_lat_deg: float,
                 drone_share: float = DRONE_VOCABULARY_SHARE, aimed_share: float = 0.0) -> None:  # fmt: skip
        """``drone_share``: of the well-formed messages, the share of a type the drone handles; ``aimed_share``
        (mode b only): the share of those addressed to the drone before the usual choice of target."""
        self._rng = rng
        self._sysid = drone_sysid
        self._drone_share = drone_share
        self._aimed_share = aimed_share if commands_to_drone else 0.0
        self._commands = commands_to_drone
        self._drone_lat_e7 = round(drone_lat_deg * 1e7)
        self._handled = drone_handled_ids()
        self._classes = sorted(mavlink.mavlink_map.values(), key=lambda c: c.id)
        self._handled_classes = [c for c in self._classes if c.id in self._handled]
        self._v1_classes = sorted(mavlink1.mavlink_map.values(), key=lambda c: c.id)
        self._param_names = [n for n in build_param_store().names if n not in NEVER_SET_PARAMS]
        self._kinds = list(KIND_WEIGHTS)
        self._weights = list(KIND_WEIGHTS.values())
        self._enc2 = mavlink.MAVLink(None)
        self._enc1 = mavlink1.MAVLink(None)
        self._makers: dict[str, Callable[[], tuple[str, list[bytes]]]] = {
            "mavlink2": self._mavlink2,
            "mavlink1": self._mavlink1,
            "signed": self._signed,
            "glued": self._glued,
            "bad_crc": self._bad_crc,
            "bad_length": self._bad_length,
            "truncated": self._truncated,
            "split": self._split,
            "random_bytes": self._random_bytes,
        }

    def next(self) -> tuple[str, str, list[bytes]]:
        kind = self._rng.choices(self._kinds, self._weights)[0]
        name, datagrams = self._makers[kind]()
        return kind, name, datagrams

    # ---- field values ----------------------------------------------------------------------------------------
    def _int(self, ctype: str, enum: str | None) -> int:
        lo, hi = INT_RANGES[ctype]
        rng = self._rng
        if enum is not None and rng.random() < 0.4:
            values = [v for v in mavlink.enums.get(enum, {}) if lo <= v <= hi]
            if values:
                return int(rng.choice(values))
        choice = rng.randrange(8)
        if choice == 0:
            return lo
        if choice == 1:
            return hi
        if choice == 2:
            return 0
        if choice == 3:
            return max(lo, min(hi, rng.choice((1, -1, 2))))
        if choice == 4:
            return rng.randint(max(lo, -1000), min(hi, 1000))
        return rng.randint(lo, hi)

    def _float(self, ctype: str) -> float:
        rng = self._rng
        if rng.random() < 0.5:
            return float(rng.choice(HOSTILE_DOUBLES if ctype == "double" else HOSTILE_FLOATS))
        scale = rng.choice((1.0, 100.0, 1e6, 1e30))
        return rng.uniform(-scale, scale)

    def _text(self, size: int, name: str) -> bytes:
        rng = self._rng
        choice = rng.randrange(7)
        if name == "param_id" and choice < 3:
            return rng.choice(self._param_names).encode()
        if choice == 0:
            return b""
        if choice == 1:  # every byte used: no terminating NUL
            return bytes(rng.randint(0x21, 0x7E) for _ in range(size))
        if choice == 2:  # over-long (pymavlink cuts it to the field's size)
            return bytes(rng.randint(0x21, 0x7E) for _ in range(size + rng.randint(1, 40)))
        if choice == 3:  # not ASCII, not UTF-8
            return rng.randbytes(rng.randint(1, size))
        if choice == 4:
            return "é°ü€".encode() * size
        if choice == 5:
            return b"\x00" * size
        return b"A\x00" + rng.randbytes(max(0, size - 2))

    def _value(self, cls: Any, name: str, ctype: str, length: int) -> Any:
        enum = cls.fieldenums_by_name.get(name)
        if ctype == "char":
            return self._text(max(1, length), name)
        if length:
            if ctype in ("float", "double"):
                return [self._float(ctype) for _ in range(length)]
            return [self._int(ctype, enum) for _ in range(length)]
        if ctype in ("float", "double"):
            return self._float(ctype)
        return self._int(ctype, enum)

    def _target_system(self, msg_id: int) -> int:
        """The drone, broadcast or another system; in mode (a) never the drone for what it would act on."""
        rng = self._rng
        protected = msg_id in NEVER_TO_DRONE or (
            not self._commands and msg_id in self._handled and msg_id not in READ_ONLY_REQUESTS
        )
        if self._aimed_share and not protected and rng.random() < self._aimed_share:
            return self._sysid
        while True:
            choice = rng.randrange(4)
            target = (self._sysid, 0, rng.randint(0, 255), 255)[choice] if choice != 3 else rng.choice((1, 255))
            if not protected or target not in (0, self._sysid):
                return target

    def _message(self, classes: Sequence[Any]) -> Any:
        rng = self._rng
        if classes is self._classes and rng.random() < self._drone_share:
            classes = self._handled_classes
        cls = rng.choice(classes)
        lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
        args = []
        for name, ctype in zip(cls.fieldnames, cls.fieldtypes, strict=True):
            if name in SYSTEM_TARGET_FIELDS and ctype == "uint8_t":
                args.append(self._target_system(cls.id))
            elif name in COMPONENT_TARGET_FIELDS:
                args.append(rng.choice((0, 1, 1, rng.randint(0, 255))))
            else:
                args.append(self._value(cls, name, ctype, lengths[name]))
        msg = cls(*args)
        if cls.id == mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT and not self._commands:
            keep_away = round(NEIGHBOUR_KEEP_AWAY_DEG * 1e7)
            if abs(msg.lat - self._drone_lat_e7) < keep_away:
                msg.lat = self._drone_lat_e7 - 20 * keep_away  # a neighbour report from far away
        return msg

    def _pack(self, msg: Any, encoder: Any) -> bytes:
        rng = self._rng
        encoder.srcSystem = rng.choice((CLIENT_SYSID, rng.randint(0, 255), self._sysid))
        encoder.srcComponent = rng.choice((CLIENT_COMPID, 1, rng.randint(0, 255)))
        encoder.seq = rng.randrange(256)
        return bytes(msg.pack(encoder))

    # ---- the kinds ---------------------------------------------------------------------------------------------
    def _valid_v2(self) -> tuple[str, bytes, Any]:
        msg = self._message(self._classes)
        return msg.get_type(), self._pack(msg, self._enc2), msg

    def _mavlink2(self) -> tuple[str, list[bytes]]:
        name, frame, _ = self._valid_v2()
        return name, [frame]

    def _mavlink1(self) -> tuple[str, list[bytes]]:
        msg = self._message(self._v1_classes)
        return msg.get_type(), [self._pack(msg, self._enc1)]

    def _signed(self) -> tuple[str, list[bytes]]:
        """A MAVLink 2 frame with the signed flag and a random 13-byte signature (link id, timestamp, signature)."""
        name, frame, msg = self._valid_v2()
        signed = bytearray(frame)
        signed[2] |= mavlink.MAVLINK_IFLAG_SIGNED
        _frame_crc(signed, msg.crc_extra, mavlink.HEADER_LEN_V2)
        return name, [bytes(signed) + self._rng.randbytes(mavlink.MAVLINK_SIGNATURE_BLOCK_LEN)]

    def _glued(self) -> tuple[str, list[bytes]]:
        """Two to five frames in one datagram, one of them with a flipped bit."""
        frames = [bytearray(self._valid_v2()[1]) for _ in range(self._rng.randint(2, 5))]
        broken = self._rng.choice(frames)
        broken[self._rng.randrange(len(broken))] ^= 1 << self._rng.randrange(8)
        return "glued", [b"".join(frames)]

    def _bad_crc(self) -> tuple[str, list[bytes]]:
        frame = bytearray(self._valid_v2()[1])
        frame[-1 - self._rng.randrange(2)] ^= self._rng.randint(1, 255)
        return "bad_crc", [bytes(frame)]

    def _bad_length(self) -> tuple[str, list[bytes]]:
        frame = bytearray(self._valid_v2()[1])
        frame[1] = (frame[1] + self._rng.randint(1, 255)) % 256
        return "bad_length", [bytes(frame)]

    def _truncated(self) -> tuple[str, list[bytes]]:
        frame = self._valid_v2()[1]
        return "truncated", [frame[: self._rng.randint(1, len(frame) - 1)]]

    def _split(self) -> tuple[str, list[bytes]]:
        frame = self._valid_v2()[1]
        cut = self._rng.randint(1, len(frame) - 1)
        return "split", [frame[:cut], frame[cut:]]

    def _random_bytes(self) -> tuple[str, list[bytes]]:
        rng = self._rng
        data = bytearray(rng.randbytes(rng.randint(1, 300)))
        magic = rng.random()
        if magic < 0.3:
            data[0] = mavlink.PROTOCOL_MARKER_V2
        elif magic < 0.4:
            data[0] = mavlink.PROTOCOL_MARKER_V1
        return "random_bytes", [bytes(data)]


# ---------------------------------------------------------------------------------------------------------------
# The drone: started here or attached to, and watched as a client sees it


@dataclass(frozen=True, slots=True, kw_only=True)
class DroneAddress:
    sysid: int
    api_host: str  # where the drone listens on its API link
    api_port: int
    listen_port: int  # where it streams to (our client binds it)
    instance: int | None  # its row in the shared world when we started it


class StartedDrone:
    """A ``sitl`` process started by the tool, with its shared world; ``stop()`` ends it by PID and reaps it."""

    def __init__(self, *, instance: int, ports: InstancePorts, seed: int, log_path: Path, speed: float) -> None:
        self.world = SharedWorld.create()
        self.log_path = log_path
        self._sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # the ground-station link streams here
        self._sink.bind((LOOPBACK, 0))
        self.address = DroneAddress(
            sysid=instance + 1, api_host=LOOPBACK, api_port=ports.api_bind, listen_port=ports.api_remote,
            instance=instance,
        )  # fmt: skip
        self.gcs_port = ports.gcs_bind
        script = Path(sys.executable).with_name("sitl")
        command = [str(script)] if script.exists() else [sys.executable, "-m", "sitl.cli"]
        argv = [
            *command, "--instance", str(instance), "--seed", str(seed), "--speed", f"{speed:g}",
            "--world", self.world.name,
            "--api-port", str(self.address.api_port),
            "--api-remote", f"{LOOPBACK}:{self.address.listen_port}",
            "--gcs-port", str(self.gcs_port),
            "--gcs-remote", f"{LOOPBACK}:{self._sink.getsockname()[1]}",
        ]  # fmt: skip
        self._log: IO[bytes] = log_path.open("wb")
        env = {k: v for k, v in os.environ.items() if k != "PX4_SIM_SPEED_FACTOR"}
        self.popen = subprocess.Popen(
            argv, stdin=subprocess.DEVNULL, stdout=self._log, stderr=subprocess.STDOUT, env=env,
            preexec_fn=_die_with_parent,
        )  # fmt: skip

    def alive(self) -> bool:
        return self.popen.poll() is None

    def cpu_s(self) -> float:
        """CPU seconds (user + system) the drone process has used so far."""
        fields = Path(f"/proc/{self.popen.pid}/stat").read_text().rpartition(")")[2].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def true_geo(self) -> tuple[float, float, float] | None:
        row = self.world.table[self.address.instance]
        if row[VALID] != 1.0:
            return None
        return float(row[LAT]), float(row[LON]), float(row[ALT])

    def stop(self) -> int | None:
        """SIGTERM, then SIGKILL after a grace period; the exit code (negative: ended by a signal)."""
        try:
            if self.popen.poll() is None:
                self.popen.send_signal(signal.SIGTERM)
                try:
                    return self.popen.wait(timeout=STOP_GRACE_S)
                except subprocess.TimeoutExpired:
                    self.popen.kill()
            return self.popen.wait(timeout=STOP_GRACE_S)
        finally:
            self._log.close()
            self._sink.close()
            self.world.close()


def _die_with_parent() -> None:
    """In the child before exec: SIGTERM when the fuzzer dies, so a killed run leaves no drone flying."""
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)


@dataclass(slots=True)
class Watch:
    """What the client sees of the drone: heartbeats, its position, its mode."""

    sysid: int
    heartbeats_s: list[float] = field(default_factory=list)
    custom_mode: int | None = None
    armed: bool = False
    local_ned_m: tuple[float, float, float] | None = None
    relative_alt_m: float | None = None
    lat_deg: float | None = None

    def note(self, msg: Any) -> Any:
        if msg.get_srcSystem() != self.sysid or msg.get_srcComponent() != 1:
            return None
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            self.heartbeats_s.append(time.monotonic())
            self.custom_mode = msg.custom_mode
            self.armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
        elif kind == "LOCAL_POSITION_NED":
            self.local_ned_m = (msg.x, msg.y, msg.z)
        elif kind == "GLOBAL_POSITION_INT":
            self.relative_alt_m = msg.relative_alt * 1e-3
            self.lat_deg = msg.lat * 1e-7
        return msg


class Client:
    """A pymavlink ground station on the drone's API link; every message read passes through ``watch``."""

    def __init__(self, address: DroneAddress) -> None:
        self.address = address
        self.watch = Watch(address.sysid)
        self.conn = mavutil.mavlink_connection(
            f"udpin:{LOOPBACK}:{address.listen_port}", source_system=CLIENT_SYSID, source_component=CLIENT_COMPID
        )
        self._last_heartbeat_s = -math.inf

    def close(self) -> None:
        self.conn.close()

    def pump(self, wait_s: float = 0.0) -> list[Any]:
        """Read what arrived (for up to ``wait_s``); returns the drone's messages. Sends our heartbeat at 1 Hz."""
        now = time.monotonic()
        if now - self._last_heartbeat_s >= 1.0:
            self.conn.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            self._last_heartbeat_s = now
        out: list[Any] = []
        deadline = now + wait_s
        while True:
            remaining = deadline - time.monotonic()
            msg = self.conn.recv_match(blocking=remaining > 0, timeout=max(remaining, 0.0) or None)
            if msg is None:
                if remaining <= 0:
                    return out
                continue
            if self.watch.note(msg) is not None:
                out.append(msg)

    def wait_for(self, predicate: Callable[[Any], bool], timeout_s: float) -> Any:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for msg in self.pump(0.05):
                if predicate(msg):
                    return msg
        return None

    def command(self, command: int, params: Sequence[float], timeout_s: float) -> Any:
        p = [*params, *([0.0] * (7 - len(params)))]
        self.conn.mav.command_long_send(self.address.sysid, 1, command, 0, *p)
        return self.wait_for(lambda m: m.get_type() == "COMMAND_ACK" and m.command == command, timeout_s)


def _connect(client: Client, timeout_s: float) -> None:
    """Wait for the drone's heartbeat; our own heartbeat makes an attached drone learn our address."""
    if client.wait_for(lambda m: m.get_type() == "HEARTBEAT", timeout_s) is None:
        raise FuzzError(f"no HEARTBEAT from system {client.address.sysid} within {timeout_s:.0f} s")


def take_off_and_hover(client: Client, timeout_s: float) -> None:
    """Arm (retrying until the drone is armable), NAV_TAKEOFF to MIS_TAKEOFF_ALT, wait for Hold."""
    deadline = time.monotonic() + timeout_s
    while True:
        ack = client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (1.0,), 2.0)
        if ack is not None and ack.result == mavlink.MAV_RESULT_ACCEPTED:
            break
        if time.monotonic() > deadline:
            raise FuzzError(f"arming refused: {ack}")
        client.pump(0.5)
    ack = client.command(mavlink.MAV_CMD_NAV_TAKEOFF, (math.nan,) * 7, 2.0)
    if ack is None or ack.result != mavlink.MAV_RESULT_ACCEPTED:
        raise FuzzError(f"takeoff refused: {ack}")
    client.pump(1.0)
    while not (client.watch.custom_mode == PX4_AUTO_LOITER and client.watch.armed):
        if time.monotonic() > deadline:
            raise FuzzError("the drone did not reach Hold after takeoff")
        client.pump(0.2)


# ---------------------------------------------------------------------------------------------------------------
# Drift


class DriftMeter:
    """Largest horizontal and vertical distance from the hover point, from a position source in metres NED."""

    def __init__(self, position: Callable[[], tuple[float, float, float] | None]) -> None:
        self._position = position
        self._point: tuple[float, float, float] | None = None
        self.max_horizontal_m = 0.0
        self.max_vertical_m = 0.0
        self.samples = 0
        self.nonfinite = 0  # positions with a NaN or infinite component: the simulation or estimator broke

    def set_point(self, samples: Sequence[tuple[float, float, float]]) -> None:
        n = len(samples)
        self._point = (sum(s[0] for s in samples) / n, sum(s[1] for s in samples) / n, sum(s[2] for s in samples) / n)

    def sample(self) -> tuple[float, float, float] | None:
        pos = self._position()
        if pos is None or self._point is None:
            return pos
        if not all(math.isfinite(c) for c in pos):
            self.nonfinite += 1
            self.max_horizontal_m = self.max_vertical_m = math.inf
            return None
        dn, de, dd = (pos[0] - self._point[0], pos[1] - self._point[1], pos[2] - self._point[2])
        self.max_horizontal_m = max(self.max_horizontal_m, math.hypot(dn, de))
        self.max_vertical_m = max(self.max_vertical_m, abs(dd))
        self.samples += 1
        return pos


def geo_to_ned(geo: tuple[float, float, float], origin: tuple[float, float, float]) -> tuple[float, float, float]:
    """Flat-earth metres from ``origin`` (plenty for the few metres a hover drifts)."""
    lat0 = math.radians(origin[0])
    return (
        math.radians(geo[0] - origin[0]) * EARTH_RADIUS_M,
        math.radians(geo[1] - origin[1]) * EARTH_RADIUS_M * math.cos(lat0),
        -(geo[2] - origin[2]),
    )


# ---------------------------------------------------------------------------------------------------------------
# The run


class FuzzError(RuntimeError):
    """The run could not start (no drone, no takeoff): one line, exit code 1."""


@dataclass(frozen=True, slots=True, kw_only=True)
class FuzzConfig:
    frames: int
    seed: int
    commands_to_drone: bool
    rate_hz: float
    instance: int = 0
    port_base: int | None = None  # ports 14580/14540/18570 + this; default: the instance's own (sitl/process/ports.py)
    speed: float = 1.0
    log_dir: Path = Path(".")
    attach: tuple[str, int] | None = None  # a running drone's API address instead of starting one
    attach_listen_port: int | None = None
    attach_sysid: int | None = None
    attach_log: Path | None = None
    gcs_port_too: bool = False


@dataclass(slots=True, kw_only=True)
class FuzzReport:
    mode: str
    seed: int
    frames_sent: int = 0
    datagrams_sent: int = 0
    by_kind: dict[str, int] = field(default_factory=dict)
    by_message: dict[str, int] = field(default_factory=dict)
    message_types_sent: int = 0
    message_types_in_dialect: int = len(mavlink.mavlink_map)
    fuzz_wall_s: float = 0.0
    drone_cpu_fraction: float = math.nan  # CPU seconds of the drone per wall second while fuzzed (started drone)
    drone_alive: bool = False
    exit_code: int | None = None
    heartbeat_hz: float = 0.0
    max_heartbeat_gap_s: float = math.inf
    param_round_trip: bool = False
    command_round_trip: bool = False
    position_source: str = ""
    max_horizontal_drift_m: float = math.nan
    max_vertical_drift_m: float = math.nan
    nonfinite_positions: int = 0
    final_mode: int | None = None
    final_armed: bool | None = None
    tracebacks: int = 0
    traceback_excerpt: str = ""
    failures: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return not self.failures

    def judge(self) -> None:
        """The verdict of the mode: what must hold in both, and the hover tolerance when no command reached it."""
        self.failures.clear()
        if not self.drone_alive:
            self.failures.append(f"the drone process ended (exit code {self.exit_code})")
        if self.tracebacks:
            self.failures.append(f"{self.tracebacks} traceback(s) in the drone's log")
        if self.nonfinite_positions:
            self.failures.append(f"{self.nonfinite_positions} positions were not finite numbers")
        if not self.param_round_trip:
            self.failures.append("no PARAM_VALUE answered PARAM_REQUEST_READ after the run")
        if not self.command_round_trip:
            self.failures.append("no COMMAND_ACK answered COMMAND_LONG after the run")
        if self.max_heartbeat_gap_s > MAX_HEARTBEAT_GAP_S:
            self.failures.append(f"heartbeats stopped for {self.max_heartbeat_gap_s:.1f} s")
        if self.mode == "a":
            drift = max(self.max_horizontal_drift_m, self.max_vertical_drift_m)
            if not drift <= HOVER_TOLERANCE_M:
                self.failures.append(f"drifted {drift:.2f} m from the hover point (limit {HOVER_TOLERANCE_M} m)")

    def text(self) -> str:
        lines = [
            f"fuzz: mode {self.mode} ({'commands to the drone' if self.mode == 'b' else 'no command to the drone'}), "
            f"seed {self.seed}",
            f"  frames sent: {self.frames_sent} in {self.datagrams_sent} datagrams, {self.fuzz_wall_s:.1f} s wall "
            f"({self.frames_sent / max(self.fuzz_wall_s, 1e-9):.0f} frames/s)"
            + (
                ""
                if math.isnan(self.drone_cpu_fraction)
                else f"; the drone used {self.drone_cpu_fraction:.0%} of a core"
            ),
            "  by kind: " + ", ".join(f"{k} {v}" for k, v in sorted(self.by_kind.items())),
            f"  message types sent: {self.message_types_sent} of {self.message_types_in_dialect} in the common "
            f"dialect (fewest: {min(self.by_message.values(), default=0)} frames of one type)",
            f"  drone alive: {self.drone_alive}; heartbeat {self.heartbeat_hz:.2f} Hz during the run, longest gap "
            f"{self.max_heartbeat_gap_s:.2f} s",
            f"  after the run: PARAM_REQUEST_READ answered {self.param_round_trip}, COMMAND_LONG answered "
            f"{self.command_round_trip}; mode {self.final_mode}, armed {self.final_armed}",
            f"  drift from the hover point ({self.position_source}): horizontal {self.max_horizontal_drift_m:.3f} m, "
            f"vertical {self.max_vertical_drift_m:.3f} m",
            f"  tracebacks in the drone's log: {self.tracebacks}",
        ]
        if self.traceback_excerpt:
            lines.append(self.traceback_excerpt)
        lines.append("PASS" if self.passed else "FAIL: " + "; ".join(self.failures))
        return "\n".join(lines)


def count_tracebacks(log_path: Path | None) -> tuple[int, str]:
    if log_path is None or not log_path.exists():
        return 0, ""
    text = log_path.read_text(errors="replace")
    count = text.count("Traceback (most recent call last)")
    if not count:
        return 0, ""
    start = text.index("Traceback (most recent call last)")
    return count, "\n".join(text[start:].splitlines()[:30])


def _ports(instance: int, port_base: int | None) -> InstancePorts:
    """The started drone's ports: the instance's own, or PX4 SITL's numbers for ``port_base``."""
    if port_base is None:
        return instance_ports(instance)
    return InstancePorts(api_bind=API_BIND_BASE_PORT + port_base, api_remote=API_REMOTE_BASE_PORT + port_base,
                         gcs_bind=GCS_BIND_BASE_PORT + port_base)  # fmt: skip


@contextlib.contextmanager
def _drone(config: FuzzConfig) -> Iterator[tuple[DroneAddress, StartedDrone | None, Path | None]]:
    if config.attach is not None:
        listen = config.attach_listen_port or instance_ports(0).api_remote  # sysid 1 by default: instance 0
        sysid = config.attach_sysid or 1
        yield DroneAddress(sysid=sysid, api_host=config.attach[0], api_port=config.attach[1],
                           listen_port=listen, instance=None), None, config.attach_log  # fmt: skip
        return
    log_path = config.log_dir / f"fuzz-sitl-{config.instance}.log"
    drone = StartedDrone(instance=config.instance, ports=_ports(config.instance, config.port_base), seed=config.seed,
                         log_path=log_path, speed=config.speed)  # fmt: skip
    try:
        yield drone.address, drone, log_path
    finally:
        drone.stop()


def run(config: FuzzConfig, *, progress: Callable[[str], None] | None = None) -> FuzzReport:
    """Start or attach, take off, hover, fuzz, check; always stops what it started."""
    say = progress or (lambda _text: None)
    report = FuzzReport(mode="b" if config.commands_to_drone else "a", seed=config.seed)
    with _drone(config) as (address, drone, log_path), contextlib.closing(Client(address)) as client:
        start = time.monotonic()
        while True:
            try:
                _connect(client, 1.0)
                break
            except FuzzError:
                if drone is not None and not drone.alive():
                    raise FuzzError(f"sitl exited with code {drone.popen.returncode}") from None
                if time.monotonic() - start > READY_TIMEOUT_S:
                    raise
        say(f"connected to system {address.sysid}; taking off")
        take_off_and_hover(client, TAKEOFF_TIMEOUT_S)
        say("hovering in Hold; settling")
        client.pump(HOVER_SETTLE_S)

        if drone is not None:
            origin = drone.true_geo()
            assert origin is not None

            def position() -> tuple[float, float, float] | None:
                geo = drone.true_geo()
                return None if geo is None else geo_to_ned(geo, origin)

            report.position_source = "true position, shared world"
        else:

            def position() -> tuple[float, float, float] | None:
                return client.watch.local_ned_m

            report.position_source = "LOCAL_POSITION_NED"
        meter = DriftMeter(position)
        samples = []
        end = time.monotonic() + HOVER_POINT_S
        while time.monotonic() < end:
            client.pump(0.02)
            if (pos := meter.sample()) is not None:
                samples.append(pos)
        meter.set_point(samples)

        factory = FrameFactory(random.Random(config.seed), drone_sysid=address.sysid,
                               commands_to_drone=config.commands_to_drone,
                               drone_lat_deg=client.watch.lat_deg or 0.0)  # fmt: skip
        targets = [(address.api_host, address.api_port)]
        if config.gcs_port_too and drone is not None:
            targets.append((LOOPBACK, drone.gcs_port))
        say(f"fuzzing: {config.frames} frames at {config.rate_hz:g} frames/s")
        by_kind: Counter[str] = Counter()
        by_message: Counter[str] = Counter()
        heartbeats_before = len(client.watch.heartbeats_s)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # replies to fuzz frames are not read
            cpu_start = drone.cpu_s() if drone is not None else math.nan
            fuzz_start = time.monotonic()
            next_report = fuzz_start + 10.0
            sent = 0
            while sent < config.frames:
                due = min(config.frames, int((time.monotonic() - fuzz_start) * config.rate_hz) + 1) - sent
                for _ in range(min(due, SEND_CHUNK)):
                    kind, name, datagrams = factory.next()
                    by_kind[kind] += 1
                    if kind in ("mavlink2", "mavlink1", "signed"):
                        by_message[name] += 1
                    target = targets[sent % len(targets)]
                    for datagram in datagrams:
                        with contextlib.suppress(OSError):
                            sock.sendto(datagram, target)
                        report.datagrams_sent += 1
                    sent += 1
                client.pump()
                meter.sample()
                if drone is not None and not drone.alive():
                    break
                if due < SEND_CHUNK:
                    time.sleep(0.002)
                if time.monotonic() > next_report:
                    say(f"  {sent} frames, drift {meter.max_horizontal_m:.2f}/{meter.max_vertical_m:.2f} m")
                    next_report += 10.0
            report.fuzz_wall_s = time.monotonic() - fuzz_start
            if drone is not None and drone.alive():
                report.drone_cpu_fraction = (drone.cpu_s() - cpu_start) / max(report.fuzz_wall_s, 1e-9)
        report.frames_sent = sent
        report.by_kind = dict(by_kind)
        report.by_message = dict(sorted(by_message.items()))
        report.message_types_sent = len({n for n in by_message if n in _DIALECT_NAMES})
        beats = client.watch.heartbeats_s[heartbeats_before:]
        report.heartbeat_hz = len(beats) / max(report.fuzz_wall_s, 1e-9)
        edges = [fuzz_start, *beats, fuzz_start + report.fuzz_wall_s]
        report.max_heartbeat_gap_s = max(b - a for a, b in itertools.pairwise(edges))

        end = time.monotonic() + AFTER_SETTLE_S
        while time.monotonic() < end:
            client.pump(0.02)
            meter.sample()
        report.max_horizontal_drift_m = meter.max_horizontal_m
        report.max_vertical_drift_m = meter.max_vertical_m
        report.nonfinite_positions = meter.nonfinite
        report.param_round_trip = _param_round_trip(client)
        report.command_round_trip = _command_round_trip(client)
        report.final_mode = client.watch.custom_mode
        report.final_armed = client.watch.armed
        report.drone_alive = drone.alive() if drone is not None else report.command_round_trip
        if drone is not None and not report.drone_alive:
            report.exit_code = drone.popen.returncode
    report.tracebacks, report.traceback_excerpt = count_tracebacks(log_path)
    report.judge()
    return report


_DIALECT_NAMES: Final = frozenset(cls.msgname for cls in mavlink.mavlink_map.values())


def _param_round_trip(client: Client) -> bool:
    for _ in range(ROUND_TRIP_TRIES):
        client.conn.mav.param_request_read_send(client.address.sysid, 1, b"MIS_TAKEOFF_ALT", -1)
        if client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "MIS_TAKEOFF_ALT",
                           ROUND_TRIP_TIMEOUT_S) is not None:  # fmt: skip
            return True
    return False


def _command_round_trip(client: Client) -> bool:
    for _ in range(ROUND_TRIP_TRIES):
        ack = client.command(mavlink.MAV_CMD_REQUEST_MESSAGE, (float(mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION),),
                             ROUND_TRIP_TIMEOUT_S)  # fmt: skip
        if ack is not None:
            return True
    return False


# ---------------------------------------------------------------------------------------------------------------
# In process: the same frames through the drone's MAVLink services over a real Simulation, many times faster

IN_PROCESS_DRONE_SHARE: Final = 0.97  # nearly every well-formed message is one the drone handles...
IN_PROCESS_AIMED_SHARE: Final = 0.8  # ...and most are addressed to it
EPISODE_FRAMES: Final = 20_000  # a fresh drone at least this often, so that no one vehicle's state dominates
# Kept out in process, so that the drone spends its time flying rather than lying disarmed: a kill and a disarm
# (forced or not) end a flight at once; the live modes send them.
GROUNDING_COMMANDS: Final = frozenset({mavlink.MAV_CMD_DO_FLIGHTTERMINATION, mavlink.MAV_CMD_COMPONENT_ARM_DISARM})


@dataclass(slots=True, kw_only=True)
class InProcessReport:
    seed: int
    frames: int = 0
    messages_handled: int = 0
    episodes: int = 0
    crashed_episodes: int = 0  # the vehicle was brought down (an accepted command did it: allowed)
    sim_s: float = 0.0
    armed_s: float = 0.0
    wall_s: float = 0.0
    cpu_s: float = 0.0  # this process's CPU time: what the run cost, whatever else the machine was doing
    errors: dict[str, int] = field(default_factory=dict)  # "where: exception" -> count
    examples: dict[str, str] = field(default_factory=dict)  # the first message behind each error
    nonfinite: int = 0

    @property
    def passed(self) -> bool:
        return not self.errors and not self.nonfinite

    def text(self) -> str:
        lines = [
            f"fuzz in process: seed {self.seed}, {self.frames} frames ({self.messages_handled} messages handled) in "
            f"{self.wall_s:.0f} s wall ({self.cpu_s:.0f} s CPU), {self.sim_s:.0f} s simulated "
            f"({self.armed_s:.0f} s armed), {self.episodes} drones "
            f"({self.crashed_episodes} brought down by what they were told)",
            f"  exceptions: {sum(self.errors.values())}; non-finite states: {self.nonfinite}",
        ]
        for key, count in sorted(self.errors.items(), key=lambda kv: -kv[1]):
            lines.append(f"  {count} x {key}\n    first after: {self.examples[key]}")
        lines.append("PASS" if self.passed else "FAIL")
        return "\n".join(lines)


def run_in_process(frames: int, seed: int, *, frames_per_step: int = 2,
                   progress: Callable[[str], None] | None = None) -> InProcessReport:  # fmt: skip
    """Feed ``frames`` frames, ``frames_per_step`` per physics step, to ``LinkServices`` over a ``Simulation``
    behind its MAVLink adapter, as the drone's UDP shell would (framing's fast parser, else pymavlink's; every reply
    packed). Any exception, and any NaN or infinite position, velocity or attitude, is a failure."""
    say = progress or (lambda _text: None)
    report = InProcessReport(seed=seed)
    start, cpu_start = time.monotonic(), time.process_time()
    while report.frames < frames:
        report.episodes += 1
        _InProcessDrone(seed * 10_000 + report.episodes, report).fly(
            min(EPISODE_FRAMES, frames - report.frames), frames_per_step
        )
        say(f"  drone {report.episodes}: {report.frames} frames so far, {sum(report.errors.values())} exceptions")
    report.wall_s = time.monotonic() - start
    report.cpu_s = time.process_time() - cpu_start
    return report


class _InProcessDrone:
    """One simulated drone behind its MAVLink services, fed frames until it is brought down or the budget ends."""

    def __init__(self, seed: int, report: InProcessReport) -> None:
        self.report = report
        self.sim = make_sim(seed=seed)
        self.vehicle = SimVehicleApi(self.sim)
        self.services = LinkServices(Identity(sysid=1), self.vehicle, self.sim.params, neighbours=NeighbourTable(1))
        self.factory = FrameFactory(random.Random(seed), drone_sysid=1, commands_to_drone=True,
                                    drone_lat_deg=self.sim.truth.geo.lat_deg, drone_share=IN_PROCESS_DRONE_SHARE,
                                    aimed_share=IN_PROCESS_AIMED_SHARE)  # fmt: skip
        self._encoder = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self._client = mavlink.MAVLink(None, srcSystem=CLIENT_SYSID, srcComponent=CLIENT_COMPID)
        self._last: Any = None

    def note(self, where: str, context: Any) -> None:
        """Record the exception being handled (every failure is recorded, the run goes on)."""
        exc = sys.exc_info()[1]
        key = f"{where}: {type(exc).__name__}: {exc}"[:200]
        self.report.errors[key] = self.report.errors.get(key, 0) + 1
        self.report.examples.setdefault(key, str(context)[:400])

    def handle(self, msg: Any) -> None:
        for effect in self.services.handle(msg, self.sim.time_s):
            try:
                effect.msg.pack(self._encoder)
            except Exception:
                self.note("pack", msg)

    def command(self, number: int, *params: float) -> None:
        p = [*params, *([math.nan] * (7 - len(params)))]
        frame = mavlink.MAVLink_command_long_message(1, 1, number, 0, *p).pack(self._client)
        for msg in mavlink.MAVLink(None).parse_buffer(frame) or []:
            self.handle(msg)

    def receive(self, datagram: bytes) -> None:
        """One datagram as the UDP shell takes it: the fast parser, else a fresh pymavlink parser."""
        try:
            messages = parse_datagram(datagram)
            if messages is None:
                parser = mavlink.MAVLink(None)
                parser.robust_parsing = True
                messages = parser.parse_buffer(datagram) or []
        except Exception:
            self.note("parse", datagram.hex())
            return
        for msg in messages:
            kind = msg.get_type()
            if kind in ("BAD_DATA", "UNKNOWN") or (
                kind in ("COMMAND_LONG", "COMMAND_INT") and msg.command in GROUNDING_COMMANDS
            ):
                continue
            self._last = msg
            self.report.messages_handled += 1
            try:
                self.handle(msg)
            except Exception:
                self.note("handle", msg)

    def fly(self, budget: int, frames_per_step: int) -> None:
        sim, vehicle, report = self.sim, self.vehicle, self.report
        sim.run_until(lambda _s: vehicle.snapshot().prearm_ok, 20.0)
        self.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
        self.command(mavlink.MAV_CMD_NAV_TAKEOFF)
        sim.run_for(6.0)
        sent = 0
        while sent < budget:
            for _ in range(frames_per_step):
                for datagram in self.factory.next()[2]:
                    self.receive(datagram)
            sent += frames_per_step
            report.frames += frames_per_step
            try:
                sim.step()
                for effect in self.services.poll(sim.time_s):
                    effect.msg.pack(self._encoder)
            except Exception:
                self.note("step", self._last)
                break
            snap = vehicle.snapshot()
            report.armed_s += sim.dt_s if snap.armed else 0.0
            state = (*sim.truth.pos_ned_m, *snap.pos_ned_m, *snap.vel_ned_mps, *snap.att_q_wxyz)
            if not all(math.isfinite(float(v)) for v in state):
                report.nonfinite += 1
                report.examples.setdefault("non-finite state", str(self._last)[:400])
                break
            if sim.vehicle.crashed:
                report.crashed_episodes += 1
                break
            if not snap.armed and snap.landed_state is LandedState.ON_GROUND and vehicle.command(Arm(), sim.time_s).ok:
                self.command(mavlink.MAV_CMD_NAV_TAKEOFF)
        report.sim_s += sim.time_s


# ---------------------------------------------------------------------------------------------------------------
# The command line


def _yes_no(text: str) -> bool:
    if text not in ("yes", "no"):
        raise argparse.ArgumentTypeError(f"must be yes or no, got {text!r}")
    return text == "yes"


def _host_port(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise argparse.ArgumentTypeError(f"must be HOST:PORT, got {text!r}")
    return host, int(port)


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> Any:  # one line and exit code 2, as every tool of the project
        self.exit(2, f"fuzz: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="bench/fuzz.py", description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=100_000, help="frames to send (default 100000)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the frame generator and the drone")
    parser.add_argument("--commands-to-drone", type=_yes_no, default=False, metavar="yes|no",
                        help="no (default): nothing the drone acts on is addressed to it, it must hold its hover "
                        "within 0.5 m; yes: commands to it too")  # fmt: skip
    parser.add_argument("--rate", type=float, default=2000.0, help="frames per second (default 2000)")
    parser.add_argument("--instance", type=int, default=220, help="instance of the drone started (sysid i+1)")
    parser.add_argument("--port-base", type=int, default=None, help="its ports are 14580/14540/18570 + this "
                        "(default: the instance's own, docs/mavlink.md)")  # fmt: skip
    parser.add_argument("--gcs-port-too", action="store_true", help="alternate frames with the ground-station link")
    parser.add_argument("--log-dir", type=Path, default=Path("."), help="where the started drone's log goes")
    parser.add_argument("--attach", type=_host_port, default=None, metavar="HOST:PORT",
                        help="fuzz a running drone listening on HOST:PORT instead of starting one")  # fmt: skip
    parser.add_argument("--listen", type=int, default=None, help="with --attach: the port it streams to")
    parser.add_argument("--sysid", type=int, default=None, help="with --attach: its system id (default 1)")
    parser.add_argument("--drone-log", type=Path, default=None, help="with --attach: its log, read for tracebacks")
    parser.add_argument("--json", type=Path, default=None, help="also write the report here as JSON")
    parser.add_argument("--in-process", action="store_true",
                        help="no sitl process: the frames go through the drone's MAVLink services over a "
                        "Simulation, mostly commands to it (finds faults faster)")  # fmt: skip
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    parser = build_parser()
    if args.frames < 0:
        parser.error(f"--frames must be >= 0, got {args.frames}")
    if not (math.isfinite(args.rate) and args.rate > 0):
        parser.error(f"--rate must be a positive number of frames per second, got {args.rate}")
    if not 0 <= args.instance <= MAX_INSTANCE:
        parser.error(f"--instance must be in 0..{MAX_INSTANCE}, got {args.instance}")
    if args.port_base is not None and not 0 <= args.port_base <= 65535 - GCS_BIND_BASE_PORT:
        parser.error(f"--port-base must be in 0..{65535 - GCS_BIND_BASE_PORT}, got {args.port_base}")
    if args.in_process:
        in_process = run_in_process(args.frames, args.seed, progress=lambda text: print(text, flush=True))
        print(in_process.text())
        if args.json is not None:
            args.json.write_text(json.dumps(asdict(in_process), indent=1) + "\n")
        return 0 if in_process.passed else 1
    config = FuzzConfig(
        frames=args.frames, seed=args.seed, commands_to_drone=args.commands_to_drone, rate_hz=args.rate,
        instance=args.instance, port_base=args.port_base, log_dir=args.log_dir, attach=args.attach,
        attach_listen_port=args.listen, attach_sysid=args.sysid, attach_log=args.drone_log,
        gcs_port_too=args.gcs_port_too,
    )  # fmt: skip
    try:
        report = run(config, progress=lambda text: print(text, flush=True))
    except FuzzError as exc:
        print(f"fuzz: {exc}", file=sys.stderr)
        return 1
    print(report.text())
    if args.json is not None:
        args.json.write_text(json.dumps(asdict(report), indent=1, default=str) + "\n")
    return 0 if report.passed else 1


if __name__ == "__main__":
    sys.exit(main())
