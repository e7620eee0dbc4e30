"""One simulated drone as its process's loop drives it: the simulation, its MAVLink links, its place in the shared
world, its perception, and its output.

A process runs one drone (the default, and the shape of PX4 SITL) or hosts several (sitl/process/runtime.py steps them
all in one loop). Either way each drone is built and driven the same way, through ``Drone``, so a hosted drone is on the
wire and in the world exactly what a lone one is: its own sysid, ports, JSBSim instance, autopilot, parameters, seed
and log. Only the loop around it, and who owns the process, differ.
"""

from __future__ import annotations

import logging
import selectors
import sys
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

from sitl.drone.awareness import Awareness
from sitl.drone.closed_loop import ClosedLoop, SimConfig
from sitl.drone.demo import DemoFlight
from sitl.drone.param_table import build_param_store
from sitl.drone.sim_vehicle_api import SimVehicleApi
from sitl.onboard.runner import OnboardRunner
from sitl.process.mavlink_io import MavlinkEndpoint
from sitl.process.specs import DroneSpec, ProcessSpec
from sitl.protocol import Identity
from sitl.protocol.framing import FrameMemo
from sitl.protocol.neighbours import NeighbourTable, SharedReports
from sitl.protocol.signing import SIGN_ALWAYS, SIGN_CFG_PARAM, key_id
from sitl.world.linkmodel import drone_channels
from sitl.world.mesh import MeshMedium, MeshRadio
from sitl.world.shared import (
    DRONE_SENT,
    END_EXITED,
    END_FAILED,
    SUPERVISOR_SENT,
    SharedWorld,
    lockstep_epoch_steps,
)
from sitl.world.view import WorldParticipant

AWAIT_SUPERVISOR_S = 1.0  # wall seconds a lockstep drone waits for a datagram the supervisor has sent
CPU_REPORT_STEPS = 100  # how often the time spent per part is published in the shared world (for benchmarks)


class DroneOutput:
    """Where one drone's lines go: its own log file when hosted with a log directory, else the process's stdout
    (and stderr for tracebacks and log records), every line naming the drone as ``sitl <instance>:``."""

    def __init__(self, instance: int, log_path: Path | None) -> None:
        self.instance = instance
        self._file: TextIO | None = log_path.open("w", buffering=1) if log_path is not None else None

    def say(self, text: str) -> None:
        out = self._file if self._file is not None else sys.stdout
        print(text, file=out, flush=True)

    def error(self, text: str) -> None:
        out = self._file if self._file is not None else sys.stderr
        print(text, file=out, flush=True)

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


class DroneLogRouter(logging.Handler):
    """Sends each log record (a MAVLink link silenced, a fall behind real time) to the log of the drone the loop is
    running at that moment, so a hosted drone's log holds its own warnings; the loop sets ``current``."""

    def __init__(self) -> None:
        super().__init__()
        self.current: DroneOutput | None = None
        self.setFormatter(logging.Formatter("%(name)s: %(message)s"))

    def emit(self, record: logging.LogRecord) -> None:
        text = self.format(record)
        if self.current is not None:
            self.current.error(f"sitl {self.current.instance}: {text}")
        else:
            print(text, file=sys.stderr, flush=True)


@dataclass(frozen=True, slots=True)
class DroneParts:
    """What a drone is made of, built and wired by ``build_drone``."""

    output: DroneOutput
    sim: ClosedLoop
    flight: DemoFlight | None
    world: SharedWorld | None
    participant: WorldParticipant | None
    endpoint: MavlinkEndpoint | None
    mesh: MeshRadio | None
    awareness: Awareness
    onboard: OnboardRunner | None


@dataclass(frozen=True, slots=True)
class HostShare:
    """What the drones of one process decode once for all of them: the relayed position frames their links receive
    alike, and the neighbour records made of them. Only a process of several drones has one: alone, a drone would
    keep what nobody else reads."""

    frames: FrameMemo = field(default_factory=FrameMemo)
    reports: SharedReports = field(default_factory=SharedReports)


def build_drone(
    spec: DroneSpec, common: ProcessSpec, *, clock_ns: Callable[[], int], share: HostShare | None = None
) -> Drone:
    """One drone from its spec, every part built and wired here, in the order each needs the others: the closed
    loop, its place in the shared world, the neighbour table, the mesh radio, the onboard behaviour, the cameras,
    and the MAVLink links that serve them all; ``share``: its host's, when it has companions."""
    output = DroneOutput(spec.instance, spec.log_path)

    def say(text: str) -> None:
        output.say(f"sitl {spec.instance}: {text}")

    behaviour = common.behaviour
    sim = ClosedLoop(SimConfig(airframe=common.airframe, seed=spec.seed, home=spec.home, wind=common.wind),
                     params=build_param_store(behaviour.params) if behaviour is not None else None)  # fmt: skip
    sim.part_clock_ns = clock_ns
    airframe = common.airframe
    pace = common.speed_factor
    speed = "lockstep" if common.lockstep else "unpaced" if pace == 0 else f"{pace:g}x real time"
    home = spec.home
    say(
        f"airframe {airframe.name} ({airframe.mass_kg:.2f} kg, hover at "
        f"{airframe.hover_thrust_fraction:.0%} of max thrust), seed {spec.seed}, {speed}, "
        f"physics {1 / sim.dt_s:.0f} Hz, home {home.lat_deg:.6f}, {home.lon_deg:.6f}, {home.alt_amsl_m:.1f} m"
    )
    wind = common.wind
    if any(wind.steady_ned_mps) or wind.gust_rms_mps > 0.0:
        north, east, down = wind.steady_ned_mps
        say(f"wind {north:g}, {east:g}, {down:g} m/s NED, gusts {wind.gust_rms_mps:g} m/s RMS")
    flight = DemoFlight(sim, say) if common.demo else None
    # Each drone maps the world itself, so that ending one (which unmaps it) leaves the others' mappings alone.
    world = SharedWorld.attach(common.world_name) if common.world_name else None
    # The body rests with its centre where it rests now, at boot on its gear: that is where it comes to lie if it
    # falls.
    participant = (
        WorldParticipant(
            world,
            spec.instance,
            airframe.collision_radius_m,
            rest_alt_amsl_m=sim.truth.geo.alt_amsl_m,
            epoch_steps=lockstep_epoch_steps(common.lockstep_quantum) if common.lockstep else None,
        )
        if world is not None
        else None
    )
    api = SimVehicleApi(sim)
    identity = Identity(sysid=spec.instance + 1)
    if common.signing_required:
        sim.params.set(SIGN_CFG_PARAM, SIGN_ALWAYS)
    linked = bool(spec.links)
    # One neighbour table, fed by whichever link the relayed positions arrive on and by the mesh radio.
    neighbours = NeighbourTable(identity.sysid, share.reports if share is not None else None) if linked else None
    # The drone-to-drone mesh: a radio on the shared world's medium (sitl/world/mesh.py), heard after every step.
    mesh = (
        MeshRadio(MeshMedium(world, spec.instance), common.mesh, common.links.neighbour, seed=spec.seed,
                  quantum_steps=common.lockstep_quantum if common.lockstep else None)
        if common.mesh is not None and world is not None and linked
        else None
    )  # fmt: skip
    # An onboard behaviour, run beside the autopilot as a companion computer runs one (sitl/onboard).
    onboard = (
        OnboardRunner(behaviour, sysid=identity.sysid, vehicle=sim.vehicle, params=sim.params,
                      estimate=lambda: sim.estimate, relayed=sim.vehicle.collision_prevention.relayed,
                      camera=sim.vehicle.collision_prevention.camera)
        if behaviour is not None
        else None
    )  # fmt: skip
    awareness = Awareness(
        sim,
        spec.instance,
        api.frame,
        world=world,
        neighbours=neighbours,
        frames_dir=spec.camera_frames,
        shared_clock=common.lockstep and world is not None,
        clock_ns=clock_ns,
    )
    impaired = linked and not common.links.is_perfect
    endpoint = (
        MavlinkEndpoint(
            identity, api, sim.params, list(spec.links), signing_key=common.signing_key, neighbours=neighbours,
            camera=awareness.image,  # MAVLink image requests: what the cameras see now
            on_named_value=onboard.receive if onboard is not None else None, mesh=mesh,
            channels=drone_channels(common.links, seed=spec.seed) if impaired else None,
            memo=share.frames if share is not None else None,
        )
        if linked
        else None
    )  # fmt: skip
    if impaired:
        say(f"links: {common.links.describe()}")
    if mesh is not None and common.mesh is not None:
        say(f"mesh radio: {common.mesh.describe()}")
    if behaviour is not None:
        say(f"onboard behaviour {behaviour.name} ({behaviour.spec}) at {behaviour.rate_hz:g} Hz; BHV_EN = 1 runs it")
    for link in endpoint.links if endpoint is not None else []:
        remote = link.config.remote
        say(
            f"MAVLink {link.config.name} link on udp {link.config.bind[0]}:{link.port}"
            + (f", streaming to {remote[0]}:{remote[1]}" if remote else "")
        )
    if common.signing_key is not None or common.signing_required:
        key = f"key {key_id(common.signing_key)}" if common.signing_key is not None else "no key yet"
        say(f"MAVLink signing: {key}, MAV_SIGN_CFG {sim.params[SIGN_CFG_PARAM]:g}")
    parts = DroneParts(output=output, sim=sim, flight=flight, world=world, participant=participant,
                       endpoint=endpoint, mesh=mesh, awareness=awareness, onboard=onboard)  # fmt: skip
    return Drone(spec, common, parts, clock_ns=clock_ns)


class Drone:
    """One drone: built from its spec, then stepped, fed and polled by its process's loop (sitl/process/runtime.py).

    ``fail`` ends it for good after an exception in its own code: the traceback goes to its log, its links close (it
    falls silent, as a crashed process does) and its body falls in the shared world; the other drones of its process
    fly on."""

    def __init__(self, spec: DroneSpec, common: ProcessSpec, parts: DroneParts, *, clock_ns: Callable[[], int]) -> None:
        """A drone of ``parts`` (``build_drone`` makes them and says what it built)."""
        self.instance = spec.instance
        self.output = parts.output
        self.ended = False
        self.failed = False
        self.sim = parts.sim
        self.flight = parts.flight
        self.world = parts.world
        self.participant = parts.participant
        self.endpoint = parts.endpoint
        self.mesh = parts.mesh
        self.awareness = parts.awareness
        self.onboard = parts.onboard
        # The link that talks to the swarm's supervisor (the ground-station link streaming to it), for lockstep delivery
        self._supervisor_link = next(
            (link for link in self.endpoint.links if link.link_class == "gcs" and link.config.remote is not None), None
        ) if self.endpoint is not None else None  # fmt: skip
        self._said_late_traffic = False
        # The link model: only a drone whose links are impaired looks at delay queues after its steps.
        self._impaired = self.endpoint is not None and not common.links.is_perfect
        self._clock_ns = clock_ns
        self.link_ns = 0
        self._steps = 0

    def say(self, text: str) -> None:
        self.output.say(f"sitl {self.instance}: {text}")

    @property
    def time_s(self) -> float:
        return self.sim.time_s

    @property
    def finished(self) -> bool:
        """The demo flight is over (never, without --demo)."""
        return self.flight is not None and self.flight.done

    def booting(self) -> bool:
        """On the ground and not yet ready to arm (GPS fix, estimator): a paced loop may fast-forward this."""
        vehicle = self.sim.vehicle
        return not vehicle.status.armed and vehicle.preflight_problem() is not None

    def stop_requested(self) -> bool:
        """The supervisor asked for this drone to end as a killed process ends (only hosted drones are asked)."""
        return self.world is not None and self.world.stop_requested(self.instance)

    def receive(self) -> None:
        if self.endpoint is not None:
            t0 = self._clock_ns()
            self.endpoint.receive(self.sim.time_s)
            self.link_ns += self._clock_ns() - t0

    def publish_sent(self) -> None:
        """Lockstep: say how many datagrams this drone has sent the supervisor, before its step is published."""
        link = self._supervisor_link
        if link is not None and self.world is not None:
            self.world.table[self.instance, DRONE_SENT] = float(link.to_remote)

    def await_supervisor(self) -> None:
        """Lockstep, before the first step the gate allows: read until every datagram the supervisor sent before it
        opened the gate is in (sitl/world/shared.py SUPERVISOR_SENT), so that all of it is used at this simulated time.
        A datagram still missing after AWAIT_SUPERVISOR_S was lost (a full socket buffer): the drone goes on, and
        says so once."""
        link = self._supervisor_link
        if link is None or self.world is None or self.endpoint is None or self.endpoint.silenced:
            return
        sent = self.world.table[self.instance, SUPERVISOR_SENT]
        if link.from_remote >= sent:
            return
        deadline = time.monotonic() + AWAIT_SUPERVISOR_S
        with selectors.DefaultSelector() as selector:
            selector.register(link.sock, selectors.EVENT_READ)
            while link.from_remote < sent and not self.endpoint.silenced:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    if not self._said_late_traffic:
                        self._said_late_traffic = True
                        self.say(
                            f"lockstep: {int(sent - link.from_remote)} datagram(s) from the supervisor never arrived "
                            f"at t={self.sim.time_s:.3f} s; going on"
                        )
                    return
                selector.select(remaining)
                self.receive()

    def step(self) -> None:
        sim = self.sim
        sim.step()
        if self.flight is not None:
            self.flight.tick()
        if self.participant is not None:
            for contact in self.participant.after_step(sim.truth, sim.vehicle.crashed):
                sim.vehicle.crash(contact.text())
        self.awareness.update(sim.time_s)
        if self.onboard is not None:
            self.onboard.tick(sim.time_s)
        if self._impaired:
            assert self.endpoint is not None
            self.endpoint.deliver_due(sim.time_s)
        if self.mesh is not None:  # the radio is part of the drone's MAVLink, and timed with it
            assert self.endpoint is not None
            t0 = self._clock_ns()
            self.endpoint.hear_mesh(sim.time_s)
            self.link_ns += self._clock_ns() - t0
        self._steps += 1
        if self.world is not None and self._steps % CPU_REPORT_STEPS == 0:
            self.world.write_cpu(self.instance, sim.physics_ns * 1e-9, sim.control_ns * 1e-9,
                                 self.awareness.cpu_ns * 1e-9, self.link_ns * 1e-9)  # fmt: skip
            self._publish_link_counters()

    def _publish_link_counters(self) -> None:
        """What the link model did to this drone's traffic, into the world for the flight report."""
        if self._impaired and self.world is not None and self.endpoint is not None:
            self.world.write_link_counters(self.instance, self.endpoint.link_counters())
        if self.mesh is not None and self.endpoint is not None:
            self.mesh.publish({source: c.updates for source, c in self.endpoint.neighbours.counts().items()})

    def after_batch(self) -> None:
        """Between batches: the autopilot's events out as STATUSTEXT (and into the demo's log), telemetry due."""
        t0 = self._clock_ns()
        events = self.sim.vehicle.events
        if events:
            for event in events:
                if self.endpoint is not None:
                    self.endpoint.statustext(event.severity, event.text)
                if self.flight is not None:
                    self.flight.event(event.text)
            events.clear()
        if self.endpoint is not None:
            self.endpoint.poll(self.sim.time_s)
        self.link_ns += self._clock_ns() - t0

    def fail(self, exc: BaseException) -> None:
        """End this drone after an exception in its own code (see the class docstring)."""
        self.failed = True
        self.output.error(f"sitl {self.instance}: drone software failed at t={self.sim.time_s:.3f} s:")
        self.output.error("".join(traceback.format_exception(exc)).rstrip())
        self.close(END_FAILED)

    def close(self, cause: float = END_EXITED, last_words: str | None = None) -> None:
        """Close the links, leave the world (the body falls from its last state) with ``cause``, say
        ``last_words`` (to stderr when the drone has no log of its own); idempotent."""
        if self.ended:
            return
        self.ended = True
        try:
            if self.endpoint is not None:
                counts = self.endpoint.signing.counters
                if self.endpoint.signing.active or counts.signed_in or counts.bad_signatures:
                    self.say(
                        f"MAVLink signing: {counts.signed_out} sent signed, {counts.signed_in} received signed; "
                        f"{counts.rejected_unsigned} unsigned dropped, {counts.bad_signatures} bad signatures, "
                        f"{counts.replays} replays"
                    )
                self._publish_link_counters()
                if self.mesh is not None:
                    m = self.mesh.counters()
                    self.say(
                        f"mesh: {self.mesh.posted} reports broadcast; heard {m.frames_delivered} of {m.frames_offered} "
                        f"({m.lost_range} beyond range, {m.lost_path} path loss, {m.lost_model} link model, "
                        f"{m.lost_overrun} overrun)"
                    )
                table = self.endpoint.neighbours.counts()
                if any(c.updates for c in table.values()):
                    self.say(
                        "neighbour table: "
                        + ", ".join(
                            f"{c.updates} reports by {source} (mean age at use {c.mean_age_s * 1000:.0f} ms since "
                            f"received, {c.mean_sent_age_s * 1000:.0f} ms since sent)"
                            for source, c in table.items()
                            if c.updates
                        )
                        + f", {self.endpoint.neighbours.stale} older copies ignored"
                    )
                if self._impaired:
                    for (link_class, direction), c in sorted(self.endpoint.link_counters().items()):
                        self.say(
                            f"link model {link_class} {direction}: {c.frames_offered} frames, {c.frames_lost} lost "
                            f"({c.lost_random} random, {c.lost_burst} burst, {c.lost_queue} queue), {c.delayed} "
                            f"delayed (mean {c.mean_delay_s * 1000:.1f} ms, max {c.max_delay_s * 1000:.1f} ms)"
                        )
                self.endpoint.close()
        finally:
            if self.participant is not None:
                self.participant.close(cause)
            elif self.world is not None:
                self.world.close()
            if last_words is not None:
                self.output.error(f"sitl {self.instance}: {last_words}")
            self.output.close()


def cpu_clock(in_world: bool) -> Callable[[], int]:
    """The clock a drone's parts are timed on: in a swarm this thread's CPU clock, so the split stays true when
    there are more drones than cores (``ClosedLoop.part_clock_ns``); alone, the wall clock."""
    return time.thread_time_ns if in_world else time.perf_counter_ns
