"""Geographic scenarios: points in lat/lon, altitudes with their reference, a region that is a polygon or derived
from the inputs (docs/scenario_format.md, "Geographic scenarios").

:func:`localise` rewrites a scenario's raw TOML into the local form the loader checks: every lat/lon point becomes
metres in a frame whose origin is the region's south-west corner at home's altitude, every altitude a height above
home, the region polygon a keep-in prism. Horizontal positions go through pymap3d; heights come from the stated
reference alone (home: as given; amsl: minus home's altitude; ground: plus the terrain under the point), as mission
items carry heights above home rather than up in a tangent plane. A scenario with nothing geographic comes back
as it was.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pymap3d

from planner.errors import ScenarioError
from planner.world.geo_inputs import ALTITUDE_REFS, LAT_LIMIT_DEG, LON_LIMIT_DEG
from planner.world.home import Home
from planner.world.terrain import Terrain

DEFAULT_REGION_MARGIN_M = 300.0  # m around every input when the region is derived (no polygon)
_WGS84 = pymap3d.Ellipsoid.from_name("wgs84")

Ground = Callable[[Home, float, float], Terrain | None]  # (origin, size_x, size_y) → the terrain, built once


@dataclass(frozen=True)
class LocalFrame:
    """Where a geographic scenario's local frame lies: its ``origin`` (the south-west corner of the region, at
    home's altitude), ``home_xy`` (home's metres east and north in it) and the ``terrain`` built on it."""

    origin: Home
    home_xy: tuple[float, float]
    terrain: Terrain | None


def _is_geo(value: Any) -> bool:
    return isinstance(value, dict) and ("lat" in value or "lon" in value)


def is_geographic(raw: dict[str, Any]) -> bool:
    """Whether a raw scenario uses the geographic form anywhere (a region, or a lat/lon point or table)."""
    if "region" in raw:
        return True
    stack: list[Any] = [v for k, v in raw.items() if k != "home"]
    while stack:
        node = stack.pop()
        if _is_geo(node):
            return True
        if isinstance(node, dict):
            stack.extend(node.values())
        elif isinstance(node, list):
            stack.extend(node)
    return False


class _Reader:
    """Reads lat/lon values from the raw tables, naming the field in every refusal."""

    def __init__(self, file: str) -> None:
        self.file = file

    def fail(self, where: str, reason: str) -> ScenarioError:
        return ScenarioError(self.file, where, reason)

    def number(self, table: dict[str, Any], key: str, where: str, lo: float = -math.inf,
               hi: float = math.inf) -> float:
        value = table.get(key)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            got = "missing" if value is None else f"got {type(value).__name__} {value!r}"
            raise self.fail(f"{where}.{key}", f"a number is required ({got})")
        if not (math.isfinite(value) and lo <= value <= hi):
            raise self.fail(f"{where}.{key}", f"{value!r} is outside [{lo:g}, {hi:g}]")
        return float(value)

    def latlon(self, table: dict[str, Any], where: str) -> tuple[float, float]:
        return (self.number(table, "lat", where, -LAT_LIMIT_DEG, LAT_LIMIT_DEG),
                self.number(table, "lon", where, -LON_LIMIT_DEG, LON_LIMIT_DEG))

    def ref(self, table: dict[str, Any], key: str, where: str) -> str:
        ref = table.get(key, "home")
        if ref not in ALTITUDE_REFS:
            raise self.fail(f"{where}.{key}", f"{ref!r} is not one of {', '.join(ALTITUDE_REFS)}")
        return str(ref)

    def pairs(self, value: Any, where: str) -> np.ndarray:
        """``[[a, b], ...]`` (at least three) as an (n, 2) array."""
        if not isinstance(value, list) or len(value) < 3:
            raise self.fail(where, "a polygon needs a list of at least 3 [lat, lon] (or [x, y]) pairs")
        out = np.empty((len(value), 2))
        for i, pair in enumerate(value):
            if not (isinstance(pair, list) and len(pair) == 2
                    and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in pair)):
                raise self.fail(f"{where}[{i}]", f"expected a pair of numbers, got {pair!r}")
            out[i] = pair
        if not np.all(np.isfinite(out)):
            raise self.fail(where, "a vertex is not a finite number")
        return out


# every place a point may stand: (list key or None, key in the entry, kind); kind "vec3" is [x, y, z] or a point
# table {lat, lon, alt, ref}; "xy" is keys x, y or lat, lon in the entry; "xyz" keys x, y, z or lat, lon, alt, ref
_POINTS = (
    ("route", "start", "vec3"), ("route", "goal", "vec3"), ("route", "vias", "vec3 list"),
    ("cylinders", None, "xy"), ("hemispheres", None, "xy"), ("spheres", None, "xyz"), ("radars", None, "xyz"),
    ("threats", "center", "vec3"), ("threats", "a", "vec3"), ("threats", "b", "vec3"),
    ("intruders", "meet", "vec3"), ("intruders", "waypoints", "vec3 list"),
)


def _entries(raw: dict[str, Any], section: str) -> list[tuple[str, dict[str, Any]]]:
    """The tables of ``section`` with their field names: ``route`` itself, or each entry of a list."""
    value = raw.get(section)
    if isinstance(value, dict):
        return [(section, value)]
    if isinstance(value, list):
        return [(f"{section}[{i}]", v) for i, v in enumerate(value) if isinstance(v, dict)]
    return []


def _visit_points(raw: dict[str, Any], visit: Callable[[str, str, Any, dict[str, Any], Any], Any]) -> None:
    """Call ``visit(where, kind, value, table, key)`` for every point of the scenario; its result replaces it."""
    for section, key, kind in _POINTS:
        for where, table in _entries(raw, section):
            if kind == "vec3 list":
                assert key is not None  # a named field (_POINTS)
                points = table.get(key)
                if isinstance(points, list):
                    table[key] = [visit(f"{where}.{key}[{j}]", "vec3", p, table, None) for j, p in enumerate(points)]
            elif kind == "vec3":
                assert key is not None
                if key in table:
                    table[key] = visit(f"{where}.{key}", kind, table[key], table, key)
            else:
                visit(where, kind, table, table, None)


def localise(raw: dict[str, Any], file: str, home: Home,
             ground: Ground) -> tuple[dict[str, Any], LocalFrame | None]:
    """The raw scenario in local metres (see the module's docstring) and where its frame lies.

    ``home`` is the scenario's validated ``[home]``; ``ground`` builds the terrain once the frame is known. The frame
    is None when the bounds are malformed (the loader then names them)."""
    read = _Reader(file)
    raw = copy.deepcopy(raw)
    region = raw.pop("region", None)
    if region is not None and "bounds" in raw:
        raise read.fail("region", "give [bounds] (home at the south-west corner) or [region], not both")
    if region is not None and not isinstance(region, dict):
        raise read.fail("region", "must be a table")
    unknown = set(region or {}) - {"polygon", "margin_m"}
    if unknown:
        raise read.fail(f"region.{sorted(unknown)[0]}", "unknown key (not part of the scenario format; check the "
                        "spelling)")

    def east_north(lat: np.ndarray, lon: np.ndarray, origin: Home) -> np.ndarray:
        e, n, _ = pymap3d.geodetic2enu(lat, lon, origin.alt, origin.lat, origin.lon, origin.alt, ell=_WGS84)
        return np.stack([np.asarray(e, dtype=float), np.asarray(n, dtype=float)], axis=-1)

    # pass 1: where everything lies around home, for the region
    seen: list[np.ndarray] = []

    def extent(where: str, kind: str, value: Any, table: dict[str, Any], key: Any) -> Any:
        if _is_geo(value):
            lat, lon = read.latlon(value, where)
            centre = east_north(np.array(lat), np.array(lon), home)
        elif kind == "vec3" and isinstance(value, list) and len(value) == 3 and _numbers(value):
            centre = np.array(value[:2], dtype=float)
        elif kind != "vec3" and isinstance(value, dict) and _numbers([value.get("x"), value.get("y")]):
            centre = np.array([value["x"], value["y"]], dtype=float)
        else:
            return value  # malformed: the loader names it
        r = value.get("radius", 0.0) if kind != "vec3" else 0.0
        r = float(r) if isinstance(r, (int, float)) and not isinstance(r, bool) else 0.0
        seen.extend([centre - r, centre + r])
        return value

    _visit_points(raw, extent)
    prisms = raw.get("prisms")
    polygons: dict[int, np.ndarray] = {}  # prism index → vertices (m from home)
    for i, table in enumerate(prisms if isinstance(prisms, list) else []):
        if not isinstance(table, dict):
            continue
        where = f"prisms[{i}]"
        if "polygon" in table and "xy" in table:
            raise read.fail(where, "give xy (m) or polygon ([lat, lon] pairs), not both")
        if "polygon" in table:
            ll = read.pairs(table["polygon"], f"{where}.polygon")
            for k, (lat, lon) in enumerate(ll):
                read.latlon({"lat": lat, "lon": lon}, f"{where}.polygon[{k}]")
            polygons[i] = east_north(ll[:, 0], ll[:, 1], home)
        elif "xy" in table:
            polygons[i] = read.pairs(table["xy"], f"{where}.xy")
        if i in polygons:
            seen.extend(polygons[i])
    keep_in = None
    if region is not None and "polygon" in region:
        ll = read.pairs(region["polygon"], "region.polygon")
        for k, (lat, lon) in enumerate(ll):
            read.latlon({"lat": lat, "lon": lon}, f"region.polygon[{k}]")
        keep_in = east_north(ll[:, 0], ll[:, 1], home)

    # the frame: the region's south-west corner, or home's own (the [bounds] form)
    if region is not None:
        if keep_in is not None:
            if "margin_m" in region:
                raise read.fail("region.margin_m", "a region polygon is the region: give polygon or margin_m")
            lo, hi = keep_in.min(axis=0), keep_in.max(axis=0)
        else:
            margin = read.number(region, "margin_m", "region", 0.0, 1e5) if "margin_m" in region \
                else DEFAULT_REGION_MARGIN_M
            if not seen:
                raise read.fail("region", "no point to derive the region from: give region.polygon")
            pts = np.asarray(seen, dtype=float).reshape(-1, 2)
            lo, hi = pts.min(axis=0) - margin, pts.max(axis=0) + margin
        size = hi - lo
        if np.any(size <= 0.0):
            raise read.fail("region", "the region has no area")
        lat0, lon0, _ = pymap3d.enu2geodetic(lo[0], lo[1], 0.0, home.lat, home.lon, home.alt, ell=_WGS84)
        origin = Home(float(lat0), float(lon0), home.alt)
        raw["bounds"] = {"x": float(size[0]), "y": float(size[1])}
        raw["home"] = {"lat": origin.lat, "lon": origin.lon, "alt": origin.alt}
    else:
        origin = home
        bounds = raw.get("bounds")
        if not (isinstance(bounds, dict) and _numbers([bounds.get("x"), bounds.get("y")])):
            return raw, None  # the loader names what is wrong with the bounds
        size = np.array([bounds["x"], bounds["y"]], dtype=float)
    terrain = ground(origin, float(size[0]), float(size[1]))

    def height(value: dict[str, Any], key: str, ref_key: str, where: str, xy: np.ndarray) -> float:
        alt = read.number(value, key, where, -1e5, 1e5)
        ref = read.ref(value, ref_key, where)
        if ref == "amsl":
            return alt - home.alt
        if ref == "ground":
            return alt + (0.0 if terrain is None else float(terrain.height_at(xy[0], xy[1])))
        return alt

    def from_home(xy: np.ndarray) -> np.ndarray:
        """Metres east and north of home → the frame (through lat/lon: the two tangent planes differ a little)."""
        if region is None:
            return np.asarray(xy, dtype=float)
        xy = np.asarray(xy, dtype=float)
        lat, lon, _ = pymap3d.enu2geodetic(xy[..., 0], xy[..., 1], 0.0, home.lat, home.lon, home.alt, ell=_WGS84)
        return east_north(np.asarray(lat), np.asarray(lon), origin)

    # pass 2: every point in the frame
    def place(where: str, kind: str, value: Any, table: dict[str, Any], key: Any) -> Any:
        if _is_geo(value):
            lat, lon = read.latlon(value, where)
            xy = east_north(np.array(lat), np.array(lon), origin)
            if kind in ("vec3", "xyz") and "alt" not in value:
                raise read.fail(f"{where}.alt", "required key is missing (a lat/lon point needs alt)")
            z = height(value, "alt", "ref", where, xy) if kind in ("vec3", "xyz") else None
            if kind == "vec3":
                extra = set(value) - {"lat", "lon", "alt", "ref"}
                if extra:
                    raise read.fail(f"{where}.{sorted(extra)[0]}", "unknown key (a point is lat, lon, alt and ref)")
                return [float(xy[0]), float(xy[1]), z]
            for k in ("lat", "lon", "alt", "ref") if kind == "xyz" else ("lat", "lon"):
                value.pop(k, None)
            value["x"], value["y"] = float(xy[0]), float(xy[1])
            if z is not None:
                value["z"] = z
            return value
        if region is None:
            return value
        if kind == "vec3" and isinstance(value, list) and len(value) == 3 and _numbers(value):
            x, y = from_home(np.array(value[:2]))
            return [float(x), float(y), value[2]]
        if kind != "vec3" and isinstance(value, dict) and _numbers([value.get("x"), value.get("y")]):
            x, y = from_home(np.array([value["x"], value["y"]]))
            value["x"], value["y"] = float(x), float(y)
        return value

    _visit_points(raw, place)
    for _where, table in _entries(raw, "cylinders"):
        if "top_ref" in table:
            top_ref = table.pop("top_ref")
            if "top" in table:
                xy = np.array([table["x"], table["y"]], dtype=float) if _numbers([table.get("x"), table.get("y")]) \
                    else np.zeros(2)
                table["top"] = height({"top": table["top"], "ref": top_ref}, "top", "ref", _where, xy)
            else:
                raise read.fail(f"{_where}.top_ref", "given without top")
    for i, table in enumerate(prisms if isinstance(prisms, list) else []):
        if not isinstance(table, dict) or i not in polygons:
            continue
        where = f"prisms[{i}]"
        if "polygon" in table:
            ll = np.asarray(table.pop("polygon"), dtype=float)
            xy = east_north(ll[:, 0], ll[:, 1], origin)
        else:
            xy = from_home(polygons[i])
        table["xy"] = [[float(x), float(y)] for x, y in xy]
        for key in ("floor", "ceiling"):
            ref_key = f"{key}_ref"
            if key not in table:
                if ref_key in table:
                    raise read.fail(f"{where}.{ref_key}", f"given without {key}")
                continue
            ref = read.ref(table, ref_key, where)
            table.pop(ref_key, None)
            value = read.number(table, key, where, -1e5, 1e5)
            if ref == "amsl":
                table[key] = value - home.alt
            elif ref == "ground" and terrain is not None:
                under = _ground_under(terrain, np.asarray(xy))
                table[key] = value + (under[0] if key == "floor" else under[1])  # the larger solid
    if region is not None and keep_in is not None:  # keep_in: the region's polygon
        ll = np.asarray(region["polygon"], dtype=float)
        region_xy = east_north(ll[:, 0], ll[:, 1], origin)
        entry = {"xy": [[float(x), float(y)] for x, y in region_xy], "keep_in": True, "name": "region.polygon"}
        raw["prisms"] = [*(prisms if isinstance(prisms, list) else []), entry]
    launch = from_home(np.zeros(2))
    return raw, LocalFrame(origin, (float(launch[0]), float(launch[1])), terrain)


def _numbers(values: list[Any]) -> bool:
    return all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)


def _ground_under(terrain: Terrain, xy: np.ndarray) -> tuple[float, float]:
    """The lowest and highest ground (m above home) under polygon ``xy``: its vertices and the grid nodes of its
    bounding box (a conservative span: a floor above ground is taken from the lowest, a ceiling from the highest)."""
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    ny, nx = terrain.heights.shape
    xs = terrain.x0 + terrain.dx * np.arange(nx)
    ys = terrain.y0 + terrain.dy * np.arange(ny)
    inside = terrain.heights[np.ix_((ys >= lo[1]) & (ys <= hi[1]), (xs >= lo[0]) & (xs <= hi[0]))]
    at = terrain.height_at(xy[:, 0], xy[:, 1])
    values = np.concatenate([np.ravel(inside), np.ravel(at)])
    return float(values.min()), float(values.max())
