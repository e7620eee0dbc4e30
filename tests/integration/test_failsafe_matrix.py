"""Every row of the failsafe matrix (docs/failsafes.md) triggered by fault injection over MAVLink on a real ``sitl``.

The test is the ground station: it sends GCS HEARTBEATs (MAV_TYPE_GCS) at 1 Hz of the drone's time, as QGroundControl
does, sets the failsafe's PX4 parameters over the wire, injects the fault with MAV_CMD_INJECT_FAILURE and checks what
a client sees (flight mode in HEARTBEAT custom_mode, system_status, STATUSTEXT) and what the drone does. The drone's
body in a shared world the test creates is ground truth: where it is and when (``sitl --world``), which is also how a
drone made silent by a link fault is watched.

Policy: drones of these tests use leased instances (tests/integration/instances.py, the ``world_drone`` fixture: the
block of ``instance_allocator``, the test's seed); each is stopped by PID and reaped at the end, its shared world
unlinked. Timeouts are kept short (COM_DL_LOSS_T at its minimum 5 s, COM_FAIL_ACT_T 1 s, RTL_RETURN_ALT 0 so a Return
flies home at the altitude it has) so each test flies a few tens of simulated seconds.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import threading
import time
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass, field
from multiprocessing import resource_tracker
from typing import Any, Final

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from sitl.estimation.estimator import EstimatorConfig
from sitl.mathutil import GRAVITY_MPS2
from sitl.sensors.models import SensorConfig
from sitl.world.shared import ALT, LAT, LON, TIME, VALID, VE, VN, SharedWorld
from tests.integration.mavlink_client import (
    PX4_AUTO_LAND,
    PX4_AUTO_LOITER,
    Message,
    arm_and_take_off,
    command_long,
    mavlink_connection,
    recv_until,
    set_param,
    wait_vehicle_heartbeat,
)
from tests.integration.sitl_process import SitlDrone, WorldDrone
from tests.integration.vehicle_link import VehicleLink

pytestmark = [pytest.mark.sim_only]

SPEED_FACTOR: Final = 4.0
INJECT: Final = mavlink.MAV_CMD_INJECT_FAILURE
PREARM: Final = mavlink.MAV_SYS_STATUS_PREARM_CHECK
PX4_AUTO_RTL: Final = 84148224  # main 4 << 16 | sub 5 << 24
PX4_OFFBOARD: Final = 6 << 16
EARTH_RADIUS_M: Final = 6_371_000.0
Geo2 = tuple[float, float]  # latitude, longitude in degrees


@pytest.fixture(scope="module", autouse=True)
def _shared_memory_tracker() -> None:
    """The shared world is tracked by Python's resource-tracker process, which lives as long as the test run:
    started before the suite's per-test leak check lists the children, it is not counted as a leak."""
    resource_tracker.ensure_running()


@dataclass(frozen=True, slots=True, kw_only=True)
class BodySample:
    """The drone's true state at one instant, read from the shared world."""

    time_s: float
    north_m: float  # from where the drone stood at start-up (home)
    east_m: float
    up_m: float
    hor_speed_mps: float

    def hor_dist_m(self, other: BodySample | tuple[float, float] = (0.0, 0.0)) -> float:
        n, e = (other.north_m, other.east_m) if isinstance(other, BodySample) else other
        return math.hypot(self.north_m - n, self.east_m - e)


@dataclass(slots=True)
class GroundStation:
    """The test's side of the API link: a pymavlink connection, a GCS HEARTBEAT thread, the drone's world row."""

    conn: mavutil.mavfile
    drone: SitlDrone
    world: SharedWorld
    home: tuple[float, float, float]  # lat, lon, alt AMSL of the body at start-up
    texts: list[tuple[int, str]] = field(default_factory=list)  # every STATUSTEXT seen by ``recv``, in order
    chunks: dict[int, list[str]] = field(default_factory=dict)  # STATUSTEXT id -> the chunks received so far

    def body(self) -> BodySample:
        return body_of(self.drone, self.world, self.home)

    def recv(self, predicate: Callable[[Message], bool], timeout_s: float, what: str) -> Message:
        """The first message from the drone's autopilot satisfying ``predicate``; every STATUSTEXT is kept."""
        deadline = time.monotonic() + timeout_s
        while (remaining := deadline - time.monotonic()) > 0:
            msg = self.conn.recv_match(blocking=True, timeout=min(remaining, 0.25))
            if msg is None or msg.get_srcSystem() != self.drone.sysid or msg.get_srcComponent() != 1:
                continue
            if msg.get_type() == "STATUSTEXT":
                msg = self._whole_text(msg)
                if msg is None:
                    continue
                self.texts.append((int(msg.severity), str(msg.text)))
            if predicate(msg):
                return msg
        raise AssertionError(f"{what}: not within {timeout_s:.1f} s; STATUSTEXTs so far: {self.texts}")

    def _whole_text(self, msg: Message) -> Message | None:
        """A STATUSTEXT longer than one message comes in chunks of 50 characters sharing an ``id`` (MAVLink 2); the
        message with the whole text once its last chunk (shorter than 50) arrived, else None."""
        if msg.id == 0:
            return msg
        self.chunks.setdefault(msg.id, []).append(str(msg.text))
        if len(msg.text) >= 50:
            return None
        msg.text = "".join(self.chunks.pop(msg.id))
        return msg

    def wait_text(self, text: str, timeout_s: float) -> int:
        """Wait for a STATUSTEXT containing ``text`` (already seen counts); returns its severity."""
        for severity, seen in self.texts:
            if text in seen:
                return severity
        msg = self.recv(lambda m: m.get_type() == "STATUSTEXT" and text in m.text, timeout_s, f"STATUSTEXT {text!r}")
        return int(msg.severity)

    def wait_heartbeat(self, custom_mode: int, timeout_s: float, what: str) -> Message:
        return self.recv(
            lambda m: m.get_type() == "HEARTBEAT" and m.custom_mode == custom_mode, timeout_s, f"HEARTBEAT {what}"
        )

    def set_param(self, name: str, value: float, *, integer: bool = False) -> None:
        set_param(self.conn, name, value, integer=integer)

    def inject(self, unit: int, failure_type: int, instance: int = 0) -> None:
        """MAV_CMD_INJECT_FAILURE, sent once (its announcement, which comes first, is kept with the other texts)."""
        self.conn.mav.command_long_send(self.conn.target_system, 1, INJECT, 0, unit, failure_type, instance, 0, 0, 0, 0)
        ack = self.recv(lambda m: m.get_type() == "COMMAND_ACK" and m.command == INJECT, 3.0, "INJECT_FAILURE ACK")
        assert ack.result == mavlink.MAV_RESULT_ACCEPTED, ack

    def reposition(self, north_m: float, east_m: float, up_m: float) -> None:
        """MAV_CMD_DO_REPOSITION (COMMAND_INT, altitude above home), as QGroundControl's "go to location"."""
        lat0, lon0, _ = self.home
        lat = lat0 + math.degrees(north_m / EARTH_RADIUS_M)
        lon = lon0 + math.degrees(east_m / (EARTH_RADIUS_M * math.cos(math.radians(lat0))))
        self.conn.mav.command_int_send(
            self.conn.target_system, 1, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mavlink.MAV_CMD_DO_REPOSITION,
            0, 0, -1, mavlink.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE, 0, math.nan, round(lat * 1e7), round(lon * 1e7),
            up_m,
        )  # fmt: skip
        ack = recv_until(self.conn, "COMMAND_ACK", lambda m: m.command == mavlink.MAV_CMD_DO_REPOSITION, 5.0, "ack")
        assert ack.result == mavlink.MAV_RESULT_ACCEPTED, ack

    def watch_body(self, until: Callable[[list[BodySample]], bool], timeout_s: float, what: str) -> list[BodySample]:
        return watch_body(lambda: self.body(), until, timeout_s, what)

    def wait_disarmed(self, timeout_s: float) -> Message:
        return self.recv(
            lambda m: m.get_type() == "HEARTBEAT" and not m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED,
            timeout_s,
            "HEARTBEAT disarmed",
        )


async def text_among(texts: list[Any], text: str, timeout_s: float) -> None:
    """Wait until MAVSDK's recorded STATUSTEXTs hold ``text``."""
    deadline = time.monotonic() + timeout_s
    while not any(t.text == text for t in texts):
        if time.monotonic() > deadline:
            raise AssertionError(f"STATUSTEXT {text!r} not within {timeout_s:.1f} s: {[t.text for t in texts]}")
        await asyncio.sleep(0.01)


@contextlib.asynccontextmanager
async def sampling(body: Callable[[], BodySample]) -> AsyncIterator[list[BodySample]]:
    """Sample the body every 10 ms of wall time in the background while the block awaits something else."""
    samples: list[BodySample] = []

    async def run() -> None:
        while True:
            samples.append(body())
            await asyncio.sleep(0.01)

    task = asyncio.create_task(run())
    try:
        yield samples
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


def body_of(drone: SitlDrone, world: SharedWorld, home: tuple[float, float, float]) -> BodySample:
    row = world.table[drone.ports.instance]
    lat0, lon0, alt0 = home
    return BodySample(
        time_s=float(row[TIME]),
        north_m=math.radians(float(row[LAT]) - lat0) * EARTH_RADIUS_M,
        east_m=math.radians(float(row[LON]) - lon0) * EARTH_RADIUS_M * math.cos(math.radians(lat0)),
        up_m=float(row[ALT]) - alt0,
        hor_speed_mps=math.hypot(float(row[VN]), float(row[VE])),
    )


def watch_body(
    body: Callable[[], BodySample], until: Callable[[list[BodySample]], bool], timeout_s: float, what: str
) -> list[BodySample]:
    """Sample the body (every 10 ms of wall time, one sample per new simulated instant) until ``until``."""
    samples: list[BodySample] = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        sample = body()
        if not samples or sample.time_s > samples[-1].time_s:
            samples.append(sample)
            if until(samples):
                return samples
        time.sleep(0.01)
    raise AssertionError(f"{what}: not within {timeout_s:.1f} s; last {samples[-1:]}")


def drone_in_world(
    world_drone: WorldDrone, speed_factor: float = SPEED_FACTOR
) -> contextlib.AbstractContextManager[tuple[SitlDrone, SharedWorld]]:
    """A drone of the test (``world_drone``: an instance of the leased block, the test's seed), publishing its body
    to a fresh shared world."""
    return world_drone(speed_factor=speed_factor, log_lines=80)


def home_of(drone: SitlDrone, world: SharedWorld) -> tuple[float, float, float]:
    row = world.table[drone.ports.instance]
    assert row[VALID] == 1.0
    return float(row[LAT]), float(row[LON]), float(row[ALT])


@contextlib.contextmanager
def periodic(send: Callable[[], None], interval_s: float) -> Iterator[threading.Event]:
    """Call ``send`` every ``interval_s`` of wall time from a thread until the block ends or the returned event is
    set (which is how a test stops a stream: the drone then loses it)."""
    stop = threading.Event()

    def run() -> None:
        while not stop.wait(interval_s):
            send()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        yield stop
    finally:
        stop.set()
        thread.join()


@contextlib.contextmanager
def ground_station(world_drone: WorldDrone, speed_factor: float = SPEED_FACTOR) -> Iterator[GroundStation]:
    """A drone in a fresh shared world, and the test as its ground station (GCS HEARTBEATs at 1 Hz of the drone's
    time, injection enabled with SYS_FAILURE_EN = 1)."""
    with (
        drone_in_world(world_drone, speed_factor) as (drone, world),
        mavlink_connection(VehicleLink.of(drone).pymavlink_url) as conn,
    ):
        wait_vehicle_heartbeat(conn, drone.sysid, 10.0)
        gcs = GroundStation(conn, drone, world, home_of(drone, world))

        def beat() -> None:
            conn.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)

        with periodic(beat, 1.0 / speed_factor):
            gcs.set_param("SYS_FAILURE_EN", 1, integer=True)
            yield gcs


def settled(samples: list[BodySample], ne_m: tuple[float, float], hold_s: float = 1.0) -> bool:
    """The body has stayed within 0.2 m of ``ne_m`` for the last ``hold_s`` of its time."""
    last = samples[-1]
    if last.hor_dist_m(ne_m) > 0.2:
        return False
    recent = [s for s in samples if s.time_s >= last.time_s - hold_s]
    return samples[0].time_s <= last.time_s - hold_s and all(s.hor_dist_m(ne_m) <= 0.2 for s in recent)


def _is_status(m: Message, custom_mode: int, system_status: int) -> bool:
    return bool(m.get_type() == "HEARTBEAT" and m.custom_mode == custom_mode and m.system_status == system_status)


# ---- pre-arm check of the datalink failsafe -----------------------------------------------------------------------
@pytest.mark.timeout(60)
def test_with_nav_dll_act_set_arming_needs_gcs_heartbeats(world_drone: WorldDrone) -> None:
    with (
        drone_in_world(world_drone) as (drone, world),
        mavlink_connection(VehicleLink.of(drone).pymavlink_url) as conn,
    ):
        wait_vehicle_heartbeat(conn, drone.sysid, 10.0)
        gcs = GroundStation(conn, drone, world, home_of(drone, world))
        # GIVEN NAV_DLL_ACT = 2 and a client that sends no GCS HEARTBEAT (a script, not a ground station)
        gcs.set_param("NAV_DLL_ACT", 2, integer=True)
        # WHEN it arms once the estimate is ready  THEN DENIED, with PX4's words
        refusal = "Preflight Fail: No connection to the ground control station"
        deadline = time.monotonic() + 30.0
        while refusal not in [t for _, t in gcs.texts]:
            assert time.monotonic() < deadline, gcs.texts
            conn.mav.command_long_send(drone.sysid, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
            ack = gcs.recv(lambda m: m.get_type() == "COMMAND_ACK", 3.0, "arming ACK")
            assert ack.result == mavlink.MAV_RESULT_DENIED, ack
            time.sleep(0.5 / SPEED_FACTOR)
            gcs.recv(lambda m: m.get_type() == "HEARTBEAT", 3.0, "HEARTBEAT")  # the refusal's text comes first

        # WHEN GCS HEARTBEATs flow  THEN it arms
        def beat() -> None:
            conn.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)

        with periodic(beat, 1.0 / SPEED_FACTOR):
            gcs.recv(lambda m: m.get_type() == "SYS_STATUS" and bool(m.onboard_control_sensors_health & PREARM), 5.0,
                     "SYS_STATUS with the pre-arm checks passing")  # fmt: skip
            ack = command_long(conn, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (1,))
            assert ack.result == mavlink.MAV_RESULT_ACCEPTED, (ack, gcs.texts)


# ---- datalink loss ------------------------------------------------------------------------------------------------
@pytest.mark.timeout(60)
def test_link_off_with_nav_dll_act_return_holds_then_returns_home_after_com_dl_loss_t(world_drone: WorldDrone) -> None:
    loss_s, act_s, goto_m = 5, 3.0, 40.0
    with ground_station(world_drone) as gcs:
        # GIVEN NAV_DLL_ACT = 2 (Return), short timeouts, a drone starting a 40 m goto north (8 s at cruise speed)
        gcs.set_param("NAV_DLL_ACT", 2, integer=True)
        gcs.set_param("COM_DL_LOSS_T", loss_s, integer=True)
        gcs.set_param("COM_FAIL_ACT_T", act_s)
        gcs.set_param("RTL_RETURN_ALT", 0.0)
        arm_and_take_off(gcs.conn, 40.0)
        gcs.reposition(goto_m, 0.0, 2.5)
        # WHEN both links are cut at once: the drone hears no more GCS HEARTBEATs and says nothing more
        gcs.inject(105, 1)
        cut = gcs.body()
        # THEN COM_DL_LOSS_T after the last heartbeat it heard (at most 1 s before the cut) it holds: it brakes and
        # stays put for COM_FAIL_ACT_T; then it returns and lands at home
        samples = gcs.watch_body(lambda s: s[-1].up_m < 0.1 and s[-1].hor_dist_m() < 1.5, 60.0, "landed back home")
        assert gcs.drone.process.alive()
    far = max(samples, key=lambda s: s.north_m)
    hold = [s for s in samples if abs(s.north_m - far.north_m) < 0.3]
    back = next(s for s in samples if s.time_s > far.time_s and s.north_m < far.north_m - 0.5)
    braking_s = CRUISE_MPS / ACC_HOR_MPS2
    assert far.north_m < goto_m - 5.0, far  # stopped well short of the goto point
    assert loss_s - 1.0 <= far.time_s - cut.time_s <= loss_s + braking_s + 0.5, (cut, far)
    # (``back`` is 0.5 m on the way home: 0.6 s from rest at MPC_ACC_HOR)
    assert loss_s + act_s - 1.0 <= back.time_s - cut.time_s <= loss_s + act_s + 1.0, (cut, back)
    assert hold[-1].time_s - hold[0].time_s >= act_s - braking_s, (hold[0], hold[-1])  # held still, then left
    assert max(abs(s.east_m) for s in samples) < 1.0  # straight out and straight home


# ---- offboard loss ------------------------------------------------------------------------------------------------
@pytest.mark.timeout(60)
def test_offboard_setpoints_stopping_with_com_obl_rc_act_land_holds_then_lands_where_it_is(
    world_drone: WorldDrone,
) -> None:
    with ground_station(world_drone) as gcs:
        # GIVEN COM_OBL_RC_ACT = 4 (Land), a drone in OFFBOARD flying to 4 m north on position setpoints
        gcs.set_param("COM_OBL_RC_ACT", 4, integer=True)
        gcs.set_param("COM_OF_LOSS_T", 0.5)
        gcs.set_param("COM_FAIL_ACT_T", 1.0)
        up_m = arm_and_take_off(gcs.conn, 40.0)
        local = recv_until(gcs.conn, "LOCAL_POSITION_NED", lambda m: True, 5.0, "LOCAL_POSITION_NED")
        target = (local.x + 4.0, local.y, local.z)
        position_only = 0b0000_1111_1111_1000  # ignore velocity, acceleration, yaw and yaw rate

        def setpoint() -> None:
            gcs.conn.mav.set_position_target_local_ned_send(
                0, gcs.drone.sysid, 1, mavlink.MAV_FRAME_LOCAL_NED, position_only, *target, 0, 0, 0, 0, 0, 0, 0, 0
            )

        with periodic(setpoint, 0.1 / SPEED_FACTOR) as stream:  # 10 Hz of the drone's time
            time.sleep(0.5 / SPEED_FACTOR)
            ack = command_long(gcs.conn, mavlink.MAV_CMD_DO_SET_MODE, (mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6))
            assert ack.result == mavlink.MAV_RESULT_ACCEPTED, ack
            gcs.watch_body(lambda s: settled(s, (4.0, 0.0), 0.5), 20.0, "holding the offboard setpoint")
            assert gcs.recv(lambda m: _is_status(m, PX4_OFFBOARD, mavlink.MAV_STATE_ACTIVE), 3.0, "OFFBOARD")
            # WHEN the setpoints stop
            stream.set()
            stopped = gcs.body()
            # THEN Hold after COM_OF_LOSS_T (system_status CRITICAL), then Land after COM_FAIL_ACT_T, where it is
            gcs.recv(lambda m: _is_status(m, PX4_AUTO_LOITER, mavlink.MAV_STATE_CRITICAL), 3.0, "Hold in failsafe")
            held = gcs.body()
            assert gcs.wait_text("Failsafe: offboard setpoints lost, holding", 2.0) == mavlink.MAV_SEVERITY_CRITICAL
            gcs.recv(lambda m: _is_status(m, PX4_AUTO_LAND, mavlink.MAV_STATE_CRITICAL), 3.0, "Land in failsafe")
            landing = gcs.body()
            assert gcs.wait_text("Failsafe: landing", 2.0) == mavlink.MAV_SEVERITY_CRITICAL
            gcs.wait_disarmed(20.0)
            down = gcs.body()
    # The last setpoint left up to 0.1 s before ``stopped``; a HEARTBEAT goes out on the change and the body is read
    # when it arrives, a few hundredths of a second of simulated time later.
    assert 0.5 - 0.3 <= held.time_s - stopped.time_s <= 0.5 + 0.6, (stopped, held)
    assert 1.0 - 0.3 <= landing.time_s - held.time_s <= 1.0 + 0.6, (held, landing)
    assert down.hor_dist_m(stopped) < 0.5 and down.up_m < 0.1 and up_m > 2.0, (stopped, down)


# ---- battery ------------------------------------------------------------------------------------------------------
def _fly_out_and_inject_battery(gcs: GroundStation, level: int, action: int) -> BodySample:
    """Take off, hold 6 m north of home, set SYS_FAIL_BAT_LVL and COM_LOW_BAT_ACT, inject a battery failure; the
    body at the injection."""
    gcs.set_param("COM_LOW_BAT_ACT", action, integer=True)
    gcs.set_param("SYS_FAIL_BAT_LVL", level, integer=True)
    arm_and_take_off(gcs.conn, 40.0)
    gcs.reposition(6.0, 0.0, 2.5)
    gcs.watch_body(lambda s: settled(s, (6.0, 0.0), 0.5), 20.0, "holding 6 m north")
    gcs.inject(100, 4)
    return gcs.body()


def _charge_state_is(state: int) -> Callable[[Message], bool]:
    return lambda m: bool(m.get_type() == "BATTERY_STATUS" and m.charge_state == state)


@pytest.mark.timeout(60)
def test_low_battery_only_warns_whatever_com_low_bat_act(world_drone: WorldDrone) -> None:
    with ground_station(world_drone) as gcs:
        injected = _fly_out_and_inject_battery(gcs, level=1, action=2)
        assert gcs.wait_text("Low battery: 14% remaining", 3.0) == mavlink.MAV_SEVERITY_WARNING
        gcs.recv(_charge_state_is(mavlink.MAV_BATTERY_CHARGE_STATE_LOW), 5.0, "BATTERY_STATUS LOW")
        # THEN nothing else: still in Hold, system_status ACTIVE, still where it was, for 3 s of its time
        end_s = injected.time_s + 3.0
        while gcs.body().time_s < end_s:
            hb = gcs.recv(lambda m: m.get_type() == "HEARTBEAT", 2.0, "HEARTBEAT")
            assert (hb.custom_mode, hb.system_status) == (PX4_AUTO_LOITER, mavlink.MAV_STATE_ACTIVE)
        assert gcs.body().hor_dist_m(injected) < 0.3 and gcs.body().up_m > 2.0
        assert not [t for _, t in gcs.texts if t.startswith("Failsafe")]


@pytest.mark.timeout(60)
@pytest.mark.parametrize(
    ("level", "action", "text", "charge_state"),
    [
        # SYS_FAIL_BAT_LVL 2 (critical) with COM_LOW_BAT_ACT = 2: Land
        (2, 2, "Failsafe: battery critical, landing", mavlink.MAV_BATTERY_CHARGE_STATE_CRITICAL),
        # 3 (emergency) with COM_LOW_BAT_ACT = 3: Return at critical, Land at emergency; the reading is below both
        (3, 3, "Failsafe: battery emergency, landing", mavlink.MAV_BATTERY_CHARGE_STATE_EMERGENCY),
    ],
    ids=["critical-land", "emergency-return-then-land"],
)
def test_a_critical_or_emergency_battery_per_com_low_bat_act_lands_where_it_is(
    world_drone: WorldDrone, level: int, action: int, text: str, charge_state: int
) -> None:
    with ground_station(world_drone) as gcs:
        injected = _fly_out_and_inject_battery(gcs, level=level, action=action)
        gcs.recv(lambda m: _is_status(m, PX4_AUTO_LAND, mavlink.MAV_STATE_CRITICAL), 3.0, "AUTO.LAND, CRITICAL")
        assert gcs.wait_text(text, 2.0) == mavlink.MAV_SEVERITY_CRITICAL
        gcs.recv(_charge_state_is(charge_state), 5.0, f"BATTERY_STATUS charge state {charge_state}")
        gcs.wait_disarmed(20.0)
        down = gcs.body()
    assert down.hor_dist_m(injected) < 0.5 and down.up_m < 0.1, (injected, down)


# ---- position loss ------------------------------------------------------------------------------------------------
# The largest tilt the attitude estimate can be off by in a hover: the gyro bias it has not learned yet (its bias loop
# settles in about a minute and a test's drone takes off seconds after boot), held against the accelerometer's
# correction, plus the accelerometer's own bias, both at the sensor model's largest on both axes: 3.1 deg. Eight
# seeds' GPS-off drifts gave 1.2-2.3 deg.
_SENSORS, _ESTIMATOR = SensorConfig(), EstimatorConfig()
TILT_ERROR_MAX_RAD: Final = (
    math.hypot(_SENSORS.gyro_bias_max_radps, _SENSORS.gyro_bias_max_radps) / _ESTIMATOR.att_kp_acc
    + math.hypot(_SENSORS.accel_bias_max_mps2, _SENSORS.accel_bias_max_mps2) / GRAVITY_MPS2
)


@pytest.mark.timeout(60)
def test_gps_off_descends_after_the_estimator_timeout_and_disarms_on_the_ground(world_drone: WorldDrone) -> None:
    with ground_station(world_drone) as gcs:
        arm_and_take_off(gcs.conn, 40.0)
        gcs.inject(4, 1)
        injected = gcs.body()
        # THEN after EKF2's 5 s without GPS: Descend (shown as AUTO.LAND), CRITICAL, PX4's words
        gcs.recv(lambda m: _is_status(m, PX4_AUTO_LAND, mavlink.MAV_STATE_CRITICAL), 10.0, "Descend, CRITICAL")
        descending = gcs.body()
        assert gcs.wait_text("Failsafe: no global position, descending", 2.0) == mavlink.MAV_SEVERITY_CRITICAL
        gcs.wait_disarmed(20.0)
        down = gcs.body()
    assert 5.0 - 0.3 <= descending.time_s - injected.time_s <= 5.0 + 0.6, (injected, descending)
    # No position loop holds it: from the injection on it drifts on the attitude estimate's error (dead reckoning
    # for 5 s, then level by that estimate), which TILT_ERROR_MAX_RAD bounds for the whole time
    drift_s = down.time_s - injected.time_s
    assert down.up_m < 0.1
    assert down.hor_dist_m(injected) < 0.5 * GRAVITY_MPS2 * math.tan(TILT_ERROR_MAX_RAD) * drift_s**2
    assert down.time_s - descending.time_s >= 2.5 / 0.7 - 1.0, (descending, down)


# ---- geofence -----------------------------------------------------------------------------------------------------
def _braking_m(speed_mps: float, accel_mps2: float) -> float:
    """How far a vehicle at ``speed_mps`` goes before it stops, braking at ``accel_mps2``."""
    return speed_mps**2 / (2.0 * accel_mps2)


CRUISE_MPS: Final = 5.0  # MPC_XY_CRUISE's default: the speed of a goto
ACC_HOR_MPS2: Final = 3.0  # MPC_ACC_HOR's default
# The failsafe stops at the braking point planned from the estimate at the breach; the body lags or leads that plan by
# the position estimate's error plus the tracking error of the cascade (a few tenths of a metre while braking).
TRACKING_M: Final = 0.5
ESTIMATE_M: Final = 0.2  # the position estimate's error in steady flight with GPS (its fixes are good to ~0.1 m)


def stop_bound_m(samples: list[BodySample], out_m: Callable[[BodySample], float], fence_m: float) -> float:
    """How far out a vehicle acting on the breach at once may get: where its body crossed the fence, plus the
    estimate's error (the breach is seen on the estimate), plus the braking distance from its true speed there (a
    goto flies a little above MPC_XY_CRUISE), plus the tracking error while braking."""
    crossing = next(s for s in samples if out_m(s) >= fence_m)
    return out_m(crossing) + ESTIMATE_M + _braking_m(crossing.hor_speed_mps, ACC_HOR_MPS2) + TRACKING_M


@pytest.mark.timeout(90)
async def test_mavsdk_uploads_a_circle_fence_and_a_breach_with_gf_action_return_flies_home(
    world_drone: WorldDrone,
) -> None:
    from mavsdk.asyncio.plugins.geofence import Circle, FenceType, GeofenceAsync, GeofenceData, Point
    from mavsdk.asyncio.plugins.telemetry import FlightMode

    from tests.integration.mavsdk_client import (
        call_within,
        connect,
        recording,
        take_off,
        wait_flight_mode,
        wait_landed_and_disarmed,
        wait_ready_to_arm,
    )

    radius_m = 5.0
    with drone_in_world(world_drone) as (drone, world):
        home = home_of(drone, world)
        async with connect(VehicleLink.of(drone).mavsdk_url, drone.sysid) as client:
            # GIVEN GF_ACTION = 3 (Return) and an inclusion circle of 5 m around home, uploaded by MAVSDK
            await call_within(client.param.set_param_int("GF_ACTION", 3), 10.0, "GF_ACTION")
            await call_within(client.param.set_param_float("RTL_RETURN_ALT", 0.0), 10.0, "RTL_RETURN_ALT")
            fence = GeofenceData(polygons=[], circles=[Circle(Point(home[0], home[1]), radius_m, FenceType.INCLUSION)])
            await call_within(GeofenceAsync(client.system).upload_geofence(fence), 10.0, "upload_geofence")
            async with recording(client.telemetry.subscribe_status_text) as texts:
                await wait_ready_to_arm(client, 30.0)
                await take_off(client, 40.0)
                # WHEN it is sent 15 m north, through the fence
                north_deg = math.degrees(15.0 / EARTH_RADIUS_M)
                await call_within(
                    client.action.goto_location(home[0] + north_deg, home[1], home[2] + 2.5, math.nan), 10.0, "goto"
                )
                # THEN it switches to Return, with PX4's words, and lands at home, never far beyond the fence
                async with sampling(lambda: body_of(drone, world, home)) as samples:
                    await wait_flight_mode(client, FlightMode.RETURN_TO_LAUNCH, 20.0)
                    turned = body_of(drone, world, home)
                    await wait_landed_and_disarmed(client, 40.0)
                down = body_of(drone, world, home)
            said = [t.text for t in texts]
    assert "Failsafe: geofence violation (Outside the geofence), returning to launch" in said, said
    # acted on the breach (seen on the estimate, a few centimetres from the truth) and not later
    assert radius_m - ESTIMATE_M <= turned.hor_dist_m() <= radius_m + 1.0, turned
    # the breach is acted on at once: it goes no further than its braking distance from cruise speed beyond the fence
    farthest = max(s.hor_dist_m() for s in samples)
    assert farthest <= stop_bound_m(samples, lambda s: s.hor_dist_m(), radius_m), farthest
    assert down.hor_dist_m() < 1.0 and down.up_m < 0.1, down


@pytest.mark.timeout(60)
def test_beyond_gf_max_hor_dist_with_gf_action_land_lands_there(world_drone: WorldDrone) -> None:
    limit_m = 4.0
    with ground_station(world_drone) as gcs:
        # GIVEN GF_ACTION = 5 (Land) and GF_MAX_HOR_DIST = 4 m, no fence uploaded
        gcs.set_param("GF_ACTION", 5, integer=True)
        gcs.set_param("GF_MAX_HOR_DIST", limit_m)
        arm_and_take_off(gcs.conn, 40.0)
        # WHEN it is sent 15 m north
        gcs.reposition(15.0, 0.0, 2.5)
        # THEN it lands as soon as it is 4 m from home: AUTO.LAND, CRITICAL, PX4's words
        gcs.recv(lambda m: _is_status(m, PX4_AUTO_LAND, mavlink.MAV_STATE_CRITICAL), 20.0, "AUTO.LAND, CRITICAL")
        breach = gcs.body()
        text = "Failsafe: geofence violation (Maximum distance from home exceeded), landing"
        assert gcs.wait_text(text, 2.0) == mavlink.MAV_SEVERITY_CRITICAL
        gcs.wait_disarmed(20.0)
        down = gcs.body()
    # the body is read when the HEARTBEAT (sent on the change) arrives: at 5 m/s, 0.1 s of latency is 0.5 m
    assert limit_m - ESTIMATE_M <= breach.hor_dist_m() <= limit_m + 1.5, breach
    stop_m = limit_m + _braking_m(CRUISE_MPS, ACC_HOR_MPS2) + TRACKING_M
    assert limit_m - ESTIMATE_M <= down.hor_dist_m() <= stop_m, down
    assert down.up_m < 0.1


# ---- motor off ----------------------------------------------------------------------------------------------------
@pytest.mark.timeout(60)
def test_a_rotor_off_in_flight_the_drone_falls_and_stays_down(world_drone: WorldDrone) -> None:
    with ground_station(world_drone) as gcs:
        up_m = arm_and_take_off(gcs.conn, 40.0)
        # WHEN rotor 1 stops
        gcs.inject(101, 1, 1)
        assert gcs.wait_text("Injected: motor off, instances 1", 2.0) is not None
        stopped = gcs.body()
        # THEN a quadrotor cannot hold on three rotors: the body is on the ground within a couple of seconds
        samples = gcs.watch_body(lambda s: s[-1].up_m < 0.05, 10.0, "on the ground")
        fell_s = samples[-1].time_s - stopped.time_s
        assert fell_s <= 2.0, fell_s
        # and what a client sees after it came down: the impact broke it (sitl/drone/closed_loop.py
        # GROUND_IMPACT_SPEED_MPS)
        assert gcs.wait_text("Ground impact at ", 2.0) is not None
        hb = gcs.recv(lambda m: m.get_type() == "HEARTBEAT", 3.0, "HEARTBEAT")
        status = gcs.recv(lambda m: m.get_type() == "SYS_STATUS", 3.0, "SYS_STATUS")
        assert gcs.body().up_m < 0.05  # and stays there
    # SYS_STATUS shows the motor outputs present but unhealthy, as PX4 does for a failed motor
    motors = mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    assert status.onboard_control_sensors_present & motors and not status.onboard_control_sensors_health & motors
    # The motors stopped and the heartbeat says FLIGHT_TERMINATION: a ground station knows this drone is down.
    assert up_m > 2.0 and hb.system_status == mavlink.MAV_STATE_FLIGHT_TERMINATION
    assert not hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED


@pytest.mark.timeout(60)
def test_above_gf_max_ver_dist_with_gf_action_terminate_falls_and_reports_flight_termination(
    world_drone: WorldDrone,
) -> None:
    with ground_station(world_drone) as gcs:
        # GIVEN GF_ACTION = 4 (Terminate) and a 4 m ceiling
        gcs.set_param("GF_ACTION", 4, integer=True)
        gcs.set_param("GF_MAX_VER_DIST", 4.0)
        arm_and_take_off(gcs.conn, 40.0)
        # WHEN it is sent up to 6 m
        gcs.reposition(0.0, 0.0, 6.0)
        # THEN the motors stop for good: HEARTBEAT disarmed with FLIGHT_TERMINATION, PX4's words, and it falls
        hb = gcs.recv(
            lambda m: m.get_type() == "HEARTBEAT" and m.system_status == mavlink.MAV_STATE_FLIGHT_TERMINATION,
            20.0,
            "HEARTBEAT FLIGHT_TERMINATION",
        )
        assert not hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        cut = gcs.body()
        assert gcs.wait_text("Flight termination", 2.0) == mavlink.MAV_SEVERITY_CRITICAL
        gcs.watch_body(lambda s: s[-1].up_m < 0.05, 10.0, "on the ground")
        assert cut.up_m + 0.5 >= 4.0
        # and it may not arm again
        ack = command_long(gcs.conn, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (1,))
        assert ack.result == mavlink.MAV_RESULT_DENIED


def _square(
    home: tuple[float, float, float], north_m: float, east_m: float, half_m: float
) -> list[tuple[float, float]]:
    """Latitude/longitude corners of a square of side 2 * ``half_m`` centred ``north_m``, ``east_m`` from home."""
    lat0, lon0, _ = home
    m_per_deg_lon = EARTH_RADIUS_M * math.cos(math.radians(lat0))
    return [
        (lat0 + math.degrees((north_m + dn) / EARTH_RADIUS_M), lon0 + math.degrees(east_m + de) / m_per_deg_lon)
        for dn, de in ((-half_m, -half_m), (-half_m, half_m), (half_m, half_m), (half_m, -half_m))
    ]


@pytest.mark.timeout(90)
async def test_mavsdk_polygon_fence_with_gf_action_hold_stops_at_the_fence_and_arming_outside_it_is_refused(
    world_drone: WorldDrone,
) -> None:
    from mavsdk.asyncio.plugins.action import ActionError
    from mavsdk.asyncio.plugins.geofence import FenceType, GeofenceAsync, GeofenceData, Point, Polygon
    from mavsdk.asyncio.plugins.telemetry import FlightMode

    from tests.integration.mavsdk_client import (
        call_within,
        connect,
        recording,
        take_off,
        wait_flight_mode,
        wait_ready_to_arm,
    )

    half_m = 6.0
    with drone_in_world(world_drone) as (drone, world):
        home = home_of(drone, world)
        async with connect(VehicleLink.of(drone).mavsdk_url, drone.sysid) as client:
            geofence = GeofenceAsync(client.system)
            await call_within(client.param.set_param_int("GF_ACTION", 2), 10.0, "GF_ACTION")
            await wait_ready_to_arm(client, 30.0)
            async with recording(client.telemetry.subscribe_status_text) as texts:
                # GIVEN an inclusion square 20 m north that home is not in: arming is refused, with PX4's words
                away = [Point(lat, lon) for lat, lon in _square(home, 20.0, 0.0, half_m)]
                fence = GeofenceData(polygons=[Polygon(away, FenceType.INCLUSION)], circles=[])
                await call_within(geofence.upload_geofence(fence), 10.0, "upload_geofence")
                with pytest.raises(ActionError):
                    await call_within(client.action.arm(), 10.0, "arm outside the fence")
                # GIVEN then an inclusion square of 12 m around home
                around = [Point(lat, lon) for lat, lon in _square(home, 0.0, 0.0, half_m)]
                fence = GeofenceData(polygons=[Polygon(around, FenceType.INCLUSION)], circles=[])
                await call_within(geofence.upload_geofence(fence), 10.0, "upload_geofence")
                await take_off(client, 40.0)
                # WHEN it is sent 20 m east, through the fence
                east_deg = math.degrees(20.0 / (EARTH_RADIUS_M * math.cos(math.radians(home[0]))))
                await call_within(
                    client.action.goto_location(home[0], home[1] + east_deg, home[2] + 2.5, math.nan), 10.0, "goto"
                )
                # THEN it says so and holds (a goto is Hold already in PX4: the mode stays HOLD) a braking distance
                # beyond the fence, and stays there
                async with sampling(lambda: body_of(drone, world, home)) as samples:
                    hold_text = "Failsafe: geofence violation (Outside the geofence), holding"
                    await text_among(texts, hold_text, 20.0)
                    turned = body_of(drone, world, home)
                    await wait_flight_mode(client, FlightMode.HOLD, 2.0)
                    await asyncio.sleep(4.0 / SPEED_FACTOR)
                last = body_of(drone, world, home)
            said = [t.text for t in texts]
    assert "Preflight Fail: Vehicle outside geofence" in said, said
    assert half_m - ESTIMATE_M <= turned.east_m <= half_m + 1.0, turned
    farthest = max(s.east_m for s in samples)
    assert farthest <= stop_bound_m(samples, lambda s: s.east_m, half_m), farthest
    assert last.hor_dist_m((0.0, farthest)) < 0.5 and last.up_m > 2.0, last  # holding, in the air
