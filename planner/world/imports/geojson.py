"""GeoJSON airspace zones → :class:`Zone` values (docs/imports.md, "GeoJSON zones").

A FeatureCollection (or one Feature) of Polygon and MultiPolygon features (outer rings; holes are refused) and
Point features with a ``radius_m``. Coordinates are RFC 7946 ``[lon, lat]``. Each feature's properties say its
vertical extent (:data:`PROPERTIES`); companion/mission/exports.py writes the same names, so a round trip holds.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from planner.errors import ScenarioError
from planner.world.geo_inputs import ALTITUDE_REFS, Altitude, Zone
from planner.world.imports.common import kind, lat_lon, load_json, number, read_text, ring

# the feature properties read (anything else is kept out of the way: airspace files carry many)
PROPERTIES = {
    "name": "a string naming the zone in messages",
    "inclusion": "true: the region to stay inside (no floor or ceiling); false or absent: no-fly",
    "floor_m": "the zone's bottom in metres (absent or null: from the ground)",
    "floor_ref": "what floor_m is measured from: home (default), ground or amsl",
    "ceiling_m": "the zone's top in metres (absent or null: unlimited)",
    "ceiling_ref": "what ceiling_m is measured from: home (default), ground or amsl",
    "radius_m": "a Point zone's radius in metres (required for a Point)",
}
DEFAULT_REF = "home"


def read_zones(path: str | Path) -> tuple[Zone, ...]:
    """The zones in a GeoJSON file: one per Polygon, one per part of a MultiPolygon, one per Point with a
    ``radius_m``; anything else is refused in one line naming the feature."""
    path, file, text = read_text(path, "GeoJSON")
    doc = load_json(file, text)
    if isinstance(doc, dict) and doc.get("type") == "Feature":
        features, prefix = [doc], ""
    elif isinstance(doc, dict) and doc.get("type") == "FeatureCollection":
        features, prefix = doc.get("features"), "features"
        if not isinstance(features, list):
            raise ScenarioError(file, "features", f"expected an array of features, got {kind(features)}")
    else:
        got = repr(doc.get("type")) if isinstance(doc, dict) else kind(doc)
        raise ScenarioError(file, "type", f"{got} is not a GeoJSON FeatureCollection or Feature")
    zones: list[Zone] = []
    for i, feature in enumerate(features):
        zones += _feature(file, f"{prefix}[{i}]" if prefix else "feature", feature)
    return tuple(zones)


def _feature(file: str, where: str, feature: Any) -> list[Zone]:
    if not isinstance(feature, dict) or feature.get("type") != "Feature":
        raise ScenarioError(file, where, "not a GeoJSON Feature (an object with \"type\": \"Feature\")")
    props = feature.get("properties") or {}
    if not isinstance(props, dict):
        raise ScenarioError(file, f"{where}.properties", f"expected an object or null, got {kind(props)}")
    name = props.get("name")
    if name is not None and not isinstance(name, str):
        raise ScenarioError(file, f"{where}.properties.name", f"expected a string, got {kind(name)}")
    label = f"{where} {name!r}" if name else where
    inclusion = props.get("inclusion", False)
    if not isinstance(inclusion, bool):
        raise ScenarioError(file, f"{where}.properties.inclusion", f"expected true or false, got {kind(inclusion)}")
    floor, ceiling = (_height(file, f"{where}.properties", props, h) for h in ("floor", "ceiling"))
    if floor is not None and ceiling is not None and floor.ref == ceiling.ref and floor.value >= ceiling.value:
        raise ScenarioError(file, f"{where}.properties", f"floor_m {floor.value:g} is not below ceiling_m "
                            f"{ceiling.value:g} (both above {floor.ref})")
    if inclusion and (floor is not None or ceiling is not None):
        raise ScenarioError(file, f"{where}.properties", "an inclusion zone holds at every height: give it no "
                            "floor_m or ceiling_m")
    geometry = feature.get("geometry")
    gtype = geometry.get("type") if isinstance(geometry, dict) else None
    here = f"{where}.geometry"
    if gtype == "Point":
        lat, lon = _position(file, f"{here}.coordinates", geometry.get("coordinates"))
        if "radius_m" not in props or props["radius_m"] is None:
            raise ScenarioError(file, f"{where}.properties.radius_m", "missing (a Point zone needs a radius in "
                                "metres)")
        radius = number(file, f"{where}.properties.radius_m", props["radius_m"])
        if radius <= 0.0:
            raise ScenarioError(file, f"{where}.properties.radius_m", f"{radius:g} m (a radius must be > 0)")
        return [Zone(label, inclusion, centre=(lat, lon), radius_m=radius, floor=floor, ceiling=ceiling)]
    if gtype == "Polygon":
        parts = [(f"{here}.coordinates", label, geometry.get("coordinates"))]
    elif gtype == "MultiPolygon":
        polygons = geometry.get("coordinates")
        if not isinstance(polygons, list):
            raise ScenarioError(file, f"{here}.coordinates", f"expected an array of polygons, got {kind(polygons)}")
        parts = [(f"{here}.coordinates[{j}]", f"{label} part {j}", p) for j, p in enumerate(polygons)]
    else:
        what = repr(gtype) if gtype else ("no geometry" if geometry is None else kind(geometry))
        raise ScenarioError(file, here, f"{what} is not a zone (a Polygon, MultiPolygon or Point with radius_m)")
    return [Zone(lbl, inclusion, polygon=_outer_ring(file, at, rings), floor=floor, ceiling=ceiling)
            for at, lbl, rings in parts]


def _height(file: str, where: str, props: dict[str, Any], which: str) -> Altitude | None:
    """``floor`` or ``ceiling``: ``<which>_m`` (absent or null: none) measured from ``<which>_ref``."""
    value, ref = props.get(f"{which}_m"), props.get(f"{which}_ref", DEFAULT_REF)
    if ref is None:
        ref = DEFAULT_REF
    if ref not in ALTITUDE_REFS:
        raise ScenarioError(file, f"{where}.{which}_ref", f"unknown reference {ref!r} (expected one of "
                            f"{', '.join(ALTITUDE_REFS)})")
    if value is None:
        return None
    return Altitude(number(file, f"{where}.{which}_m", value), ref)


def _position(file: str, where: str, value: Any) -> tuple[float, float]:
    """A GeoJSON position [lon, lat] or [lon, lat, alt] → (lat, lon)."""
    if not isinstance(value, list) or len(value) not in (2, 3):
        raise ScenarioError(file, where, f"expected a position [lon, lat], got {kind(value)}"
                            + (f" of {len(value)}" if isinstance(value, list) else ""))
    lon, lat = value[0], value[1]
    return lat_lon(file, where, lat, lon)


def _outer_ring(file: str, where: str, rings: Any) -> tuple[tuple[float, float], ...]:
    """A Polygon's coordinates → its outer ring as (lat, lon) vertices; a hole is refused."""
    if not isinstance(rings, list) or not rings or not isinstance(rings[0], list):
        raise ScenarioError(file, where, f"expected an array of linear rings, got {kind(rings)}")
    if len(rings) > 1:
        raise ScenarioError(file, where, f"{len(rings) - 1} hole(s): holes are not supported (split the zone "
                            "into polygons without holes)")
    points = [_position(file, f"{where}[0][{i}]", p) for i, p in enumerate(rings[0])]
    return ring(file, f"{where}[0]", points)
