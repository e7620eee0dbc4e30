"""A flying drone survives what real links deliver: noise, broken frames, nonsense, and clients that walk away.

UDP links carry stray datagrams (other tools, port scanners, a second vehicle's traffic, a ground station that
crashed mid-transfer). PX4 drops what it cannot parse and times out protocols a client abandoned; a drone that
crashes, stalls its loop, or stays stuck in a half-finished mission transfer would fall out of the sky or refuse
the next client. These tests need simulation powers (raw injection into the drone's port, a process to watch),
so they only run against drones this suite starts.
"""

from __future__ import annotations

import contextlib
import math
import random
import socket
import time
from collections.abc import Iterator
from dataclasses import dataclass, field

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from tests.integration.mavlink_client import (
    PX4_AUTO_LOITER,
    Message,
    arm_and_take_off,
    mavlink_connection,
    recv_until,
    request_message,
    upload_mission,
    wait_vehicle_heartbeat,
)
from tests.integration.sitl_process import LOOPBACK, SitlDrone, SpawnDrones
from tests.integration.vehicle_link import VehicleLink

pytestmark = [pytest.mark.sim_only, pytest.mark.timeout(90)]

ALTITUDE_TOLERANCE_M = 0.5
MAX_HEARTBEAT_GAP_WALL_S = 2.0  # MAVSDK calls a system lost after 3 s without a heartbeat
CORPUS_SEED = 20240601
STRANGER_SYSID = 200  # the sender of the garbage: no drone of the suite has it (tests/integration/instances.py)
OTHER_SYSID = 201  # a system that is not the drone, for requests addressed elsewhere
UNKNOWN_COMMAND = 65000  # no MAV_CMD has this number
NONSENSE_COPIES = 5
CLIENT_SYSID = 255  # with component 190: how QGroundControl identifies itself
CLIENT_TRIES = 5

# ---------------------------------------------------------------------------------------------------------------
# What the drone is seen doing while it is being disturbed


@dataclass(slots=True)
class FlightWatch:
    """Heartbeats, altitudes and modes of the target system, as received by the client."""

    heartbeat_wall_s: list[float] = field(default_factory=list)
    relative_alt_m: list[float] = field(default_factory=list)
    custom_modes: set[int] = field(default_factory=set)
    armed: set[bool] = field(default_factory=set)

    def drain(self, conn: mavutil.mavfile, for_s: float = 0.0) -> list[Message]:
        """Read everything pending (and for ``for_s`` more), recording the flight state; returns other messages."""
        others: list[Message] = []
        deadline = time.monotonic() + for_s
        while True:
            remaining = deadline - time.monotonic()
            msg = conn.recv_match(blocking=remaining > 0, timeout=remaining if remaining > 0 else None)
            if msg is None:
                if remaining <= 0:
                    return others
                continue
            if msg.get_srcSystem() != conn.target_system:
                continue
            kind = msg.get_type()
            if kind == "HEARTBEAT" and msg.get_srcComponent() == 1:
                self.heartbeat_wall_s.append(time.monotonic())
                self.custom_modes.add(msg.custom_mode)
                self.armed.add(bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED))
            elif kind == "GLOBAL_POSITION_INT":
                self.relative_alt_m.append(msg.relative_alt / 1000.0)
            else:
                others.append(msg)

    def assert_kept_flying(self, altitude_m: float) -> None:
        assert len(self.heartbeat_wall_s) >= 2, f"heartbeats seen: {len(self.heartbeat_wall_s)}"
        gaps = [b - a for a, b in zip(self.heartbeat_wall_s, self.heartbeat_wall_s[1:], strict=False)]
        assert max(gaps) < MAX_HEARTBEAT_GAP_WALL_S, f"heartbeat stalled for {max(gaps):.2f} s"
        assert self.relative_alt_m, "no GLOBAL_POSITION_INT"
        worst = max(self.relative_alt_m, key=lambda alt: abs(alt - altitude_m))
        assert abs(worst - altitude_m) <= ALTITUDE_TOLERANCE_M, f"altitude went to {worst:.2f} m (hold {altitude_m})"
        assert self.custom_modes == {PX4_AUTO_LOITER}, f"modes seen: {self.custom_modes}"
        assert self.armed == {True}, f"armed states seen: {self.armed}"


@contextlib.contextmanager
def _hovering_drone(
    spawn_drones: SpawnDrones,
) -> Iterator[tuple[SitlDrone, VehicleLink, mavutil.mavfile, float, FlightWatch]]:
    """One drone hovering in Hold with a client connected: the drone, its link, the connection, the altitude it
    holds, and a watch that has read everything so far."""
    (drone,) = spawn_drones()
    link = VehicleLink.of(drone)
    with mavlink_connection(link.pymavlink_url) as conn:
        wait_vehicle_heartbeat(conn, drone.sysid, link.wall_s(5))
        altitude_m = arm_and_take_off(conn, link.wall_s(20))
        watch = FlightWatch()
        watch.drain(conn)
        yield drone, link, conn, altitude_m, watch


# ---------------------------------------------------------------------------------------------------------------
# The garbage


def _encoder() -> mavlink.MAVLink:
    return mavlink.MAVLink(None, srcSystem=STRANGER_SYSID, srcComponent=42)


def _harmless_messages(sysid: int) -> list[mavlink.MAVLink_message]:
    """Messages whose effect is at most a reply; their frames are the templates for truncation and bit flips."""
    return [
        mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3),
        mavlink.MAVLink_param_request_read_message(sysid, 1, b"MPC_XY_CRUISE", -1),
        mavlink.MAVLink_timesync_message(0, 123456789),
        mavlink.MAVLink_system_time_message(1_700_000_000_000_000, 1234),
        mavlink.MAVLink_param_request_list_message(OTHER_SYSID, 1),
    ]


def _harmless_frames(sysid: int) -> list[bytes]:
    enc = _encoder()
    return [msg.pack(enc) for msg in _harmless_messages(sysid)]


def _nonsense_frames(sysid: int) -> list[bytes]:
    """Valid frames with absurd content that a vehicle must answer or ignore, never act on or crash over."""
    enc = _encoder()
    nan, inf = float("nan"), float("inf")
    return [
        # unknown command with NaN/inf parameters: COMMAND_ACK UNSUPPORTED expected
        mavlink.MAVLink_command_long_message(sysid, 1, UNKNOWN_COMMAND, 0, nan, inf, -inf, nan, 1e38, -1e38, nan).pack(
            enc
        ),
        # parameter names that are not text, or unknown
        mavlink.MAVLink_param_request_read_message(sysid, 1, b"\xff\xfe\x80\x00garbage", -1).pack(enc),
        mavlink.MAVLink_param_request_read_message(sysid, 1, b"", 32767).pack(enc),
        mavlink.MAVLink_param_set_message(sysid, 1, b"NO_SUCH_PARAM_X", 1.0, 9).pack(enc),
        mavlink.MAVLink_param_set_message(sysid, 1, b"\xc3\x28\xa0\xa1", nan, 200).pack(enc),
        # mission items nobody asked for, outside any transfer
        mavlink.MAVLink_mission_item_int_message(sysid, 1, 7, 6, 16, 0, 1, 0, 0, 0, nan, 2**31 - 1, -(2**31), inf).pack(
            enc
        ),
        mavlink.MAVLink_mission_request_int_message(sysid, 1, 999).pack(enc),
        mavlink.MAVLink_mission_ack_message(sysid, 1, 0).pack(enc),
        # offboard setpoints while not in offboard, with NaN everywhere and a mask of all ones
        mavlink.MAVLink_set_position_target_local_ned_message(
            0, sysid, 1, 1, 0xFFFF, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan
        ).pack(enc),
        # a message id no dialect defines, with a plausible header
        bytes([0xFD, 4, 0, 0, 7, 200, 42, 0xCD, 0xAB, 0x0F]) + b"\x01\x02\x03\x04" + b"\x00\x00",
    ]


def _garbage_corpus(sysid: int, rng: random.Random) -> list[bytes]:
    harmless = _harmless_frames(sysid)
    corpus: list[bytes] = [b"", b"\xfd", b"\xfe", bytes(1472), b"\xfd" * 8000]
    corpus += [rng.randbytes(rng.randint(1, 600)) for _ in range(150)]
    # headers announcing more payload than the datagram holds, or claiming MAVLink 1 with a v2 body
    corpus += [bytes([rng.choice((0xFD, 0xFE)), 255]) + rng.randbytes(rng.randint(0, 40)) for _ in range(60)]
    for _ in range(150):
        frame = rng.choice(harmless)
        cut = rng.randint(1, len(frame) - 1)
        corpus.append(frame[:cut])  # truncated
    for _ in range(200):
        mutated = bytearray(rng.choice(harmless))
        for _ in range(rng.randint(1, 3)):
            mutated[rng.randrange(len(mutated))] ^= 1 << rng.randrange(8)
        corpus.append(bytes(mutated))
    # several frames glued into one datagram, the middle one broken
    for _ in range(40):
        a, b, c = (rng.choice(harmless) for _ in range(3))
        corpus.append(a + b[: len(b) // 2] + c)
    return corpus


def _decodable(datagram: bytes) -> list[Message]:
    """The messages a MAVLink parser would act on (CRC-checked, of a known message id)."""
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    unusable = (mavlink.MAVLink_bad_data, mavlink.MAVLink_unknown)
    return [m for m in parser.parse_buffer(datagram) or [] if not isinstance(m, unusable)]


# ---------------------------------------------------------------------------------------------------------------
# Tests


def test_garbage_truncated_and_mutated_datagrams_do_not_disturb_a_hovering_drone(spawn_drones: SpawnDrones) -> None:
    # GIVEN a drone hovering in Hold
    with _hovering_drone(spawn_drones) as (drone, link, conn, altitude_m, watch):
        # AND a corpus of broken datagrams none of which decodes to a message (checked here, so that a lucky bit
        # flip cannot turn into a real command)
        rng = random.Random(CORPUS_SEED)
        broken = _garbage_corpus(drone.sysid, rng)
        harmless_ids = {msg.id for msg in _harmless_messages(drone.sysid)}
        for datagram in broken:
            assert all(m.get_msgId() in harmless_ids for m in _decodable(datagram)), datagram.hex()

        # WHEN they are sent to the drone's port from a stranger's socket, shuffled with copies of valid frames
        # with nonsensical content, while the drone streams to its client
        nonsense = _nonsense_frames(drone.sysid) * NONSENSE_COPIES
        datagrams = broken + nonsense
        rng.shuffle(datagrams)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger:
            stranger.bind((LOOPBACK, 0))
            replies: list[Message] = []  # read as they come: the drone streams telemetry to the stranger too
            for start in range(0, len(datagrams), 25):
                for datagram in datagrams[start : start + 25]:
                    stranger.sendto(datagram, (LOOPBACK, drone.ports.api_bind))
                watch.drain(conn, for_s=0.02)
                replies += _decodable_replies(stranger, 0.0)
            # THEN every copy of the unknown command among them is answered UNSUPPORTED, to the stranger: a broken
            # datagram costs nothing but itself, since UDP delivers whole datagrams
            replies += _decodable_replies(stranger, link.window_s(2.0) + 0.5)
            acks = [
                (m.result, m.target_system)
                for m in replies
                if m.get_type() == "COMMAND_ACK" and m.command == UNKNOWN_COMMAND
            ]
            kinds = sorted({m.get_type() for m in replies})
            assert len(acks) == NONSENSE_COPIES, f"{len(acks)} of {NONSENSE_COPIES} answered; replies: {kinds}"
            assert set(acks) == {(mavlink.MAV_RESULT_UNSUPPORTED, STRANGER_SYSID)}, acks

        watch.drain(conn, for_s=link.window_s(3.0))
        # THEN the drone kept flying: heartbeats on time, altitude held, still armed in Hold; and answers its client
        _assert_kept_flying_and_answering(drone, conn, watch, altitude_m)


def _assert_kept_flying_and_answering(drone: SitlDrone, conn: mavutil.mavfile, watch: FlightWatch,
                                      altitude_m: float) -> None:  # fmt: skip
    watch.assert_kept_flying(altitude_m)
    assert drone.process.alive(), drone.process.log_tail()
    ack, version = request_message(conn, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION, "AUTOPILOT_VERSION", 3.0)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED, ack
    assert version.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT, version


def _decodable_replies(sock: socket.socket, for_s: float) -> list[Message]:
    """Decodable messages arriving on ``sock`` within ``for_s`` (0: only those already waiting)."""
    replies: list[Message] = []
    deadline = time.monotonic() + for_s
    while (remaining := deadline - time.monotonic()) > -1.0:  # past the deadline: only what is already waiting
        sock.settimeout(remaining if remaining > 0 else 0.0)
        try:
            replies += _decodable(sock.recv(65535))
        except (TimeoutError, BlockingIOError):
            break
    return replies


def _waypoint(conn: mavutil.mavfile, seq: int, lat_e7: int, lon_e7: int, rel_alt_m: float) -> Message:
    return conn.mav.mission_item_int_encode(
        conn.target_system,
        conn.target_component,
        seq,
        mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        mavlink.MAV_CMD_NAV_WAYPOINT,
        0,
        1,
        0.0,
        1.0,
        0.0,
        math.nan,
        lat_e7,
        lon_e7,
        rel_alt_m,
        mavlink.MAV_MISSION_TYPE_MISSION,
    )


def test_abandoned_mission_upload_leaves_the_drone_flying_and_a_fresh_upload_succeeds(
    spawn_drones: SpawnDrones,
) -> None:
    # GIVEN a drone hovering in Hold
    with _hovering_drone(spawn_drones) as (drone, link, conn, altitude_m, watch):
        # WHEN a client announces a 5-item mission upload and then never sends an item
        conn.mav.mission_count_send(conn.target_system, conn.target_component, 5, mavlink.MAV_MISSION_TYPE_MISSION)
        # THEN the drone asks for item 0, and after its retries gives up (goes quiet, or says so with a MISSION_ACK)
        requests: list[int] = []
        give_up_ack: Message | None = None
        deadline = time.monotonic() + link.wall_s(10)
        last_request_at = time.monotonic()
        while time.monotonic() < deadline and give_up_ack is None:
            for msg in watch.drain(conn, for_s=0.1):
                if msg.get_type() in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
                    requests.append(msg.seq)
                    last_request_at = time.monotonic()
                elif msg.get_type() == "MISSION_ACK":
                    give_up_ack = msg
            if requests and time.monotonic() - last_request_at > 1.5:
                break
        assert requests and set(requests) == {0}, f"item requests seen: {requests}"
        assert give_up_ack is not None or time.monotonic() - last_request_at > 1.5, (
            f"still requesting item 0 after {link.wall_s(10):.0f} s ({len(requests)} requests)"
        )
        if give_up_ack is not None:
            assert give_up_ack.type != mavlink.MAV_MISSION_ACCEPTED, f"abandoned upload acknowledged: {give_up_ack}"
        # AND it kept flying meanwhile
        watch.assert_kept_flying(altitude_m)

        # WHEN a fresh 2-item upload follows
        here = recv_until(conn, "GLOBAL_POSITION_INT", lambda m: True, 2.0, "GLOBAL_POSITION_INT")
        items = [
            _waypoint(conn, 0, here.lat + 500, here.lon, 5.0),
            _waypoint(conn, 1, here.lat, here.lon + 500, 5.0),
        ]
        ack = upload_mission(conn, items, link.wall_s(5))
        # THEN it is accepted, and the drone now holds exactly that mission
        assert ack.type == mavlink.MAV_MISSION_ACCEPTED, ack
        conn.mav.mission_request_list_send(conn.target_system, conn.target_component, mavlink.MAV_MISSION_TYPE_MISSION)
        count = recv_until(conn, "MISSION_COUNT", lambda m: True, link.wall_s(2), "MISSION_COUNT")
        assert count.count == len(items), count
        conn.mav.mission_ack_send(conn.target_system, conn.target_component, 0, mavlink.MAV_MISSION_TYPE_MISSION)
        # AND the drone is still hovering in Hold, untouched by either transfer
        watch.drain(conn, for_s=0.5)
        watch.assert_kept_flying(altitude_m)
        assert drone.process.alive(), drone.process.log_tail()


def test_commands_addressed_to_another_system_are_ignored(spawn_drones: SpawnDrones) -> None:
    (drone,) = spawn_drones()
    link = VehicleLink.of(drone)
    with mavlink_connection(link.pymavlink_url) as conn:
        # GIVEN a drone ready to arm
        wait_vehicle_heartbeat(conn, drone.sysid, link.wall_s(5))
        recv_until(
            conn,
            "SYS_STATUS",
            lambda m: bool(m.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_PREARM_CHECK),
            link.wall_s(10),
            "armable",
        )
        # WHEN an arm command and a parameter set addressed to another sysid arrive on its port
        other = drone.sysid + 1
        for confirmation in range(3):
            conn.mav.command_long_send(
                other, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, confirmation, 1, 0, 0, 0, 0, 0, 0
            )
        conn.mav.param_set_send(other, 1, b"MPC_XY_CRUISE", 12.0, mavlink.MAV_PARAM_TYPE_REAL32)
        # THEN it neither answers nor acts: no ACK, still disarmed, parameter unchanged
        watch = FlightWatch()
        others = watch.drain(conn, for_s=link.window_s(3.0))
        assert not [m for m in others if m.get_type() in ("COMMAND_ACK", "PARAM_VALUE")], others
        assert watch.armed == {False}, watch.armed
        conn.mav.param_request_read_send(drone.sysid, 1, b"MPC_XY_CRUISE", -1)
        value = recv_until(conn, "PARAM_VALUE", lambda m: m.param_id == "MPC_XY_CRUISE", 2.0, "MPC_XY_CRUISE")
        assert value.param_value != pytest.approx(12.0), value


def test_a_strangers_truncated_datagram_does_not_lock_another_client_out(spawn_drones: SpawnDrones) -> None:
    (drone,) = spawn_drones()
    link = VehicleLink.of(drone)
    target = (LOOPBACK, drone.ports.api_bind)
    client_encoder = mavlink.MAVLink(None, srcSystem=CLIENT_SYSID, srcComponent=190)
    # A complete, valid command whose last bytes hold 0xFD (the MAVLink 2 start byte), as any frame may: here the
    # command number 65000 = 0xFDE8. Its answer is COMMAND_ACK UNSUPPORTED.
    command = mavlink.MAVLink_command_long_message(drone.sysid, 1, UNKNOWN_COMMAND, 0, 0, 0, 0, 0, 0, 0, 0)
    frame = command.pack(client_encoder)
    assert 0xFD in frame[-8:]
    with (
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as client,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger,
    ):
        client.bind((LOOPBACK, 0))
        stranger.bind((LOOPBACK, 0))
        # GIVEN a client whose command the drone answers
        client.sendto(frame, target)
        assert _acks_for(client, UNKNOWN_COMMAND, link.window_s(1.0) + 0.3), "no answer even before any garbage"
        # WHEN a stranger sends one truncated frame (the first 10 bytes of a valid one) to the same port
        stranger.sendto(frame[:10], target)
        time.sleep(0.05)
        # THEN the client's command is answered again by its second try at the latest, as a retrying ground
        # station expects: UDP delivers whole datagrams, so one sender's broken datagram says nothing about the
        # next datagram, least of all another sender's
        answered = []
        for _ in range(CLIENT_TRIES):
            client.sendto(frame, target)
            answered.append(bool(_acks_for(client, UNKNOWN_COMMAND, link.window_s(1.0) + 0.3)))
        assert any(answered[:2]), f"client answered on tries {answered} after one truncated datagram from a stranger"


def _acks_for(sock: socket.socket, command: int, for_s: float) -> list[Message]:
    return [m for m in _decodable_replies(sock, for_s) if m.get_type() == "COMMAND_ACK" and m.command == command]


FLOOD_WALL_S = 3.0  # longer than MAX_HEARTBEAT_GAP_WALL_S: a loop stuck reading for the whole flood fails


def test_a_flood_of_datagrams_does_not_stall_a_hovering_drone(spawn_drones: SpawnDrones) -> None:
    """A peer sending faster than the drone can parse (a runaway script, a loop bug in a ground station) costs
    the drone the datagrams its socket cannot hold, never its flight loop."""
    # GIVEN a drone hovering in Hold
    with _hovering_drone(spawn_drones) as (drone, link, conn, altitude_m, watch):
        # WHEN a stranger sends it heartbeats as fast as one process can, for longer than a heartbeat gap may last
        heartbeat = mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(_encoder())
        sent = 0
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger:
            stranger.bind((LOOPBACK, 0))
            end = time.monotonic() + FLOOD_WALL_S
            while time.monotonic() < end:
                for _ in range(500):
                    stranger.sendto(heartbeat, (LOOPBACK, drone.ports.api_bind))
                sent += 500
                watch.drain(conn)
        watch.drain(conn, for_s=link.window_s(2.0))
        # THEN it kept flying, heartbeats on time, and still answers its client
        assert sent > 10_000, f"only {sent} datagrams sent: not a flood"
        _assert_kept_flying_and_answering(drone, conn, watch, altitude_m)
