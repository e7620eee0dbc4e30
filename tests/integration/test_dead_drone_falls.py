"""A drone process killed in the air leaves a body that falls to the ground in the shared world.

Two real ``sitl`` processes in lockstep on a shared world created here, as the supervisor creates it, with the gate
moved on by this test at 4x real time: one drone stays on the ground and is the reader; the other takes off
(pymavlink) and is SIGKILLed at its takeoff altitude. After ``mark_ended`` its body falls and the reader, no longer
held back by the dead member, runs on a frame at a time, the test looking at every frame: its view of the body
(``others_ned_m`` at its own simulated time, the view its camera and contact check use) has the body on the ground
within 3 s.

Policy: loopback only; two leased instances (tests/integration/instances.py); a time limit; every process stopped
by PID and reaped.
"""

from __future__ import annotations

import contextlib
import math
import signal
import threading
import time
from collections.abc import Iterator
from multiprocessing import resource_tracker
from pathlib import Path

import pytest

from sitl.dynamics.geodesy import LocalFrame
from sitl.dynamics.plant import DEFAULT_HOME
from sitl.world.lockstep import LockstepGate
from sitl.world.shared import ALT, REST_ALT, TIME, SharedWorld
from sitl.world.view import others_ned_m
from tests.integration.instances import Leases
from tests.integration.mavlink_client import arm_and_take_off, mavlink_connection, wait_vehicle_heartbeat
from tests.integration.sitl_process import SitlDrone, start_drone, stop_drone
from tests.integration.vehicle_link import VehicleLink

pytestmark = [pytest.mark.sim_only, pytest.mark.timeout(120)]

SPEED = 4.0
PHYSICS_DT_S = 1.0 / 250.0
FRAME_S = 0.02  # the gate's step while the body falls (5 physics steps): a fall from 3 m takes some 40 of them
IN_STEP_S = 0.1  # the victim is killed once its published time is this close to the reader's


@pytest.fixture(scope="module", autouse=True)
def shared_memory_tracker() -> Iterator[None]:
    """A shared world created in this process starts Python's shared-memory tracker, a child process that lives as
    long as the interpreter; started before the leak check's snapshot, it is not taken for a leftover drone."""
    resource_tracker.ensure_running()
    yield


def _move_the_gate(gate: LockstepGate, stop: threading.Event) -> None:
    """The supervisor's part of lockstep: the gate moves 20 ms past the common time every 5 ms of wall time, so the
    common clock runs at most 4x real time and never leaps after a pause."""
    while not stop.wait(0.005):
        gate.open_until(gate.time_s() + 0.005 * SPEED)


def test_a_drone_killed_in_the_air_is_on_the_ground_within_3_s_in_the_other_drones_view(
    tmp_path: Path, instances: Leases, drone_seed: int
) -> None:
    reader = instances(2)
    victim_instance = reader + 1
    world = SharedWorld.create()
    with contextlib.ExitStack() as stack:
        stack.callback(world.close)
        gate = LockstepGate(world, PHYSICS_DT_S)
        stack.callback(gate.close)
        stop = threading.Event()
        mover = threading.Thread(target=_move_the_gate, args=(gate, stop), name="gate")
        mover.start()
        stack.callback(mover.join)
        stack.callback(stop.set)
        drones: list[SitlDrone] = []
        for k, (instance, north_m) in enumerate(((reader, 0.0), (victim_instance, 5.0))):
            home = LocalFrame(DEFAULT_HOME).geo_from_ned((north_m, 0.0, 0.0))
            home_arg = f"{home.lat_deg:.9f},{home.lon_deg:.9f},{home.alt_amsl_m:.3f}"
            drone = start_drone(instance=instance, speed_factor=SPEED, seed=drone_seed + k, log_dir=tmp_path,
                                extra_args=("--world", world.name, "--lockstep", "--home", home_arg))  # fmt: skip
            stack.callback(stop_drone, drone)
            drones.append(drone)
        victim = VehicleLink.of(drones[1])
        with mavlink_connection(victim.pymavlink_url) as conn:
            wait_vehicle_heartbeat(conn, victim.sysid, victim.wall_s(5))
            # GIVEN the victim hovering at its takeoff altitude
            alt_m = arm_and_take_off(conn, victim.wall_s(30))
        table = world.table
        # ... and in step with the reader: a drone that joined the swarm late runs behind it until it catches up, and
        # the reader, looking from its own later time, would see a body killed meanwhile fall before it looked
        in_step_by = time.monotonic() + 30.0
        while table[reader, TIME] - table[victim_instance, TIME] > IN_STEP_S and time.monotonic() < in_step_by:
            time.sleep(0.01)
        assert table[reader, TIME] - table[victim_instance, TIME] <= IN_STEP_S, "the victim never caught up"
        assert table[victim_instance, ALT] - table[victim_instance, REST_ALT] == pytest.approx(alt_m, abs=0.4)
        # WHEN its process is killed and the supervisor's part is done: the row marked ended
        drones[1].process.signal(signal.SIGKILL)
        drones[1].process.wait(10.0)
        assert not world.ended(victim_instance)
        world.mark_ended(victim_instance)
        killed_at_s = float(table[victim_instance, TIME])
        stop.set()  # from here the test moves the gate itself, a frame at a time, and looks at every frame: what it
        mover.join()  # sees then does not depend on when the machine lets it run
        gate.remove(victim_instance)  # as the supervisor does for an exited member (mark_ended has already freed it)
        # THEN in the reader's view the body falls and lies on the ground by 3 s after its last state
        deadline = time.monotonic() + 30.0
        heights = []
        while time.monotonic() < deadline and table[reader, TIME] < killed_at_s + 3.0:
            frame_end_s = gate.time_s() + FRAME_S  # the reader's completed steps (its published time lags them)
            gate.open_until(frame_end_s)
            while gate.time_s() < frame_end_s - PHYSICS_DT_S / 2 and time.monotonic() < deadline:
                time.sleep(0.001)
            ids, offsets = others_ned_m(world, reader)
            (k,) = [i for i, ident in enumerate(ids) if ident == victim_instance]
            heights.append(-float(offsets[k][2]))
        assert table[reader, TIME] >= killed_at_s + 3.0, "the reader's clock did not advance"
        ids, offsets = others_ned_m(world, reader)
        (k,) = [i for i, ident in enumerate(ids) if ident == victim_instance]
        assert abs(offsets[k][2]) < 0.05, offsets[k]  # both rest on their gear at the same ground level
        assert max(heights) > 1.0 and min(heights) < 0.05, heights  # it was seen up there, and coming down
        _lat, _lon, alt = world.body_geo(victim_instance, math.inf)  # type: ignore[misc]
        assert alt == pytest.approx(table[victim_instance, REST_ALT])
        assert drones[0].process.alive()
