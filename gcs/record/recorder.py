"""The flight recorder: everything a flight's report needs, taken from the MAVLink traffic as it passes.

Each drone's reported position (swarm frame) with the slot it was commanded to, its STATUSTEXTs (a collision
counted once per pair), each failsafe it enters (HEARTBEAT system_status turning MAV_STATE_CRITICAL, with its
warning), and every message both ways in ``flight.tlog``. Used by ``swarm fly`` (gcs/supervisor/mission_runner.py) and
by
``swarm up --report`` (gcs/supervisor/station.py); the report itself is gcs/view/report.py.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from gcs.fleet.losses import MAV_STATE_CRITICAL
from gcs.fleet.swarm import Swarm
from gcs.flight.frames import Targets
from gcs.mavlink.statustext import StatusTextAssembler, parse_contact
from gcs.record.metrics import LiveMetrics
from gcs.record.recording import DroneSample, EventRecord, FlightRecording, ItemReached
from gcs.record.tlog import TlogWriter

Say = Callable[[str], None]


class CollisionPairs:
    """Collisions counted once per pair of drones: both drones of a collision report it in a STATUSTEXT."""

    def __init__(self) -> None:
        self.pairs: set[frozenset[int]] = set()

    def observe(self, sysid: int, text: str) -> bool | None:
        """One STATUSTEXT from ``sysid``: None when it reports no collision, else whether the pair is new."""
        contact = parse_contact(text)
        if contact is None or contact.drone is None:
            return None
        pair = frozenset((sysid, contact.drone))
        if pair in self.pairs:
            return False
        self.pairs.add(pair)
        return True

    def __len__(self) -> int:
        return len(self.pairs)


class FlightRecorder:
    def __init__(self, swarm: Swarm, targets: Targets, recording: FlightRecording, clock: Callable[[], float],
                 tlog_path: Path, say: Say | None) -> None:  # fmt: skip
        """What it reads: the swarm's traffic, fleet view, picture and attached vehicles, and ``targets``, each
        drone's slot (the setpoint streamer's, never the streamer); ``clock`` is the flight's time (simulated
        seconds); ``say`` prints drones' warnings and failsafes (None: the caller prints them itself)."""
        self.targets = targets
        self.swarm = swarm
        self._texts = StatusTextAssembler()  # long texts arrive in chunks: each is recorded once, whole
        self.recording = recording
        self.clock = clock
        self.say = say
        self.live = LiveMetrics()
        self.collisions = CollisionPairs()
        self._system_status: dict[int, int] = {}
        self._last_reached: dict[int, int] = {}  # sysid -> the seq of its last MISSION_ITEM_REACHED
        self._epoch_us = int(time.time() * 1e6)
        self._tlog = TlogWriter(tlog_path)
        self.swarm.router.listeners.append(self.on_message)
        self.swarm.router.sent_listeners.append(self.on_sent)

    def _stamp_us(self) -> int:
        # Stamped in simulated time from the flight's start, so a replay runs at the flight's own pace
        return self._epoch_us + int(self.clock() * 1e6)

    def _attached_sample(self, msg: Any, sysid: int, now: float) -> None:
        """An attached vehicle's report, where it says it is, in the swarm frame (docs/external.md)."""
        if sysid not in self.recording.attached:
            spec = self.swarm.attachments.vehicles[sysid].spec
            self.recording.attached[sysid] = (spec.role, spec.url.describe())
        placed = self.swarm.picture.placed(sysid)  # where it says it is (its report just placed it)
        if placed is None:
            return
        pos, vel = placed.pos_ned_m, placed.vel_ned_mps
        view = self.swarm.fleet.drones.get(sysid)
        target = self.targets(now).get(sysid)  # a member's slot, while it has one
        self.recording.attached_samples.append(DroneSample(
            time_s=now, sysid=sysid, pos_ned_m=pos, vel_ned_mps=vel, armed=view.armed if view else True,
            mode=view.mode if view else "EXTERNAL", target_ned_m=target,
        ))  # fmt: skip

    def on_sent(self, data: bytes, _now_s: float) -> None:
        """What the ground station commanded (COMMAND_LONG, PARAM_SET) goes into the tlog beside the answers."""
        if not self._tlog.closed:
            self._tlog.write(data, self._stamp_us())

    def on_message(self, msg: Any, _now_s: float) -> None:
        if not self._tlog.closed:
            self._tlog.write(bytes(msg.get_msgbuf()), self._stamp_us())
        kind = msg.get_type()
        sysid = msg.get_srcSystem()
        now = self.clock()
        attached = self.swarm.attachments.vehicles
        if kind == "LOCAL_POSITION_NED" and sysid not in attached:  # an attached one: from where it says
            placed = self.swarm.picture.placed(sysid)  # the report just placed it (gcs/fleet/picture.py)
            view = self.swarm.fleet.drones.get(sysid)
            if placed is None or view is None:
                return
            pos, vel = placed.pos_ned_m, placed.vel_ned_mps
            target = self.targets(now).get(sysid)
            sample = DroneSample(time_s=now, sysid=sysid, pos_ned_m=pos, vel_ned_mps=vel, armed=view.armed,
                                 mode=view.mode, target_ned_m=target)  # fmt: skip
            self.recording.samples.append(sample)
            self.live.observe(sample)
        elif kind == "GLOBAL_POSITION_INT" and sysid in attached:
            self._attached_sample(msg, sysid, now)
        elif kind == "HEARTBEAT" and msg.get_srcComponent() == 1:
            before = self._system_status.get(sysid)
            self._system_status[sysid] = msg.system_status
            if msg.system_status == MAV_STATE_CRITICAL and before != MAV_STATE_CRITICAL:
                view = self.swarm.fleet.drones.get(sysid)
                warnings = [t for _t, sev, t in (view.texts if view else []) if sev <= mavlink.MAV_SEVERITY_WARNING]
                # (its warning was printed as it came, with the other STATUSTEXTs)
                text = warnings[-1] if warnings else "system status CRITICAL (no warning received)"
                self.recording.failsafes.append(EventRecord(time_s=now, sysid=sysid, text=text))
        elif kind == "MISSION_ITEM_REACHED":
            if self._last_reached.get(sysid) != msg.seq:  # PX4 may repeat the report of one arrival
                self._last_reached[sysid] = msg.seq
                self.recording.items_reached.append(ItemReached(time_s=now, sysid=sysid, seq=msg.seq))
        elif kind == "STATUSTEXT":
            whole = self._texts.feed(sysid, msg)
            if whole is None:
                return  # a chunk of a long text: it is recorded once whole
            if self.collisions.observe(sysid, whole) is False:
                return  # the other drone's report of a collision already recorded
            event = EventRecord(time_s=now, sysid=sysid, text=whole)
            self.recording.events.append(event)
            self.live.observe_event(event, self.recording.collision_radius_m, attached)
            if self.say is not None and msg.severity <= mavlink.MAV_SEVERITY_WARNING:
                self.say(f"  sysid {sysid}: {whole}")

    def close(self) -> None:
        self._tlog.close()
