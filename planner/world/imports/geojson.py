"""Our GeoJSON zones → :class:`Zone` values (docs/imports.md, "GeoJSON zones"), and the GeoJSON geometry the
airspace readers share (planner/world/imports/airspace.py).

Polygon and MultiPolygon features (outer rings; holes are refused) and Point features with a ``radius_m``.
Coordinates are RFC 7946 ``[lon, lat]``. Each feature's properties say its vertical extent (:data:`PROPERTIES`);
companion/mission/exports.py writes the same names, so a round trip holds. Which format a file is in is decided in
planner/world/imports/zones.py.
"""

from __future__ import annotations

from typing import Any

from planner.errors import ScenarioError
from planner.world.geo_inputs import ALTITUDE_REFS, Altitude, Zone
from planner.world.imports.common import check_band, kind, lat_lon, number, ring

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
Ring = tuple[tuple[float, float], ...]  # a polygon's (lat, lon) vertices, not closed


def labelled(where: str, name: Any) -> str:
    """How a zone is named in messages and values: ``features[3] 'Danger area D123'`` (``where`` alone without a
    name)."""
    return f"{where} {name!r}" if name else where


def name_of(file: str, where: str, obj: dict[str, Any], key: str = "name") -> str | None:
    """``obj[key]`` when it is a string, None when absent or null; anything else is refused."""
    name = obj.get(key)
    if name is not None and not isinstance(name, str):
        raise ScenarioError(file, f"{where}.{key}", f"expected a string, got {kind(name)}")
    return name


def properties(file: str, where: str, feature: Any) -> dict[str, Any]:
    """A GeoJSON Feature's properties (null: none); anything but a Feature is refused."""
    if not isinstance(feature, dict) or feature.get("type") != "Feature":
        raise ScenarioError(file, where, "not a GeoJSON Feature (an object with \"type\": \"Feature\")")
    props = feature.get("properties") or {}
    if not isinstance(props, dict):
        raise ScenarioError(file, f"{where}.properties", f"expected an object or null, got {kind(props)}")
    return props


def feature_zones(file: str, where: str, feature: Any) -> list[Zone]:
    """The zones of one feature in our property names: one per Polygon, one per part of a MultiPolygon, one per
    Point with a ``radius_m``; anything else is refused in one line naming the feature."""
    props = properties(file, where, feature)
    label = labelled(where, name_of(file, f"{where}.properties", props))
    inclusion = props.get("inclusion", False)
    if not isinstance(inclusion, bool):
        raise ScenarioError(file, f"{where}.properties.inclusion", f"expected true or false, got {kind(inclusion)}")
    floor, ceiling = (_height(file, f"{where}.properties", props, h) for h in ("floor", "ceiling"))
    check_band(file, f"{where}.properties", floor, ceiling)
    if inclusion and (floor is not None or ceiling is not None):
        raise ScenarioError(file, f"{where}.properties", "an inclusion zone holds at every height: give it no "
                            "floor_m or ceiling_m")
    geometry = feature.get("geometry")
    gtype = geometry.get("type") if isinstance(geometry, dict) else None
    here = f"{where}.geometry"
    if gtype == "Point":
        lat, lon = position(file, f"{here}.coordinates", geometry.get("coordinates"))
        if "radius_m" not in props or props["radius_m"] is None:
            raise ScenarioError(file, f"{where}.properties.radius_m", "missing (a Point zone needs a radius in "
                                "metres)")
        radius = number(file, f"{where}.properties.radius_m", props["radius_m"])
        if radius <= 0.0:
            raise ScenarioError(file, f"{where}.properties.radius_m", f"{radius:g} m (a radius must be > 0)")
        return [Zone(label, inclusion, centre=(lat, lon), radius_m=radius, floor=floor, ceiling=ceiling)]
    parts = polygon_parts(file, here, label, geometry)
    if parts is None:
        raise ScenarioError(file, here, f"{what_geometry(geometry)} is not a zone (a Polygon, MultiPolygon or Point "
                            "with radius_m)")
    return [Zone(lbl, inclusion, polygon=vertices, floor=floor, ceiling=ceiling) for lbl, vertices in parts]


def what_geometry(geometry: Any) -> str:
    """A geometry's type for messages: ``'LineString'``, ``no geometry``, ``an array`` …"""
    gtype = geometry.get("type") if isinstance(geometry, dict) else None
    return repr(gtype) if gtype else ("no geometry" if geometry is None else kind(geometry))


def polygon_parts(file: str, here: str, label: str, geometry: Any) -> list[tuple[str, Ring]] | None:
    """A Polygon's or MultiPolygon's zones as (name, outer ring (lat, lon)) pairs (a MultiPolygon's parts named
    ``label part j``); None when ``geometry`` is neither."""
    gtype = geometry.get("type") if isinstance(geometry, dict) else None
    if gtype == "Polygon":
        return [(label, outer_ring(file, f"{here}.coordinates", geometry.get("coordinates")))]
    if gtype == "MultiPolygon":
        polygons = geometry.get("coordinates")
        if not isinstance(polygons, list):
            raise ScenarioError(file, f"{here}.coordinates", f"expected an array of polygons, got {kind(polygons)}")
        return [(f"{label} part {j}", outer_ring(file, f"{here}.coordinates[{j}]", p)) for j, p in enumerate(polygons)]
    return None


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


def position(file: str, where: str, value: Any) -> tuple[float, float]:
    """A GeoJSON position [lon, lat] or [lon, lat, alt] → (lat, lon)."""
    if not isinstance(value, list) or len(value) not in (2, 3):
        raise ScenarioError(file, where, f"expected a position [lon, lat], got {kind(value)}"
                            + (f" of {len(value)}" if isinstance(value, list) else ""))
    lon, lat = value[0], value[1]
    return lat_lon(file, where, lat, lon)


def outer_ring(file: str, where: str, rings: Any) -> Ring:
    """A Polygon's coordinates → its outer ring as (lat, lon) vertices; a hole is refused."""
    if not isinstance(rings, list) or not rings or not isinstance(rings[0], list):
        raise ScenarioError(file, where, f"expected an array of linear rings, got {kind(rings)}")
    if len(rings) > 1:
        raise ScenarioError(file, where, f"{len(rings) - 1} hole(s): holes are not supported (split the zone "
                            "into polygons without holes)")
    points = [position(file, f"{where}[0][{i}]", p) for i, p in enumerate(rings[0])]
    return ring(file, f"{where}[0]", points)
