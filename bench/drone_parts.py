"""Benchmark: CPU per drone per simulated second of each part of a drone, and two code trees compared in one run.

Flights, each timed per part on the thread's CPU clock exactly as a swarm drone times itself
(``ClosedLoop.physics_ns`` / ``control_ns``, ``Awareness.cpu_ns``, and the MAVLink endpoint's reads and polls):

- **lone**: one drone as an unpaced ``sitl`` runs it (batches of PACED_WAKE_STEPS steps between socket reads and
  telemetry polls, with both MAVLink links streaming to a UDP sink nobody reads and a shared world in which it is
  alone: it takes off to 3 m, flies 10 m north and hovers; the ground-station link receives what a supervisor of a
  9-drone swarm sends it). Not a default: its loop is written out here, not ``run_loop`` itself.
- **hosted**: 25 drones built and run as one ``sitl`` process hosts them (``build_drone``, batches between socket
  reads and polls), hovering on an 8 m circle in one shared world, beside a stand-in supervisor that sends each drone
  a setpoint every 50 ms and every other drone's 10 Hz position report, forwarded byte for byte as the relay does:
  what the host's relay path, MAVLink and perception cost per drone. Not a default.
- **hosted-offboard**: the same host, each drone switched to OFFBOARD on that setpoint once its takeoff is done, as
  a formation flies: the steady ticks' share of the control stage. Not a default.
- **circle**: tests/closed_loop/circle_swarm.py, nine drones on one shared world (eight on a rotating 4 m circle
  and a silent one), omnidirectional cameras: every drone has others in view. No MAVLink.
- **dense**: the same with 24 drones on an 8 m circle (the radius ``swarm bench`` gives 24 slots) turning at half
  the rate, and the silent one: every drone has 20-odd others in camera range and 23 relayed.
- **frames**: an omnidirectional rig's frame alone, from the bodies to their NED positions as a drone gets them, on
  200 random scenes of 8 bodies at 2-8 m and of 24 at 2-15 m: microseconds of thread CPU per four-camera frame,
  best of three (``perception`` is the first, ``dense_frame`` the second). Not a default.

The circle flights also report a digest of every drone's true state at every step: trees that should fly alike
show the same digest in the same run that times them.

    python bench/drone_parts.py [--sim-seconds 20] [--repeats 3]
        [--scenarios lone hosted hosted-offboard circle dense frames]
        [--trees DIR ...]

With ``--trees``, each repeat runs every tree in a subprocess of its own (``PYTHONPATH=DIR``), interleaved, so the
machine's load falls on all alike; medians are printed per tree, and each part as a multiple of physics (code the
trees share) in the same run, which cancels the machine's drift between runs. A tree is a checkout of this
repository (for example ``git worktree add /tmp/base HEAD~3`` or ``git archive``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

PARTS = ("physics", "control", "perception", "mavlink", "total")


def lone(sim_seconds: float) -> dict[str, float]:
    import socket

    from sitl.drone.awareness import Awareness
    from sitl.drone.closed_loop import ClosedLoop, SimConfig
    from sitl.drone.sim_vehicle_api import SimVehicleApi
    from sitl.dynamics.airframe import load_airframe
    from sitl.process.mavlink_io import LinkConfig, MavlinkEndpoint
    from sitl.process.runtime import PACED_WAKE_STEPS
    from sitl.protocol import Identity
    from sitl.world.shared import SharedWorld
    from sitl.world.view import WorldParticipant

    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(("127.0.0.1", 0))
    sink_addr = sink.getsockname()
    airframe = load_airframe()
    sim = ClosedLoop(SimConfig(airframe=airframe, seed=3))
    sim.part_clock_ns = time.thread_time_ns
    world = SharedWorld.create()
    part = WorldParticipant(world, 0, airframe.collision_radius_m, rest_alt_amsl_m=sim.truth.geo.alt_amsl_m)
    api = SimVehicleApi(sim)
    links = [
        LinkConfig(name="api", bind=("127.0.0.1", 0), remote=sink_addr),
        LinkConfig(name="gcs", bind=("127.0.0.1", 0), remote=sink_addr),
    ]
    endpoint = MavlinkEndpoint(Identity(sysid=1), api, sim.params, links)
    eyes = Awareness(sim, 0, api.frame, world=world, neighbours=endpoint.neighbours, clock_ns=time.thread_time_ns)
    phase = 0
    # The supervisor's traffic, packed once: relayed frames keep their senders' sysids, as the relay forwards them.
    from pymavlink.dialects.v20 import common as mavlink

    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    neighbours = [mavlink.MAVLink(None, srcSystem=2 + k, srcComponent=1) for k in range(8)]
    gcs_port = endpoint.links[1].port
    supervisor = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    next_tick_s = 0.0
    tick = 0

    def traffic(now_s: float) -> None:
        nonlocal next_tick_s, tick
        if now_s < next_tick_s:
            return
        next_tick_s = now_s + 0.05
        setpoint = gcs.set_position_target_local_ned_encode(
            int(now_s * 1e3), 1, 1, mavlink.MAV_FRAME_LOCAL_NED, 0x0DF8, 10.0, 0.0, -3.0, 0, 0, 0, 0, 0, 0, 0, 0
        )
        frames = [setpoint.pack(gcs)]
        for k in range(4):
            n = neighbours[(tick * 4 + k) % 8]
            frames.append(n.global_position_int_encode(int(now_s * 1e3), 473977420 + 90000 + 2000 * k, 85455940, 490000,
                                                       3000, 10, 20, 0, 9000).pack(n))  # fmt: skip
        if tick % 20 == 0:
            frames.append(gcs.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(gcs))
        tick += 1
        supervisor.sendto(b"".join(frames), ("127.0.0.1", gcs_port))

    def on_step() -> None:
        nonlocal phase
        part.after_step(sim.truth, sim.vehicle.crashed)
        eyes.update(sim.time_s)
        traffic(sim.time_s)
        v = sim.vehicle
        if phase == 0 and v.preflight_problem() is None:
            assert v.arm().ok and v.takeoff(3.0).ok
            phase = 1
        elif phase == 1 and sim.time_s > 12.0:
            import numpy as np

            assert v.goto(np.array((10.0, 0.0, -3.0))).ok
            phase = 2

    t0 = time.thread_time_ns()
    link_ns = 0
    try:
        # A lone drone's unpaced loop (sitl/process/runtime.py): read the sockets, a batch of steps, the telemetry due.
        while sim.time_s < sim_seconds - 1e-9:
            start = time.thread_time_ns()
            endpoint.receive(sim.time_s)
            link_ns += time.thread_time_ns() - start
            for _ in range(PACED_WAKE_STEPS):
                sim.step()
                on_step()
            start = time.thread_time_ns()
            endpoint.poll(sim.time_s)
            link_ns += time.thread_time_ns() - start
    finally:
        endpoint.close()
        part.close()
        world.close()
        sink.close()
        supervisor.close()
    total_ns = time.thread_time_ns() - t0
    ms = 1e-6 / sim.time_s
    return {
        "physics": sim.physics_ns * ms,
        "control": sim.control_ns * ms,
        "perception": eyes.cpu_ns * ms,
        "mavlink": link_ns * ms,
        "total": total_ns * ms,
    }


HOSTED_DRONES = 25
HOSTED_RADIUS_M = 8.0  # the radius swarm bench gives 25 slots: every drone within 15 m of every other


def hosted(sim_seconds: float, *, offboard: bool = False) -> dict[str, float]:
    """A host of HOSTED_DRONES drones as ``sitl`` builds and runs them in one process (``build_drone``, the host's
    shared decoding where the tree has it, batches of PACED_WAKE_STEPS steps between socket reads and telemetry
    polls), on a circle, hovering at 3 m in one shared world, beside a stand-in supervisor on a UDP socket: every
    50 ms of simulated time it sends each drone one datagram, a setpoint and the latest position report of every
    other drone, each forwarded byte for byte as the relay forwards it (every drone is within the relay's reach of
    every other). The drones' own telemetry streams to that socket, which reads and drops it. With ``offboard``, each
    drone enters OFFBOARD on that setpoint (3 m above its home) once its takeoff is done, as a formation flies."""
    import socket

    from pymavlink.dialects.v20 import common as mavlink

    from sitl.autopilot.px4_modes import Px4Mode
    from sitl.dynamics.airframe import load_airframe
    from sitl.dynamics.geodesy import LocalFrame
    from sitl.dynamics.plant import GeoPoint
    from sitl.dynamics.wind import WindConfig
    from sitl.process import drone as drone_module
    from sitl.process.mavlink_io import LinkConfig
    from sitl.process.runtime import PACED_WAKE_STEPS
    from sitl.process.specs import DroneSpec, ProcessSpec
    from sitl.world.shared import SharedWorld

    supervisor = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    supervisor.bind(("127.0.0.1", 0))
    supervisor.setblocking(False)
    world = SharedWorld.create()
    common = ProcessSpec(airframe=load_airframe(), speed_factor=0.0, wind=WindConfig(), world_name=world.name)
    origin = GeoPoint(lat_deg=47.397742, lon_deg=8.545594, alt_amsl_m=488.0)
    frame = LocalFrame(origin)
    homes = [
        frame.geo_from_ned((HOSTED_RADIUS_M * math.cos(a), HOSTED_RADIUS_M * math.sin(a), 0.0))
        for a in (2.0 * math.pi * k / HOSTED_DRONES for k in range(HOSTED_DRONES))
    ]
    specs = [
        DroneSpec(instance=k, seed=k, home=home,
                  links=(LinkConfig(name="gcs", bind=("127.0.0.1", 0), remote=supervisor.getsockname()),))
        for k, home in enumerate(homes)
    ]  # fmt: skip
    share = drone_module.HostShare() if hasattr(drone_module, "HostShare") else None
    build = drone_module.build_drone
    drones = [
        build(spec, common, clock_ns=time.thread_time_ns, **({"share": share} if share is not None else {}))
        for spec in specs
    ]
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    senders = [mavlink.MAVLink(None, srcSystem=k + 1, srcComponent=1) for k in range(HOSTED_DRONES)]
    ports = [d.endpoint.links[0].port for d in drones]
    next_tick_s, tick = 0.0, 0

    def traffic(now_s: float) -> None:
        nonlocal next_tick_s, tick
        while True:  # the drones' telemetry: read and dropped
            try:
                supervisor.recvfrom(65535)
            except BlockingIOError:
                break
        if now_s < next_tick_s:
            return
        next_tick_s = now_s + 0.05
        reports = []
        if tick % 2 == 0:  # every drone reports at 10 Hz, each report relayed once
            reports = [
                n.global_position_int_encode(int(now_s * 1e3), round(h.lat_deg * 1e7), round(h.lon_deg * 1e7),
                                             round((h.alt_amsl_m + 3.0) * 1e3), 3000, 0, 0, 0, 9000).pack(n)
                for n, h in zip(senders, homes, strict=True)
            ]  # fmt: skip
        for k, port in enumerate(ports):
            setpoint = gcs.set_position_target_local_ned_encode(
                int(now_s * 1e3), k + 1, 1, mavlink.MAV_FRAME_LOCAL_NED, 0x0DF8, 0.0, 0.0, -3.0, 0, 0, 0, 0, 0, 0, 0, 0
            )
            frames = [setpoint.pack(gcs), *(r for j, r in enumerate(reports) if j != k)]
            if tick % 20 == 0:
                beat = gcs.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                frames.append(beat.pack(gcs))
            supervisor.sendto(b"".join(frames), ("127.0.0.1", port))
        tick += 1

    armed = [False] * HOSTED_DRONES
    flying_offboard = [not offboard] * HOSTED_DRONES
    t0 = time.thread_time_ns()
    try:
        while drones[0].time_s < sim_seconds - 1e-9:
            traffic(drones[0].time_s)
            for drone in drones:
                drone.receive()
            for k, drone in enumerate(drones):
                for _ in range(PACED_WAKE_STEPS):
                    drone.step()
                v = drone.sim.vehicle
                if not armed[k]:
                    armed[k] = v.preflight_problem() is None and v.arm().ok and v.takeoff(3.0).ok
                elif not flying_offboard[k] and v.status.mode is Px4Mode.AUTO_LOITER:
                    flying_offboard[k] = v.start_offboard(drone.time_s).ok
            for drone in drones:
                drone.after_batch()
    finally:
        total_ns = time.thread_time_ns() - t0
        for drone in drones:
            drone.close()
        world.close()
        supervisor.close()
    ms = 1e-6 / (drones[0].time_s * HOSTED_DRONES)
    return {
        "physics": sum(d.sim.physics_ns for d in drones) * ms,
        "control": sum(d.sim.control_ns for d in drones) * ms,
        "perception": sum(d.awareness.cpu_ns for d in drones) * ms,
        "mavlink": sum(d.link_ns for d in drones) * ms,
        "total": total_ns * ms,
    }


def circle(sim_seconds: float, *, dense: bool = False) -> dict[str, float | None]:
    """The circle flight (or the dense one) timed per part, and ``digest``: a hash of every drone's true state at
    every step, so two trees that should fly alike can be seen to (the same digest) in the same run that times them.
    A tree from before the digests were recorded (no ``fly_with_digest``) flies the same scenario without one."""
    sys.path.insert(0, os.getcwd())
    from dataclasses import replace

    from tests.closed_loop import circle_swarm

    rotate_s = max(sim_seconds - 10.0, 5.0)
    digest: str | None = None
    if hasattr(circle_swarm, "fly_with_digest"):
        scenario = replace(circle_swarm.DENSE if dense else circle_swarm.CIRCLE, rotate_s=rotate_s)
        digest, out, flown = circle_swarm.fly_with_digest(scenario)
    else:
        params = {"drones": 24, "radius_m": 8.0, "rate_radps": 0.15} if dense else {}
        flown = []
        scenario = circle_swarm.CircleScenario(rotate_s=rotate_s, **params)
        out = circle_swarm.fly_circle_past_a_silent_drone(scenario, on_tick=lambda s, _t: flown or flown.extend(s))
    return {
        "physics": 1e-6 * sum(s.physics_ns for s in flown) / (len(flown) * out.sim_s),
        "control": out.control_ms_per_drone_sim_s,
        "perception": out.perception_ms_per_drone_sim_s,
        "total": out.cpu_ms_per_drone_sim_s,
        "digest": None if digest is None else int(digest[:15], 16),
        "collisions": out.collisions,
    }


def frames() -> dict[str, float]:
    """Microseconds per four-camera frame, from the bodies to NED positions, in this tree's drone path (one pass per
    camera where it exists, the rendered images and ``detect_rig`` before it)."""
    import numpy as np

    from sitl.mathutil import quat_from_euler
    from sitl.perception import CameraConfig, CameraRig, detector, spheres
    from sitl.perception import camera as camera_module

    rig = CameraRig.omni(CameraConfig(noise_seed=1))
    scene_rng = np.random.default_rng(5)

    def scene(count: int, near_m: float, far_m: float) -> tuple[object, object]:
        direction = scene_rng.standard_normal((count, 3))
        direction /= np.linalg.norm(direction, axis=1)[:, None]
        direction[:, 2] *= 0.2
        q = quat_from_euler(*scene_rng.uniform(-0.2, 0.2, 2).tolist(), float(scene_rng.uniform(-3.0, 3.0)))
        return direction * scene_rng.uniform(near_m, far_m, count)[:, None], q

    out = {}
    for name, count, near_m, far_m in (("perception", 8, 2.0, 8.0), ("dense_frame", 24, 2.0, 15.0)):
        scenes = [scene(count, near_m, far_m) for _ in range(200)]
        rng = np.random.default_rng(1)
        best = math.inf
        for _ in range(3):
            start = time.thread_time_ns()
            for offsets, q in scenes:
                if hasattr(detector, "sense_rig"):  # one pass per camera
                    rows = np.column_stack((offsets, np.full(count, 0.35)))
                    detector.rig_ned(detector.sense_rig(rig, q, rows, [], rng, 0.35), q)
                else:
                    images = camera_module.render_rig_if_drawn(rig, q, spheres(offsets, 0.35), rng)
                    detector.to_ned_all(detector.detect_rig(images, rig, 0.35), q)
            best = min(best, (time.thread_time_ns() - start) / len(scenes) / 1e3)
        out[name] = best
    return out


def one(sim_seconds: float, scenarios: list[str]) -> dict[str, dict[str, float]]:
    runs = {
        "lone": lambda: lone(sim_seconds),
        "hosted": lambda: hosted(sim_seconds),
        "hosted-offboard": lambda: hosted(sim_seconds, offboard=True),
        "circle": lambda: circle(sim_seconds),
        "dense": lambda: circle(sim_seconds, dense=True),
        "frames": frames,
    }
    return {name: runs[name]() for name in scenarios}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sim-seconds", type=float, default=30.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--trees", nargs="+", type=Path, default=None)
    parser.add_argument(
        "--scenarios",
        nargs="+",
        choices=("lone", "hosted", "hosted-offboard", "circle", "dense", "frames"),
        default=["circle", "dense"],
    )
    parser.add_argument(
        "--reference", choices=PARTS, default="physics", help="the part the ratios are to: one both trees share"
    )
    parser.add_argument("--one", action="store_true", help=argparse.SUPPRESS)  # a subprocess of --trees
    args = parser.parse_args()
    if args.one:
        print(json.dumps(one(args.sim_seconds, args.scenarios)), flush=True)
        return
    trees = [p.resolve() for p in args.trees] if args.trees else [Path.cwd()]
    results: dict[Path, list[dict[str, dict[str, float]]]] = {t: [] for t in trees}
    for rep in range(args.repeats):
        for tree in trees:
            env = {**os.environ, "PYTHONPATH": str(tree)}
            cmd = [sys.executable, str(Path(__file__).resolve()), "--one", "--sim-seconds", str(args.sim_seconds),
                   "--scenarios", *args.scenarios]  # fmt: skip
            proc = subprocess.run(cmd, env=env, cwd=tree, capture_output=True, text=True, check=True)
            row = json.loads(proc.stdout.strip().splitlines()[-1])
            results[tree].append(row)
            print(f"repeat {rep + 1} {tree}: {json.dumps(row)}", flush=True)
    for scenario in args.scenarios:
        reference = args.reference
        if any(r[scenario].get("digest") is not None for runs in results.values() for r in runs):
            digests = {tree: sorted({r[scenario]["digest"] for r in runs}) for tree, runs in results.items()
                       if all(r[scenario].get("digest") is not None for r in runs)}  # fmt: skip
            same = len({tuple(d) for d in digests.values()}) == 1
            verdict = "identical" if same else "DIFFERENT"
            if len(digests) < len(results):
                verdict += f" (no digest from {len(results) - len(digests)} tree(s) older than the recorded flights)"
            print(f"\n{scenario}: flight digests {digests}: {verdict}")
        if scenario == "frames":
            print(f"\nframes: us of CPU per four-camera frame (8 bodies; 24 bodies), median of {args.repeats}")
            for tree, runs in results.items():
                medians = [statistics.median(r["frames"][key] for r in runs) for key in ("perception", "dense_frame")]
                print(f"| {tree} | {medians[0]:.0f} | {medians[1]:.0f} |")
            continue
        print(f"\n{scenario}: ms of CPU per drone per simulated second, median of {args.repeats}")
        _print_medians(results, scenario, ".2f")
        # The machine's speed drifts between runs (other work, cache sharing): each part as a multiple of a part
        # whose code both trees share, within each run, is the steadier comparison.
        print(f"\n{scenario}: each part / {reference} in the same run, median of {args.repeats}")
        _print_medians(results, scenario, ".3f", reference)


def _print_medians(results: dict[Path, list[dict[str, dict[str, float]]]], scenario: str, fmt: str,
                   reference: str | None = None) -> None:  # fmt: skip
    """One markdown row per tree: the median over its runs of each part of ``scenario`` it measured, in ms, or as a
    multiple of the ``reference`` part of the same run."""
    print("| tree | " + " | ".join(PARTS) + " |")
    print("|---|" + "---|" * len(PARTS))
    for tree, runs in results.items():
        cells = []
        for part in PARTS:
            values = [r[scenario][part] / (r[scenario][reference] if reference else 1.0) for r in runs
                      if part in r[scenario]]  # fmt: skip
            cells.append(format(statistics.median(values), fmt) if values else "-")
        print(f"| {tree} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
