"""The drone-to-drone mesh: every drone broadcasts its own position reports on a simulated radio, and the drones
within range hear them directly, with no ground station in between.

The medium is simulation-side, like the bodies: one ring per drone in the shared world (sitl/world/shared.py), into
which the drone posts the GLOBAL_POSITION_INT frame it builds for its links (at most ``MESH_RATE_HZ``), with the physics
step and simulated time it was sent at. A slot is written before the ring's count is advanced; the ring has a single
writer, and a reader that falls a whole ring behind skips what was overwritten (counted as an overrun). The ground
station never reads it.

Each drone, after every physics step, takes the posts of the other drones that are due and decides, for itself,
which it hears:

1. **Range.** Nothing is heard from a sender farther than ``range_m`` (the true distance between the two bodies,
   from the world's rows: the lockstep snapshot in lockstep, so every run measures the same).
2. **Path loss.** Within range a post is lost with probability ``(d / range_m) ** exponent``: a free-space link
   budget falls with a power of the distance (2 in free space, 3 to 4 near the ground and among obstacles), and
   a receiver loses frames more and more often as the signal nears its sensitivity, until it hears nothing at the
   edge. With the default exponent 4, half range loses 6 %, three quarters 32 %, 90 % of the range 66 %.
3. **The link model** (sitl/world/linkmodel.py) with the neighbour class's settings: loss, bursts, latency and jitter,
   bandwidth, on the receiver's own mesh channel, as independent events after the path loss.

What survives is handed to the drone's neighbour table as a report heard over the mesh (sitl/protocol/neighbours.py).

Reproducible in lockstep: a post made at step k is taken at the receiver's step k + Q (Q the lockstep quantum) and
not before. Running step k + Q, the receiver knows every member has completed step k (the barrier: no member is more
than Q steps ahead of the slowest), and a member posts at a step before publishing it as completed, so every post a
receiver takes is already written whatever the machine's load, and a post it does not take yet is one it would not
take in any run. Posts are taken in a fixed order (time, then sender), and each receiver draws from generators
seeded from (the drone's seed, the neighbour class, the mesh), so two runs hear the same frames at the same steps.
Latency is counted from the post: a frame due before the step it is taken at is heard at that step. Paced, a
receiver takes whatever has been posted up to now, and the sender's time is its own clock, so the receiver counts
the delay from its own time of taking the post.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from sitl.world.linkmodel import (
    CHANNEL_SEED_TAG,
    DIRECTIONS,
    DelayLine,
    LinkChannel,
    LinkCounters,
    LinkImpairment,
)
from sitl.world.shared import (
    ALT,
    EARTH_RADIUS_M,
    LAT,
    LON,
    MESH_FIELDS,
    MESH_LENGTH,
    MESH_SLOT_BYTES,
    MESH_SLOTS,
    MESH_STEP,
    MESH_TIME,
    VALID,
    SharedWorld,
)
from swarmcommon.links import DEFAULT_MESH_EXPONENT, DEFAULT_MESH_RANGE_M, LINK_CLASSES, mesh_value_problem

# A drone posts at most this often (its GLOBAL_POSITION_INT stream's default rate, and the relay's limit per source):
# a client that raises the stream's rate (SET_MESSAGE_INTERVAL) does not flood the medium or overrun its ring.
MESH_RATE_HZ: Final = 10.0
# The mesh channel's seed entry after the link directions (up 0, down 1): its own entropy, next to the relay's
# neighbour channels, so switching the mesh on changes none of their draws.
MESH_SEED_INDEX: Final = len(DIRECTIONS)
_NEIGHBOUR_INDEX: Final = LINK_CLASSES.index("neighbour")
# A delay that ends on a physics step is heard at that step, not the next one, whatever the rounding of the post's
# time plus the latency against the step's time (0.1 + 0.04 is not 0.14 in floating point).
_TIME_TOLERANCE_S: Final = 1e-9


def mesh_problem(range_m: object, exponent: object) -> str | None:
    """Why these mesh settings are not valid, in one line (the ground station's words: swarmcommon/links.py)."""
    for key, value in (("range_m", range_m), ("exponent", exponent)):
        problem = mesh_value_problem(key, value)
        if problem is not None:
            return problem
    return None


@dataclass(frozen=True, slots=True, kw_only=True)
class MeshSettings:
    """The radio of every drone of a swarm: how far it carries, and how fast reception fades towards that range."""

    range_m: float = DEFAULT_MESH_RANGE_M
    exponent: float = DEFAULT_MESH_EXPONENT

    def __post_init__(self) -> None:
        problem = mesh_problem(self.range_m, self.exponent)
        if problem is not None:
            raise ValueError(problem)

    def loss_probabilities(self, distances_m: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """The path-loss rule: 1 at or beyond the range, ``(d / range_m) ** exponent`` within it."""
        within = distances_m < self.range_m
        return np.where(within, (np.where(within, distances_m, 0.0) / self.range_m) ** self.exponent, 1.0)

    def loss_probability(self, distance_m: float) -> float:
        """``loss_probabilities`` at one distance."""
        return float(self.loss_probabilities(np.array([distance_m]))[0])

    def describe(self) -> str:
        return f"range {self.range_m:g} m, path loss (d/range)^{self.exponent:g}"


def mesh_seed(seed: int) -> np.random.SeedSequence:
    """The seed of one drone's mesh reception (the neighbour class, after its up and down channels)."""
    return np.random.SeedSequence([seed, CHANNEL_SEED_TAG, _NEIGHBOUR_INDEX, MESH_SEED_INDEX])


@dataclass(frozen=True, slots=True, kw_only=True)
class MeshCounters:
    """What one drone's radio heard of the others' posts. Every post offered is delivered or lost for one reason."""

    frames_offered: int = 0  # posts of other drones this drone took from the medium (or found overwritten)
    frames_delivered: int = 0  # at the time they are due (the link model's delay), to the neighbour table
    lost_range: int = 0  # the sender was beyond range_m
    lost_path: int = 0  # the path-loss draw
    lost_model: int = 0  # the link model (loss, bursts, the bandwidth queue)
    lost_overrun: int = 0  # overwritten in the sender's ring before this drone read it (a reader far behind)
    delayed: int = 0  # delivered later than posted by the link model's latency and jitter
    total_delay_s: float = 0.0

    @property
    def frames_lost(self) -> int:
        return self.lost_range + self.lost_path + self.lost_model + self.lost_overrun


def distances_m(me: npt.NDArray[np.float64], others: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Straight-line distances from world row ``me`` to each of the rows ``others`` (flat earth, exact to
    millimetres over a swarm); 0 to a row that holds no body yet, or when ``me`` holds none (nobody is out of range
    before the world knows where they are)."""
    north = np.radians(others[:, LAT] - me[LAT]) * EARTH_RADIUS_M
    east = np.radians(others[:, LON] - me[LON]) * EARTH_RADIUS_M * math.cos(math.radians(me[LAT]))
    down = others[:, ALT] - me[ALT]
    known = (others[:, VALID] == 1.0) & (me[VALID] == 1.0)
    return np.where(known, np.sqrt(north * north + east * east + down * down), 0.0)


class MeshMedium:
    """The rings of the shared world as one drone uses them: it posts into its own and reads the others'."""

    def __init__(self, world: SharedWorld, instance: int) -> None:
        self.world = world
        self.instance = instance
        self._counts = world.mesh_posts
        self._meta = world.mesh_meta
        self._frames = world.mesh_frames
        self._read = np.zeros(len(self._counts), dtype=np.float64)  # posts taken from each ring so far
        self._read[instance] = math.inf  # never our own
        self.overruns = 0
        world.mesh_posts[instance] = 0.0  # a row reused by a new drone starts an empty ring
        # The counts as bytes at the last look, and whether a post seen then was not yet due: a receiver looks at
        # the medium after every step, and mostly nothing has changed; comparing 2 kB of bytes says so in a
        # fraction of the numpy comparison's time (0.3 against 5 us, the larger part of an idle step's cost).
        self._counts_bytes = world.mesh_posts.data.cast("B")
        self._seen = b""
        self._waiting = False

    def post(self, frame: bytes, step: int, time_s: float) -> bool:
        """Broadcast ``frame`` (False when it does not fit a slot). The slot first, then the count: a reader that
        sees the count sees the slot."""
        if len(frame) > MESH_SLOT_BYTES:
            return False
        count = int(self._counts[self.instance])
        slot = count % MESH_SLOTS
        self._frames[self.instance, slot, : len(frame)] = np.frombuffer(frame, dtype=np.uint8)
        meta = self._meta[self.instance, slot]
        meta[MESH_STEP], meta[MESH_TIME], meta[MESH_LENGTH] = step, time_s, len(frame)
        self._counts[self.instance] = count + 1
        return True

    def take(self, until_step: int | None) -> list[tuple[float, int, bytes]]:
        """The posts of the other drones not taken yet, as (time, sender instance, frame) sorted by time then sender;
        with ``until_step`` only those posted at or before it (lockstep), else all."""
        seen = self._counts_bytes.tobytes()
        if seen == self._seen and not self._waiting:
            return []
        self._seen = seen
        self._waiting = False
        senders = np.flatnonzero(self._counts > self._read)
        if len(senders) == 0:
            return []
        out: list[tuple[float, int, bytes]] = []
        for sender in senders.tolist():
            count = int(self._counts[sender])
            first = int(self._read[sender])
            if count - first > MESH_SLOTS:  # overwritten before we came: skip to the oldest still there
                self.overruns += count - MESH_SLOTS - first
                first = count - MESH_SLOTS
            meta, frames = self._meta[sender], self._frames[sender]
            k = first
            while k < count:
                slot = k % MESH_SLOTS
                row = meta[slot].tolist()  # one call for the three numbers (numpy scalars cost one each)
                if until_step is not None and row[MESH_STEP] > until_step:
                    self._waiting = True  # not due yet: look again at the next step, changed counts or not
                    break
                out.append((row[MESH_TIME], sender, frames[slot, : int(row[MESH_LENGTH])].tobytes()))
                k += 1
            self._read[sender] = k
        out.sort(key=lambda post: (post[0], post[1]))
        return out


class MeshRadio:
    """One drone's mesh radio: posts its reports into the medium and decides which of the others' it hears.

    ``quantum_steps``: in lockstep, the quantum (posts are taken exactly that many steps after they were made);
    None when paced. ``impairment``: the neighbour class's link model settings (None or perfect: no model)."""

    def __init__(self, medium: MeshMedium, settings: MeshSettings, impairment: LinkImpairment | None, *, seed: int,
                 quantum_steps: int | None) -> None:  # fmt: skip
        self.medium = medium
        self.settings = settings
        self.quantum_steps = quantum_steps
        channel_rng, path_rng = np.random.default_rng(mesh_seed(seed)).spawn(2)
        self.channel = (
            LinkChannel(impairment, channel_rng) if impairment is not None and not impairment.is_perfect else None
        )
        self._path_rng = path_rng
        self._inbox: DelayLine[bytes] = DelayLine()  # heard later than the step that took them (latency, jitter)
        self._ready: list[bytes] = []  # heard at the step that took them, in order
        self._steps = 0
        self._next_post_s = -math.inf
        self._offered = 0
        self._lost_range = 0
        self._lost_path = 0
        self._delivered = 0
        self.posted = 0

    def broadcast(self, frame: bytes, time_s: float) -> None:
        """Post this drone's position report (at most MESH_RATE_HZ; a report between is not sent on the mesh)."""
        if time_s < self._next_post_s:
            return
        if self.medium.post(frame, self._steps, time_s):
            self.posted += 1
            # 10 % slack, as the relay's token bucket has: a stream at exactly the rate must not lose every other
            # report to rounding of its tick times.
            self._next_post_s = time_s + 0.9 / MESH_RATE_HZ

    def after_step(self, now_s: float) -> list[bytes]:
        """Called after every physics step: the frames heard by now (taken from the medium, range, path loss and
        link model applied), in the order they are delivered."""
        self._steps += 1
        until = None if self.quantum_steps is None else self._steps - self.quantum_steps
        if until is None or until >= 0:
            posts = self.medium.take(until)
            if posts:
                self._receive(posts, now_s)
        inbox = self._inbox
        due_by_s = now_s + _TIME_TOLERANCE_S
        heard = inbox.pop_due(due_by_s) if inbox.next_due_s <= due_by_s else []
        if self._ready:
            heard += self._ready
            self._ready = []
        return heard

    def _receive(self, posts: list[tuple[float, int, bytes]], now_s: float) -> None:
        """Range, path loss (one draw per post, whatever its distance: the draws stay aligned with the posts) and the
        link model, in the posts' order; the distances and the path-loss draws are computed for all posts at once."""
        bodies = self.medium.world.bodies
        senders = np.fromiter((sender for _, sender, _ in posts), dtype=np.intp, count=len(posts))
        loss = self.settings.loss_probabilities(distances_m(bodies[self.medium.instance], bodies[senders])).tolist()
        draws = self._path_rng.random(len(posts)).tolist()
        lockstep = self.quantum_steps is not None
        channel, inbox, ready = self.channel, self._inbox, self._ready
        self._offered += len(posts)
        for (time_s, _sender, frame), p, draw in zip(posts, loss, draws, strict=True):
            if p >= 1.0:
                self._lost_range += 1
                continue
            if draw < p:
                self._lost_path += 1
                continue
            sent_s = time_s if lockstep else now_s
            due_s = channel.transmit(sent_s, len(frame)) if channel is not None else sent_s
            if due_s is None:
                continue
            self._delivered += 1
            if due_s <= now_s and not inbox:  # heard now, and nothing is held before it: no need to queue
                ready.append(frame)
            else:
                inbox.push(due_s, frame)

    def counters(self) -> MeshCounters:
        model = self.channel.counters() if self.channel is not None else LinkCounters()
        return MeshCounters(
            frames_offered=self._offered + self.medium.overruns,
            frames_delivered=self._delivered,
            lost_range=self._lost_range,
            lost_path=self._lost_path,
            lost_model=model.frames_lost,
            lost_overrun=self.medium.overruns,
            delayed=model.delayed,
            total_delay_s=model.total_delay_s,
        )

    def publish(self, updates: Mapping[str, int]) -> None:
        """This drone's counts into the world (``MESH_FIELDS``) for the flight report, with the neighbour table's
        updates by source (``relay``, ``link``, ``mesh``)."""
        c = self.counters()
        values: dict[str, float] = {f: getattr(c, f) for f in MESH_FIELDS if hasattr(c, f)}
        values.update({f"{source}_updates": count for source, count in updates.items()})
        self.medium.world.mesh_stats[self.medium.instance] = [values[f] for f in MESH_FIELDS]
