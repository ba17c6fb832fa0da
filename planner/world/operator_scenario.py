"""An operator's mission (a ground station's file, or the vehicle's own mission and fence) as a geographic
scenario: its home, its goal, its fence and any airspace zones, on a base scenario's vehicle, band and planner
settings (docs/scenario_format.md, "Missions and zones from ground stations").

The scenario is written as TOML (:func:`scenario_text`) and loaded like any other, so every check, message and
PLAN.json's ``scenario_file`` work unchanged.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pymap3d

from planner.errors import ScenarioError
from planner.world import toml_text
from planner.world.geo_inputs import Altitude, GeoPoint, OperatorMission, Zone

# without a base scenario: the band around the mission's own heights, and the clearances kept from zones
BAND_BELOW_M = 30.0  # m the band reaches below the lowest height of the mission (never below BAND_LOWEST_M)
BAND_ABOVE_M = 60.0  # m above its highest
BAND_LOWEST_M = 10.0
OPERATOR_HAZARD = {"d_coll": 20.0, "d_safe": 60.0}  # m from a zone's edge: closer is a violation / costs
CIRCLE_SIDES = 32  # a circle with a floor or ceiling, or a keep-in circle, as a polygon
QGC_PLANE_TYPES = {1}  # MAV_TYPE_FIXED_WING (VTOLs fly their missions as planes)
QGC_COPTER_TYPES = {2, 3, 4, 13, 14, 15}  # quad, coaxial, heli, hexa, octo, tri


def point_table(p: GeoPoint, alt: Altitude | float | None = None) -> dict[str, Any]:
    """A scenario's point table for ``p``; ``alt`` (a number: above home) in place of its own altitude."""
    a = Altitude(float(alt)) if isinstance(alt, (int, float)) else alt if alt is not None else p.alt
    out: dict[str, Any] = {"lat": p.lat, "lon": p.lon}
    if a is not None:
        out["alt"], out["ref"] = float(a.value), a.ref
    return out


def _heights_above_home(points: Sequence[GeoPoint], home_amsl: float) -> list[float]:
    """The points' heights above home (above ground taken as above home: the band is a first guess)."""
    out = []
    for p in points:
        if p.alt is not None:
            out.append(p.alt.value - home_amsl if p.alt.ref == "amsl" else p.alt.value)
    return out


def _circle(zone: Zone, sides: int, outside: bool) -> list[list[float]]:
    """A circle zone as a [lat, lon] polygon: circumscribed (``outside``: never smaller, for a no-fly zone) or
    inscribed (never larger, for a keep-in one)."""
    assert zone.centre is not None and zone.radius_m is not None
    lat0, lon0 = zone.centre
    r = zone.radius_m / math.cos(math.pi / sides) if outside else zone.radius_m
    a = np.linspace(0.0, 2.0 * math.pi, sides, endpoint=False)
    lat, lon, _ = pymap3d.enu2geodetic(r * np.cos(a), r * np.sin(a), 0.0, lat0, lon0, 0.0)
    return [[float(la), float(lo)] for la, lo in zip(lat, lon, strict=True)]


def zone_tables(zones: Sequence[Zone], source: str) -> tuple[list[dict], list[dict], list[list[float]] | None]:
    """(prisms, cylinders, region polygon) for the zones: exclusion polygons are prisms; exclusion circles are
    cylinders, or prisms when they have a floor or ceiling; the one inclusion zone is the region."""
    prisms: list[dict] = []
    cylinders: list[dict] = []
    inclusion = [z for z in zones if z.inclusion]
    if len(inclusion) > 1:
        raise ScenarioError(source, inclusion[1].name, f"a second inclusion zone (besides {inclusion[0].name}): "
                            "plan within one; merge them into one polygon")
    region = None
    for z in zones:
        if z.inclusion:
            if z.floor is not None or z.ceiling is not None:
                raise ScenarioError(source, z.name, "an inclusion zone with a floor or ceiling is not supported "
                                    "(the altitude band bounds heights)")
            region = [list(v) for v in z.polygon] if z.polygon is not None else _circle(z, CIRCLE_SIDES, False)
            continue
        slab: dict[str, Any] = {"name": z.name}
        for key, alt in (("floor", z.floor), ("ceiling", z.ceiling)):
            if alt is not None:
                slab[key], slab[f"{key}_ref"] = float(alt.value), alt.ref
        if z.polygon is not None:
            prisms.append({"polygon": [list(v) for v in z.polygon], **slab})
        elif len(slab) > 1:
            prisms.append({"polygon": _circle(z, CIRCLE_SIDES, True), **slab})
        else:
            assert z.centre is not None and z.radius_m is not None
            cylinders.append({"lat": z.centre[0], "lon": z.centre[1], "radius": float(z.radius_m)})
    return prisms, cylinders, region


def operator_raw(mission: OperatorMission, base: Mapping[str, Any] | None = None, zones: Sequence[Zone] = (),
                 base_dir: Path | None = None) -> dict[str, Any]:
    """The raw scenario (geographic form) for ``mission`` with its fence and ``zones`` added, on ``base``'s
    vehicle, hazard, planner, altitude and terrain tables (a base scenario's raw TOML; None: defaults, the band
    around the mission's heights; a relative terrain path is taken from ``base_dir``). The start is home at the height
    of the mission's first position item; the positions between it and the goal are ``route.vias``."""
    source = str(mission.source)
    home = mission.home or mission.start
    if home is None or home.alt is None or home.alt.ref != "amsl":
        raise ScenarioError(source, "home", "the mission has no home with an altitude above sea level (QGC: "
                            "plannedHomePosition; Mission Planner: item 0)")
    if mission.goal is None:
        raise ScenarioError(source, "goal", "the mission has no navigation item with a position to fly to")
    start = mission.start or home
    first = next((p for p in (*mission.vias, mission.goal) if p.alt is not None), None)
    raw: dict[str, Any] = {"name": mission.source.stem, "description": f"imported from {mission.source.name}"}
    raw["home"] = {"lat": home.lat, "lon": home.lon, "alt": float(home.alt.value)}
    prisms, cylinders, region = zone_tables([*mission.zones, *zones], source)
    raw["region"] = {"polygon": region} if region is not None else {}
    base = dict(base or {})
    for key in ("vehicle", "hazard", "planner", "altitude", "terrain"):
        if key in base:
            raw[key] = base[key]
    terrain = raw.get("terrain")
    if isinstance(terrain, dict) and isinstance(terrain.get("path"), str) and base_dir is not None:
        raw["terrain"] = {**terrain, "path": str((base_dir / terrain["path"]).resolve())}
    if "altitude" not in raw:
        heights = _heights_above_home([*mission.vias, mission.goal], home.alt.value) or [60.0]
        raw["altitude"] = {"min": max(BAND_LOWEST_M, min(heights) - BAND_BELOW_M),
                           "max": max(heights) + BAND_ABOVE_M}
    raw.setdefault("hazard", dict(OPERATOR_HAZARD))
    vehicle_type = mission.extras.get("vehicle_type")
    if "vehicle" not in raw and isinstance(vehicle_type, int):
        if vehicle_type in QGC_COPTER_TYPES:
            raw["vehicle"] = {"type": "copter"}
        elif vehicle_type in QGC_PLANE_TYPES:
            raw["vehicle"] = {"type": "plane"}
    height = first.alt if first is not None else Altitude(60.0)  # for the start, and any place without its own
    raw["route"] = {"start": point_table(start, height),
                    "goal": point_table(mission.goal, None if mission.goal.alt is not None else height)}
    if mission.vias:  # the operator's intermediate places: the route passes through each, in order
        raw["route"]["vias"] = [point_table(v, None if v.alt is not None else height) for v in mission.vias]
    if prisms:
        raw["prisms"] = prisms
    if cylinders:
        raw["cylinders"] = cylinders
    return raw


def scenario_text(mission: OperatorMission, base: Mapping[str, Any] | None = None, zones: Sequence[Zone] = (),
                  base_path: Path | None = None) -> str:
    """:func:`operator_raw` as the TOML text of a scenario file, with a header saying where it came from."""
    header = f"A scenario made by fuseplan from {mission.source}" + (f" on {base_path}" if base_path else "") \
        + "\n(docs/scenario_format.md). Edit it, or the mission, and plan again."
    base_dir = base_path.parent if base_path is not None else None
    return toml_text.dumps(operator_raw(mission, base, zones, base_dir), header)
