"""A hosted lockstep mission flies bit for bit as it did when recorded: the digest of its whole flight log.

The closed-loop digests (tests/closed_loop/test_reference_flight.py) hold what a drone computes; this one holds what
lies around it: the host stepping its drones (``--drones-per-process auto``), MAVLink both ways, the neighbour relay,
the lockstep frame and the supervisor's commands, as the ground station logged them (flight.tlog: every message
received and every command sent, in order). A change meant to leave flights alone must leave this digest alone; a
deliberate change of behaviour (a new relay set, a pipelined frame) re-records it once, in its own commit, saying why
and by how much flights moved.

The log's own timestamps are left out, and so are the instances the test was leased: every sysid is counted from the
swarm's first (a drone's randomness comes from its seed, not its instance), in the headers, in a command's target
and in the texts that name a drone, each text whole (a three-digit sysid cuts a long text into chunks elsewhere
than a two-digit one): the same digest from instances 20, 60 and 120. Cost: about 6 s of wall time (9 hosted
drones in lockstep).
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path
from typing import Any

import pytest
from pymavlink import mavutil

from gcs.mavlink.statustext import StatusTextAssembler
from tests.integration.instances import Leases
from tests.integration.mission_flight import MISSIONS, fly_mission

pytestmark = [pytest.mark.sim_only, pytest.mark.timeout(300)]

# Recorded with the pipelined lockstep frame (FLIGHT_VERSION 2: the supervisor's answers a frame later)
RECORDED_DIGEST = "7a168bdd5353b62f6a22291ce7c1dcd18028767f60eebd828f85739532fa0d26"
RECORDED_MESSAGES = 15332  # long STATUSTEXTs counted once, whole
CIRCLE_HOLD_S = 5.0  # the circle held 5 s instead of 30: the transition, avoidance and the relay at work, then land
_DRONE_IN_TEXT = re.compile(r"\b(drone|sysid) (\d+)")


def normalised_log(path: Path, first_sysid: int, drones: int) -> list[tuple[Any, ...]]:
    """Every message of a flight log as (sender, type, fields), each drone's sysid counted from the swarm's first."""

    def drone(sysid: int) -> int:
        return sysid - first_sysid + 1 if first_sysid <= sysid < first_sysid + drones else sysid

    log = mavutil.mavlogfile(str(path))
    texts = StatusTextAssembler()
    out: list[tuple[Any, ...]] = []
    while (msg := log.recv_match()) is not None:
        if msg.get_type() == "BAD_DATA":
            continue
        fields = msg.to_dict()
        if msg.get_type() == "STATUSTEXT":  # whole: a sysid's digits move where a long text is cut into chunks
            text = texts.feed(msg.get_srcSystem(), msg)
            if text is None:
                continue
            fields = {"severity": msg.severity, "text": text}
        if "target_system" in fields:
            fields["target_system"] = drone(fields["target_system"])
        if isinstance(fields.get("text"), str):
            fields["text"] = _DRONE_IN_TEXT.sub(lambda m: f"{m.group(1)} #{drone(int(m.group(2)))}", fields["text"])
        out.append((drone(msg.get_srcSystem()), msg.get_srcComponent(), repr(sorted(fields.items()))))
    return out


def test_a_hosted_lockstep_mission_flies_bit_for_bit_as_recorded(tmp_path: Path, instances: Leases) -> None:
    # GIVEN the classic demo's nine drones, hosted in processes of several drones, in lockstep, the circle held 5 s
    text = (MISSIONS / "grid_to_circle.toml").read_text()
    assert text.count("hold_s = 30.0") == 1
    mission = tmp_path / "grid_to_circle.toml"
    mission.write_text(text.replace("hold_s = 30.0", f"hold_s = {CIRCLE_HOLD_S}"))
    first = instances(9)
    # WHEN it is flown
    metrics, _ = fly_mission(str(mission), ["--lockstep", "--drones-per-process", "auto"], tmp_path, 240, first)
    # THEN its flight log holds, message for message, what it held when recorded
    messages = normalised_log(tmp_path / "report" / "flight.tlog", first + 1, 9)
    digest = hashlib.sha256("\n".join(map(repr, messages)).encode()).hexdigest()
    assert metrics["collisions"] == 0
    assert (len(messages), digest) == (RECORDED_MESSAGES, RECORDED_DIGEST), (len(messages), digest)
