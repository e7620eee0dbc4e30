"""``swarm fly``: run a mission file end to end: spawn, take off, formations, land, shut down, report.

The runner talks to the drones only over MAVLink, as it would to real PX4 drones: NAV_TAKEOFF and NAV_LAND
commands, and OFFBOARD with SET_POSITION_TARGET_LOCAL_NED streamed at 20 Hz for formations. Formation targets live
in the swarm frame (gcs/frames.py) and are converted into each drone's own local frame, anchored where that drone
booted (reported in its HOME_POSITION). Mission time runs at the simulation's speed factor, so a step's
``hold_s`` is simulated seconds.

Everything received is written to ``flight.tlog`` and recorded for the flight report (gcs/report.py).
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from gcs.formation import SETPOINT_STREAM_HZ
from gcs.frames import SwarmFrame
from gcs.metrics import LiveMetrics
from gcs.mission_file import FormationStep, HoldStep, LandStep, MissionSpec, RtlStep, Step, TakeoffStep
from gcs.recording import DroneSample, EventRecord, FlightRecording, StepRecord
from gcs.report import write_report
from gcs.streamer import FormationStreamer
from gcs.supervisor import SpawnPlan
from gcs.swarm import Swarm, SwarmError
from gcs.tlog import TlogWriter
from sitl.airframe import load_airframe
from sitl.dynamics.plant import GeoPoint

Say = Callable[[str], None]
ALT_TOLERANCE_M = 0.2  # takeoff is done when every drone holds the target altitude within this...
ALT_HOLD_S = 1.0  # ...for this long (simulated seconds)
STATUS_EVERY_S = 2.0
ARMABLE_TIMEOUT_S = 30.0
COLLISION_TEXT = re.compile(r"Collision with drone (\d+)")


class MissionRunner:
    def __init__(self, mission: MissionSpec, *, speed_factor: float, origin: GeoPoint, first_instance: int,
                 report_dir: Path, say: Say, airframe: str | None = None, seed: int = 0,
                 forward: tuple[str, int] | None = None) -> None:  # fmt: skip
        self.mission = mission
        self.speed = speed_factor
        self.say = say
        self.report_dir = report_dir
        self.swarm_frame = SwarmFrame(origin)
        plan = SpawnPlan(
            n_drones=mission.swarm.drones,
            spacing_m=mission.swarm.spacing_m,
            layout=mission.swarm.layout,
            origin=origin,
            speed_factor=speed_factor,
            first_instance=first_instance,
            airframe=airframe,
            seed=seed,
            log_dir=report_dir / "logs",
        )
        self.swarm = Swarm(plan, forward=forward)
        self.streamer = FormationStreamer(self.swarm, self.swarm_frame)
        # Two bodies touch when their centres are closer than the sum of both collision radii.
        contact_distance = 2.0 * (load_airframe(airframe) if airframe else load_airframe()).collision_radius_m
        self.recording = FlightRecording(
            mission_name=mission.name, n_drones=mission.swarm.drones, collision_radius_m=contact_distance
        )
        self._collision_pairs: set[frozenset[int]] = set()
        self.live = LiveMetrics()
        self._t0_wall = time.monotonic()
        self._tlog: TlogWriter | None = None
        self._next_status_s = 0.0
        self._step_name = "spawn"

    # ---- time and telemetry ----------------------------------------------------------------------------------------
    def now(self) -> float:
        """Mission time in simulated seconds (wall time since start times the speed factor)."""
        return (time.monotonic() - self._t0_wall) * self.speed

    def _on_message(self, msg: Any, _wall_s: float) -> None:
        if self._tlog is not None:
            self._tlog.write(bytes(msg.get_msgbuf()), int(time.time() * 1e6))
        kind = msg.get_type()
        sysid = msg.get_srcSystem()
        now = self.now()
        if kind == "LOCAL_POSITION_NED":
            frame = self.streamer.drone_frame(sysid)
            view = self.swarm.fleet.drones.get(sysid)
            if frame is None or view is None:
                return
            pos = frame.to_swarm((msg.x, msg.y, msg.z))
            vel = frame.vector_to_swarm((msg.vx, msg.vy, msg.vz))
            target = self.streamer.targets(now).get(sysid)
            sample = DroneSample(time_s=now, sysid=sysid, pos_ned_m=pos, vel_ned_mps=vel, armed=view.armed,
                                 mode=view.mode, target_ned_m=target)  # fmt: skip
            self.recording.samples.append(sample)
            self.live.observe(sample)
        elif kind == "STATUSTEXT":
            match = COLLISION_TEXT.match(msg.text)
            if match is not None:  # both drones of a collision report it: count the pair once
                pair = frozenset((sysid, int(match.group(1))))
                if pair in self._collision_pairs:
                    return
                self._collision_pairs.add(pair)
            self.recording.events.append(EventRecord(time_s=now, sysid=sysid, text=msg.text))
            if msg.severity <= mavlink.MAV_SEVERITY_WARNING:
                self.say(f"  sysid {sysid}: {msg.text}")

    def _tick(self, _wall_s: float) -> None:
        now = self.now()
        self.streamer.tick(now)
        if now >= self._next_status_s:
            self._next_status_s = now + STATUS_EVERY_S
            self.say(f"[{now:6.1f} s] {self._step_name:<10} {self.live.status().line()}")

    def _wait(self, condition: Callable[[], bool], timeout_sim_s: float) -> bool:
        return self.swarm.wait_until(condition, timeout_sim_s / self.speed, tick=self._tick)

    def _hold(self, duration_sim_s: float) -> None:
        self.swarm.run_for(duration_sim_s / self.speed, tick=self._tick, tick_s=1.0 / SETPOINT_STREAM_HZ)

    # ---- steps -----------------------------------------------------------------------------------------------------
    def _takeoff(self, step: TakeoffStep) -> None:
        swarm = self.swarm
        if not all(swarm.fleet.drones[s].armed for s in swarm.sysids):
            swarm.arm_all(ARMABLE_TIMEOUT_S, tick=self._tick)
        swarm.takeoff_all(step.alt_m)
        target = -step.alt_m
        since: list[float | None] = [None]

        def holding() -> bool:
            positions = self.streamer.positions()
            ok = len(positions) == len(swarm.sysids) and all(
                abs(p[2] - target) < ALT_TOLERANCE_M for p in positions.values()
            )
            now = self.now()
            since[0] = (since[0] if since[0] is not None else now) if ok else None
            return since[0] is not None and now - since[0] >= ALT_HOLD_S

        if not self._wait(holding, step.timeout_s):
            raise SwarmError(f"takeoff to {step.alt_m:g} m not reached within {step.timeout_s:g} s")

    def _formation(self, step: FormationStep) -> None:
        self.streamer.command(step.formation, self.now())
        self._hold(step.hold_s)

    def _land(self, step: LandStep | RtlStep) -> None:
        """Land (or return) every drone still armed; a crashed or already landed drone has nothing to do."""
        self.streamer.stop()
        flying = self.swarm.land_all(return_to_launch=isinstance(step, RtlStep))
        if not self._wait(lambda: not any(self.swarm.fleet.drones[s].armed for s in flying), step.timeout_s):
            raise SwarmError(f"not every drone landed and disarmed within {step.timeout_s:g} s")

    def _run_step(self, index: int, step: Step) -> None:
        start = self.now()
        kind = type(step).__name__.removesuffix("Step").lower()
        name = step.name if isinstance(step, FormationStep) else kind
        self._step_name = name
        self.say(f"[{start:6.1f} s] step {index + 1}/{len(self.mission.steps)}: {name}")
        if isinstance(step, TakeoffStep):
            self._takeoff(step)
        elif isinstance(step, FormationStep):
            self._formation(step)
        elif isinstance(step, HoldStep):
            self._hold(step.duration_s)
        else:
            self._land(step)
        self.recording.steps.append(
            StepRecord(
                index=index,
                name=name,
                kind=kind,
                start_s=start,
                end_s=self.now(),
                target_alt_m=step.alt_m if isinstance(step, TakeoffStep) else None,
            )
        )

    def run(self) -> Path:
        """Fly the mission; always shuts the swarm down and writes the report, also after a failure."""
        self.report_dir.mkdir(parents=True, exist_ok=True)
        self._tlog = TlogWriter(self.report_dir / "flight.tlog")
        self.swarm.listeners.append(self._on_message)
        failure: BaseException | None = None
        try:
            self.say(f"mission {self.mission.name}: spawning {self.mission.swarm.drones} drones "
                     f"(speed {self.speed:g}x)")  # fmt: skip
            self.swarm.up()
            self._t0_wall = time.monotonic()
            self.swarm.arm_all(ARMABLE_TIMEOUT_S, tick=self._tick)  # before the takeoff step's clock starts
            for index, step in enumerate(self.mission.steps):
                self._run_step(index, step)
        except (SwarmError, KeyboardInterrupt) as exc:
            failure = exc
        finally:
            self.streamer.stop()
            self.swarm.shutdown()
            self._tlog.close()
        out = write_report(self.recording, self.report_dir)
        self.say((out / "summary.txt").read_text().rstrip())
        if failure is not None:
            raise failure
        return out
