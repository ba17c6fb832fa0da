"""Mission exports: QGC WPL 110 ``.waypoints``, QGroundControl ``.plan``, GeoJSON and Mission Planner fence files
(docs/design.md, "Companion"; docs/imports.md for the fence and zone formats, which the importers read back).

Files carry degrees and the plain frame numbers (``GLOBAL_RELATIVE_ALT`` = 3, not the ``_INT`` twin 6), as
Mission Planner and QGroundControl write them. Fence and zone writers take geographic :class:`Zone` values;
:func:`zones_from_prisms` makes them from the planner's polygon prisms.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.items import FRAME_GLOBAL, MissionItem, normalise_frame
from companion.mission.builder import (
    Autopilot,
    MissionSpec,
    fenced_circles,
    is_home_item,
    mission_from_plan_json,
    prisms_left_out,
    spec_from_plan_json,
)
from companion.mission.geo import Circle, as_circles, circle_ring, enu_to_geodetic, lonlatalt, to_int_e7
from planner.errors import one_line
from planner.world.environment import Cylinders, Prisms
from planner.world.geo_inputs import Altitude, GeoPoint, OperatorMission, Zone
from planner.world.home import Home
from planner.world.polygons import signed_area
from planner.world.scenario import Scenario

ExportFormat = Literal["waypoints", "plan", "geojson"]
FORMATS: tuple[str, ...] = ("waypoints", "plan", "geojson")
SUFFIX = {"waypoints": ".waypoints", "plan": ".plan", "geojson": ".geojson"}

UNCHECKED = "UNCHECKED: written with --force from a PLAN.json that fails its check; do not fly"
VEHICLE_TYPE = {"plane": mavlink.MAV_TYPE_FIXED_WING, "copter": mavlink.MAV_TYPE_QUADROTOR}  # 1, 2


# --- QGC WPL 110 -----------------------------------------------------------------------------------------------

def _wpl_number(value: float, decimals: int) -> str:
    return "NaN" if math.isnan(value) else f"{value:.{decimals}f}"


def _home_line_item(home: Home) -> MissionItem:
    return MissionItem(0, FRAME_GLOBAL, mavlink.MAV_CMD_NAV_WAYPOINT, x=to_int_e7(home.lat),
                       y=to_int_e7(home.lon), z=float(home.alt))


def waypoints_text(items: Sequence[MissionItem], home: Home | None = None) -> str:
    """QGC WPL 110 text. Line 0 is home (the format's convention, ArduPilot's too): ArduPilot missions have it
    as item 0; for PX4 missions (no home item) ``home`` is required and written first, shifting seq by one."""
    rows = list(items)
    if not rows or not is_home_item(rows[0]):
        if home is None:
            raise ValueError("these items have no home item 0 (PX4 layout): pass home to write line 0")
        rows = [_home_line_item(home)] + rows
    lines = ["QGC WPL 110"]
    for seq, it in enumerate(rows):
        fields = [str(seq), str(it.current), str(normalise_frame(it.frame)), str(it.command),
                  *(_wpl_number(p, 8) for p in (it.param1, it.param2, it.param3, it.param4)),
                  f"{it.x / 1e7:.8f}", f"{it.y / 1e7:.8f}", _wpl_number(it.z, 6), str(it.autocontinue)]
        lines.append("\t".join(fields))
    return "\n".join(lines) + "\n"


def write_waypoints(path: str | Path, items: Sequence[MissionItem], home: Home | None = None,
                    unchecked: str | None = None) -> Path:
    """Write a QGC WPL 110 ``.waypoints`` file (Mission Planner, MAVProxy ``wp load``); see :func:`waypoints_text`.
    ``unchecked`` (export --force): why, as a ``#`` line after the header, which pymavlink's reader skips."""
    text = waypoints_text(items, home)
    if unchecked:
        header, rest = text.split("\n", 1)
        text = f"{header}\n# {UNCHECKED}: {one_line(unchecked)}\n{rest}"
    path = Path(path)
    path.write_text(text, encoding="ascii", errors="replace")
    return path


# --- zones: the planner's prisms on the map, and what a fence can hold ---------------------------------------------

def _write_atomic(path: Path, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` through a temporary file beside it and a rename: never half a file."""
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        tmp.write_text(text, encoding=encoding, errors="replace")
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def zones_from_prisms(prisms: Prisms, home: Home, names: Sequence[str] | None = None) -> list[Zone]:
    """The planner's polygon prisms (ENU metres, heights above home) as geographic zones: vertices through
    :func:`enu_to_geodetic` at home, floor and ceiling above home (None for -inf / inf), keep-in as inclusion.
    ``names`` (one a prism) label them; by default ``prisms[k]``."""
    if not len(prisms):
        return []
    flat = np.column_stack([prisms.vertices, np.zeros(len(prisms.vertices))])
    lat, lon, _ = enu_to_geodetic(flat, home)
    zones = []
    for k in range(len(prisms)):
        i, j = prisms.start[k], prisms.start[k + 1]
        floor, ceiling = float(prisms.floor[k]), float(prisms.ceiling[k])
        zones.append(Zone(names[k] if names is not None else f"prisms[{k}]", bool(prisms.keep_in[k]),
                          polygon=tuple((float(a), float(o)) for a, o in zip(lat[i:j], lon[i:j])),
                          floor=Altitude(floor, "home") if math.isfinite(floor) else None,
                          ceiling=Altitude(ceiling, "home") if math.isfinite(ceiling) else None))
    return zones


def _check_zone(zone: Zone) -> None:
    """A zone a file can hold: a polygon of at least 3 vertices (QGroundControl's QGCMapPolygon::isValid) or a
    circle of positive radius, not both."""
    if (zone.polygon is None) == (zone.centre is None):
        raise ValueError(f"zone {zone.name}: give either a polygon or a centre and radius")
    if zone.polygon is not None and len(zone.polygon) < 3:
        raise ValueError(f"zone {zone.name}: {len(zone.polygon)} vertices (a polygon needs at least 3)")
    if zone.centre is not None and not (zone.radius_m is not None and zone.radius_m > 0):
        raise ValueError(f"zone {zone.name}: a circle needs a radius > 0, got {zone.radius_m!r}")


def _above_home(alt: Altitude | None, home: Home) -> float | None:
    """A height as metres above home (None: ``alt`` is None, or above ground, which needs terrain)."""
    if alt is None or alt.ref == "ground":
        return None
    return alt.value if alt.ref == "home" else alt.value - home.alt


def fence_zones(zones: Iterable[Zone], home: Home, low_m: float, high_m: float) -> list[Zone]:
    """The zones an autopilot fence can hold for a route flown between ``low_m`` and ``high_m`` above home. A
    fence zone holds at every height, so a no-fly zone goes in only when the route cannot pass over or under it:
    its ceiling unlimited or at least ``high_m``, its floor absent or at most ``low_m`` (heights above ground
    cannot be compared without terrain: such zones are left out, as a cylinder the route may pass over is)."""
    kept = []
    for z in zones:
        ceiling, floor = _above_home(z.ceiling, home), _above_home(z.floor, home)
        over = z.ceiling is not None and (ceiling is None or ceiling < high_m)
        under = z.floor is not None and (floor is None or floor > low_m)
        if z.inclusion or not (over or under):
            kept.append(z)
    return kept


# --- QGroundControl .plan ----------------------------------------------------------------------------------------

PLAN_FENCE_POLYGON_VERSION, PLAN_FENCE_CIRCLE_VERSION = 1, 1  # QGCFencePolygon, QGCFenceCircle


def _json_number(value: float) -> float | None:
    return None if not math.isfinite(value) else float(value)


def _plan_fence(zones: Sequence[Zone], circles: Sequence[Circle]) -> dict[str, Any]:
    """A .plan ``geoFence`` (version 2): ``zones`` as polygons and circles (their floors and ceilings cannot be
    written: a QGroundControl fence holds at every height), then the no-fly map ``circles``."""
    for z in zones:
        _check_zone(z)
    polygons = [{"inclusion": bool(z.inclusion), "polygon": [[float(a), float(o)] for a, o in z.polygon],
                 "version": PLAN_FENCE_POLYGON_VERSION} for z in zones if z.polygon is not None]
    rings = [{"circle": {"center": [float(z.centre[0]), float(z.centre[1])], "radius": float(z.radius_m)},
              "inclusion": bool(z.inclusion), "version": PLAN_FENCE_CIRCLE_VERSION}
             for z in zones if z.centre is not None and z.radius_m is not None]  # _check_zone: both or neither
    rings += [{"circle": {"center": [c.lat, c.lon], "radius": float(c.radius_m)}, "inclusion": False,
               "version": PLAN_FENCE_CIRCLE_VERSION} for c in circles]
    return {"version": 2, "circles": rings, "polygons": polygons}


def qgc_plan(items: Sequence[MissionItem], spec: MissionSpec, fence: Cylinders | Sequence[Circle] = (),
             rally: Iterable[Sequence[float]] = (), zones: Sequence[Zone] = ()) -> dict[str, Any]:
    """The QGroundControl ``.plan`` (v1) document. ArduPilot's home item is not an item here: QGC keeps home in
    ``plannedHomePosition``. ``rally``: (lat deg, lon deg, alt m above home) points. The geofence holds the
    ``zones`` (polygons and circles, inclusion or not), then the ``fence`` no-fly circles."""
    home, vehicle = spec.home, spec.vehicle
    mission_items = [it for it in items if not is_home_item(it)]
    plan_items = [{
        "type": "SimpleItem",
        "autoContinue": bool(it.autocontinue),
        "command": int(it.command),
        "doJumpId": n,
        "frame": int(normalise_frame(it.frame)),
        "params": [_json_number(p) for p in (it.param1, it.param2, it.param3, it.param4)]
                  + [it.x / 1e7, it.y / 1e7, _json_number(it.z)],
    } for n, it in enumerate(mission_items, start=1)]
    return {
        "fileType": "Plan",
        "version": 1,
        "groundStation": "fuseplan",
        "mission": {
            "version": 2,
            "firmwareType": spec.layout.qgc_firmware_type,  # 3 ArduPilot, 12 PX4
            "vehicleType": VEHICLE_TYPE[vehicle.type],
            "cruiseSpeed": float(vehicle.cruise_speed),
            "hoverSpeed": float(vehicle.cruise_speed),
            "plannedHomePosition": [spec.planned_home.lat, spec.planned_home.lon, spec.planned_home.alt],
            "items": plan_items,
        },
        "geoFence": _plan_fence(zones, as_circles(fence, home)),
        "rallyPoints": {"version": 2, "points": [[float(v) for v in p] for p in rally]},
    }


def _write_plan(path: str | Path, doc: dict[str, Any], unchecked: str | None) -> Path:
    if unchecked:
        doc["groundStation"] = f"fuseplan ({UNCHECKED})"
        doc["fuseplanUnchecked"] = str(unchecked)
    return _write_atomic(Path(path), json.dumps(doc, indent=2, allow_nan=False))


def write_qgc_plan(path: str | Path, items: Sequence[MissionItem], spec: MissionSpec,
                   fence: Cylinders | Sequence[Circle] = (), rally: Iterable[Sequence[float]] = (),
                   unchecked: str | None = None, zones: Sequence[Zone] = ()) -> Path:
    """Write a QGroundControl ``.plan`` file; see :func:`qgc_plan`. ``unchecked`` (export --force): why, in
    ``groundStation`` and ``fuseplanUnchecked`` (QGroundControl keeps but does not show them)."""
    return _write_plan(path, qgc_plan(items, spec, fence, rally, zones), unchecked)


def _rally_row(point: GeoPoint, home: Home, what: str) -> list[float]:
    """[lat, lon, alt above home]: a .plan rally point or breach return."""
    alt = _above_home(point.alt, home) if point.alt is not None else 0.0
    if alt is None:
        raise ValueError(f"{what} at {point.lat:.7f}, {point.lon:.7f} is above ground: a .plan needs it above "
                         "home")
    return [float(point.lat), float(point.lon), float(alt)]


def operator_plan(items: Sequence[MissionItem], spec: MissionSpec, mission: OperatorMission,
                  zones: Sequence[Zone] | None = None) -> dict[str, Any]:
    """A ``.plan`` of the safe route's ``items`` that keeps what the operator's file held: its fence
    (``mission.zones``, or ``zones`` in their place), rally points, breach return point and, from ``extras``,
    cruise and hover speed and vehicle type. Its firmware type must be the items' (ArduPilot and PX4 items
    differ): a plan made for the other autopilot is refused with ValueError."""
    extras = mission.extras
    firmware = extras.get("firmware_type")
    ours = spec.layout.qgc_firmware_type
    if firmware in (mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, mavlink.MAV_AUTOPILOT_PX4) and firmware != ours:
        raise ValueError(f"{mission.source}: the operator's plan is for firmwareType {firmware}, the items for "
                         f"{ours} ({spec.autopilot}); plan for the operator's autopilot")
    rally = [_rally_row(p, spec.home, "rally point") for p in mission.rally]
    doc = qgc_plan(items, spec, rally=rally, zones=mission.zones if zones is None else zones)
    for key, name in (("cruiseSpeed", "cruise_speed"), ("hoverSpeed", "hover_speed"), ("vehicleType", "vehicle_type")):
        if isinstance(extras.get(name), (int, float)):
            doc["mission"][key] = extras[name]
    back = extras.get("breach_return", extras.get("fence_return"))
    if isinstance(back, GeoPoint):
        doc["geoFence"]["breachReturn"] = _rally_row(back, spec.home, "breach return point")
    return doc


def write_operator_plan(path: str | Path, items: Sequence[MissionItem], spec: MissionSpec,
                        mission: OperatorMission, zones: Sequence[Zone] | None = None,
                        unchecked: str | None = None) -> Path:
    """Write the safe route as a ``.plan`` keeping the operator's fence, rally points and settings; see
    :func:`operator_plan` (``unchecked`` as for :func:`write_qgc_plan`)."""
    return _write_plan(path, operator_plan(items, spec, mission, zones), unchecked)


# --- GeoJSON -----------------------------------------------------------------------------------------------------

def _point(coords: Sequence[float], **properties: Any) -> dict[str, Any]:
    return {"type": "Feature", "geometry": {"type": "Point", "coordinates": list(coords)}, "properties": properties}


def zone_feature(zone: Zone) -> dict[str, Any]:
    """A zone as the GeoJSON Feature planner.world.imports.read_zones reads back: a Polygon (closed ring,
    counter-clockwise, [lon, lat]) or a Point with ``radius_m``; ``name``, ``inclusion`` and, when set,
    ``floor_m``/``floor_ref`` and ``ceiling_m``/``ceiling_ref`` (docs/imports.md, "GeoJSON zones")."""
    _check_zone(zone)
    props: dict[str, Any] = {"name": zone.name, "inclusion": bool(zone.inclusion)}
    for which, alt in (("floor", zone.floor), ("ceiling", zone.ceiling)):
        if alt is not None:
            props[f"{which}_m"] = float(alt.value)
            props[f"{which}_ref"] = alt.ref
    if zone.centre is not None and zone.radius_m is not None:  # _check_zone: both or neither
        return _point([float(zone.centre[1]), float(zone.centre[0])], **props, radius_m=float(zone.radius_m))
    assert zone.polygon is not None  # _check_zone: a polygon or a circle
    lonlat = [[float(o), float(a)] for a, o in zone.polygon]
    if signed_area(np.array(lonlat)) < 0.0:  # RFC 7946: exterior rings counter-clockwise
        lonlat.reverse()
    return {"type": "Feature", "geometry": {"type": "Polygon", "coordinates": [lonlat + lonlat[:1]]},
            "properties": props}


def zones_geojson(zones: Sequence[Zone]) -> dict[str, Any]:
    """A FeatureCollection of :func:`zone_feature` for each zone."""
    return {"type": "FeatureCollection", "features": [zone_feature(z) for z in zones]}


def write_zones_geojson(path: str | Path, zones: Sequence[Zone]) -> Path:
    """Write zones as GeoJSON (:func:`zones_geojson`), which planner.world.imports.read_zones reads back."""
    return _write_atomic(Path(path), json.dumps(zones_geojson(zones), indent=1, allow_nan=False))


def geojson(route: Sequence[Sequence[float]], zones: Sequence[Circle] = (),
            trajectory: Sequence[Sequence[float]] | None = None, properties: Mapping[str, Any] | None = None,
            geo_zones: Sequence[Zone] = ()) -> dict[str, Any]:
    """A FeatureCollection: the route LineString, optionally the smoothed trajectory, each no-fly zone as a
    Polygon (closed ring, counter-clockwise) with ``radius_m`` and ``top`` (m above home, null = unlimited),
    each of ``geo_zones`` as :func:`zone_feature` writes it, and start/goal Points. Positions are (lon, lat,
    alt m AMSL), GeoJSON order."""
    route = [tuple(float(v) for v in p) for p in route]
    if len(route) < 2:
        raise ValueError("a route needs at least two positions")
    features = [{"type": "Feature", "geometry": {"type": "LineString", "coordinates": [list(p) for p in route]},
                 "properties": {"name": "route", **(properties or {})}}]
    if trajectory is not None:
        features.append({"type": "Feature",
                         "geometry": {"type": "LineString", "coordinates": [[float(v) for v in p] for p in trajectory]},
                         "properties": {"name": "trajectory"}})
    for i, c in enumerate(zones):
        features.append({"type": "Feature",
                         "geometry": {"type": "Polygon", "coordinates": [[list(p) for p in circle_ring(c)]]},
                         "properties": {"name": f"{c.kind}_{i}", "kind": c.kind, "radius_m": float(c.radius_m),
                                        "top": _json_number(c.top_m), "center": [c.lon, c.lat]}})
    features += [zone_feature(z) for z in geo_zones]
    features.append(_point(route[0], name="start"))
    features.append(_point(route[-1], name="goal"))
    return {"type": "FeatureCollection", "features": features}


def write_geojson(path: str | Path, route: Sequence[Sequence[float]], zones: Sequence[Circle] = (),
                  trajectory: Sequence[Sequence[float]] | None = None,
                  properties: Mapping[str, Any] | None = None, geo_zones: Sequence[Zone] = ()) -> Path:
    """Write a GeoJSON file; see :func:`geojson` (route and trajectory as (lon, lat, alt) positions)."""
    path = Path(path)
    doc = geojson(route, zones, trajectory, properties, geo_zones)
    path.write_text(json.dumps(doc, indent=1, allow_nan=False), encoding="utf-8")
    return path


# --- Mission Planner fence -----------------------------------------------------------------------------------------

MP_FENCE_FRAME = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT  # Mission Planner's default altitude frame; fences ignore it


def mp_fence_text(zones: Sequence[Zone], home: Home, return_point: GeoPoint | None = None) -> str:
    """A fence as Mission Planner saves and loads it in the Fence mission type: ``QGC WPL 110``, line 0 home
    (which Mission Planner drops on loading a fence), then per polygon one FENCE_POLYGON_VERTEX_INCLUSION or
    _EXCLUSION item a vertex (param1 = vertex count), per circle one FENCE_CIRCLE_INCLUSION or _EXCLUSION item
    (param1 = radius m), and the FENCE_RETURN_POINT if given (altitude above home). Floors and ceilings cannot be
    written: pass :func:`fence_zones` to keep only the zones that hold at every height."""
    rows: list[tuple[int, int, float, float, float, float]] = []  # command, frame, param1, lat, lon, alt
    if return_point is not None:
        rows.append((mavlink.MAV_CMD_NAV_FENCE_RETURN_POINT, MP_FENCE_FRAME, 0.0, return_point.lat,
                     return_point.lon, _rally_row(return_point, home, "fence return point")[2]))
    for z in zones:
        _check_zone(z)
        if z.polygon is not None:
            command = mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION if z.inclusion \
                else mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION
            rows += [(command, MP_FENCE_FRAME, float(len(z.polygon)), a, o, 0.0) for a, o in z.polygon]
        else:
            assert z.centre is not None and z.radius_m is not None  # _check_zone: a polygon or a circle
            command = mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION if z.inclusion \
                else mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION
            rows.append((command, MP_FENCE_FRAME, float(z.radius_m), z.centre[0], z.centre[1], 0.0))
    lines = ["QGC WPL 110", f"0\t1\t{FRAME_GLOBAL}\t{mavlink.MAV_CMD_NAV_WAYPOINT}\t0\t0\t0\t0\t"
             f"{home.lat:.8f}\t{home.lon:.8f}\t{home.alt:.6f}\t1"]
    for seq, (command, frame, p1, lat, lon, alt) in enumerate(rows, start=1):
        lines.append("\t".join([str(seq), "0", str(frame), str(command), f"{p1:.8f}", "0.00000000", "0.00000000",
                                "0.00000000", f"{lat:.8f}", f"{lon:.8f}", f"{alt:.6f}", "1"]))
    return "\n".join(lines) + "\n"


def write_mp_fence(path: str | Path, zones: Sequence[Zone], home: Home, return_point: GeoPoint | None = None) -> Path:
    """Write a Mission Planner fence file (:func:`mp_fence_text`); planner.world.imports.read_waypoints reads it
    back as ``fence_path``."""
    return _write_atomic(Path(path), mp_fence_text(zones, home, return_point), encoding="ascii")


def zones_of(scenario: Scenario, home: Home) -> list[Circle]:
    """Every no-fly zone of a scenario as a map circle: cylinders, then spheres (widest footprint)."""
    circles = as_circles(scenario.environment.cylinders, home)
    spheres = scenario.environment.spheres
    if len(spheres):
        lat, lon, _ = enu_to_geodetic(spheres.center * [1.0, 1.0, 0.0], home)
        circles += [Circle(float(a), float(o), float(r), float(c[2] + r), "sphere")
                    for a, o, r, c in zip(lat, lon, spheres.radius, spheres.center)]
    return circles


# --- PLAN.json → file ----------------------------------------------------------------------------------------------

def export_from_plan_json(plan_doc: Mapping[str, Any], scenario: Scenario, fmt: ExportFormat, path: str | Path,
                          autopilot: Autopilot = "ardupilot", *, densify: bool = False,
                          densify_spacing_m: float = 50.0, fence: bool = True) -> Path:
    """Write ``fuseplan plan``'s PLAN.json as ``fmt`` (waypoints | plan | geojson) for ``fuseplan export``.

    The ``.plan`` geofence holds the scenario's cylinders and prisms (``fence=False`` leaves it empty); zones the
    route may pass over or under (a top below its highest point, a floor above home) are left out.
    """
    if fmt not in FORMATS:
        raise ValueError(f"unknown export format {fmt!r} (choose from {', '.join(FORMATS)})")
    options = {"densify": densify, "densify_spacing_m": densify_spacing_m}
    spec = spec_from_plan_json(plan_doc, scenario, autopilot, **options)
    waypoints = np.asarray(plan_doc["waypoints"], dtype=float)
    trajectory = plan_doc.get("trajectory", {}).get("points")
    if fmt == "geojson":
        traj = lonlatalt(np.asarray(trajectory, dtype=float), spec.home) if trajectory else None
        marks = {"unchecked": f"{UNCHECKED}: {unchecked}"} if (unchecked := plan_doc.get("unchecked")) else {}
        return write_geojson(path, lonlatalt(waypoints, spec.home), zones_of(scenario, spec.home), traj,
                             {"scenario": plan_doc.get("scenario", scenario.name), "status": plan_doc.get("status"),
                              **marks}, geo_zones=zones_from_prisms(scenario.environment.prisms, spec.home))
    items = mission_from_plan_json(plan_doc, scenario, autopilot, **options)
    unchecked = plan_doc.get("unchecked")
    if fmt == "waypoints":
        return write_waypoints(path, items, spec.home, unchecked)
    zones: list[Circle] = []
    polygons: list[Zone] = []
    if fence:
        heights = np.asarray(trajectory, dtype=float)[:, 2] if trajectory else waypoints[:, 2]
        route_top = float(np.max(heights))
        zones = fenced_circles(scenario.environment.cylinders, spec.home, route_top)
        # a fence holds at every height: polygons the route (and its climb from home) may pass over or under stay out
        prisms = scenario.environment.prisms
        left_out = prisms_left_out(prisms, 0.0, route_top)
        polygons = [z for k, z in enumerate(zones_from_prisms(prisms, spec.home)) if k not in left_out]
    return write_qgc_plan(path, items, spec, zones, unchecked=unchecked, zones=polygons)
