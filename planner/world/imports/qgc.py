"""QGroundControl ``.plan`` files → :class:`OperatorMission` (docs/imports.md, "QGroundControl plans").

Read as QGroundControl loads them (PlanMasterController, MissionController, GeoFenceController, QGCFencePolygon,
QGCFenceCircle, RallyPointController): ``fileType`` "Plan" version 1, mission version 2, geoFence version 2,
rallyPoints version 2. A file QGroundControl would refuse is refused here too, in one line naming the item.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from planner.errors import ScenarioError
from planner.world.geo_inputs import Altitude, GeoPoint, OperatorMission, Zone
from planner.world.imports.common import (
    POSITION_COMMANDS,
    NavItem,
    altitude,
    kind,
    lat_lon,
    load_json,
    located,
    member,
    number,
    read_text,
    ring,
    route_of,
)

PLAN_VERSION, MISSION_VERSION, GEOFENCE_VERSION, RALLY_VERSION = 1, 2, 2, 2
FENCE_POLYGON_VERSION, FENCE_CIRCLE_VERSION = 1, 1
ALTITUDE_MODE_CALC_ABOVE_TERRAIN = 3  # QGroundControlQmlGlobal::AltMode: AMSL in params[6], "Altitude" above terrain
MISSION_KEYS = {"firmwareType": "firmware_type", "vehicleType": "vehicle_type", "cruiseSpeed": "cruise_speed",
                "hoverSpeed": "hover_speed", "globalPlanAltitudeMode": "global_altitude_mode"}


def read_qgc_plan(path: str | Path) -> OperatorMission:
    """The operator's mission in a QGroundControl ``.plan``: planned home (AMSL) as start (else the first
    position), the last position item as goal, the positions between as vias, the geofence polygons and circles
    as zones, the rally points. ``extras`` keeps what writing the plan back needs (docs/imports.md)."""
    path, file, text = read_text(path, "QGroundControl plan")
    doc = load_json(file, text)
    if not isinstance(doc, dict):
        raise ScenarioError(file, "", f"expected a JSON object (a QGroundControl .plan), got {kind(doc)}")
    file_type = doc.get("fileType")
    if file_type != "Plan":
        raise ScenarioError(file, "fileType", f"{file_type!r} is not a QGroundControl plan (expected \"Plan\")")
    _version(file, "version", doc, PLAN_VERSION, "plan")
    mission = member(file, "", doc, "mission", dict, "an object")
    _version(file, "mission.version", mission, MISSION_VERSION, "mission")
    home = _home(file, mission)
    items = member(file, "mission", mission, "items", list, "an array of mission items")
    nav = [_item(file, f"mission.items[{i}]", item) for i, item in enumerate(items)]
    route = route_of(home, nav)
    extras: dict[str, object] = {"format": "qgc-plan", "plan_version": PLAN_VERSION,
                                 "mission_version": MISSION_VERSION, "end_command": route.end_command}
    if isinstance(doc.get("groundStation"), str):
        extras["ground_station"] = doc["groundStation"]
    for key, name in MISSION_KEYS.items():
        if key in mission:
            value = mission[key]
            extras[name] = int(number(file, f"mission.{key}", value)) if key not in ("cruiseSpeed", "hoverSpeed") \
                else number(file, f"mission.{key}", value)
    zones: tuple[Zone, ...] = ()
    if "geoFence" in doc:
        zones, breach_return = _fence(file, member(file, "", doc, "geoFence", dict, "an object"))
        extras["geofence_version"] = GEOFENCE_VERSION
        if breach_return is not None:
            extras["breach_return"] = breach_return
    rally: tuple[GeoPoint, ...] = ()
    if "rallyPoints" in doc:
        rally = _rally(file, member(file, "", doc, "rallyPoints", dict, "an object"))
        extras["rally_version"] = RALLY_VERSION
    return OperatorMission(source=path, home=home, start=route.start, goal=route.goal, vias=route.vias,
                           zones=zones, rally=rally, extras=extras)


def _version(file: str, where: str, obj: dict[str, Any], supported: int, what: str) -> None:
    version = member(file, where.rpartition(".")[0], obj, "version", int, "an integer")
    if version != supported:
        raise ScenarioError(file, where, f"{what} version {version} is not supported (QGroundControl writes "
                            f"{supported}; open and save the plan in a current QGroundControl)")


def _coordinate(file: str, where: str, value: Any, with_alt: bool) -> tuple[float, ...]:
    """A QGroundControl coordinate array: [lat, lon] or [lat, lon, alt] (``with_alt``: the altitude required)."""
    n = "3" if with_alt else "2 or 3"
    if not isinstance(value, list) or len(value) not in ((3,) if with_alt else (2, 3)):
        raise ScenarioError(file, where, f"expected [lat, lon{', alt' if with_alt else ''}] ({n} numbers), "
                            f"got {kind(value)}" + (f" of {len(value)}" if isinstance(value, list) else ""))
    lat, lon = lat_lon(file, where, value[0], value[1])
    return (lat, lon, number(file, where, value[2])) if with_alt else (lat, lon)


def _home(file: str, mission: dict[str, Any]) -> GeoPoint | None:
    """The planned home (AMSL), or None when the plan has none (absent, or 0, 0: QGroundControl's "not set")."""
    if "plannedHomePosition" not in mission:
        return None
    lat, lon, alt = _coordinate(file, "mission.plannedHomePosition", mission["plannedHomePosition"], True)
    return GeoPoint(lat, lon, Altitude(alt, "amsl")) if located(lat, lon) else None


def _item(file: str, where: str, item: Any) -> NavItem:
    """One ``mission.items`` entry: a SimpleItem's command and position; a ComplexItem is refused."""
    kind_ = member(file, where, item, "type", str, "a string")
    if kind_ == "ComplexItem":
        name = item.get("complexItemType", "unknown")
        raise ScenarioError(file, where, f"ComplexItem {name!r} (a survey, corridor scan, structure scan or landing "
                            "pattern) is not supported: replace it with waypoints")
    if kind_ != "SimpleItem":
        raise ScenarioError(file, f"{where}.type", f"{kind_!r} is not a mission item type (SimpleItem)")
    command = member(file, where, item, "command", int, "an integer")
    frame = member(file, where, item, "frame", int, "an integer")
    params = member(file, where, item, "params", list, "an array of 7 numbers or nulls")
    if len(params) != 7:
        raise ScenarioError(file, f"{where}.params", f"{len(params)} values (a mission item has 7)")
    if command not in POSITION_COMMANDS or params[4] is None or params[5] is None:
        return NavItem(where, command, None)
    lat, lon = lat_lon(file, f"{where}.params", params[4], params[5])
    if not located(lat, lon):
        return NavItem(where, command, None)
    alt = altitude(file, f"{where}.frame", frame, number(file, f"{where}.params[6]", params[6]))
    above_terrain = item.get("Altitude")
    if item.get("AltitudeMode") == ALTITUDE_MODE_CALC_ABOVE_TERRAIN and above_terrain is not None:
        # QGroundControl put an AMSL altitude it worked out from its terrain tiles in params[6]
        # (AMSLAltAboveTerrain); the operator asked for a height above the ground, which the planner's DEM gives
        alt = Altitude(number(file, f"{where}.Altitude", above_terrain), "ground")
    return NavItem(where, command, GeoPoint(lat, lon, alt))


def _fence(file: str, fence: dict[str, Any]) -> tuple[tuple[Zone, ...], GeoPoint | None]:
    """geoFence polygons and circles as zones, and the breach return point (relative altitude) if any."""
    _version(file, "geoFence.version", fence, GEOFENCE_VERSION, "geoFence")
    zones: list[Zone] = []
    for k, poly in enumerate(member(file, "geoFence", fence, "polygons", list, "an array")):
        where = f"geoFence.polygons[{k}]"
        _version(file, f"{where}.version", poly, FENCE_POLYGON_VERSION, "fence polygon")
        inclusion = member(file, where, poly, "inclusion", bool, "true or false")
        vertices = member(file, where, poly, "polygon", list, "an array of [lat, lon]")
        points = [(c[0], c[1]) for c in (_coordinate(file, f"{where}.polygon[{i}]", p, False)
                                         for i, p in enumerate(vertices))]
        zones.append(Zone(where, inclusion, polygon=ring(file, f"{where}.polygon", points)))
    for k, circle in enumerate(member(file, "geoFence", fence, "circles", list, "an array")):
        where = f"geoFence.circles[{k}]"
        _version(file, f"{where}.version", circle, FENCE_CIRCLE_VERSION, "fence circle")
        inclusion = member(file, where, circle, "inclusion", bool, "true or false")
        shape = member(file, where, circle, "circle", dict, "an object with center and radius")
        lat, lon = _coordinate(file, f"{where}.circle.center", shape.get("center"), False)[:2]
        radius = number(file, f"{where}.circle.radius", shape.get("radius"))
        if radius <= 0.0:
            raise ScenarioError(file, f"{where}.circle.radius", f"{radius:g} m (a circle's radius must be > 0)")
        zones.append(Zone(where, inclusion, centre=(lat, lon), radius_m=radius))
    breach = None
    if fence.get("breachReturn") is not None:
        lat, lon, alt = _coordinate(file, "geoFence.breachReturn", fence["breachReturn"], True)
        breach = GeoPoint(lat, lon, Altitude(alt, "home"))
    return tuple(zones), breach


def _rally(file: str, rally: dict[str, Any]) -> tuple[GeoPoint, ...]:
    """rallyPoints points: [lat, lon, alt relative to home] each."""
    _version(file, "rallyPoints.version", rally, RALLY_VERSION, "rallyPoints")
    points = member(file, "rallyPoints", rally, "points", list, "an array of [lat, lon, alt]")
    out = []
    for i, p in enumerate(points):
        lat, lon, alt = _coordinate(file, f"rallyPoints.points[{i}]", p, True)
        out.append(GeoPoint(lat, lon, Altitude(alt, "home")))
    return tuple(out)
