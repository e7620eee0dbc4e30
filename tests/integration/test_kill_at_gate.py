"""A kill the supervisor orders (a mission's ``crash`` fault, ``swarm kill``) lands at a lockstep gate, so a flight
with a kill replays exactly: one process per drone (SIGKILL once every drone stands at the gate) and hosted drones
(the host stops the drone before it reads or steps again).

Between two gates the drones fly while the supervisor handles the last frame (the pipelined frame,
gcs/fleet/pump.py); a kill carried out there would land at whatever step the drone had reached, and the same
mission would lose its drone a few steps apart from run to run. Each mode flies the same mission twice on the same
instances and must give the same flight log, message for message.

Policy: loopback only; leased instances; lockstep; about 25 s of wall time per mode on two cores.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.integration.instances import Leases
from tests.integration.mission_flight import fly_mission
from tests.integration.test_links_fly import tlog_messages

pytestmark = [pytest.mark.sim_only, pytest.mark.timeout(400)]

MISSION = """\
name = "kill_at_gate"
[swarm]
drones = 3
spacing_m = 3.0

[[steps]]
action = "takeoff"
alt_m = 3.0

[[steps]]
action = "fault"
drone = 2
fault = "crash"
after_s = 0.5

[[steps]]
action = "formation"
shape = "line"
spacing_m = 3.0
alt_m = 3.0
hold_s = 2.0

[[steps]]
action = "land"
"""
FRAME_S = 0.02  # gcs/fleet/clock.py LOCKSTEP_LEAD_S: the gates are this far apart
_AT_GATE = re.compile(r"at the lockstep gate of t=(\d+\.\d+) s")


@pytest.mark.parametrize("per_process", ["1", "3"], ids=["one-process-per-drone", "hosted"])
def test_a_kill_lands_at_a_gate_and_the_flight_replays_exactly(
    tmp_path: Path, instances: Leases, per_process: str
) -> None:
    # GIVEN a mission whose second drone is killed half a second after the takeoff
    mission = tmp_path / "kill_at_gate.toml"
    mission.write_text(MISSION)
    first = instances(3)
    victim = first + 2
    # WHEN it is flown twice in lockstep on the same instances
    runs = []
    for name in ("first", "second"):
        metrics, _ = fly_mission(mission, ["--lockstep", "--drones-per-process", per_process], tmp_path / name, 180,
                                 first)  # fmt: skip
        runs.append((metrics, tlog_messages(tmp_path / name / "report" / "flight.tlog")))
    (metrics, log), (again, log_again) = runs
    # THEN the kill was carried out at a gate, a whole number of frames into the flight
    [fault] = metrics["faults"]
    assert fault["sysid"] == victim and fault["fault"] == "crash", fault
    gate = _AT_GATE.search(fault["result"])
    assert gate is not None, fault["result"]
    gate_s = float(gate.group(1))
    assert abs(gate_s / FRAME_S - round(gate_s / FRAME_S)) < 1e-6, gate_s
    cause = "killed inside its host process" if per_process == "3" else "process killed by SIGKILL"
    assert [(x["sysid"], x["cause"]) for x in metrics["losses"]] == [(victim, cause)], metrics["losses"]
    # AND the two flights' logs hold the same messages in the same order, the victim's last ones included
    assert sum(1 for sysid, _, _ in log if sysid == victim) > 100
    first_difference = next((k for k, (x, y) in enumerate(zip(log, log_again, strict=False)) if x != y), None)
    assert first_difference is None, (first_difference, log[first_difference][:2], log_again[first_difference][:2])
    assert len(log) == len(log_again)
    assert [(x["sysid"], x["time_s"], x["down_ne_m"]) for x in metrics["losses"]] == [
        (x["sysid"], x["time_s"], x["down_ne_m"]) for x in again["losses"]
    ]
    assert gate.group(0) in again["faults"][0]["result"], again["faults"]
