"""The supervisor's MAVLink traffic, as a router carries it: reading, batching, forwarding and the relay.

One socket (gcs/mavlink/transport.py) that every drone's ground-station link streams to. What comes in is read per
pump (paced: whatever has arrived; lockstep: everything the drones say they sent up to the gate, in sysid order).
What goes out either leaves at once (a command whose answer is awaited) or is held for the next batch
(``BATCH_HOLD_S``): setpoints, relayed positions and copies for another ground station leave together in one
datagram per drone. In lockstep nothing leaves at once: the drones fly while the supervisor works (the pipelined
frame, gcs/fleet/pump.py), so everything waits for the pump's flush at the next gate, where every drone reads it
before its next step. Every drone's traffic is copied to a forward address (QGroundControl, MAVProxy on 14550), and
what comes back from there goes to the drones by target system. The ground station's own HEARTBEAT goes to every
drone at 1 Hz.
"""

from __future__ import annotations

import logging
import math
import selectors
import time
from collections.abc import Callable, Collection, Mapping
from typing import Any, Final

from pymavlink.dialects.v20 import common as mavlink

from gcs.fleet.clock import LOCKSTEP_MAX_WAIT_S
from gcs.fleet.relay import NeighbourRelay
from gcs.fleet.telemetry import Fleet
from gcs.mavlink.transport import GcsSocket

log = logging.getLogger(__name__)

Address = tuple[str, int]

# Relayed positions (and copies for another ground station) are held up to this long, in simulated seconds, and
# leave with the next setpoint tick in one datagram per drone (gcs/mavlink/transport.py). A drone then wakes once per
# tick instead of once per neighbour report: with 8 neighbours reporting at 10 Hz that is 20 wake-ups a second instead
# of 100, and a wake-up costs a drone more CPU than the message it brings (docs/benchmarks.md). The receiving drone's
# neighbour table ages every report by its sender's timestamp in lockstep; paced, by its arrival.
BATCH_HOLD_S: Final = 0.05
GCS_HEARTBEAT_PERIOD_S: Final = 1.0  # QGroundControl's HEARTBEAT rate; PX4's datalink-loss failsafe watches it
LOCKSTEP_AWAIT_S: Final = 1.0  # wall seconds the supervisor waits for a datagram a drone says it has sent
# Paced, a pump that gathers reads at most this often (wall seconds): what arrives meanwhile is read in one go. A host
# sends its drones' telemetry as a burst of datagrams, and a supervisor woken by each one read a datagram or two per
# wake-up; a wake-up costs more than the datagrams it reads (docs/benchmarks.md). Work that waits for an answer
# (a command being timed, a protocol client's transfer) pumps without gathering.
GATHER_S: Final = 0.005


class Router:
    """The socket's traffic both ways; see the module docstring."""

    def __init__(self, link: GcsSocket, *, relay: NeighbourRelay | None, forward: Address | None,
                 batch_hold_s: float = BATCH_HOLD_S, lockstep: bool = False) -> None:  # fmt: skip
        self.link = link
        # Lockstep: what would leave at once is queued for the next gate instead (the module docstring says why)
        self.lockstep = lockstep
        self.relay = relay
        # Every drone's traffic also goes to this address, and what comes back from there is routed to the drones by
        # target system, as a MAVLink router does.
        self.forward = forward
        self.batch_hold_s = batch_hold_s
        # Every message received (from the drones' socket or an attached vehicle's link), once the swarm has taken it
        # in (``delivered``): the flight log, the live view, a front-end's status; and every command and parameter
        # write sent (to a drone or an attached vehicle), as a packed MAVLink frame: the flight log keeps both ways
        self.listeners: list[Callable[[Any, float], None]] = []
        self.sent_listeners: list[Callable[[bytes, float], None]] = []
        self._flush_due_s = math.inf  # when the queued traffic must leave (-inf: at the next pump)
        self._next_heartbeat_s = 0.0
        self._said_late_traffic = False
        self._last_read_wall_s = -math.inf  # when the socket was last read (paced gathering)
        # Lockstep delivery: each drone's datagrams taken into a frame so far, by address, and the datagrams read
        # beyond what a drone had sent up to the gate (it flies the next frame while the supervisor reads), kept in
        # order for the next frame
        self._taken: dict[Address, int] = {}
        self._held: list[tuple[Address, list[Any]]] = []
        self._selector = selectors.DefaultSelector()
        self._selector.register(link.sock, selectors.EVENT_READ)

    # ---- in --------------------------------------------------------------------------------------------------------
    def wait(self, wait_s: float, speed_factor: float, now_s: float, *, gather: bool = False) -> None:
        """Paced: wait up to ``wait_s`` simulated seconds for traffic (less when a batch is due sooner); with
        ``gather``, not until GATHER_S of wall time has passed since the socket was last read (within the wait)."""
        if wait_s > 0:
            if self.link.queued:
                wait_s = min(wait_s, max(0.0, self._flush_due_s - now_s))
            wall_s = wait_s / speed_factor
            if gather:
                rest_s = min(wall_s, self._last_read_wall_s + GATHER_S - time.monotonic())
                if rest_s > 0.0:
                    time.sleep(rest_s)
                    wall_s -= rest_s
            self._selector.select(wall_s)

    def receive(self) -> list[tuple[Any, Address]]:
        """Paced: what has arrived."""
        self._last_read_wall_s = time.monotonic()
        return self.link.receive()

    def receive_frame(self, sent_by_drones: Mapping[int, int], skip: Collection[int]) -> list[tuple[Any, Address]]:
        """Lockstep: everything the drones sent up to the gate they stood at (``sent_by_drones``: each one's count
        of datagrams then), in sysid order (each sender's own order kept). The drones fly the next frame meanwhile,
        so a drone's datagrams beyond its count are the next frame's: they are kept for it. Loopback UDP may hand a
        datagram over a little after its ``sendto`` returned, so the supervisor reads until it has as many from
        each drone as the drone says it sent (``skip``: the lost, whose count no longer matters); one that never
        comes (a full buffer) is given up after LOCKSTEP_AWAIT_S, and said once."""
        messages: list[tuple[Any, Address]] = []
        link, taken = self.link, self._taken
        deadline = time.monotonic() + LOCKSTEP_AWAIT_S
        pending, self._held = self._held, []
        while True:
            pending += link.receive_datagrams()
            owners = {address: sysid for sysid, address in link.addresses.items()}
            for address, frames in pending:
                expected = sent_by_drones.get(owners.get(address, -1))
                if expected is not None and taken.get(address, 0) >= expected:
                    self._held.append((address, frames))  # sent after the gate: the next frame's
                    continue
                taken[address] = taken.get(address, 0) + 1
                messages.extend((msg, address) for msg in frames)
            pending = []
            addresses = link.addresses
            missing = [s for s, n in sent_by_drones.items()
                       if s not in skip and s in addresses and n > taken.get(addresses[s], 0)]  # fmt: skip
            if not missing:
                break
            if time.monotonic() > deadline:
                if not self._said_late_traffic:
                    self._said_late_traffic = True
                    log.warning("lockstep: datagrams from sysid %s never arrived; going on", missing)
                break
            self._selector.select(LOCKSTEP_MAX_WAIT_S)
        messages.sort(key=lambda item: int(item[0].get_srcSystem()))
        return messages

    def carry(self, msg: Any, now_s: float, fleet: Fleet, *, relay: bool = True) -> None:
        """A drone's message, carried on: a copy to the forward address, and (``relay``) its position to the other
        drones the relay chooses."""
        if self.forward is not None:
            self.hold(bytes(msg.get_msgbuf()), self.forward, now_s)
        if relay and self.relay is not None and msg.get_type() == "GLOBAL_POSITION_INT":
            data = bytes(msg.get_msgbuf())
            for target in self.relay.targets(msg.get_srcSystem(), now_s, fleet):
                address = self.link.addresses.get(target)
                if address is not None:
                    self.hold(data, address, now_s)

    def relay_traffic(self, source: int, report: Any, now_s: float, fleet: Fleet) -> None:
        """A report of traffic (``report``, an ADSB_VEHICLE about ``source``, packed as the ground station's own)
        to the drones the relay chooses for ``source``'s position, at the relay's rate."""
        if self.relay is None:
            return
        targets = self.relay.targets(source, now_s, fleet)
        if not targets:
            return
        data = self.link.pack(report)
        for target in targets:
            address = self.link.addresses.get(target)
            if address is not None:
                self.hold(data, address, now_s)

    def delivered(self, msg: Any, now_s: float) -> None:
        """A message the swarm has taken in (fleet view, liveness, the protocol clients), handed to ``listeners``."""
        for listener in self.listeners:
            listener(msg, now_s)

    def from_ground_station(self, msg: Any, sysids: list[int]) -> None:
        """A message from another ground station (QGroundControl, MAVProxy on the forward port): to its target."""
        if self.forward is None:
            return
        target = getattr(msg, "target_system", 0)
        data = bytes(msg.get_msgbuf())
        for sysid in sysids if target == 0 else [target]:
            address = self.link.addresses.get(sysid)
            if address is not None:
                if self.lockstep:
                    self.link.queue_raw(data, address)
                    self._flush_due_s = -math.inf
                else:
                    self.link.send_raw(data, address)

    def sent_to_drones(self) -> dict[int, int]:
        """The datagrams sent so far to each drone, by sysid (lockstep delivery counts them)."""
        return {s: self.link.sent_to.get(a, 0) for s, a in self.link.addresses.items()}

    # ---- out -------------------------------------------------------------------------------------------------------
    def hold(self, data: bytes, address: Address, now_s: float) -> None:
        """Queue traffic that may wait for the next batch (at most ``batch_hold_s``)."""
        if not self.link.queued:
            self._flush_due_s = now_s + self.batch_hold_s
        self.link.queue_raw(data, address)

    def flush(self, now_s: float) -> None:
        """Send what is queued, once its batch is due."""
        if self.link.queued and now_s >= self._flush_due_s:
            self.link.flush()
            self._flush_due_s = math.inf

    def heartbeat(self, now_s: float, lost: Collection[int]) -> None:
        """The ground station's own HEARTBEAT to every drone heard (as QGroundControl sends it) at 1 Hz of simulated
        time: PX4's datalink-loss failsafe (COM_DL_LOSS_T) counts from the last one. Lost drones get none."""
        if now_s < self._next_heartbeat_s:
            return
        self._next_heartbeat_s = now_s + GCS_HEARTBEAT_PERIOD_S
        msg = mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE, 3
        )
        for sysid in list(self.link.addresses):
            if sysid not in lost:
                self.link.queue(sysid, msg)
        self._flush_due_s = -math.inf

    def send(self, sysid: int, msg: Any) -> None:
        """Streamed traffic (setpoints): leaves at the start of the next pump, batched with whatever else is queued
        for the drone."""
        if self.link.queue(sysid, msg):
            self._flush_due_s = -math.inf

    def send_now(self, sysid: int, msg: Any) -> None:
        """One message to one drone at once, outside any batch (a command whose answer is being timed); in lockstep
        at the next gate, with the batch."""
        if self.lockstep:
            self.send(sysid, msg)
        else:
            self.link.send(sysid, msg)

    def send_logged(self, sysid: int, msg: Any, *, now: bool, clock_s: float) -> None:
        """A command or parameter write, at once (in lockstep: at the next gate) or with the next batch, also handed
        to ``sent_listeners``."""
        data = self.link.pack(msg)
        address = self.link.addresses.get(sysid)
        if address is None:
            return
        if now and not self.lockstep:
            if self.link.queued:
                self.link.flush()
            self.link.send_raw(data, address)
        else:
            self.link.queue_raw(data, address)
            self._flush_due_s = -math.inf
        for listener in self.sent_listeners:
            listener(data, clock_s)

    def close(self) -> None:
        self._selector.close()
        self.link.close()
