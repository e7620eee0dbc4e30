"""The link model: what a radio does to the frames that cross it (loss, burst outages, latency, jitter, a bandwidth
cap), as a pure, seeded core with no sockets and no clocks.

One ``LinkChannel`` is one direction of one link. The caller owns the socket and the clock: it offers each frame
with the (simulated) time it is sent and its size, and is told when the frame arrives, or that it never does.
Given its random generator and the sequence of calls, a channel always decides the same, which is what makes
lockstep runs reproducible with impaired links. docs/links.md describes the model and why each choice was made.

A frame's way through a channel, in the order a radio imposes:
1. the transmit queue (with ``bandwidth_bps``): frames go on the air one after another, ``size * 8 / bps`` seconds
   each; a frame that would wait longer than ``MAX_QUEUE_S`` is dropped, as a radio's full buffer drops it;
2. the channel state (Gilbert-Elliott): a continuous-time two-state Markov chain, good and bad, with exponential
   dwell times of means ``burst_good_s`` and ``burst_bad_s``; a frame sent while the channel is bad is lost with
   ``burst_loss`` (default 1: an outage), while it is good with ``loss``;
3. the delay: ``latency_ms`` plus a jitter draw (a normal of standard deviation ``jitter_ms``, truncated so the
   delay is never negative), independent per frame, so frames overtake each other as they do on a real network.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Final, Generic, Literal, TypeVar

import numpy as np

from swarmcommon.links import LINK_CLASSES, LINK_KEYS, LinkClass, parse_value, settings_problem, value_problem

# A radio modem holds a few kilobytes waiting to go on the air: about a second at telemetry-radio rates. A frame
# that would wait longer is dropped at the sender, as a full buffer drops it; a longer queue would only deliver
# position reports too stale for a swarm to act on, and would grow without bound when the offered rate exceeds the
# cap.
MAX_QUEUE_S: Final = 1.0

Direction = Literal["up", "down"]
# The order is part of the seeding (a direction's index goes into its seed, as a class's does): append, never reorder.
DIRECTIONS: Final[tuple[Direction, ...]] = ("up", "down")  # up: to the drone; down: from the drone
ALL_CLASSES: Final = "all"  # the --link class that sets every class at once

T = TypeVar("T")
# A frame's jitter is redrawn while it would make the delay negative. With latency >= 0 at least half of the normal
# lies above -latency, so a draw is kept with probability >= 1/2; this bound is never reached in practice (2^-64)
# and only guards the loop.
_MAX_JITTER_DRAWS = 64

CHANNEL_SEED_TAG = 0x4C494E4B  # "LINK": keeps the link channels' entropy apart from SeedSequence(seed) itself


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkImpairment:
    """What one link class does to its frames; the defaults are a perfect link. Rates are per frame, times in the
    units their names say."""

    loss: float = 0.0  # probability that a frame is lost while the channel is good
    burst_good_s: float = 0.0  # Gilbert-Elliott: mean time in the good state (exponential); 0 and 0: no bursts
    burst_bad_s: float = 0.0  # mean time in the bad state (exponential): the mean outage
    burst_loss: float = 1.0  # probability that a frame is lost while the channel is bad
    latency_ms: float = 0.0  # one-way delay of every frame
    jitter_ms: float = 0.0  # standard deviation of the normal added to the latency (truncated at a delay of 0)
    bandwidth_bps: float | None = None  # air rate; None: unlimited (no queueing)

    def __post_init__(self) -> None:
        problem = settings_problem(
            {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}
        )
        if problem is not None:
            raise ValueError(problem)

    @property
    def has_bursts(self) -> bool:
        return self.burst_bad_s > 0

    @property
    def is_perfect(self) -> bool:
        """Nothing to do: callers bypass the model entirely (no draws, no counters, no cost)."""
        return (
            self.loss == 0
            and not (self.has_bursts and self.burst_loss > 0)
            and self.latency_ms == 0
            and self.jitter_ms == 0
            and self.bandwidth_bps is None
        )

    def describe(self) -> str:
        """The settings that differ from a perfect link, as ``key=value`` (``perfect`` when none)."""
        given = _given_fields(self)
        return ",".join(f"{k}={v:g}" for k, v in given.items()) if given else "perfect"


PERFECT: Final = LinkImpairment()


def _given_fields(impairment: LinkImpairment) -> dict[str, float]:
    """The settings that differ from the perfect link's, in ``LINK_KEYS`` order."""
    out: dict[str, float] = {}
    for key in LINK_KEYS:
        value = getattr(impairment, key)
        if value is not None and value != getattr(PERFECT, key):
            out[key] = value
    return out


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkCounters:
    """What a channel did to the frames offered to it. Every offered frame is delivered or lost for one reason."""

    frames_offered: int = 0
    frames_delivered: int = 0
    lost_random: int = 0  # lost while the channel was good (``loss``)
    lost_burst: int = 0  # lost while the channel was bad (``burst_loss``)
    lost_queue: int = 0  # dropped by the transmit queue (``bandwidth_bps``, ``MAX_QUEUE_S``)
    delayed: int = 0  # delivered later than sent (latency, jitter, queueing)
    total_delay_s: float = 0.0  # over the delivered frames
    max_delay_s: float = 0.0

    @property
    def frames_lost(self) -> int:
        return self.lost_random + self.lost_burst + self.lost_queue

    @property
    def mean_delay_s(self) -> float:
        return self.total_delay_s / self.frames_delivered if self.frames_delivered else 0.0

    def merged(self, other: LinkCounters) -> LinkCounters:
        """The counts of both channels together (a report's totals over drones, directions or classes)."""
        return LinkCounters(
            frames_offered=self.frames_offered + other.frames_offered,
            frames_delivered=self.frames_delivered + other.frames_delivered,
            lost_random=self.lost_random + other.lost_random,
            lost_burst=self.lost_burst + other.lost_burst,
            lost_queue=self.lost_queue + other.lost_queue,
            delayed=self.delayed + other.delayed,
            total_delay_s=self.total_delay_s + other.total_delay_s,
            max_delay_s=max(self.max_delay_s, other.max_delay_s),
        )


def total_counters(counters: Iterable[LinkCounters]) -> LinkCounters:
    out = LinkCounters()
    for item in counters:
        out = out.merged(item)
    return out


class LinkChannel:
    """One direction of one link: decides each frame's fate and delivery time.

    Two generators are spawned from the one given: one draws the Gilbert-Elliott timeline, the other the per-frame
    decisions (loss, jitter). The outages therefore fall at the same simulated times whatever the traffic, and
    their lengths do not depend on the frame rate, which per-frame state flips would make them do."""

    def __init__(self, impairment: LinkImpairment, rng: np.random.Generator) -> None:
        self.impairment = impairment
        timeline_rng, frame_rng = rng.spawn(2)
        self._timeline_rng = timeline_rng
        self._frame_rng = frame_rng
        self._bad = False
        self._state_until_s = math.nan  # the chain starts at the first frame's time
        self._last_time_s = -math.inf
        self._busy_until_s = -math.inf  # when the transmitter is free again (bandwidth)
        self._latency_s = impairment.latency_ms / 1000.0
        self._jitter_s = impairment.jitter_ms / 1000.0
        self._offered = 0
        self._delivered = 0
        self._lost_random = 0
        self._lost_burst = 0
        self._lost_queue = 0
        self._delayed = 0
        self._total_delay_s = 0.0
        self._max_delay_s = 0.0

    def transmit(self, time_s: float, size_bytes: int) -> float | None:
        """A frame of ``size_bytes`` sent at ``time_s``: the simulated time it is delivered, or None when it is lost.

        Times must not run backwards between calls (a frame sent earlier than the last is taken as sent then)."""
        self._offered += 1
        now_s = max(time_s, self._last_time_s)
        self._last_time_s = now_s
        bad = self._advance(now_s)
        imp = self.impairment
        on_air_s = now_s
        if imp.bandwidth_bps is not None:
            start_s = max(now_s, self._busy_until_s)
            if start_s - now_s > MAX_QUEUE_S:
                self._lost_queue += 1
                return None
            self._busy_until_s = start_s + size_bytes * 8.0 / imp.bandwidth_bps
            on_air_s = self._busy_until_s  # the whole frame has to be sent before it can arrive
        # A frame lost on the air has still used its airtime (above), as it does on a radio.
        if bad:
            if imp.burst_loss > 0 and self._frame_rng.random() < imp.burst_loss:
                self._lost_burst += 1
                return None
        elif imp.loss > 0 and self._frame_rng.random() < imp.loss:
            self._lost_random += 1
            return None
        arrival_s = on_air_s + self._latency_s + self._jitter()
        delay_s = arrival_s - time_s
        self._delivered += 1
        if delay_s > 0:
            self._delayed += 1
            self._total_delay_s += delay_s
            self._max_delay_s = max(self._max_delay_s, delay_s)
        return arrival_s

    def _jitter(self) -> float:
        """A normal of standard deviation ``jitter_ms`` around 0, redrawn while latency + jitter would be negative.

        Redrawing (truncation) rather than clamping: a clamp would pile a share of the frames up at exactly zero
        delay, all arriving in order, a lump no radio shows."""
        if self._jitter_s == 0:
            return 0.0
        for _ in range(_MAX_JITTER_DRAWS):
            draw = float(self._frame_rng.normal(0.0, self._jitter_s))
            if self._latency_s + draw >= 0:
                return draw
        return -self._latency_s

    def _advance(self, now_s: float) -> bool:
        """Run the Gilbert-Elliott chain up to ``now_s``; True when the channel is bad then."""
        imp = self.impairment
        if not imp.has_bursts:
            return False
        if math.isnan(self._state_until_s):
            # The chain starts in its stationary distribution: a run is as likely to begin in an outage as any
            # other moment is, and the exponential dwell times are memoryless, so the process is stationary.
            self._bad = bool(self._timeline_rng.random() < imp.burst_bad_s / (imp.burst_good_s + imp.burst_bad_s))
            self._state_until_s = now_s + self._dwell_s()
        while now_s >= self._state_until_s:
            self._bad = not self._bad
            self._state_until_s += self._dwell_s()
        return self._bad

    def _dwell_s(self) -> float:
        mean_s = self.impairment.burst_bad_s if self._bad else self.impairment.burst_good_s
        return float(self._timeline_rng.exponential(mean_s))

    def counters(self) -> LinkCounters:
        return LinkCounters(
            frames_offered=self._offered,
            frames_delivered=self._delivered,
            lost_random=self._lost_random,
            lost_burst=self._lost_burst,
            lost_queue=self._lost_queue,
            delayed=self._delayed,
            total_delay_s=self._total_delay_s,
            max_delay_s=self._max_delay_s,
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkProfile:
    """The impairment of each link class: ``gcs`` (ground station <-> drone, both ways), ``api`` (a client such as
    MAVSDK <-> the drone's API link), ``neighbour`` (neighbour positions relayed to a drone, and the drone-to-drone
    mesh). Every drone of a process shares its process's profile; their draws differ by seed."""

    gcs: LinkImpairment = field(default=PERFECT)
    api: LinkImpairment = field(default=PERFECT)
    neighbour: LinkImpairment = field(default=PERFECT)

    def of(self, link_class: LinkClass) -> LinkImpairment:
        impairment: LinkImpairment = getattr(self, link_class)
        return impairment

    @property
    def is_perfect(self) -> bool:
        return all(self.of(c).is_perfect for c in LINK_CLASSES)

    def describe(self) -> str:
        """One line: each class's settings (``perfect`` when nothing is impaired)."""
        if self.is_perfect:
            return "perfect"
        return "; ".join(f"{c} {self.of(c).describe()}" for c in LINK_CLASSES)


def channel_seed(seed: int, link_class: LinkClass, direction: Direction) -> np.random.SeedSequence:
    """The seed of one channel of one drone: its own entropy from (the drone's seed, class, direction), so a run is
    reproducible from the seed, the channels draw independently of each other and of the drone's other generators
    (sensors, wind: ``SeedSequence(seed)`` and its children), and adding a drone leaves the others' draws alone.
    Not from the drone's instance: which instances a swarm runs on (its UDP ports) changes nothing it does."""
    return np.random.SeedSequence([seed, CHANNEL_SEED_TAG, LINK_CLASSES.index(link_class), DIRECTIONS.index(direction)])


def drone_channels(profile: LinkProfile, *, seed: int) -> dict[tuple[LinkClass, Direction], LinkChannel]:
    """The channels of one drone, by (class, direction), for the classes that are impaired; a class absent from the
    result is perfect and its frames bypass the model."""
    out: dict[tuple[LinkClass, Direction], LinkChannel] = {}
    for link_class in LINK_CLASSES:
        impairment = profile.of(link_class)
        if impairment.is_perfect:
            continue
        for direction in DIRECTIONS:
            rng = np.random.default_rng(channel_seed(seed, link_class, direction))
            out[(link_class, direction)] = LinkChannel(impairment, rng)
    return out


def counters_by_class(
    channels: dict[tuple[LinkClass, Direction], LinkChannel],
) -> dict[tuple[LinkClass, Direction], LinkCounters]:
    """A snapshot of every channel's counters (a drone's figures for its log or the report), by (class, direction)."""
    return {key: chan.counters() for key, chan in channels.items()}


class DelayLine(Generic[T]):
    """Items held until their simulated delivery time, handed out in delivery order (ties: the order they came in).

    What the link model delays waits here on the receiving side of its channel; whoever holds the line asks for what
    is due at fixed points of its own clock, so in lockstep a delayed message is used at the same simulated time in
    every run."""

    def __init__(self) -> None:
        self._heap: list[tuple[float, int, T]] = []
        self._count = 0

    def __len__(self) -> int:
        return len(self._heap)

    @property
    def next_due_s(self) -> float:
        return self._heap[0][0] if self._heap else math.inf

    def push(self, due_s: float, item: T) -> None:
        heapq.heappush(self._heap, (due_s, self._count, item))
        self._count += 1

    def pop_due(self, now_s: float) -> list[T]:
        out: list[T] = []
        heap = self._heap
        while heap and heap[0][0] <= now_s:
            out.append(heapq.heappop(heap)[2])
        return out


# ---- the drone's --link option -------------------------------------------------------------------------------------


def parse_link_option(text: str) -> tuple[tuple[LinkClass, ...], dict[str, float]]:
    """``CLASS:key=value,key=value`` (CLASS: gcs, api, neighbour or all): the classes it sets and the values.

    ValueError with one line when it is malformed or a value is out of range."""
    name, sep, body = text.partition(":")
    name = name.strip()
    if not sep:
        raise ValueError(f"must be CLASS:key=value[,key=value...], got {text!r}")
    if name == ALL_CLASSES:
        classes: tuple[LinkClass, ...] = LINK_CLASSES
    elif name in LINK_CLASSES:
        classes = (name,)
    else:
        raise ValueError(f"link class must be {', '.join(LINK_CLASSES)} or {ALL_CLASSES}, got {name!r}")
    values: dict[str, float] = {}
    for item in body.split(","):
        key, eq, value = (part.strip() for part in item.partition("="))
        if not eq or not key:
            raise ValueError(f"must be CLASS:key=value[,key=value...], got {text!r}")
        if key not in LINK_KEYS:
            raise ValueError(value_problem(key, 0.0))
        values[key] = parse_value(key, value)
    return classes, values


def link_profile(options: Sequence[str]) -> LinkProfile:
    """The profile that ``--link`` options give, applied in order from a perfect profile (a later option's key
    replaces an earlier one's for the classes it names). ValueError with one line for a bad option or combination."""
    merged: dict[LinkClass, dict[str, float]] = {c: {} for c in LINK_CLASSES}
    for text in options:
        classes, values = parse_link_option(text)
        for link_class in classes:
            merged[link_class].update(values)
    impairments: dict[str, LinkImpairment] = {}
    for link_class, values in merged.items():
        problem = settings_problem(values)
        if problem is not None:
            raise ValueError(f"{link_class}: {problem}")
        impairments[link_class] = replace(PERFECT, **values)
    return LinkProfile(**impairments)


def link_arguments(profile: LinkProfile) -> list[str]:
    """The ``--link`` arguments that give ``profile`` to a drone (none for a perfect profile; one ``all:`` when every
    class is impaired alike). Values are written with ``repr`` so that they parse back exactly."""
    texts = {c: ",".join(f"{k}={v!r}" for k, v in _given_fields(profile.of(c)).items()) for c in LINK_CLASSES}
    if len(set(texts.values())) == 1:
        only = texts[LINK_CLASSES[0]]
        return ["--link", f"{ALL_CLASSES}:{only}"] if only else []
    out: list[str] = []
    for link_class, text in texts.items():
        if text:
            out += ["--link", f"{link_class}:{text}"]
    return out
