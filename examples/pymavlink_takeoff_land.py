"""A plain pymavlink script, as one would write it for any PX4 vehicle: wait for the heartbeat, arm, take off,
hover, land, wait for the disarm. With ``--start-drone`` it first starts one simulated drone (``sitl``) and stops it
at the end; without, it talks to whatever vehicle sends to ``--port`` (a running ``sitl``, or PX4 SITL itself).

    python examples/pymavlink_takeoff_land.py --start-drone [--instance 0]

Exits 1 if the drone did not reach the altitude or did not land and disarm.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from sitl.process.ports import instance_ports  # the drone's API port: PX4 SITL's 14540+instance below 40

ALT_M = 3.0


def wait(conn: mavutil.mavfile, kind: str, condition: object, timeout_s: float) -> object:
    """The first ``kind`` message for which ``condition(msg)`` holds, or None after ``timeout_s`` (wall clock)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        msg = conn.recv_match(type=kind, blocking=True, timeout=0.5)
        if msg is not None and condition(msg):  # type: ignore[operator]
            return msg
    return None


def fly(port: int) -> bool:
    conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
    try:
        conn.wait_heartbeat(timeout=30)
        print(f"heartbeat from system {conn.target_system}")
        # PX4 refuses to arm before its pre-arm checks pass: SYS_STATUS says when they do
        prearm = mavlink.MAV_SYS_STATUS_PREARM_CHECK
        if wait(conn, "SYS_STATUS", lambda m: m.onboard_control_sensors_health & prearm, 60.0) is None:
            print("the pre-arm checks never passed")
            return False
        conn.arducopter_arm()
        if wait(conn, "HEARTBEAT", lambda m: m.get_srcSystem() == conn.target_system
                and m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED, 10.0) is None:  # fmt: skip
            print("arming refused")
            return False
        # NAV_TAKEOFF's param7 is an altitude above mean sea level: the ground's is the position's minus its height
        ground = wait(conn, "GLOBAL_POSITION_INT", lambda m: True, 5.0)
        target_amsl_m = (ground.alt - ground.relative_alt) * 1e-3 + ALT_M  # type: ignore[union-attr]
        conn.mav.command_long_send(conn.target_system, 1, mavlink.MAV_CMD_NAV_TAKEOFF, 0,
                                   0, 0, 0, 0, 0, 0, target_amsl_m)  # fmt: skip
        up = wait(conn, "GLOBAL_POSITION_INT", lambda m: abs(m.relative_alt * 1e-3 - ALT_M) < 0.3, 30.0)
        print(f"at {up.relative_alt * 1e-3:.2f} m" if up else "never reached the altitude")  # type: ignore[union-attr]
        conn.set_mode("LAND")  # pymavlink's PX4 mode table: AUTO.LAND
        down = wait(conn, "HEARTBEAT", lambda m: m.get_srcSystem() == conn.target_system
                    and not m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED, 90.0)  # fmt: skip
        print("landed and disarmed" if down else "did not land and disarm")
        return up is not None and down is not None
    finally:
        conn.close()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--start-drone", action="store_true", help="start one simulated drone first")
    parser.add_argument("--instance", type=int, default=0, help="its instance (sysid instance+1, port "
                        "14540+instance, 15000+instance from 40 on)")  # fmt: skip
    args = parser.parse_args()
    drone = None
    if args.start_drone:
        drone = subprocess.Popen([sys.executable, "-m", "sitl.cli", "--instance", str(args.instance), "--no-gcs"])
    try:
        return 0 if fly(instance_ports(args.instance).api_remote) else 1
    finally:
        if drone is not None:
            drone.terminate()
            drone.wait(timeout=30)


if __name__ == "__main__":
    sys.exit(main())
