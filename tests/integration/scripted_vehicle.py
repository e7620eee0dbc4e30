"""A vehicle the simulation does not run, played by a plain pymavlink script: what a real drone on a radio looks like
to the ground station (a HEARTBEAT at 1 Hz, GLOBAL_POSITION_INT at 10 Hz), and nothing of it reaches the simulated
world except through MAVLink.

It flies a scripted path (a function of wall time since ``start``: paced swarms keep wall time), answers nothing, and
can fall silent on request (a cut link). Its link is one of the kinds ``--attach`` opens: UDP to a port the ground
station listens on (``UdpLink``), a TCP server the ground station connects to (``TcpServerLink``), or a serial line,
played by a pseudo-terminal (``PtyLink``: the ground station opens its other end as a serial device).
"""

from __future__ import annotations

import contextlib
import math
import os
import socket
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass
from typing import Self

from pymavlink.dialects.v20 import common as mavlink

from gcs.flight.geodesy import GeoPoint, NedFrame

Path = Callable[[float], tuple[float, float, float]]  # seconds since start -> NED metres from the origin


def back_and_forth(start_ne_m: tuple[float, float], end_ne_m: tuple[float, float], alt_m: float,
                   speed_mps: float) -> Path:  # fmt: skip
    """Along the segment from start to end and back, at ``speed_mps``, ``alt_m`` above the origin."""
    (n0, e0), (n1, e1) = start_ne_m, end_ne_m
    length = math.hypot(n1 - n0, e1 - e0)

    def at(t_s: float) -> tuple[float, float, float]:
        s = (speed_mps * t_s) % (2.0 * length)
        f = (s if s <= length else 2.0 * length - s) / length
        return (n0 + f * (n1 - n0), e0 + f * (e1 - e0), -alt_m)

    return at


class UdpLink:
    """Datagrams to ``port`` on 127.0.0.1, where ``--attach udpin:127.0.0.1:PORT`` listens."""

    def __init__(self, port: int) -> None:
        self.port = port
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    def url(self) -> str:
        return f"udpin:127.0.0.1:{self.port}"

    def write(self, data: bytes) -> None:
        self._sock.sendto(data, ("127.0.0.1", self.port))

    def read(self) -> list[mavlink.MAVLink_message]:
        """What the ground station has sent back so far (it answers the address it hears the vehicle from)."""
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        out: list[mavlink.MAVLink_message] = []
        self._sock.setblocking(False)
        while True:
            try:
                data = self._sock.recv(65536)
            except (BlockingIOError, OSError):
                return out
            out.extend(m for m in parser.parse_buffer(data) or [] if m.get_type() != "BAD_DATA")

    def close(self) -> None:
        self._sock.close()


class TcpServerLink:
    """A TCP server on a port of 127.0.0.1 the system picks, as a vehicle's Wi-Fi bridge or another autopilot's SITL
    offers one; ``--attach tcp:127.0.0.1:PORT`` connects to it. What is written before a client connects is lost."""

    def __init__(self) -> None:
        self._server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._server.bind(("127.0.0.1", 0))
        self._server.listen(1)
        self._server.setblocking(False)
        self.port = int(self._server.getsockname()[1])
        self._client: socket.socket | None = None

    def url(self) -> str:
        return f"tcp:127.0.0.1:{self.port}"

    def write(self, data: bytes) -> None:
        if self._client is None:
            try:
                self._client, _ = self._server.accept()
            except BlockingIOError:
                return
        try:
            self._client.sendall(data)
        except OSError:  # the ground station hung up: the next one to connect is served
            self._client.close()
            self._client = None

    def close(self) -> None:
        if self._client is not None:
            self._client.close()
        self._server.close()


class PtyLink:
    """A pseudo-terminal: the vehicle writes to its master side, the ground station opens the other side as a serial
    device (``--attach /dev/pts/N,57600``), as it would a telemetry radio's USB serial port."""

    def __init__(self) -> None:
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.device = os.ttyname(self._slave)

    def url(self) -> str:
        return f"{self.device},57600"

    def write(self, data: bytes) -> None:
        with contextlib.suppress(OSError):
            os.write(self._master, data)

    def close(self) -> None:
        os.close(self._master)
        os.close(self._slave)


Link = UdpLink | TcpServerLink | PtyLink


class _Script:
    """What both scripts share: a thread that runs ``_run`` from ``start`` until ``stop``, and their MAVLink out."""

    link: Link
    _mav: mavlink.MAVLink

    def _begin(self, name: str) -> None:
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self.t0 = time.monotonic()

    def _run(self) -> None:
        raise NotImplementedError

    def start(self) -> Self:
        self.t0 = time.monotonic()
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.link.close()

    def _send(self, msg: mavlink.MAVLink_message) -> None:
        self.link.write(msg.pack(self._mav))


@dataclass
class ScriptedVehicle(_Script):
    """Sends as sysid ``sysid`` over ``link``."""

    sysid: int
    link: Link
    origin: GeoPoint
    path: Path
    rate_hz: float = 10.0
    autopilot: int = mavlink.MAV_AUTOPILOT_PX4
    reports_position: bool = True  # False: HEARTBEATs only (a vehicle without a position estimate)
    signing_key: bytes | None = None  # MAVLink 2 signing of everything it sends

    def __post_init__(self) -> None:
        self._mav = mavlink.MAVLink(None, srcSystem=self.sysid, srcComponent=1)
        if self.signing_key is not None:  # pymavlink's own signing, as a vehicle's MAVLink library does it
            self._mav.signing.secret_key = self.signing_key
            self._mav.signing.link_id = 1
            self._mav.signing.timestamp = int((time.time() - 1420070400) * 1e5)  # 10 us since 2015-01-01
            self._mav.signing.sign_outgoing = True
        self._frame = NedFrame(self.origin)
        self.silent = threading.Event()
        self._begin(f"scripted-{self.sysid}")

    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        next_beat = 0.0
        while not self._stop.wait(period):
            if self.silent.is_set():
                continue
            now = time.monotonic()
            t = now - self.t0
            if now >= next_beat:
                next_beat = now + 1.0
                self._send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, self.autopilot,
                                                             mavlink.MAV_MODE_FLAG_SAFETY_ARMED, 0,
                                                             mavlink.MAV_STATE_ACTIVE, 3))  # fmt: skip
            if not self.reports_position:
                continue
            north, east, down = self.path(t)
            dt = 0.05
            n2, e2, d2 = self.path(t + dt)
            vel = ((n2 - north) / dt, (e2 - east) / dt, (d2 - down) / dt)
            geo = self._frame.geo_from_ned((north, east, down))
            self._send(mavlink.MAVLink_global_position_int_message(
                int(t * 1000) & 0xFFFFFFFF, round(geo.lat_deg * 1e7), round(geo.lon_deg * 1e7),
                round(geo.alt_amsl_m * 1e3), round(-down * 1e3), round(vel[0] * 100), round(vel[1] * 100),
                round(vel[2] * 100), 0))  # fmt: skip


def hover_then_circle(centre_ne_m: tuple[float, float], radius_m: float, alt_m: float, speed_mps: float,
                      wait_s: float) -> Path:  # fmt: skip
    """Hover at the circle's southernmost point for ``wait_s``, then fly round the circle anticlockwise seen from
    above (east first) at ``speed_mps``, as a pilot flies a smooth turn."""
    n0, e0 = centre_ne_m

    def at(t_s: float) -> tuple[float, float, float]:
        angle = -math.pi + max(0.0, t_s - wait_s) * speed_mps / radius_m
        return (n0 + radius_m * math.cos(angle), e0 - radius_m * math.sin(angle), -alt_m)

    return at


ARDUCOPTER_GUIDED = 4  # ArduCopter's custom modes (pymavlink's mode_mapping_acm)
ARDUCOPTER_LOITER = 5
ARDUCOPTER_STABILIZE = 0
TAKEOVER_ALT_M = 8.0  # a copter its pilot takes over climbs to this height, where it is
_CLIMB_MPS = 1.0
_MAX_SPEED_MPS = 3.0
_POSITION_GAIN = 1.5  # 1/s: velocity asked per metre from the target, as a position loop's P
_VELOCITY_LAG_S = 0.3  # the vehicle reaches a commanded velocity with this time constant


@dataclass
class Received:
    """What a scripted copter was sent, by wall seconds since its start."""

    time_s: float
    msg: mavlink.MAVLink_message


class ScriptedCopter(_Script):
    """An ArduPilot Copter as a ground station knows one, played by a script over UDP: HEARTBEAT with ArduCopter's
    custom modes, SYS_STATUS (pre-arm checks passed), EXTENDED_SYS_STATE, GLOBAL_POSITION_INT; it answers DO_SET_MODE
    (GUIDED, LOITER), arming, NAV_TAKEOFF (in GUIDED, altitude above home) and a request for its HOME_POSITION with
    COMMAND_ACK, and in GUIDED flies to SET_POSITION_TARGET_GLOBAL_INT setpoints (a position loop with velocity
    feed-forward, a lag on velocity, a speed limit); in LOITER it brakes and holds. With ``takeover_after_setpoints``
    its pilot switches it to LOITER once it has flown that many setpoints, and climbs it to TAKEOVER_ALT_M where it
    is. Everything it is sent is kept (``received``), so a test can check what the ground station asked of it. It
    stands on the ground at ``start_ne_m`` until told otherwise."""

    link: UdpLink  # it reads what the ground station sends back

    def __init__(self, sysid: int, link: UdpLink, origin: GeoPoint, start_ne_m: tuple[float, float],
                 rate_hz: float = 20.0, takeover_after_setpoints: int | None = None) -> None:  # fmt: skip
        self.sysid = sysid
        self.link = link
        self.rate_hz = rate_hz
        self._frame = NedFrame(origin)
        self._home_alt_m = origin.alt_amsl_m
        self.pos = [start_ne_m[0], start_ne_m[1], 0.0]
        self._home_ne_m = start_ne_m
        self.vel = [0.0, 0.0, 0.0]
        self.armed = False
        self.mode = ARDUCOPTER_STABILIZE
        self._target: tuple[float, float, float] | None = None  # NED of the last position setpoint
        self._target_vel = (0.0, 0.0, 0.0)
        self._takeoff_down: float | None = None
        self.received: list[Received] = []
        # its pilot takes it over (LOITER, by its own switch) once it has flown this many setpoints; when, if so
        self._takeover_after = takeover_after_setpoints
        self.taken_over_s: float | None = None
        self._mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
        self._begin(f"copter-{sysid}")

    def commands(self, command: int | None = None) -> list[Received]:
        """The COMMAND_LONGs (or COMMAND_INTs) it was sent, of one command or all."""
        return [r for r in self.received if r.msg.get_type() in ("COMMAND_LONG", "COMMAND_INT")
                and (command is None or r.msg.command == command)]  # fmt: skip

    def setpoints(self) -> list[Received]:
        return [r for r in self.received if r.msg.get_type() == "SET_POSITION_TARGET_GLOBAL_INT"]

    def _ack(self, command: int, ok: bool) -> None:
        result = mavlink.MAV_RESULT_ACCEPTED if ok else mavlink.MAV_RESULT_FAILED
        self._send(mavlink.MAVLink_command_ack_message(command, result, 0, 0, 255, 190))

    def _handle(self, msg: mavlink.MAVLink_message, t_s: float) -> None:
        kind = msg.get_type()
        if getattr(msg, "target_system", self.sysid) not in (0, self.sysid):
            return
        if kind in ("COMMAND_LONG", "COMMAND_INT", "SET_POSITION_TARGET_GLOBAL_INT", "SET_MODE"):
            self.received.append(Received(t_s, msg))
        if kind == "COMMAND_LONG":
            self._command(msg)
        elif kind == "SET_POSITION_TARGET_GLOBAL_INT" and self.mode == ARDUCOPTER_GUIDED and self.armed:
            geo = GeoPoint(lat_deg=msg.lat_int * 1e-7, lon_deg=msg.lon_int * 1e-7, alt_amsl_m=msg.alt)
            self._target = self._frame.ned_from_geo(geo)
            self._target_vel = (msg.vx, msg.vy, msg.vz)
            self._takeoff_down = None
            if self._takeover_after is not None and len(self.setpoints()) >= self._takeover_after:
                self._takeover_after = None
                self.taken_over_s = t_s
                self.mode, self._target = ARDUCOPTER_LOITER, None
                self._takeoff_down = -TAKEOVER_ALT_M  # its pilot climbs it out of the swarm's way

    def _command(self, msg: mavlink.MAVLink_message) -> None:
        command = msg.command
        if command == mavlink.MAV_CMD_DO_SET_MODE:
            ok = int(msg.param2) in (ARDUCOPTER_GUIDED, ARDUCOPTER_LOITER)
            if ok:
                self.mode = int(msg.param2)
                self._target = None
            self._ack(command, ok)
        elif command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            self.armed = msg.param1 == 1.0 or (self.armed and self.pos[2] < -0.1)  # no disarm in the air
            self._ack(command, self.armed == (msg.param1 == 1.0))
        elif command == mavlink.MAV_CMD_REQUEST_MESSAGE and int(msg.param1) == mavlink.MAVLINK_MSG_ID_HOME_POSITION:
            self._ack(command, True)
            home = self._frame.geo_from_ned((self._home_ne_m[0], self._home_ne_m[1], 0.0))
            self._send(mavlink.MAVLink_home_position_message(
                round(home.lat_deg * 1e7), round(home.lon_deg * 1e7), round(home.alt_amsl_m * 1e3), 0.0, 0.0, 0.0,
                [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0))  # fmt: skip
        elif command == mavlink.MAV_CMD_NAV_TAKEOFF:
            ok = self.armed and self.mode == ARDUCOPTER_GUIDED
            if ok:
                self._takeoff_down = -msg.param7
            self._ack(command, ok)
        else:
            self._ack(command, False)

    def _step(self, dt: float) -> None:
        """Kinematics: where the mode and the last command take it, the velocity lagging the one asked."""
        want = [0.0, 0.0, 0.0]
        if self.armed and self._takeoff_down is not None:  # climbs at _CLIMB_MPS, slowing into the altitude (a
            # takeoff, or its pilot's climb)
            want[2] = max(-_CLIMB_MPS, min(_CLIMB_MPS, _POSITION_GAIN * (self._takeoff_down - self.pos[2])))
        elif self.armed and self.mode == ARDUCOPTER_GUIDED and self._target is not None:
            aims = zip(self._target_vel, self._target, self.pos, strict=True)
            want = [v + _POSITION_GAIN * (t - p) for v, t, p in aims]
            speed = math.hypot(*want)
            if speed > _MAX_SPEED_MPS:
                want = [w * _MAX_SPEED_MPS / speed for w in want]
        blend = dt / (_VELOCITY_LAG_S + dt)
        self.vel = [v + blend * (w - v) for v, w in zip(self.vel, want, strict=True)]
        if not self.armed:
            self.vel = [0.0, 0.0, 0.0]
        self.pos = [p + v * dt for p, v in zip(self.pos, self.vel, strict=True)]
        if self.pos[2] > 0.0:  # the ground
            self.pos[2], self.vel[2] = 0.0, min(self.vel[2], 0.0)

    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        next_slow = 0.0
        next_position = 0.0
        last = time.monotonic()
        while not self._stop.wait(period):
            now = time.monotonic()
            t = now - self.t0
            for msg in self.link.read():
                self._handle(msg, t)
            self._step(now - last)
            last = now
            if now >= next_slow:
                next_slow = now + 1.0
                armed = mavlink.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0
                base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | armed
                self._send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR,
                                                             mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, base, self.mode,
                                                             mavlink.MAV_STATE_ACTIVE, 3))  # fmt: skip
                prearm = mavlink.MAV_SYS_STATUS_PREARM_CHECK
                self._send(mavlink.MAVLink_sys_status_message(prearm, prearm, prearm, 100, 16000, -1, 90, 0, 0, 0, 0,
                                                              0, 0))  # fmt: skip
                flying = self.armed and self.pos[2] < -0.1
                landed = mavlink.MAV_LANDED_STATE_IN_AIR if flying else mavlink.MAV_LANDED_STATE_ON_GROUND
                self._send(mavlink.MAVLink_extended_sys_state_message(0, landed))
            if now >= next_position:
                next_position = now + 0.1
                geo = self._frame.geo_from_ned(tuple(self.pos))
                self._send(mavlink.MAVLink_global_position_int_message(
                    int(t * 1000) & 0xFFFFFFFF, round(geo.lat_deg * 1e7), round(geo.lon_deg * 1e7),
                    round(geo.alt_amsl_m * 1e3), round((geo.alt_amsl_m - self._home_alt_m) * 1e3),
                    round(self.vel[0] * 100), round(self.vel[1] * 100), round(self.vel[2] * 100), 0))  # fmt: skip
