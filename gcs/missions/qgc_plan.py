"""QGroundControl ``.plan`` files: read, check, shift and write them (pure: text in, values out).

The format is QGroundControl's own (its developer guide, "Plan File Format"): a JSON object with ``fileType``
"Plan", ``version`` 1, ``groundStation``, and

- ``mission`` (version 2): ``firmwareType`` (12 = PX4), ``vehicleType`` (2 = quadrotor), ``cruiseSpeed``,
  ``hoverSpeed``, ``plannedHomePosition`` [lat, lon, alt AMSL] and ``items``. A ``SimpleItem`` is one MAVLink
  mission item: ``command``, ``frame``, ``params`` (seven numbers; null = not set, NaN on the wire; params 5 and 6
  are latitude and longitude in degrees for global frames), ``autoContinue``, ``doJumpId``. A ``ComplexItem``
  (survey, corridor scan, structure scan) is expanded into simple items by QGroundControl only when it uploads;
  the file holds its description, not its items, so it is refused here with one line.
- ``geoFence`` (version 2): ``polygons`` ({``inclusion``, ``polygon``: [[lat, lon], ...], ``version`` 1}) and
  ``circles`` ({``inclusion``, ``circle``: {``center``: [lat, lon], ``radius``}, ``version`` 1}), which travel as
  mission type 1 (NAV_FENCE_* items);
- ``rallyPoints`` (version 2): ``points`` [[lat, lon, alt], ...].

Every problem is one line naming the file, the place and what is wrong:
``survey.plan: mission.items[3].params: must be a list of 7 numbers or null, got 6 values``.

``shifted`` moves a whole plan (items, fence, rally points, planned home) by a north/east offset in metres: one plan
drawn for one drone flies as a formation of copies, one per drone.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Final

from pymavlink.dialects.v20 import common as mavlink

from gcs.flight.geodesy import GeoPoint, NedFrame
from gcs.mavlink.mission_transfer import GLOBAL_FRAMES, MISSION_TYPE_FENCE, MISSION_TYPE_MISSION, WireItem

PLAN_FILE_VERSION: Final = 1
MISSION_VERSION: Final = 2
GEOFENCE_VERSION: Final = 2
RALLY_VERSION: Final = 2
FENCE_SHAPE_VERSION: Final = 1  # of each polygon and circle
FIRMWARE_PX4: Final = mavlink.MAV_AUTOPILOT_PX4  # 12
VEHICLE_QUADROTOR: Final = mavlink.MAV_TYPE_QUADROTOR  # 2
# What QGroundControl writes for a new multicopter plan, kept when a plan is written from a download
DEFAULT_CRUISE_SPEED_MPS: Final = 15.0
DEFAULT_HOVER_SPEED_MPS: Final = 5.0
ALTITUDE_MODE_RELATIVE: Final = 1  # QGroundControl's "AltitudeMode" for frame GLOBAL_RELATIVE_ALT
MIN_POLYGON_VERTICES: Final = 3
POLYGON_INCLUSION: Final = mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION  # 5001
POLYGON_EXCLUSION: Final = mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION  # 5002
CIRCLE_INCLUSION: Final = mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION  # 5003
CIRCLE_EXCLUSION: Final = mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION  # 5004

LatLon = tuple[float, float]


class PlanFileError(ValueError):
    """One line: the file, where in it, and what is wrong."""


@dataclass(frozen=True, slots=True, kw_only=True)
class PlanItem:
    """A SimpleItem: one MAVLink mission item as QGroundControl stores it (params 5/6 in degrees when global)."""

    command: int
    frame: int
    params: tuple[float, float, float, float, float, float, float]  # NaN: null in the file, "not set" on the wire
    auto_continue: bool = True
    do_jump_id: int | None = None

    @property
    def is_global(self) -> bool:
        return self.frame in GLOBAL_FRAMES

    @property
    def has_position(self) -> bool:
        """A global item with a coordinate (0, 0 means "where the vehicle is", as MAVLink items use it)."""
        lat, lon = self.params[4], self.params[5]
        return self.is_global and math.isfinite(lat) and math.isfinite(lon) and (lat, lon) != (0.0, 0.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class FencePolygon:
    inclusion: bool
    vertices_deg: tuple[LatLon, ...]


@dataclass(frozen=True, slots=True, kw_only=True)
class FenceCircle:
    inclusion: bool
    centre_deg: LatLon
    radius_m: float


@dataclass(frozen=True, slots=True, kw_only=True)
class QgcPlan:
    items: tuple[PlanItem, ...]
    planned_home: tuple[float, float, float]  # lat, lon (degrees), alt AMSL (m)
    polygons: tuple[FencePolygon, ...] = ()
    circles: tuple[FenceCircle, ...] = ()
    rally_points: tuple[tuple[float, float, float], ...] = ()  # lat, lon, alt
    cruise_speed_mps: float = DEFAULT_CRUISE_SPEED_MPS
    hover_speed_mps: float = DEFAULT_HOVER_SPEED_MPS
    firmware_type: int = FIRMWARE_PX4
    vehicle_type: int = VEHICLE_QUADROTOR
    ground_station: str = "QGroundControl"

    @property
    def has_fence(self) -> bool:
        return bool(self.polygons or self.circles)


# ---- reading ---------------------------------------------------------------------------------------------------------
class _Reader:
    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, where: str, problem: str) -> PlanFileError:
        return PlanFileError(f"{self.path}: {where}: {problem}" if where else f"{self.path}: {problem}")

    def table(self, data: Any, where: str) -> dict[str, Any]:
        if not isinstance(data, dict):
            raise self.fail(where, f"must be a JSON object, got {_kind(data)}")
        return data

    def require(self, table: dict[str, Any], key: str, where: str) -> Any:
        if key not in table:
            raise self.fail(where, f"missing key '{key}'")
        return table[key]

    def version(self, table: dict[str, Any], where: str, expected: int) -> None:
        version = self.require(table, "version", where)
        if version != expected or isinstance(version, bool):
            raise self.fail(f"{where}.version" if where else "version",
                            f"must be {expected} (the version QGroundControl writes), got {version!r}")  # fmt: skip

    def number(self, value: Any, where: str, *, null: bool = False) -> float:
        if value is None and null:
            return math.nan
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            expected = "a number or null" if null else "a number"
            raise self.fail(where, f"must be {expected}, got {value!r}")
        return float(value)

    def integer(self, value: Any, where: str, lo: int, hi: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise self.fail(where, f"must be a whole number {lo}..{hi}, got {value!r}")
        return value

    def latlon(self, value: Any, where: str) -> LatLon:
        if not isinstance(value, list) or len(value) < 2:  # QGC's coordinates may carry an altitude third
            raise self.fail(where, f"must be [latitude, longitude] in degrees, got {value!r}")
        lat = self.number(value[0], where)
        lon = self.number(value[1], where)
        _check_latlon(self, lat, lon, where)
        return lat, lon


def _check_latlon(reader: _Reader, lat: float, lon: float, where: str) -> None:
    if not -90.0 <= lat <= 90.0:
        raise reader.fail(where, f"latitude must be within -90..90 degrees, got {lat:g}")
    if not -180.0 <= lon <= 180.0:
        raise reader.fail(where, f"longitude must be within -180..180 degrees, got {lon:g}")


def _kind(value: Any) -> str:
    return {dict: "an object", list: "a list", str: "a string", bool: "true/false", type(None): "null"}.get(
        type(value), f"{value!r}"
    )


def _item(reader: _Reader, data: Any, where: str) -> PlanItem:
    table = reader.table(data, where)
    kind = reader.require(table, "type", where)
    if kind == "ComplexItem":
        complex_type = table.get("complexItemType", "?")
        raise reader.fail(where, f"complex item '{complex_type}' is not supported: QGroundControl keeps only its "
                                 "outline in the file; convert it to waypoints in QGroundControl first")  # fmt: skip
    if kind != "SimpleItem":
        raise reader.fail(f"{where}.type", f"must be SimpleItem or ComplexItem, got {kind!r}")
    command = reader.integer(reader.require(table, "command", where), f"{where}.command", 0, 0xFFFF)
    frame = reader.integer(reader.require(table, "frame", where), f"{where}.frame", 0, 0xFF)
    params_data = reader.require(table, "params", where)
    if not isinstance(params_data, list) or len(params_data) != 7:
        got = f"{len(params_data)} values" if isinstance(params_data, list) else _kind(params_data)
        raise reader.fail(f"{where}.params", f"must be a list of 7 numbers or null, got {got}")
    params = tuple(reader.number(p, f"{where}.params[{i}]", null=True) for i, p in enumerate(params_data))
    item = PlanItem(
        command=command,
        frame=frame,
        params=params,  # type: ignore[arg-type]  # seven, checked above
        auto_continue=_bool(reader, table.get("autoContinue", True), f"{where}.autoContinue"),
        do_jump_id=reader.integer(table["doJumpId"], f"{where}.doJumpId", 0, 0xFFFF) if "doJumpId" in table else None,
    )
    if item.is_global and math.isfinite(params[4]) and math.isfinite(params[5]):
        _check_latlon(reader, params[4], params[5], f"{where}.params")
    return item


def _bool(reader: _Reader, value: Any, where: str) -> bool:
    if not isinstance(value, bool):
        raise reader.fail(where, f"must be true or false, got {value!r}")
    return value


def _fence(reader: _Reader, data: Any) -> tuple[tuple[FencePolygon, ...], tuple[FenceCircle, ...]]:
    table = reader.table(data, "geoFence")
    reader.version(table, "geoFence", GEOFENCE_VERSION)
    polygons: list[FencePolygon] = []
    circles: list[FenceCircle] = []
    polygons_data = table.get("polygons", [])
    if not isinstance(polygons_data, list):
        raise reader.fail("geoFence.polygons", f"must be a list, got {_kind(polygons_data)}")
    for i, poly in enumerate(polygons_data):
        where = f"geoFence.polygons[{i}]"
        poly_table = reader.table(poly, where)
        vertices = reader.require(poly_table, "polygon", where)
        if not isinstance(vertices, list) or len(vertices) < MIN_POLYGON_VERTICES:
            got = f"{len(vertices)} vertices" if isinstance(vertices, list) else _kind(vertices)
            raise reader.fail(f"{where}.polygon", f"must be a list of at least {MIN_POLYGON_VERTICES} "
                                                  f"[latitude, longitude] vertices, got {got}")  # fmt: skip
        polygons.append(FencePolygon(
            inclusion=_bool(reader, reader.require(poly_table, "inclusion", where), f"{where}.inclusion"),
            vertices_deg=tuple(reader.latlon(v, f"{where}.polygon[{j}]") for j, v in enumerate(vertices)),
        ))  # fmt: skip
    circles_data = table.get("circles", [])
    if not isinstance(circles_data, list):
        raise reader.fail("geoFence.circles", f"must be a list, got {_kind(circles_data)}")
    for i, circ in enumerate(circles_data):
        where = f"geoFence.circles[{i}]"
        circ_table = reader.table(circ, where)
        shape = reader.table(reader.require(circ_table, "circle", where), f"{where}.circle")
        radius = reader.number(reader.require(shape, "radius", f"{where}.circle"), f"{where}.circle.radius")
        if radius <= 0:
            raise reader.fail(f"{where}.circle.radius", f"must be a positive number of metres, got {radius:g}")
        circles.append(FenceCircle(
            inclusion=_bool(reader, reader.require(circ_table, "inclusion", where), f"{where}.inclusion"),
            centre_deg=reader.latlon(reader.require(shape, "center", f"{where}.circle"), f"{where}.circle.center"),
            radius_m=radius,
        ))  # fmt: skip
    return tuple(polygons), tuple(circles)


def _rally(reader: _Reader, data: Any) -> tuple[tuple[float, float, float], ...]:
    table = reader.table(data, "rallyPoints")
    reader.version(table, "rallyPoints", RALLY_VERSION)
    points = table.get("points", [])
    if not isinstance(points, list):
        raise reader.fail("rallyPoints.points", f"must be a list, got {_kind(points)}")
    out = []
    for i, point in enumerate(points):
        where = f"rallyPoints.points[{i}]"
        if not isinstance(point, list) or len(point) != 3:
            raise reader.fail(where, f"must be [latitude, longitude, altitude], got {point!r}")
        lat, lon = reader.latlon(point, where)
        out.append((lat, lon, reader.number(point[2], where)))
    return tuple(out)


def parse_plan(text: str, path: Path) -> QgcPlan:
    """The plan in ``text`` (read from ``path``, which names it in errors); PlanFileError is one line."""
    reader = _Reader(path)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise PlanFileError(f"{path}:{exc.lineno}: not valid JSON: {exc.msg} (column {exc.colno})") from None
    top = reader.table(data, "")
    file_type = reader.require(top, "fileType", "")
    if file_type != "Plan":
        raise reader.fail("fileType", f'must be "Plan" (a QGroundControl plan file), got {file_type!r}')
    reader.version(top, "", PLAN_FILE_VERSION)
    ground_station = top.get("groundStation", "QGroundControl")
    if not isinstance(ground_station, str):
        raise reader.fail("groundStation", f"must be a string, got {ground_station!r}")
    mission = reader.table(reader.require(top, "mission", ""), "mission")
    reader.version(mission, "mission", MISSION_VERSION)
    home_data = reader.require(mission, "plannedHomePosition", "mission")
    if not isinstance(home_data, list) or len(home_data) != 3:
        raise reader.fail("mission.plannedHomePosition", f"must be [latitude, longitude, altitude], got {home_data!r}")
    home_lat, home_lon = reader.latlon(home_data, "mission.plannedHomePosition")
    home = (home_lat, home_lon, reader.number(home_data[2], "mission.plannedHomePosition"))
    items_data = reader.require(mission, "items", "mission")
    if not isinstance(items_data, list):
        raise reader.fail("mission.items", f"must be a list of mission items, got {_kind(items_data)}")
    items = tuple(_item(reader, item, f"mission.items[{i}]") for i, item in enumerate(items_data))
    jump_ids = _jump_ids(items)
    for i, item in enumerate(items):
        if item.command == mavlink.MAV_CMD_DO_JUMP and item.params[0] not in jump_ids:
            raise reader.fail(f"mission.items[{i}].params[0]",
                              f"DO_JUMP to doJumpId {item.params[0]:g}, which no item has")  # fmt: skip
    speeds = {}
    for key, default in (("cruiseSpeed", DEFAULT_CRUISE_SPEED_MPS), ("hoverSpeed", DEFAULT_HOVER_SPEED_MPS)):
        speeds[key] = reader.number(mission.get(key, default), f"mission.{key}")
        if speeds[key] <= 0:
            raise reader.fail(f"mission.{key}", f"must be a positive speed in m/s, got {speeds[key]:g}")
    polygons, circles = _fence(reader, top["geoFence"]) if "geoFence" in top else ((), ())
    return QgcPlan(
        items=items,
        planned_home=home,
        polygons=polygons,
        circles=circles,
        rally_points=_rally(reader, top["rallyPoints"]) if "rallyPoints" in top else (),
        cruise_speed_mps=speeds["cruiseSpeed"],
        hover_speed_mps=speeds["hoverSpeed"],
        firmware_type=reader.integer(mission.get("firmwareType", FIRMWARE_PX4), "mission.firmwareType", 0, 255),
        vehicle_type=reader.integer(mission.get("vehicleType", VEHICLE_QUADROTOR), "mission.vehicleType", 0, 255),
        ground_station=ground_station,
    )


def load_plan(path: Path) -> QgcPlan:
    try:
        text = path.read_text()
    except OSError as exc:
        raise PlanFileError(f"{path}: cannot read: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise PlanFileError(f"{path}: not a text file") from None
    return parse_plan(text, path)


# ---- writing ---------------------------------------------------------------------------------------------------------
def _json_number(value: float) -> float | int | None:
    if not math.isfinite(value):
        return None
    return int(value) if value.is_integer() and abs(value) < 2**53 else value


def plan_document(plan: QgcPlan) -> dict[str, Any]:
    """The plan as QGroundControl's JSON object (keys as QGroundControl writes them)."""
    items = []
    for n, item in enumerate(plan.items, start=1):
        entry: dict[str, Any] = {
            "autoContinue": item.auto_continue,
            "command": item.command,
            "doJumpId": item.do_jump_id if item.do_jump_id is not None else n,
            "frame": item.frame,
            "params": [_json_number(p) for p in item.params],
            "type": "SimpleItem",
        }
        if item.frame == mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT:  # what QGroundControl adds for its altitude editor
            entry |= {"AMSLAltAboveTerrain": None, "Altitude": _json_number(item.params[6]),
                      "AltitudeMode": ALTITUDE_MODE_RELATIVE}  # fmt: skip
        items.append(entry)
    return {
        "fileType": "Plan",
        "geoFence": {
            "circles": [
                {"circle": {"center": list(c.centre_deg), "radius": c.radius_m}, "inclusion": c.inclusion,
                 "version": FENCE_SHAPE_VERSION}
                for c in plan.circles
            ],
            "polygons": [
                {"inclusion": p.inclusion, "polygon": [list(v) for v in p.vertices_deg], "version": FENCE_SHAPE_VERSION}
                for p in plan.polygons
            ],
            "version": GEOFENCE_VERSION,
        },
        "groundStation": plan.ground_station,
        "mission": {
            "cruiseSpeed": _json_number(plan.cruise_speed_mps),
            "firmwareType": plan.firmware_type,
            "globalPlanAltitudeMode": ALTITUDE_MODE_RELATIVE,
            "hoverSpeed": _json_number(plan.hover_speed_mps),
            "items": items,
            "plannedHomePosition": list(plan.planned_home),
            "vehicleType": plan.vehicle_type,
            "version": MISSION_VERSION,
        },
        "rallyPoints": {"points": [list(p) for p in plan.rally_points], "version": RALLY_VERSION},
        "version": PLAN_FILE_VERSION,
    }  # fmt: skip


def plan_text(plan: QgcPlan) -> str:
    """The plan as a ``.plan`` file's text (indented like QGroundControl's, 4 spaces, sorted keys)."""
    return json.dumps(plan_document(plan), indent=4, sort_keys=True) + "\n"


# ---- to and from the wire --------------------------------------------------------------------------------------------
def _degrees_e7(value: float) -> int:
    return round(value * 1e7) if math.isfinite(value) else 0


def _jump_ids(items: Sequence[PlanItem]) -> dict[float, int]:
    """doJumpId -> the item's index (an item without one has its position from 1, as QGroundControl numbers them)."""
    return {float(item.do_jump_id if item.do_jump_id is not None else n + 1): n for n, item in enumerate(items)}


def mission_items(plan: QgcPlan) -> list[WireItem]:
    """The plan's mission (type 0) as MISSION_ITEM_INTs, numbered from 0 (QGroundControl uploads them this way to
    PX4: latitude and longitude in degE7 for global frames, an unset one as 0; other frames' params 5/6 as integers;
    a DO_JUMP's target, a doJumpId in the file, as the target's sequence number)."""
    out = []
    jump_ids = _jump_ids(plan.items)
    for seq, item in enumerate(plan.items):
        p = item.params
        if item.command == mavlink.MAV_CMD_DO_JUMP:
            p = (float(jump_ids[p[0]]), *p[1:])
        if item.is_global:
            x, y = _degrees_e7(p[4]), _degrees_e7(p[5])
        else:
            x = round(p[4]) if math.isfinite(p[4]) else 0
            y = round(p[5]) if math.isfinite(p[5]) else 0
        out.append(WireItem(seq=seq, frame=item.frame, command=item.command, autocontinue=item.auto_continue,
                            param1=p[0], param2=p[1], param3=p[2], param4=p[3], x=x, y=y, z=p[6],
                            mission_type=MISSION_TYPE_MISSION))  # fmt: skip
    return out


def fence_items(plan: QgcPlan) -> list[WireItem]:
    """The plan's fence (type 1) as PX4 takes it: one NAV_FENCE_POLYGON_VERTEX item per vertex with the polygon's
    vertex count in param1, one NAV_FENCE_CIRCLE item per circle with its radius in param1, frame GLOBAL, and no
    auto-continue (a zone is not flown; MAVSDK's importer makes the same items)."""
    out: list[WireItem] = []
    for poly in plan.polygons:
        command = POLYGON_INCLUSION if poly.inclusion else POLYGON_EXCLUSION
        for lat, lon in poly.vertices_deg:
            out.append(WireItem(seq=len(out), frame=mavlink.MAV_FRAME_GLOBAL, command=command, autocontinue=False,
                                param1=float(len(poly.vertices_deg)), x=_degrees_e7(lat), y=_degrees_e7(lon),
                                mission_type=MISSION_TYPE_FENCE))  # fmt: skip
    for circle in plan.circles:
        command = CIRCLE_INCLUSION if circle.inclusion else CIRCLE_EXCLUSION
        lat, lon = circle.centre_deg
        out.append(WireItem(seq=len(out), frame=mavlink.MAV_FRAME_GLOBAL, command=command, autocontinue=False,
                            param1=circle.radius_m, x=_degrees_e7(lat), y=_degrees_e7(lon),
                            mission_type=MISSION_TYPE_FENCE))  # fmt: skip
    return out


class FenceItemsError(ValueError):
    """A downloaded fence that is not a list of whole polygons and circles (one line)."""


def plan_from_items(
    mission: Sequence[WireItem],
    fence: Sequence[WireItem] = (),
    *,
    home: tuple[float, float, float],
) -> QgcPlan:
    """A plan from a drone's downloaded mission and fence (the export: ``swarm plan download``)."""
    items = []
    for item in mission:
        if item.is_global:
            lat, lon = item.x / 1e7, item.y / 1e7
        else:
            lat, lon = float(item.x), float(item.y)
        # every item's doJumpId is its seq + 1, so a DO_JUMP to seq n names doJumpId n + 1
        param1 = item.param1 + 1 if item.command == mavlink.MAV_CMD_DO_JUMP else item.param1
        items.append(PlanItem(command=item.command, frame=item.frame, auto_continue=item.autocontinue,
                              params=(param1, item.param2, item.param3, item.param4, lat, lon, item.z),
                              do_jump_id=item.seq + 1))  # fmt: skip
    polygons: list[FencePolygon] = []
    circles: list[FenceCircle] = []
    i = 0
    while i < len(fence):
        item = fence[i]
        if item.command in (POLYGON_INCLUSION, POLYGON_EXCLUSION):
            count = int(item.param1)
            run = list(fence[i : i + count])
            if count < MIN_POLYGON_VERTICES or len(run) < count or any(v.command != item.command for v in run):
                raise FenceItemsError(f"fence item {i}: a polygon of {item.param1:g} vertices is incomplete")
            polygons.append(FencePolygon(inclusion=item.command == POLYGON_INCLUSION,
                                         vertices_deg=tuple((v.x / 1e7, v.y / 1e7) for v in run)))  # fmt: skip
            i += count
        elif item.command in (CIRCLE_INCLUSION, CIRCLE_EXCLUSION):
            circles.append(FenceCircle(inclusion=item.command == CIRCLE_INCLUSION,
                                       centre_deg=(item.x / 1e7, item.y / 1e7), radius_m=item.param1))  # fmt: skip
            i += 1
        else:
            raise FenceItemsError(f"fence item {i}: command {item.command} is not a fence polygon vertex or circle")
    return QgcPlan(items=tuple(items), planned_home=home, polygons=tuple(polygons), circles=tuple(circles))


# ---- shifting copies -------------------------------------------------------------------------------------------------
def shifted(plan: QgcPlan, north_m: float, east_m: float) -> QgcPlan:
    """The plan moved ``north_m``/``east_m`` as a whole: every coordinate (items with a position, fence, rally points,
    planned home) by the same offset in the local tangent plane at the planned home, so distances and headings
    between them are kept. Altitudes are unchanged (relative items stay relative to each drone's own home)."""
    if north_m == 0.0 and east_m == 0.0:
        return plan
    lat0, lon0, alt0 = plan.planned_home
    frame = NedFrame(GeoPoint(lat_deg=lat0, lon_deg=lon0, alt_amsl_m=alt0))

    def move(lat: float, lon: float) -> LatLon:
        n, e, d = frame.ned_from_geo(GeoPoint(lat_deg=lat, lon_deg=lon, alt_amsl_m=alt0))
        moved = frame.geo_from_ned((n + north_m, e + east_m, d))
        return moved.lat_deg, moved.lon_deg

    items = []
    for item in plan.items:
        if item.has_position:
            lat, lon = move(item.params[4], item.params[5])
            item = replace(item, params=(*item.params[:4], lat, lon, item.params[6]))
        items.append(item)
    home_lat, home_lon = move(lat0, lon0)
    return replace(
        plan,
        items=tuple(items),
        planned_home=(home_lat, home_lon, alt0),
        polygons=tuple(replace(p, vertices_deg=tuple(move(*v) for v in p.vertices_deg)) for p in plan.polygons),
        circles=tuple(replace(c, centre_deg=move(*c.centre_deg)) for c in plan.circles),
        rally_points=tuple((*move(lat, lon), alt) for lat, lon, alt in plan.rally_points),
    )


def last_item_lands(plan: QgcPlan) -> bool:
    """Whether the mission ends on the ground: its last item is a land or a return to launch."""
    return bool(plan.items) and plan.items[-1].command in (
        mavlink.MAV_CMD_NAV_LAND,
        mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH,
    )
