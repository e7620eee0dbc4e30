"""MAVLink 2 signing on the wire: a drone that requires signing (``sitl --signing-key FILE --signing-required``)
is armed and flown by a pymavlink client holding the key, and refuses the same commands unsigned and signed with
another key, saying why once per reason; every frame it sends is signed (the client's parser, given the key,
drops anything unsigned or wrongly signed, and still hears the whole flight). Hosted drones sign too."""

from __future__ import annotations

import hashlib
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl.protocol.signing import REJECTION_TEXT, Verdict
from tests.integration.mavlink_client import (
    command_long,
    mavlink_connection,
    recv_until,
    wait_armable,
    wait_armed_state,
    wait_relative_alt,
    wait_vehicle_heartbeat,
)
from tests.integration.sitl_process import LOOPBACK, InstanceAllocator, SitlDrone, start_drones, stop_drone

pytestmark = [pytest.mark.sim_only, pytest.mark.timeout(150)]

PASSPHRASE = "swarm signing test passphrase"
KEY = hashlib.sha256(PASSPHRASE.encode()).digest()  # what MAVProxy's `signing setup` makes of the passphrase
WRONG_KEY = hashlib.sha256(b"not the swarm's passphrase").digest()
SPEED = 4.0
TAKEOFF_REL_M = 3.0
ATTEMPTS = 4  # each refused command is sent this often: the drone must say why once, not four times
SIGNING_ARGS = ("--signing-required",)
FORCE = 21196.0  # COMPONENT_ARM_DISARM param2: disarm even in flight


@pytest.fixture
def key_file(tmp_path: Path) -> Path:
    path = tmp_path / "swarm.key"
    path.write_text(PASSPHRASE + "\n")
    return path


@pytest.fixture
def signing_drones(
    request: pytest.FixtureRequest,
    instance_allocator: InstanceAllocator,
    tmp_path: Path,
    key_file: Path,
    drone_seed: int,
) -> Iterator[list[SitlDrone]]:
    count, hosted, with_key = request.param
    key_args = ("--signing-key", str(key_file)) if with_key else ()
    instances = instance_allocator.take(count)
    drones: list[SitlDrone] = []
    try:
        drones = start_drones(instances=instances, speed_factor=SPEED, seed=drone_seed, log_dir=tmp_path,
                              extra_args=(*key_args, *SIGNING_ARGS), hosted=hosted)  # fmt: skip
        yield drones
    finally:
        for drone in drones:
            stop_drone(drone)
            print(f"--- sitl instance {drone.ports.instance} ---\n{drone.process.log_tail()}")
        for instance in instances:
            instance_allocator.give_back(instance)


class Intruder:
    """Someone on the network without the key: sends commands to the drone's API port (unsigned, or signed with
    another key) and reads what the drone then streams to it, with a parser that checks no signature."""

    def __init__(self, drone: SitlDrone) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((LOOPBACK, 0))
        self.sock.settimeout(0.1)
        self.target = (LOOPBACK, drone.ports.api_bind)
        self.sysid = drone.sysid
        self.unsigned = mavlink.MAVLink(None, srcSystem=254, srcComponent=191)
        self.wrong = mavlink.MAVLink(None, srcSystem=254, srcComponent=192)
        self.wrong.signing.secret_key = WRONG_KEY
        self.wrong.signing.sign_outgoing = True
        self.wrong.signing.link_id = 0
        self.wrong.signing.timestamp = int((time.time() - 1_420_070_400) * 100_000)
        self.parser = mavlink.MAVLink(None)
        self.parser.robust_parsing = True
        self.heard: list[Any] = []

    def command(self, encoder: Any, command: int, *params: float) -> None:
        padded = (*params, *([0.0] * (7 - len(params))))
        msg = mavlink.MAVLink_command_long_message(self.sysid, 1, command, 0, *padded)
        self.sock.sendto(msg.pack(encoder), self.target)

    def listen(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                data = self.sock.recv(65535)
            except TimeoutError:
                continue
            self.heard += [m for m in self.parser.parse_buffer(data) or [] if m.get_type() != "BAD_DATA"]

    def texts(self) -> list[str]:
        return [m.text for m in self.heard if m.get_type() == "STATUSTEXT"]

    def acks(self) -> list[Any]:
        """The COMMAND_ACKs addressed to the intruder (a link streams every reply to all its peers)."""
        return [m for m in self.heard if m.get_type() == "COMMAND_ACK" and m.target_component in (191, 192)]

    def close(self) -> None:
        self.sock.close()


def _signed_client(conn: Any, sysid: int, wall_s: float) -> None:
    """Hear the drone (pymavlink switches to MAVLink 2 on its first frame), then sign with the key and accept
    nothing unsigned: from here on every frame the client keeps carries a correct signature."""
    wait_vehicle_heartbeat(conn, sysid, wall_s)
    conn.setup_signing(KEY, sign_outgoing=True, allow_unsigned_callback=lambda _mav, _msg_id: False, link_id=0)


@pytest.mark.parametrize("signing_drones", [(1, False, True)], indirect=True)
def test_a_pymavlink_client_with_the_key_flies_a_drone_that_refuses_unsigned_and_wrongly_signed_commands(
    signing_drones: list[SitlDrone],
) -> None:
    (drone,) = signing_drones
    intruder = Intruder(drone)
    try:
        with mavlink_connection(f"udpin:{LOOPBACK}:{drone.ports.api_remote}") as conn:
            _signed_client(conn, drone.sysid, 10)
            wait_armable(conn, 20)

            # WHEN someone without the key tries to arm it, unsigned and then signed with another key
            for _ in range(ATTEMPTS):
                intruder.command(intruder.unsigned, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
                intruder.command(intruder.wrong, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
                intruder.listen(0.25)
            intruder.listen(1.0)
            # THEN the drone does not act (no answer at all, as PX4 drops such frames) and stays disarmed
            assert intruder.acks() == []
            hb = recv_until(conn, "HEARTBEAT", lambda m: m.get_srcComponent() == 1, 5, "heartbeat")
            assert not hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED, hb
            # AND it said why, once for each reason, to everyone on the link (the intruder included)
            texts = intruder.texts()
            assert texts.count(REJECTION_TEXT[Verdict.REJECTED_UNSIGNED]) == 1, texts
            assert texts.count(REJECTION_TEXT[Verdict.REJECTED_BAD_SIGNATURE]) == 1, texts

            # WHEN the client holding the key arms and takes off
            ack = command_long(conn, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (1.0,), 10)
            assert ack.result == mavlink.MAV_RESULT_ACCEPTED, ack
            wait_armed_state(conn, True, 5)
            ground = recv_until(conn, "GLOBAL_POSITION_INT", lambda m: True, 5, "position")
            ground_amsl_m = (ground.alt - ground.relative_alt) / 1000.0
            ack = command_long(conn, mavlink.MAV_CMD_NAV_TAKEOFF, (0, 0, 0, 0, 0, 0, ground_amsl_m + TAKEOFF_REL_M), 10)
            assert ack.result == mavlink.MAV_RESULT_ACCEPTED, ack
            # THEN it climbs to 3 m, every frame the client heard on the way correctly signed
            wait_relative_alt(conn, TAKEOFF_REL_M, 0.3, 30)
            signing = conn.mav.signing
            assert signing.goodsig_count > 100 and signing.badsig_count == 0 and signing.reject_count == 0

            # WHEN the intruder tries to kill the motors in flight, unsigned and wrongly signed
            intruder.listen(0.3)  # what the drone streamed to the intruder during the takeoff
            intruder.heard.clear()
            for _ in range(ATTEMPTS):
                intruder.command(intruder.unsigned, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0.0, FORCE)
                intruder.command(intruder.wrong, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0.0, FORCE)
                intruder.listen(0.25)
            intruder.listen(1.0)
            # THEN the drone flies on at its altitude and says nothing more (it already said why)
            assert intruder.acks() == []
            assert not set(intruder.texts()) & set(REJECTION_TEXT.values()), intruder.texts()
            hb = recv_until(conn, "HEARTBEAT", lambda m: m.get_srcComponent() == 1, 5, "heartbeat")
            assert hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED, hb
            wait_relative_alt(conn, TAKEOFF_REL_M, 0.3, 5)
    finally:
        intruder.close()
    drone.process.stop()
    tail = drone.process.log_tail()
    assert f"{2 * ATTEMPTS} unsigned dropped, {2 * ATTEMPTS} bad signatures, 0 replays" in tail, tail


@pytest.mark.parametrize("signing_drones", [(2, True, True)], indirect=True)
def test_every_hosted_drone_signs_with_the_key_and_refuses_unsigned_commands(signing_drones: list[SitlDrone]) -> None:
    for drone in signing_drones:
        with mavlink_connection(f"udpin:{LOOPBACK}:{drone.ports.api_remote}") as conn:
            _signed_client(conn, drone.sysid, 10)
            wait_armable(conn, 20)
            intruder = Intruder(drone)
            try:
                intruder.command(intruder.unsigned, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
                intruder.listen(1.0)
                assert intruder.acks() == []
                assert REJECTION_TEXT[Verdict.REJECTED_UNSIGNED] in intruder.texts()
            finally:
                intruder.close()
            ack = command_long(conn, mavlink.MAV_CMD_REQUEST_MESSAGE, (mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION,), 10)
            assert ack.result == mavlink.MAV_RESULT_ACCEPTED, ack
            assert conn.mav.signing.goodsig_count > 10 and conn.mav.signing.reject_count == 0


@pytest.mark.parametrize("signing_drones", [(1, False, False)], indirect=True)
def test_setup_signing_over_the_link_installs_the_key_on_a_drone_that_has_none(signing_drones: list[SitlDrone]) -> None:
    (drone,) = signing_drones
    with mavlink_connection(f"udpin:{LOOPBACK}:{drone.ports.api_remote}") as conn:
        # GIVEN a drone that requires signing but has no key yet (so it checks nothing), and a client that heard it
        wait_vehicle_heartbeat(conn, drone.sysid, 10)
        wait_armable(conn, 20)
        # WHEN the client sends SETUP_SIGNING with the key, as QGroundControl and MAVProxy provision a vehicle
        initial = int((time.time() - 1_420_070_400) * 100_000)
        conn.mav.setup_signing_send(drone.sysid, 1, list(KEY), initial)
        # THEN the drone says it installed the key (named by its id, never shown)
        key_id = hashlib.sha256(KEY).hexdigest()[:8]
        recv_until(conn, "STATUSTEXT", lambda m: m.text == f"MAVLink signing key {key_id} installed", 5, "installed")
        # AND from then on an unsigned command is dropped, with the reason said once
        conn.mav.command_long_send(drone.sysid, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        required = REJECTION_TEXT[Verdict.REJECTED_UNSIGNED]
        recv_until(conn, "STATUSTEXT", lambda m: m.text == required, 5, "signing required")
        with pytest.raises(AssertionError, match="not within"):
            recv_until(conn, "COMMAND_ACK", lambda m: True, 2, "an ACK for the unsigned arm")
        # AND the same command signed with the installed key is obeyed
        conn.setup_signing(KEY, sign_outgoing=True, allow_unsigned_callback=lambda _mav, _msg_id: False, link_id=0)
        ack = command_long(conn, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (1.0,), 10)
        assert ack.result == mavlink.MAV_RESULT_ACCEPTED, ack
        wait_armed_state(conn, True, 5)
