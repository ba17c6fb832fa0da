"""Mission exports: QGC WPL 110 ``.waypoints``, QGroundControl ``.plan`` and GeoJSON (docs/design.md, "Companion").

Files carry degrees and the plain frame numbers (``GLOBAL_RELATIVE_ALT`` = 3, not the ``_INT`` twin 6), as
Mission Planner and QGroundControl write them.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.items import FRAME_GLOBAL, MissionItem, normalise_frame
from companion.mission.builder import (
    Autopilot,
    MissionSpec,
    is_home_item,
    mission_from_plan_json,
    spec_from_plan_json,
)
from companion.mission.geo import Circle, as_circles, circle_ring, enu_to_geodetic, lonlatalt, to_int_e7
from planner.errors import one_line
from planner.world.environment import Cylinders
from planner.world.home import Home
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


# --- QGroundControl .plan ----------------------------------------------------------------------------------------

def _json_number(value: float) -> float | None:
    return None if not math.isfinite(value) else float(value)


def qgc_plan(items: Sequence[MissionItem], spec: MissionSpec, fence: Cylinders | Sequence[Circle] = (),
             rally: Iterable[Sequence[float]] = ()) -> dict[str, Any]:
    """The QGroundControl ``.plan`` (v1) document. ArduPilot's home item is not an item here: QGC keeps home in
    ``plannedHomePosition``. ``rally``: (lat deg, lon deg, alt m above home) points."""
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
    circles = [{"circle": {"center": [c.lat, c.lon], "radius": float(c.radius_m)}, "inclusion": False, "version": 1}
               for c in as_circles(fence, home)]
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
            "plannedHomePosition": [home.lat, home.lon, home.alt],
            "items": plan_items,
        },
        "geoFence": {"version": 2, "circles": circles, "polygons": []},
        "rallyPoints": {"version": 2, "points": [[float(v) for v in p] for p in rally]},
    }


def write_qgc_plan(path: str | Path, items: Sequence[MissionItem], spec: MissionSpec,
                   fence: Cylinders | Sequence[Circle] = (), rally: Iterable[Sequence[float]] = (),
                   unchecked: str | None = None) -> Path:
    """Write a QGroundControl ``.plan`` file; see :func:`qgc_plan`. ``unchecked`` (export --force): why, in
    ``groundStation`` and ``fuseplanUnchecked`` (QGroundControl keeps but does not show them)."""
    doc = qgc_plan(items, spec, fence, rally)
    if unchecked:
        doc["groundStation"] = f"fuseplan ({UNCHECKED})"
        doc["fuseplanUnchecked"] = str(unchecked)
    path = Path(path)
    path.write_text(json.dumps(doc, indent=2, allow_nan=False), encoding="utf-8")
    return path


# --- GeoJSON -----------------------------------------------------------------------------------------------------

def _point(coords: Sequence[float], **properties: Any) -> dict[str, Any]:
    return {"type": "Feature", "geometry": {"type": "Point", "coordinates": list(coords)}, "properties": properties}


def geojson(route: Sequence[Sequence[float]], zones: Sequence[Circle] = (),
            trajectory: Sequence[Sequence[float]] | None = None, properties: Mapping[str, Any] | None = None,
            ) -> dict[str, Any]:
    """A FeatureCollection: the route LineString, optionally the smoothed trajectory, each no-fly zone as a
    Polygon (closed ring, counter-clockwise) with ``radius_m`` and ``top`` (m above home, null = unlimited),
    and start/goal Points. Positions are (lon, lat, alt m AMSL), GeoJSON order."""
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
    features.append(_point(route[0], name="start"))
    features.append(_point(route[-1], name="goal"))
    return {"type": "FeatureCollection", "features": features}


def write_geojson(path: str | Path, route: Sequence[Sequence[float]], zones: Sequence[Circle] = (),
                  trajectory: Sequence[Sequence[float]] | None = None,
                  properties: Mapping[str, Any] | None = None) -> Path:
    """Write a GeoJSON file; see :func:`geojson` (route and trajectory as (lon, lat, alt) positions)."""
    path = Path(path)
    doc = geojson(route, zones, trajectory, properties)
    path.write_text(json.dumps(doc, indent=1, allow_nan=False), encoding="utf-8")
    return path


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

    The ``.plan`` geofence holds the scenario's cylinders (``fence=False`` leaves it empty); cylinders whose
    top is below the route's highest point are left out, since the route may pass over them.
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
                              **marks})
    items = mission_from_plan_json(plan_doc, scenario, autopilot, **options)
    unchecked = plan_doc.get("unchecked")
    if fmt == "waypoints":
        return write_waypoints(path, items, spec.home, unchecked)
    zones: list[Circle] = []
    if fence:
        route_top = float(np.max(np.asarray(trajectory, dtype=float)[:, 2] if trajectory else waypoints[:, 2]))
        zones = [c for c in as_circles(scenario.environment.cylinders, spec.home) if c.top_m >= route_top]
    return write_qgc_plan(path, items, spec, zones, unchecked=unchecked)
