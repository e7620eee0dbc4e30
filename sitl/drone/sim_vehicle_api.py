"""The autopilot as the MAVLink services see it: ``VehicleApi`` implemented over one ``ClosedLoop``.

This is the translation layer between wire concepts (geodetic coordinates, AMSL altitudes, PX4 modes, MISSION_ITEM_INT)
and the autopilot's local-frame requests. It is pure: it reads the simulation's estimate and sensor samples (never
ground truth) and calls the vehicle's request methods; the IO shell owns the sockets.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from pymavlink.dialects.v20 import common as mavlink

from sitl.autopilot import vehicle_api as api
from sitl.autopilot.mission_exec import MissionRun
from sitl.autopilot.mission_plan import NavItem, to_nav_items
from sitl.autopilot.orbit import OrbitCommand
from sitl.autopilot.px4_modes import Px4Mode
from sitl.control.cascade import AttitudeSetpoint, TrajectorySetpoint
from sitl.drone.closed_loop import ClosedLoop
from sitl.dynamics.geodesy import LocalFrame
from sitl.dynamics.plant import GeoPoint
from sitl.faults.failures import BATTERY_LEVELS, FaultError, GpsFault, apply_request, decode_request
from sitl.mathutil import Vec3, fast_constructor, vec3
from sitl.protocol.fence import to_geofence
from sitl.sensors.models import GpsSample

ALT_QUANTUM_M = 0.001  # HOME_POSITION's altitude is whole millimetres: a ground station's "home + 2.5 m" may be less

_MISSION_STATE = {
    MissionRun.NO_MISSION: api.MissionState.NO_MISSION,
    MissionRun.NOT_STARTED: api.MissionState.NOT_STARTED,
    MissionRun.ACTIVE: api.MissionState.ACTIVE,
    MissionRun.PAUSED: api.MissionState.PAUSED,
    MissionRun.COMPLETE: api.MissionState.COMPLETE,
}
_ALL_HEALTHY = api.SensorHealth()
# Telemetry asks for a snapshot a dozen times a second: its records built without the frozen classes' ``__init__``.
_new_snapshot = fast_constructor(api.VehicleSnapshot)
_new_battery = fast_constructor(api.BatteryStatus)
_new_progress = fast_constructor(api.MissionProgress)
# Most severe first; BAT_EMERGEN_THR may be absent from an older parameter table (that grade is then skipped).
_CHARGE_STATES = (
    ("BAT_EMERGEN_THR", int(mavlink.MAV_BATTERY_CHARGE_STATE_EMERGENCY)),
    ("BAT_CRIT_THR", int(mavlink.MAV_BATTERY_CHARGE_STATE_CRITICAL)),
    ("BAT_LOW_THR", int(mavlink.MAV_BATTERY_CHARGE_STATE_LOW)),
)
NO_RC_MODES = frozenset(
    {Px4Mode.MANUAL, Px4Mode.ALTCTL, Px4Mode.POSCTL, Px4Mode.STABILIZED, Px4Mode.ACRO, Px4Mode.AUTO_READY}
)


def _nan_if_invalid(values: Vec3, valid: bool) -> tuple[float, float, float]:
    return (float(values[0]), float(values[1]), float(values[2])) if valid else api.NAN3


class SimVehicleApi:
    """``VehicleApi`` for a simulated drone. One instance serves every MAVLink link of the process."""

    def __init__(self, sim: ClosedLoop) -> None:
        self.sim = sim
        self.vehicle = sim.vehicle
        # The estimator's frame starts at the resting CG at boot: that point, in geodetic terms, is the origin.
        self.origin = sim.truth.geo
        self.frame = LocalFrame(self.origin)
        self._mission_items: tuple[api.MissionItem, ...] = ()
        self._mission_home_alt_amsl_m = math.nan  # home altitude the stored mission's relative altitudes used
        self._fence_items: tuple[api.MissionItem, ...] = ()
        self._snapshot: api.VehicleSnapshot | None = None
        self._snapshot_time_s = -1.0
        # Parts of a snapshot that change far less often than telemetry asks: home (its local position and yaw, and
        # the geodetic position worked out from them) and the receiver's status of its latest fix.
        self._home: tuple[tuple[float, float, float, float], api.HomePosition] | None = None
        self._gps: tuple[object, api.GpsStatus] | None = None

    # ---- conversions --------------------------------------------------------------------------------------------
    def home_alt_amsl_m(self) -> float:
        return self.origin.alt_amsl_m - float(self.vehicle.home_ned_m[2])

    def _local_of(self, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> tuple[float, float, float]:
        """Local NED of a geodetic point; NaN inputs keep the vehicle's current coordinate."""
        est = self.vehicle.estimate
        current = est.pos_ned_m if est is not None else vec3(0.0, 0.0, 0.0)
        north, east = float(current[0]), float(current[1])
        if math.isfinite(lat_deg) and math.isfinite(lon_deg):
            north, east, _ = self.frame.ned_from_geo(
                GeoPoint(lat_deg=lat_deg, lon_deg=lon_deg, alt_amsl_m=self.origin.alt_amsl_m)
            )
        down = self.origin.alt_amsl_m - alt_amsl_m if math.isfinite(alt_amsl_m) else float(current[2])
        return (north, east, down)

    # ---- VehicleApi ---------------------------------------------------------------------------------------------
    def mission_items(self) -> Sequence[api.MissionItem]:
        return self._mission_items

    def fence_items(self) -> Sequence[api.MissionItem]:
        return self._fence_items

    def note_gcs_heartbeat(self, now_s: float) -> None:
        self.vehicle.note_gcs_heartbeat(now_s)

    def mavlink_silent_until_s(self) -> float:
        return self.sim.faults.link_off_until_s

    def set_offboard_setpoint(self, setpoint: TrajectorySetpoint | AttitudeSetpoint, now_s: float) -> None:
        self.vehicle.set_offboard_setpoint(setpoint, now_s)

    def command(self, request: api.VehicleRequest, now_s: float) -> api.CommandOutcome:
        outcome = self._command(request, now_s)
        if self._mission_items and self.home_alt_amsl_m() != self._mission_home_alt_amsl_m:
            # Home moved (arming sets it, so does DO_SET_HOME): relative altitudes are above the current home, as
            # PX4 resolves them when it flies an item, not above wherever home was at upload time.
            self._mission_home_alt_amsl_m = self.home_alt_amsl_m()
            self.vehicle.retarget_mission(self._nav_items())
        # A request can change what telemetry reports (armed, mode, mission) without a physics step in between: the
        # HEARTBEAT sent right after an accepted mode change must show the new mode, not the cached old one.
        self._snapshot = None
        return outcome

    def _command(self, request: api.VehicleRequest, now_s: float) -> api.CommandOutcome:
        v = self.vehicle
        match request:
            case api.Arm(force=force):
                return v.arm(force)
            case api.Disarm(force=force):
                return v.kill() if force else v.disarm()
            case api.Kill():
                return v.kill()
            case api.Takeoff(alt_amsl_m=alt):
                minimum = self.sim.params["MIS_TAKEOFF_ALT"]
                relative = alt - self.home_alt_amsl_m() if math.isfinite(alt) else minimum
                if relative < minimum - ALT_QUANTUM_M:  # as PX4's takeoff: never lower than the minimum, and says so
                    v.event(mavlink.MAV_SEVERITY_INFO, f"Using minimum takeoff altitude: {minimum:.2f} m")
                return v.takeoff(max(relative, minimum))
            case api.Land(lat_deg=lat, lon_deg=lon):
                return v.land(self._local_of(lat, lon, math.nan) if math.isfinite(lat) else None)
            case api.ReturnToLaunch():
                return v.return_to_launch()
            case api.SetMode(mode=mode):
                return self._set_mode(mode, now_s)
            case api.Reposition():
                if math.isfinite(request.ground_speed_mps):
                    v.set_speed(request.ground_speed_mps)
                target = self._local_of(request.lat_deg, request.lon_deg, request.alt_amsl_m)
                return v.goto(vec3(*target), request.yaw_rad)
            case api.Orbit():
                return v.orbit(self._orbit_command(request))
            case api.ChangeSpeed(kind=kind, speed_mps=speed):
                if kind is not api.SpeedKind.HORIZONTAL:
                    return api.CommandOutcome(api.CommandResult.UNSUPPORTED, "Only horizontal speed can change")
                return v.set_speed(speed if math.isfinite(speed) else -1.0)
            case api.SetHome(use_current=True):
                return v.set_home(None)
            case api.SetHome(lat_deg=lat, lon_deg=lon, alt_amsl_m=alt):
                if not (math.isfinite(lat) and math.isfinite(lon) and math.isfinite(alt)):
                    return api.CommandOutcome.denied("Set home denied: position incomplete")
                return v.set_home(vec3(*self._local_of(lat, lon, alt)))
            case api.MissionStart(first_seq=first):
                if first is not None and not (outcome := v.set_mission_current(first)).ok:
                    return outcome
                return v.start_mission()
            case api.SetMissionCurrent(seq=seq):
                return v.set_mission_current(seq)
            case api.SetMission(items=items):
                self._mission_items = items
                self._mission_home_alt_amsl_m = self.home_alt_amsl_m()
                return v.set_mission(self._nav_items())
            case api.SetFence(items=items):
                # Zones in the local frame the autopilot flies in (fences are vertical prisms: no altitude).
                v.set_fence(to_geofence(items, self._ne_of))
                self._fence_items = items
                return api.CommandOutcome.accepted()
            case api.InjectFailure():
                return self._inject_failure(request)
        return api.CommandOutcome(api.CommandResult.UNSUPPORTED, "Not supported")

    def _orbit_command(self, request: api.Orbit) -> OrbitCommand:
        """DO_ORBIT's geodetic centre in the local frame; what it leaves out stays NaN for the autopilot to fill."""
        north = east = math.nan
        if math.isfinite(request.lat_deg) and math.isfinite(request.lon_deg):
            north, east = self._ne_of(request.lat_deg, request.lon_deg)
        alt = request.alt_amsl_m
        return OrbitCommand(
            radius_m=request.radius_m,
            velocity_mps=request.velocity_mps,
            yaw=request.yaw,
            centre_north_m=north,
            centre_east_m=east,
            centre_down_m=self.origin.alt_amsl_m - alt if math.isfinite(alt) else math.nan,
        )

    def _ne_of(self, lat_deg: float, lon_deg: float) -> tuple[float, float]:
        north, east, _ = self.frame.ned_from_geo(
            GeoPoint(lat_deg=lat_deg, lon_deg=lon_deg, alt_amsl_m=self.origin.alt_amsl_m)
        )
        return (north, east)

    def _inject_failure(self, request: api.InjectFailure) -> api.CommandOutcome:
        """MAV_CMD_INJECT_FAILURE as PX4 answers it: DENIED unless SYS_FAILURE_EN = 1, UNSUPPORTED for a failure
        the simulation cannot produce; accepted, the reason is the text that announces the failure."""
        params = self.sim.params
        if params["SYS_FAILURE_EN"] != 1:
            return api.CommandOutcome.denied("Failure injection disabled")
        # BAT_EMERGEN_THR may be absent from an older parameter table: that level is then refused, never guessed.
        thresholds = {name: params[name] for _, name in BATTERY_LEVELS.values() if name in params}
        try:
            fault = decode_request(request.unit, request.failure_type, request.instance, request.duration_s)
            state, text = apply_request(
                self.sim.faults,
                fault,
                rotor_count=len(self.sim.config.airframe.rotors),
                battery_level=round(params["SYS_FAIL_BAT_LVL"]),
                battery_thresholds=thresholds,
                now_s=self.sim.time_s,
            )
        except FaultError as exc:
            result = api.CommandResult.UNSUPPORTED if exc.unsupported else api.CommandResult.DENIED
            return api.CommandOutcome(result, str(exc))
        self.sim.set_faults(state)
        return api.CommandOutcome(api.CommandResult.ACCEPTED, text)

    def _nav_items(self) -> tuple[NavItem, ...]:
        return to_nav_items(self._mission_items, self.origin, self._mission_home_alt_amsl_m)

    def _set_mode(self, mode: Px4Mode, now_s: float) -> api.CommandOutcome:
        v = self.vehicle
        if mode in NO_RC_MODES:
            return api.CommandOutcome.temporarily_rejected(f"{mode.px4_name} needs manual control: no RC")
        if mode is Px4Mode.AUTO_LOITER:
            outcome = v.hold()
        elif mode is Px4Mode.AUTO_TAKEOFF:
            outcome = v.takeoff()
        elif mode is Px4Mode.AUTO_LAND:
            outcome = v.land()
        elif mode is Px4Mode.AUTO_RTL:
            outcome = v.return_to_launch()
        elif mode is Px4Mode.AUTO_MISSION:
            outcome = v.start_mission()
        elif mode is Px4Mode.OFFBOARD:
            outcome = v.start_offboard(now_s)
        elif mode is Px4Mode.ORBIT:  # PX4's mode switch to Orbit: the orbit flown now, or a new one with PX4's defaults
            outcome = v.orbit(OrbitCommand())
        else:
            return api.CommandOutcome.temporarily_rejected(f"{mode.px4_name} is not supported")
        # PX4 answers a refused mode change with TEMPORARILY_REJECTED.
        if outcome.result is api.CommandResult.DENIED:
            return api.CommandOutcome.temporarily_rejected(outcome.reason)
        return outcome

    def event_state(self) -> tuple[object, ...]:
        """Every input of the event messages (extra HEARTBEAT, MISSION_CURRENT, MISSION_ITEM_REACHED, HOME_POSITION,
        EXTENDED_SYS_STATE), read without building a snapshot: while it stays equal, telemetry knows no event is due
        and skips the snapshot on polls with no stream due (sitl/protocol/telemetry.py)."""
        v = self.vehicle
        status = v.status
        est = v.estimate
        mission = v.mission
        pos_valid = est is not None and est.position_valid and est.altitude_valid
        home = tuple(v.home_ned_m.tolist()) if pos_valid or status.armed else None
        return (
            status.armed,
            status.mode,
            status.failsafe,
            v.crashed,
            status.landed_state,
            mission.current_seq,
            len(mission.items),
            mission.state,
            mission.reached_seq,
            home,
        )

    def snapshot(self) -> api.VehicleSnapshot:
        sim = self.sim
        if self._snapshot is not None and self._snapshot_time_s == sim.time_s:
            return self._snapshot
        v = self.vehicle
        est = v.estimate
        status = v.status
        pos_valid = est is not None and est.position_valid and est.altitude_valid
        att_valid = est is not None and est.attitude_valid
        global_position = self.frame.geo_from_ned(est.pos_ned_m) if pos_valid and est is not None else None
        home = self._home_position() if pos_valid or status.armed else None
        battery = sim.battery.state()
        mission = v.mission
        self._snapshot = _new_snapshot(
            time_boot_us=round(sim.time_s * 1e6),
            armed=status.armed,
            mode=status.mode,
            landed_state=status.landed_state,
            failsafe=status.failsafe,
            prearm_ok=v.preflight_problem() is None,
            pos_ned_m=_nan_if_invalid(est.pos_ned_m, pos_valid) if est is not None else api.NAN3,
            vel_ned_mps=_nan_if_invalid(est.vel_ned_mps, pos_valid) if est is not None else api.NAN3,
            global_position=global_position,
            att_q_wxyz=tuple(float(c) for c in est.att_q_frd_to_ned)  # type: ignore[arg-type]
            if att_valid and est is not None
            else (math.nan,) * 4,
            rates_frd_radps=_nan_if_invalid(est.rates_frd_radps, att_valid) if est is not None else api.NAN3,
            gps=self._gps_status(),
            battery=_new_battery(
                voltage_v=battery.voltage_v,
                current_a=battery.current_a,
                remaining=battery.remaining,
                consumed_mah=battery.consumed_mah,
                cell_count=sim.config.battery.cells,
                charge_state=self._charge_state(battery.remaining),
            ),
            home=home,
            local_origin=self.origin,
            mission=_new_progress(
                current_seq=mission.current_seq,
                total=len(mission.items),
                state=_MISSION_STATE[mission.state],
                reached_seq=mission.reached_seq,
            ),
            throttle=status.thrust_n / max(v.cascade.collective_max_n, 1e-9),
            collective_max_n=v.cascade.collective_max_n,
            sensors=self._sensor_health(),
            flight_terminated=v.crashed,  # a crash or a flight termination: HEARTBEAT FLIGHT_TERMINATION
            orbit=self._orbit_status(),
        )
        self._snapshot_time_s = sim.time_s
        return self._snapshot

    def _home_position(self) -> api.HomePosition:
        """Home as telemetry reports it, worked out again only when it moved (the geodetic conversion iterates)."""
        v = self.vehicle
        home_ned = v.home_ned_m
        key = (float(home_ned[0]), float(home_ned[1]), float(home_ned[2]), v.home_yaw_rad)
        known = self._home
        if known is not None and known[0] == key:
            return known[1]
        home = api.HomePosition(position=self.frame.geo_from_ned(home_ned), pos_ned_m=key[:3], yaw_rad=key[3])
        self._home = (key, home)
        return home

    def _orbit_status(self) -> api.OrbitStatus | None:
        plan = self.vehicle.orbit_plan
        if plan is None:
            return None
        return api.OrbitStatus(
            radius_m=plan.signed_radius_m, centre=self.frame.geo_from_ned(plan.centre_ned_m), yaw=plan.yaw
        )

    def _charge_state(self, remaining: float) -> int:
        """BATTERY_STATUS charge_state as PX4's battery library grades the charge against the BAT_*_THR levels."""
        params = self.sim.params
        for name, state in _CHARGE_STATES:
            if name in params and remaining < params[name]:
                return state
        return int(mavlink.MAV_BATTERY_CHARGE_STATE_OK)

    def _sensor_health(self) -> api.SensorHealth:
        """SYS_STATUS health: an injected GPS failure makes the GPS unhealthy and a failed rotor the motor outputs,
        as PX4 reports a receiver without fix and a failed ESC."""
        faults = self.sim.faults
        if faults.gps is GpsFault.NONE and not faults.motors_off:
            return _ALL_HEALTHY
        healthy = api.SIM_SENSOR_BITS
        if faults.gps is not GpsFault.NONE:
            healthy &= ~mavlink.MAV_SYS_STATUS_SENSOR_GPS
        if faults.motors_off:
            healthy &= ~mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
        return api.SensorHealth(healthy=healthy)

    def _gps_status(self) -> api.GpsStatus:
        """The receiver's status of its latest fix, made once per fix."""
        gps = self.sim.last_gps
        known = self._gps
        if known is not None and known[0] is gps:
            return known[1]
        status = self._gps_status_of(gps)
        self._gps = (gps, status)
        return status

    def _gps_status_of(self, gps: GpsSample | None) -> api.GpsStatus:
        if gps is None:
            return api.GpsStatus(
                fix_type=api.GpsFixType.NO_GPS, satellites_visible=0, eph_m=math.nan, epv_m=math.nan, position=None
            )
        fixed = gps.fix_type >= 3
        return api.GpsStatus(
            fix_type=api.GpsFixType(gps.fix_type),
            satellites_visible=gps.satellites,
            eph_m=gps.eph_m,
            epv_m=gps.epv_m,
            position=GeoPoint(lat_deg=gps.lat_deg, lon_deg=gps.lon_deg, alt_amsl_m=gps.alt_amsl_m) if fixed else None,
            ground_speed_mps=math.hypot(gps.vel_ned_mps[0], gps.vel_ned_mps[1]) if fixed else math.nan,
            course_over_ground_rad=math.atan2(gps.vel_ned_mps[1], gps.vel_ned_mps[0]) if fixed else math.nan,
            h_acc_m=gps.eph_m / 3 if fixed else math.nan,
            v_acc_m=gps.epv_m / 3 if fixed else math.nan,
        )
