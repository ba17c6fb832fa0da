"""Mission Planner files → :class:`OperatorMission` (docs/imports.md, "Mission Planner files").

What Mission Planner writes (GCSViews/FlightPlanner.cs, ExtLibs/Utilities/MissionFile.cs):

- ``.waypoints``: ``QGC WPL 110``, then one item a line (seq, current, frame, command, param1..4, lat, lon, alt,
  autocontinue); line ``0`` is home (AMSL). Saved in the Fence or Rally mission type, the same file holds
  FENCE_* or NAV_RALLY_POINT items after the home line, which Mission Planner drops on loading.
- ``.fen`` (the older polygon fence): ``lat lon`` lines; the first is the fence return point, the rest one
  inclusion polygon, closed (its first vertex repeated last).
- ``.ral``: ``RALLY lat lon alt break_alt land_dir flags`` lines (altitude above home).

Lines starting with ``#`` are comments; fields are split on tabs, spaces or commas, as Mission Planner does.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from planner.errors import ScenarioError
from planner.world.geo_inputs import Altitude, GeoPoint, OperatorMission, Zone
from planner.world.imports.common import (
    FENCE_CIRCLE_EXCLUSION,
    FENCE_CIRCLE_INCLUSION,
    FENCE_POLYGON_EXCLUSION,
    FENCE_POLYGON_INCLUSION,
    FENCE_RETURN_POINT,
    FRAME_REFS,
    NAV_RALLY_POINT,
    NAV_WAYPOINT,
    POSITION_COMMANDS,
    NavItem,
    altitude,
    lat_lon,
    located,
    read_text,
    ring,
    route_of,
)

WPL_HEADER = "QGC WPL 110"
_FIELDS = re.compile(r"[\t ,]+")
_POLYGONS = {FENCE_POLYGON_INCLUSION: True, FENCE_POLYGON_EXCLUSION: False}
_CIRCLES = {FENCE_CIRCLE_INCLUSION: True, FENCE_CIRCLE_EXCLUSION: False}


@dataclass(frozen=True)
class WplItem:
    """One ``QGC WPL 110`` line: its line number and the fields the importer uses."""

    line: int
    seq: int
    frame: int
    command: int
    params: tuple[float, float, float, float]
    lat: float
    lon: float
    alt: float


@dataclass
class _Contents:
    """What a ``QGC WPL 110`` file holds, sorted by kind."""

    home: GeoPoint | None = None
    nav: list[NavItem] = field(default_factory=list)
    zones: list[Zone] = field(default_factory=list)
    rally: list[GeoPoint] = field(default_factory=list)
    fence_return: GeoPoint | None = None


def read_waypoints(path: str | Path, fence_path: str | Path | None = None,
                   rally_path: str | Path | None = None) -> OperatorMission:
    """The operator's mission in a Mission Planner ``.waypoints`` file: home (line 0, AMSL) as start (else the
    first position), the last position item as goal, the positions between as vias; fence and rally items in it,
    and those of ``fence_path`` (a ``QGC WPL 110`` fence or an older ``.fen``) and ``rally_path`` (a
    ``QGC WPL 110`` rally file or a ``.ral``), become zones and rally points."""
    path, file, text = read_text(path, "Mission Planner waypoints")
    if not _is_wpl(text):
        raise ScenarioError(file, "line 1", f"not a waypoint file (expected the header {WPL_HEADER!r})")
    got = _read_wpl(file, text, "")
    extras: dict[str, object] = {"format": "qgc-wpl-110"}
    zones, rally, fence_return = list(got.zones), list(got.rally), got.fence_return
    if fence_path is not None:
        fence = _extra_file(fence_path, "fence", _read_fen)
        zones += fence.zones
        fence_return = fence.fence_return or fence_return
        extras["fence_file"] = Path(fence_path)
    if rally_path is not None:
        rally += _extra_file(rally_path, "rally", _read_ral).rally
        extras["rally_file"] = Path(rally_path)
    route = route_of(got.home, got.nav)
    extras["end_command"] = route.end_command
    if fence_return is not None:
        extras["fence_return"] = fence_return
    return OperatorMission(source=path, home=got.home, start=route.start, goal=route.goal, vias=route.vias,
                           zones=tuple(zones), rally=tuple(rally), extras=extras)


def _is_wpl(text: str) -> bool:
    first = next((ln.strip() for ln in text.splitlines() if ln.strip()), "")
    return first.startswith("QGC WPL")


def _extra_file(path: str | Path, what: str, legacy: Callable[[str, str], _Contents]) -> _Contents:
    """A fence or rally file: ``QGC WPL 110`` with only ``what`` items (after the home line), or the older
    Mission Planner format ``legacy`` reads."""
    path, file, text = read_text(path, f"Mission Planner {what}")
    if not _is_wpl(text):
        return legacy(file, text)
    got = _read_wpl(file, text, f"{path.name} ")
    if got.nav:
        it = got.nav[0]
        raise ScenarioError(file, it.where, f"command {it.command} is a mission item, not a {what} item "
                            f"(is this the mission file?)")
    if what == "fence" and got.rally or what == "rally" and (got.zones or got.fence_return):
        raise ScenarioError(file, "", f"holds {'rally' if what == 'fence' else 'fence'} items, not {what} items")
    return got


def _number(file: str, where: str, text: str, integer: bool = False) -> float:
    try:
        return int(text) if integer else float(text)
    except ValueError:
        raise ScenarioError(file, where, f"{text!r} is not {'an integer' if integer else 'a number'}") from None


def wpl_items(file: str, text: str) -> list[WplItem]:
    """Every item line of ``QGC WPL 110`` text (after the header; comments and blank lines skipped)."""
    lines = text.splitlines()
    header = next((i for i, ln in enumerate(lines) if ln.strip()), None)
    if header is None:
        raise ScenarioError(file, "", f"empty (expected the header {WPL_HEADER!r})")
    if lines[header].strip() != WPL_HEADER:
        raise ScenarioError(file, f"line {header + 1}", f"{lines[header].strip()!r} is not supported "
                            f"(expected {WPL_HEADER!r})")
    items = []
    for n, raw in enumerate(lines[header + 1:], start=header + 2):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        where = f"line {n}"
        fields = _FIELDS.split(line)
        if len(fields) != 12:
            raise ScenarioError(file, where, f"{len(fields)} fields (a QGC WPL 110 item has 12: seq, current, "
                                "frame, command, param1..4, lat, lon, alt, autocontinue)")
        seq, _, frame, command = (int(_number(file, where, f, True)) for f in fields[:4])
        values = [_number(file, where, f) for f in fields[4:11]]
        lat, lon, alt = values[4:7]
        if not (math.isfinite(lat) and math.isfinite(lon)):
            raise ScenarioError(file, where, "latitude and longitude must be numbers, not NaN")
        items.append(WplItem(n, seq, frame, command, (values[0], values[1], values[2], values[3]), lat, lon, alt))
    return items


def _read_wpl(file: str, text: str, prefix: str) -> _Contents:
    """Sort a ``QGC WPL 110`` file's items: home (the first item when its seq is 0), route items, fence items
    (polygons of param1 vertices, circles of param1 metres, the return point), rally points. ``prefix`` starts
    zone names (a fence file's name)."""
    items = wpl_items(file, text)
    out = _Contents()
    if items and items[0].seq == 0:
        home, items = items[0], items[1:]
        if home.command in (NAV_WAYPOINT, 0) and located(home.lat, home.lon):
            lat, lon = lat_lon(file, f"line {home.line}", home.lat, home.lon)
            if not math.isfinite(home.alt):
                raise ScenarioError(file, f"line {home.line}", "home's altitude must be a number, not NaN")
            out.home = GeoPoint(lat, lon, Altitude(home.alt, "amsl"))
    k = 0
    while k < len(items):
        it = items[k]
        where = f"line {it.line}"
        if it.command in _POLYGONS:
            k = _polygon(file, items, k, prefix, out)
            continue
        k += 1
        if it.command in _CIRCLES:
            lat, lon = lat_lon(file, where, it.lat, it.lon)
            if not it.params[0] > 0.0:
                raise ScenarioError(file, where, f"a fence circle's radius (param1) is {it.params[0]:g} m; it must "
                                    "be > 0")
            out.zones.append(Zone(f"{prefix}{where}", _CIRCLES[it.command], centre=(lat, lon),
                                  radius_m=it.params[0]))
        elif it.command in (FENCE_RETURN_POINT, NAV_RALLY_POINT):
            lat, lon = lat_lon(file, where, it.lat, it.lon)
            point = GeoPoint(lat, lon, Altitude(it.alt, FRAME_REFS.get(it.frame, "home")))
            if it.command == NAV_RALLY_POINT:
                out.rally.append(point)
            else:
                out.fence_return = point
        elif it.command in POSITION_COMMANDS and located(it.lat, it.lon):
            lat, lon = lat_lon(file, where, it.lat, it.lon)
            if not math.isfinite(it.alt):
                raise ScenarioError(file, where, "a position's altitude must be a number, not NaN")
            out.nav.append(NavItem(where, it.command, GeoPoint(lat, lon, altitude(file, where, it.frame, it.alt))))
        else:
            out.nav.append(NavItem(where, it.command, None))
    return out


def _polygon(file: str, items: list[WplItem], k: int, prefix: str, out: _Contents) -> int:
    """The fence polygon whose first vertex is ``items[k]``: param1 vertices of one command in a row. Returns
    the index after it."""
    first = items[k]
    where = f"line {first.line}"
    count = first.params[0]
    if not (math.isfinite(count) and count >= 3 and count == int(count)):
        raise ScenarioError(file, where, f"a fence polygon's vertex count (param1) is {count:g}; it must be a whole "
                            "number of at least 3")
    n = int(count)
    vertices = items[k:k + n]
    for i, v in enumerate(vertices):
        if v.command != first.command or v.params[0] != count:
            raise ScenarioError(file, f"line {v.line}", f"the polygon starting at {where} has {n} vertices "
                                f"(param1) but {i} are given")
    if len(vertices) < n:
        raise ScenarioError(file, where, f"the polygon has {n} vertices (param1) but the file ends after "
                            f"{len(vertices)}")
    points = [lat_lon(file, f"line {v.line}", v.lat, v.lon) for v in vertices]
    out.zones.append(Zone(f"{prefix}{where}", _POLYGONS[first.command], polygon=ring(file, where, points)))
    return k + n


def _read_fen(file: str, text: str) -> _Contents:
    """An older Mission Planner ``.fen``: the return point, then one inclusion polygon (closed)."""
    points = []
    for n, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        fields = _FIELDS.split(line)
        if len(fields) != 2:
            raise ScenarioError(file, f"line {n}", f"{len(fields)} fields (a fence line is: lat lon)")
        lat, lon = (_number(file, f"line {n}", f) for f in fields)
        points.append((n, lat_lon(file, f"line {n}", lat, lon)))
    if not points:
        raise ScenarioError(file, "", "no fence points (expected the return point, then the polygon)")
    (_, back), vertices = points[0], points[1:]
    where = f"line {vertices[0][0]}" if vertices else f"line {points[0][0]}"
    zone = Zone(f"{Path(file).name} {where}", True, polygon=ring(file, where, [p for _, p in vertices]))
    return _Contents(zones=[zone], fence_return=GeoPoint(back[0], back[1]))


def _read_ral(file: str, text: str) -> _Contents:
    """A Mission Planner ``.ral``: ``RALLY lat lon alt break_alt land_dir flags`` lines."""
    rally = []
    for n, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        fields = _FIELDS.split(line)
        if fields[0] != "RALLY" or len(fields) < 4:
            raise ScenarioError(file, f"line {n}", "not a rally line (expected: RALLY lat lon alt ...)")
        lat, lon, alt = (_number(file, f"line {n}", f) for f in fields[1:4])
        lat, lon = lat_lon(file, f"line {n}", lat, lon)
        rally.append(GeoPoint(lat, lon, Altitude(alt, "home")))
    return _Contents(rally=rally)
