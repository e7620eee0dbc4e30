"""Vehicles the ground station did not start, attached to the swarm over MAVLink: a real drone on a telemetry radio or
Wi-Fi, another autopilot's SITL, a scripted stand-in (docs/external.md).

An attached vehicle is known only by what it says on its link, as any ground station knows a vehicle: its HEARTBEAT
(sysid, autopilot, mode), its GLOBAL_POSITION_INT. The swarm puts its body into the simulated world where that
telemetry says it is (``SimulationHarness.place_external_body``), so the simulated drones' cameras see it and a
drone that touches it crashes; an intruder's position reports reach the simulated drones as traffic (ADSB_VEHICLE),
which their collision prevention avoids in full.

Roles (``ROLES``): an ``intruder`` is never commanded, only seen, avoided and counted; a ``leader`` is not commanded
either, and the simulated drones follow it (the ``follow_attached`` verb); a ``member`` takes a slot in the swarm's
formations and behaviours and is flown as a ground station flies a vehicle (PX4 in OFFBOARD, ArduPilot Copter in
GUIDED, position setpoints in SET_POSITION_TARGET_GLOBAL_INT), under the safety rules of hardware
(gcs/fleet/attachments.py): armed and taken off only when the user says so (``arm``), no setpoint outside its
keep-in (``keep_in_m``), a radio's budget, and Hold when the swarm stops.

Pure parts (the attach spec, its parser) and one IO shell (``ExternalLink``: a pymavlink connection, so every link
pymavlink opens works: UDP either way, TCP, serial).
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from pymavlink.dialects.v20 import common as mavlink

from gcs.flight.geodesy import GeoPoint, geo_from_ned
from gcs.mavlink import signing
from gcs.mavlink.commands import AUTOPILOT_COMPID
from gcs.mavlink.signing import SigningKeyError, load_key
from gcs.mavlink.transport import GCS_COMPID
from gcs.mavlink.urls import UrlError, VehicleUrl, parse_vehicle_url

ROLES: Final = ("member", "leader", "intruder")
DEFAULT_ROLE: Final = "member"
# A member is sent no setpoint farther than this from the swarm's origin horizontally, nor higher above it, nor lower
# than KEEP_IN_FLOOR_M above it: a cylinder around where the swarm flies, as PX4's GF_MAX_HOR_DIST and GF_MAX_VER_DIST
DEFAULT_KEEP_IN_M: Final = 100.0
KEEP_IN_FLOOR_M: Final = 0.5
HEARTBEAT_TIMEOUT_S: Final = 10.0  # wall seconds an attach waits for the vehicle's first HEARTBEAT
OTHERS_SETTLE_S: Final = 1.5  # after the first vehicle's HEARTBEAT, listen this long for others on the same link
# A vehicle farther than this from the swarm's origin when it is attached is refused: it is not where the swarm flies
# (a wrong origin, a vehicle on another field), and its body would be kilometres off
DEFAULT_MAX_DISTANCE_M: Final = 500.0
MAX_READ_PER_POLL: Final = 200  # messages one poll of a link reads at most (a flooding link cannot stall the swarm)
EXTRAPOLATE_MAX_S: Final = 1.0  # a report older than this is not carried on further: the vehicle may have stopped
# Frames a second the ground station sends on an attached link at most (51-byte ADSB_VEHICLE reports of the simulated
# drones): about 1 kB/s, a sixth of what a 57.6 kbit/s telemetry radio carries
LINK_BUDGET_PER_S: Final = 20.0


class AttachError(ValueError):
    """An attach that cannot be done; the message is one line. A swarm already flying is not disturbed by it."""


@dataclass(frozen=True, slots=True, kw_only=True)
class AttachSpec:
    """What to attach: a role, and the link the vehicle (or several, on one radio) is heard on."""

    role: str
    url: VehicleUrl
    radius_m: float | None = None  # its body's size; None: the simulated drones' own
    max_distance_m: float = DEFAULT_MAX_DISTANCE_M  # a vehicle farther from the swarm's origin is refused
    # MAVLink 2 signing on this link: its frames must be signed with this key (others are dropped), ours are signed
    signing_key_file: Path | None = None
    arm: bool = False  # a member: armed and taken off with the swarm (else the user flies it up, and it joins)
    keep_in_m: float = DEFAULT_KEEP_IN_M  # a member: no setpoint outside this cylinder around the origin

    def describe(self) -> str:
        return f"{self.role}={self.url.describe()}"


def parse_attach(text: str, *, radius_m: float | None = None, max_distance_m: float = DEFAULT_MAX_DISTANCE_M,
                 signing_key_file: Path | None = None, arm: bool = False,
                 keep_in_m: float = DEFAULT_KEEP_IN_M) -> AttachSpec:  # fmt: skip
    """``[ROLE=]URL`` as ``--attach`` takes it; AttachError (one line) for an unknown role, a bad URL or a bad
    number."""
    role, rest = _split_role(text)
    if role not in ROLES:
        raise AttachError(f"--attach {text!r}: no role {role!r} (roles: {', '.join(ROLES)})")
    if arm and role != "member":
        raise AttachError(f"--attach {text!r}: only a member is armed by the swarm, not a {role}")
    if not (math.isfinite(keep_in_m) and keep_in_m > KEEP_IN_FLOOR_M):
        raise AttachError(f"--attach {text!r}: the keep-in must be more than {KEEP_IN_FLOOR_M:g} m, got {keep_in_m}")
    if radius_m is not None and not (math.isfinite(radius_m) and 0.0 < radius_m <= 10.0):
        raise AttachError(f"--attach {text!r}: radius_m must be in (0, 10] m, got {radius_m}")
    if not (math.isfinite(max_distance_m) and max_distance_m > 0.0):
        raise AttachError(f"--attach {text!r}: the largest distance from the origin must be positive, got "
                          f"{max_distance_m}")  # fmt: skip
    try:
        url = parse_vehicle_url(rest)
    except UrlError as exc:
        raise AttachError(f"--attach: {exc}") from None
    return AttachSpec(role=role, url=url, radius_m=radius_m, max_distance_m=max_distance_m,
                      signing_key_file=signing_key_file, arm=arm, keep_in_m=keep_in_m)  # fmt: skip


def _split_role(text: str) -> tuple[str, str]:
    """``[ROLE=]URL`` -> role (lower case, DEFAULT_ROLE when none is given), URL."""
    role, sep, rest = text.partition("=")
    if not sep or not role.isalpha():
        return DEFAULT_ROLE, text
    return role.lower(), rest


def role_of(text: str) -> str:
    """The role an ``[ROLE=]URL`` names (DEFAULT_ROLE when it names none)."""
    return _split_role(text)[0]


def is_vehicle_heartbeat(msg: Any) -> bool:
    """A HEARTBEAT of an autopilot (not of a ground station, a camera or a companion computer)."""
    return (
        msg.get_type() == "HEARTBEAT"
        and msg.get_srcComponent() == AUTOPILOT_COMPID
        and msg.autopilot != mavlink.MAV_AUTOPILOT_INVALID
        and msg.type != mavlink.MAV_TYPE_GCS
    )


@dataclass(slots=True)
class AttachedVehicle:
    """One attached vehicle, as the swarm knows it."""

    sysid: int
    spec: AttachSpec
    link: ExternalLink
    position: GeoPoint | None = None  # where its last GLOBAL_POSITION_INT put it
    vel_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    position_s: float = math.nan  # supervisor clock when that report arrived
    lost: bool = False
    # A member's commanding (gcs/fleet/attachments.py): the purpose of the last mode the swarm asked of it
    # (gcs/mavlink/modes.py OFFBOARD, HOLD; None: never asked) and when, and why the swarm no longer commands it
    asked: str | None = None
    asked_s: float = math.nan
    released: str | None = None
    setpoint_s: float = -math.inf  # when its last setpoint went out

    def body_at(self, now_s: float) -> GeoPoint | None:
        """Where its last report, carried on at its velocity to ``now_s`` (EXTRAPOLATE_MAX_S at most), puts it; a
        vehicle gone silent stays where it was last known (a real drone does not vanish)."""
        if self.position is None:
            return None
        age_s = 0.0 if self.lost else min(max(now_s - self.position_s, 0.0), EXTRAPOLATE_MAX_S)
        if age_s == 0.0:
            return self.position
        return geo_from_ned(tuple(v * age_s for v in self.vel_ned_mps), self.position)


def reported_geo(position: Any) -> GeoPoint:
    """Where a GLOBAL_POSITION_INT puts its sender."""
    return GeoPoint(lat_deg=position.lat * 1e-7, lon_deg=position.lon * 1e-7, alt_amsl_m=position.alt * 1e-3)


@dataclass(slots=True)
class TokenBucket:
    """At most ``rate_per_s`` on average, ``burst`` at once: what a link's radio may be given."""

    rate_per_s: float
    burst: float
    _tokens: float = 0.0
    _last_s: float = -math.inf

    def take(self, now_s: float) -> bool:
        """One token now, if there is one."""
        elapsed = now_s - self._last_s if math.isfinite(self._last_s) else math.inf
        self._tokens = min(self.burst, self._tokens + elapsed * self.rate_per_s)
        self._last_s = now_s
        if self._tokens < 1.0:
            return False
        self._tokens -= 1.0
        return True


@dataclass(slots=True)
class ExternalLink:
    """One link to vehicles outside the simulation, opened with pymavlink (its transport for every kind of link),
    read and written as MAVLink 2 by the ground station's own identity (sysid 255 unless set, component 190)."""

    spec: AttachSpec
    source_system: int
    conn: Any = None
    sysids: set[int] = field(default_factory=set)
    # what the ground station may send on the link each second (the simulated drones as traffic): a radio's budget
    budget: TokenBucket = field(
        default_factory=lambda: TokenBucket(rate_per_s=LINK_BUDGET_PER_S, burst=LINK_BUDGET_PER_S)
    )

    def open(self) -> None:
        """Open the link; AttachError (one line) when it cannot be (a port taken, a refused TCP connection, a missing
        serial device, no pyserial)."""
        from pymavlink import mavutil  # opening links is the only use, and it costs 0.1 s to import

        url = self.spec.url
        key = None
        if self.spec.signing_key_file is not None:
            try:
                key = load_key(self.spec.signing_key_file)
            except SigningKeyError as exc:
                raise AttachError(f"--attach {self.spec.describe()}: {exc}") from None
        if url.kind == "serial":
            try:
                import serial  # noqa: F401  (pymavlink opens serial ports through pyserial)
            except ImportError:
                raise AttachError(
                    f"--attach {self.spec.describe()}: serial links need pyserial (pip install 'swarmsitl[serial]')"
                ) from None
        try:
            conn = mavutil.mavlink_connection(url.device, source_system=self.source_system,
                                              source_component=GCS_COMPID, autoreconnect=False)  # fmt: skip
        except Exception as exc:  # pymavlink raises what its transport raises: OSError, serial errors, ValueError
            raise AttachError(f"--attach {self.spec.describe()}: cannot open the link: {_one_line(exc)}") from None
        # Read and write MAVLink 2 from the start (pymavlink would switch a process-wide setting on the first MAVLink 2
        # frame it sees); the common dialect's parser reads MAVLink 1 frames too.
        conn.first_byte = False
        conn.WIRE_PROTOCOL_VERSION = "2.0"
        conn.mav = mavlink.MAVLink(conn, srcSystem=self.source_system, srcComponent=GCS_COMPID)
        conn.mav.robust_parsing = True
        if key is not None:  # pymavlink then drops unsigned and badly signed frames as BAD_DATA
            signing.enable(conn.mav, key, time.time())
        self.conn = conn

    def receive(self) -> list[Any]:
        """What has arrived, without waiting (at most MAX_READ_PER_POLL messages)."""
        out: list[Any] = []
        if self.conn is None:
            return out
        for _ in range(MAX_READ_PER_POLL):
            try:
                msg = self.conn.recv_msg()
            except OSError:
                break
            if msg is None:
                break
            if msg.get_type() != "BAD_DATA":
                out.append(msg)
        return out

    def send(self, msg: Any) -> None:
        if self.conn is not None:
            with contextlib.suppress(OSError):  # a radio gone or a peer not yet heard: the link's own business
                self.conn.mav.send(msg)

    def close(self) -> None:
        if self.conn is not None:
            with contextlib.suppress(Exception):
                self.conn.close()
            self.conn = None


TRAFFIC_FLAGS: Final = (
    mavlink.ADSB_FLAGS_VALID_COORDS
    | mavlink.ADSB_FLAGS_VALID_ALTITUDE
    | mavlink.ADSB_FLAGS_VALID_HEADING
    | mavlink.ADSB_FLAGS_VALID_VELOCITY
    | mavlink.ADSB_FLAGS_VALID_CALLSIGN
)


def traffic_report(position: Any) -> Any:
    """A vehicle's GLOBAL_POSITION_INT as the ADSB_VEHICLE a ground station relays for traffic that does not avoid
    in turn: its sysid as the ICAO address, geometric altitude, heading and speeds from its velocity (PX4 takes
    traffic so, from an ADS-B receiver or a ground station; the simulated drones avoid it in full:
    sitl/protocol/neighbours.py)."""
    return _adsb(position.get_srcSystem(), position.lat, position.lon, position.alt, position.vx, position.vy,
                 position.vz, 0)  # fmt: skip


def last_known_traffic(sysid: int, where: GeoPoint, age_s: float) -> Any:
    """A vehicle no longer heard, as traffic where it was last known, standing still, with ``tslc`` the whole seconds
    since (at most 255): the simulated drones widen their keep-out around it with that age (AVOID_STALE_RATE)."""
    return _adsb(sysid, round(where.lat_deg * 1e7), round(where.lon_deg * 1e7), round(where.alt_amsl_m * 1e3), 0, 0,
                 0, min(255, max(0, math.floor(age_s))))  # fmt: skip


def _adsb(sysid: int, lat_e7: int, lon_e7: int, alt_mm: int, vx_cms: int, vy_cms: int, vz_cms: int, tslc_s: int) -> Any:
    vn, ve = vx_cms * 0.01, vy_cms * 0.01
    heading_cdeg = round(math.degrees(math.atan2(ve, vn)) * 100.0) % 36000
    return mavlink.MAVLink_adsb_vehicle_message(
        sysid, lat_e7, lon_e7, mavlink.ADSB_ALTITUDE_TYPE_GEOMETRIC, alt_mm, heading_cdeg,
        min(round(math.hypot(vn, ve) * 100.0), 0xFFFF), max(-32768, min(32767, -vz_cms)), f"SYS{sysid}".encode(),
        mavlink.ADSB_EMITTER_TYPE_UAV, tslc_s, TRAFFIC_FLAGS, 0,
    )  # fmt: skip


HOME_WAIT_S: Final = 10.0  # wall seconds to wait for a vehicle's home before the swarm's origin is put there
HOME_ASK_PERIOD_S: Final = 1.0  # HOME_POSITION asked for this often meanwhile (as MAVSDK asks until home exists)
HOME_FALLBACK_S: Final = 3.0  # with no HOME_POSITION by then, a vehicle standing still gives its ground point
_PROBE_POLL_S: Final = 0.02


def find_home(spec: AttachSpec, own_sysid: int, timeout_s: float = HOME_WAIT_S) -> tuple[int, GeoPoint]:
    """The first vehicle heard on ``spec``'s link and its home, for the swarm's origin (``--origin attached``),
    before the swarm exists: its HOME_POSITION (asked for with MAV_CMD_REQUEST_MESSAGE, which PX4 and ArduPilot
    answer), or, when none comes within HOME_FALLBACK_S, where it stands (its GLOBAL_POSITION_INT less its height
    above home). The link is closed again (the attach opens it anew); AttachError (one line) when nothing comes."""
    link = ExternalLink(spec=spec, source_system=own_sysid)
    link.open()
    try:
        sysid: int | None = None
        standing: GeoPoint | None = None
        start = time.monotonic()
        asked_s = -math.inf
        while (now := time.monotonic()) - start < timeout_s:
            for msg in link.receive():
                if sysid is None and is_vehicle_heartbeat(msg):
                    sysid = msg.get_srcSystem()
                if sysid is None or msg.get_srcSystem() != sysid or msg.get_srcComponent() != AUTOPILOT_COMPID:
                    continue
                if msg.get_type() == "HOME_POSITION":
                    return sysid, GeoPoint(lat_deg=msg.latitude * 1e-7, lon_deg=msg.longitude * 1e-7,
                                           alt_amsl_m=msg.altitude * 1e-3)  # fmt: skip
                if msg.get_type() == "GLOBAL_POSITION_INT":
                    here = reported_geo(msg)
                    standing = GeoPoint(lat_deg=here.lat_deg, lon_deg=here.lon_deg,
                                        alt_amsl_m=here.alt_amsl_m - msg.relative_alt * 1e-3)  # fmt: skip
            if sysid is not None and now - asked_s >= HOME_ASK_PERIOD_S:
                asked_s = now
                link.send(mavlink.MAVLink_command_long_message(
                    sysid, AUTOPILOT_COMPID, mavlink.MAV_CMD_REQUEST_MESSAGE, 0,
                    mavlink.MAVLINK_MSG_ID_HOME_POSITION, 0, 0, 0, 0, 0, 0))  # fmt: skip
            if standing is not None and now - start >= HOME_FALLBACK_S:
                return sysid or 0, standing
            time.sleep(_PROBE_POLL_S)
        what = "no vehicle HEARTBEAT" if sysid is None else f"no home or position from sysid {sysid}"
        raise AttachError(f"--origin attached: {what} on {spec.url.describe()} within {timeout_s:g} s")
    finally:
        link.close()


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def sysid_problem(
    sysid: int, simulated: Mapping[int, object], attached: Mapping[int, object], own_sysid: int
) -> str | None:
    """Why a vehicle of this sysid cannot be attached (one phrase), or None."""
    if sysid == own_sysid:
        return f"sysid {sysid} is the ground station's own"
    if sysid in simulated:
        return f"sysid {sysid} is a simulated drone's (move them with --first-instance)"
    if sysid in attached:
        return f"sysid {sysid} is attached already"
    return None
