"""Relay latency, measured from outside: a probe joins the swarm as two vehicles and times the relay hop.

The relay's job is to move one drone's GLOBAL_POSITION_INT to the others. Timing that hop inside the drones would
need their clocks aligned (each paced process has its own simulated clock), so the probe stands in for two drones on
one loopback socket instead: it sends a position report as system A, stamped with a sequence marker in
``time_boot_ms``, and the relay forwards it to every other live system - including B, which is the same socket.
Send and receive times are read from one clock in one process, so the difference is exactly what a drone's report
spends between leaving its socket and arriving at a neighbour's: the UDP hops both ways and the supervisor's
receive, parse, rate limit and forward. The probe reports from a point 10 km north of the first drone and 100 m up,
so no drone's avoidance ever reacts to it.
"""

from __future__ import annotations

import argparse
import json
import math
import selectors
import socket
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink

from gcs.mavlink.transport import GCS_SYSID

HEARTBEAT_INTERVAL_S = 0.5
# After the last report, how long the probe keeps listening for replies still on their way: a report sent just before
# the end is not lost because the run stopped first (on a loaded machine the hop can take a good part of a second).
DRAIN_S = 1.0
PROBE_OFFSET_NORTH_DEG = 0.09  # about 10 km
PROBE_SYSIDS = (240, 241)  # A and B unless the swarm flies them (probe_sysids)
MAX_SYSID = GCS_SYSID - 1  # 255 is the ground station's


def probe_sysids(drone_sysids: Iterable[int]) -> tuple[int, int] | None:
    """The probe's two sysids beside a swarm of these drones: PROBE_SYSIDS, or the highest two no drone has if it
    flies one of them; None if the swarm leaves fewer than two (253 or 254 drones)."""
    taken = set(drone_sysids)
    if not taken & set(PROBE_SYSIDS):
        return PROBE_SYSIDS
    free = [s for s in range(MAX_SYSID, 0, -1) if s not in taken]
    return (free[0], free[1]) if len(free) >= 2 else None


@dataclass(frozen=True, slots=True, kw_only=True)
class LatencyStats:
    """Summary of one probe run (milliseconds; NaN when nothing came back)."""

    sent: int
    received: int
    median_ms: float
    p95_ms: float
    max_ms: float

    @property
    def lost(self) -> int:
        return self.sent - self.received


def percentile(values: Sequence[float], q: float) -> float:
    """Nearest-rank percentile: the smallest value with at least ``q`` of the samples at or below it (NaN if none)."""
    if not values:
        return math.nan
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, math.ceil(q * len(ordered)) - 1))]


def latency_stats(latencies_s: Sequence[float], sent: int) -> LatencyStats:
    """Median, 95th percentile and maximum of the measured hops."""
    ms = [v * 1e3 for v in latencies_s]
    return LatencyStats(
        sent=sent,
        received=len(ms),
        median_ms=percentile(ms, 0.5),
        p95_ms=percentile(ms, 0.95),
        max_ms=max(ms, default=math.nan),
    )


class RelayProbe:
    """Two probe vehicles on one socket: A reports its position at ``rate_hz``, B receives A's relayed reports."""

    def __init__(
        self,
        gcs_port: int,
        anchor_lat_lon_alt: tuple[float, float, float],
        rate_hz: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
        sysids: tuple[int, int] = PROBE_SYSIDS,
    ) -> None:
        self._gcs = ("127.0.0.1", gcs_port)
        self.sysids = sysids
        self._clock = clock
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self._sender = mavlink.MAVLink(None, srcSystem=sysids[0], srcComponent=1)
        self._other = mavlink.MAVLink(None, srcSystem=sysids[1], srcComponent=1)
        self._parser = mavlink.MAVLink(None)
        self._parser.robust_parsing = True
        lat, lon, alt = anchor_lat_lon_alt
        self._position = (round((lat + PROBE_OFFSET_NORTH_DEG) * 1e7), round(lon * 1e7), round((alt + 100.0) * 1e3))
        self._interval_s = 1.0 / rate_hz
        self._next_report_s = 0.0
        self._next_heartbeat_s = 0.0
        self._marker = 0
        self._sent_at: dict[int, float] = {}
        self.latencies_s: list[float] = []

    def tick(self) -> None:
        """Keep both probe vehicles alive and send A's next position report when due."""
        now = self._clock()
        if now >= self._next_heartbeat_s:
            self._next_heartbeat_s = now + HEARTBEAT_INTERVAL_S
            for encoder in (self._sender, self._other):
                hb = mavlink.MAVLink_heartbeat_message(
                    mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0, 0, 3, 3
                )
                self.sock.sendto(hb.pack(encoder), self._gcs)
        if now >= self._next_report_s:
            self._next_report_s = now + self._interval_s
            self._marker += 1
            lat, lon, alt = self._position
            report = mavlink.MAVLink_global_position_int_message(self._marker, lat, lon, alt, 100_000, 0, 0, 0, 0)
            data = report.pack(self._sender)
            self._sent_at[self._marker] = self._clock()
            self.sock.sendto(data, self._gcs)

    def receive(self) -> None:
        """Time every relayed report of A that has arrived (everything else the relay sends is ignored)."""
        while True:
            try:
                data = self.sock.recv(65535)
            except (BlockingIOError, InterruptedError):
                return
            now = self._clock()
            for msg in self._parser.parse_buffer(data) or []:
                if msg.get_type() != "GLOBAL_POSITION_INT" or msg.get_srcSystem() != self.sysids[0]:
                    continue
                sent = self._sent_at.pop(msg.time_boot_ms, None)
                if sent is not None:
                    self.latencies_s.append(now - sent)

    def stats(self) -> LatencyStats:
        return latency_stats(self.latencies_s, self._marker)

    def run_for(self, duration_s: float) -> LatencyStats:
        """Probe for ``duration_s``, waking on arrivals (so a reply is timed when it lands, not on a poll), then wait up
        to DRAIN_S for the replies still in flight."""
        end = self._clock() + duration_s
        with selectors.DefaultSelector() as selector:
            selector.register(self.sock, selectors.EVENT_READ)
            while (now := self._clock()) < end:
                self.tick()
                selector.select(max(0.0, min(self._next_report_s, self._next_heartbeat_s, end) - now))
                self.receive()
            drained = end + DRAIN_S  # no more reports: only wait for the ones in flight
            while self._sent_at and (now := self._clock()) < drained:
                selector.select(drained - now)
                self.receive()
        return self.stats()

    def close(self) -> None:
        self.sock.close()


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m gcs.bench.probe PORT``: probe a running swarm's relay from a process of its own, print JSON stats."""
    parser = argparse.ArgumentParser(prog="python -m gcs.bench.probe", description=__doc__.splitlines()[0])
    parser.add_argument("port", type=int, help="the supervisor's MAVLink port (swarm up prints it)")
    parser.add_argument("--seconds", type=float, default=10.0, help="how long to probe (default 10)")
    parser.add_argument("--rate", type=float, default=10.0, help="reports per second (default 10)")
    parser.add_argument("--anchor", default="47.397742,8.545594,488.0", help="LAT,LON,ALT near the swarm")
    parser.add_argument("--sysids", default=f"{PROBE_SYSIDS[0]},{PROBE_SYSIDS[1]}",
                        help=f"A,B: the probe's two sysids, none of the swarm's (default {PROBE_SYSIDS[0]},"
                        f"{PROBE_SYSIDS[1]})")  # fmt: skip
    args = parser.parse_args(argv)
    try:
        lat, lon, alt = (float(v) for v in args.anchor.split(","))
    except ValueError:
        print(f"error: --anchor must be LAT,LON,ALT, got {args.anchor!r}", file=sys.stderr)
        return 2
    try:
        a, b = (int(v) for v in args.sysids.split(","))
    except ValueError:
        a = b = 0
    if not (1 <= a <= MAX_SYSID and 1 <= b <= MAX_SYSID and a != b):
        print(f"error: --sysids must be two different sysids in 1..{MAX_SYSID}, got {args.sysids!r}", file=sys.stderr)
        return 2
    probe = RelayProbe(args.port, (lat, lon, alt), rate_hz=args.rate, sysids=(a, b))
    try:
        stats = probe.run_for(args.seconds)
    finally:
        probe.close()
    print(json.dumps({"sent": stats.sent, "received": stats.received, "median_ms": stats.median_ms,
                      "p95_ms": stats.p95_ms, "max_ms": stats.max_ms}))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
