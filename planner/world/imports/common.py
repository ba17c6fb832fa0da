"""What the importers share: reading the file, JSON with its line and column, checked numbers and coordinates,
MAVLink frames and commands, and the route an operator's mission items describe (docs/imports.md).

Every check raises :class:`planner.errors.ScenarioError` (``FILE: WHERE: REASON``, one line), never a traceback.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from planner.errors import ScenarioError
from planner.files import FileRefused, read_regular_file
from planner.world.geo_inputs import LAT_LIMIT_DEG, LON_LIMIT_DEG, Altitude, AltitudeRef, GeoPoint
from planner.world.polygons import simplicity_problem

MAX_IMPORT_BYTES = 64 * 2**20  # a national airspace GeoJSON is tens of MB; a mission file far less
EARTH_RADIUS_M = 6378137.0  # WGS-84 semi-major axis: the local projection that checks a ring's shape

# MAVLink frames a position may be in (plain and _INT twins) and what its altitude is measured from
FRAME_REFS: dict[int, AltitudeRef] = {0: "amsl", 5: "amsl", 3: "home", 6: "home", 10: "ground", 11: "ground"}

# MAV_CMD numbers the importers read (common.xml)
NAV_WAYPOINT, NAV_LOITER_UNLIM, NAV_LOITER_TURNS, NAV_LOITER_TIME = 16, 17, 18, 19
NAV_RETURN_TO_LAUNCH, NAV_LAND, NAV_TAKEOFF, NAV_LOITER_TO_ALT = 20, 21, 22, 31
NAV_SPLINE_WAYPOINT, NAV_VTOL_TAKEOFF, NAV_VTOL_LAND = 82, 84, 85
FENCE_RETURN_POINT, FENCE_POLYGON_INCLUSION, FENCE_POLYGON_EXCLUSION = 5000, 5001, 5002
FENCE_CIRCLE_INCLUSION, FENCE_CIRCLE_EXCLUSION, NAV_RALLY_POINT = 5003, 5004, 5100

# items whose latitude and longitude are a place the vehicle flies to (a take-off climbs where the vehicle is)
POSITION_COMMANDS = {NAV_WAYPOINT: "WAYPOINT", NAV_LOITER_UNLIM: "LOITER_UNLIM", NAV_LOITER_TURNS: "LOITER_TURNS",
                     NAV_LOITER_TIME: "LOITER_TIME", NAV_LAND: "LAND", NAV_LOITER_TO_ALT: "LOITER_TO_ALT",
                     NAV_SPLINE_WAYPOINT: "SPLINE_WAYPOINT", NAV_VTOL_LAND: "VTOL_LAND"}
END_COMMANDS = {NAV_RETURN_TO_LAUNCH: "RETURN_TO_LAUNCH", **POSITION_COMMANDS}  # what a mission may end with
TAKEOFF_COMMANDS = {NAV_TAKEOFF, NAV_VTOL_TAKEOFF}


def read_text(path: str | Path, what: str) -> tuple[Path, str, str]:
    """``(path, file name for messages, text)`` of a UTF-8 file (a byte-order mark is allowed: Windows tools
    write one); anything else is ``FILE: REASON``."""
    path = Path(path)
    file = str(path)
    try:
        data = read_regular_file(path, MAX_IMPORT_BYTES, what)
    except FileRefused as exc:
        raise ScenarioError(file, "", exc.reason) from None
    try:
        return path, file, data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ScenarioError(file, "", f"not UTF-8 text ({exc.reason} at byte {exc.start})") from None


def _refuse_constant(name: str) -> float:
    raise ValueError(f"{name} is not JSON (write a number or null)")


def load_json(file: str, text: str) -> Any:
    """The JSON document in ``text``; malformed JSON is refused with its line and column, and so are ``NaN`` and
    ``Infinity`` (not JSON, though Python reads them) and nesting too deep to walk."""
    try:
        return json.loads(text, parse_constant=_refuse_constant)
    except json.JSONDecodeError as exc:
        raise ScenarioError(file, f"line {exc.lineno} column {exc.colno}", f"malformed JSON: {exc.msg}") from None
    except ValueError as exc:
        raise ScenarioError(file, "", str(exc)) from None
    except RecursionError:
        raise ScenarioError(file, "", "JSON nested too deeply to read") from None


def kind(value: Any) -> str:
    """What a JSON value is, for messages: ``a string``, ``an array`` …"""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "a boolean"
    return {str: "a string", list: "an array", dict: "an object", int: "a number", float: "a number"}.get(
        type(value), type(value).__name__)


def number(file: str, where: str, value: Any) -> float:
    """``value`` as a float when it is a finite JSON number (not a boolean), else ``FILE: WHERE: REASON``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ScenarioError(file, where, f"expected a number, got {kind(value)}")
    if not math.isfinite(value):
        raise ScenarioError(file, where, f"{value} is not a finite number")
    return float(value)


def member(file: str, where: str, obj: Any, key: str, types: type | tuple[type, ...], what: str) -> Any:
    """``obj[key]``, required and of ``types`` (``what`` names them in the message)."""
    if not isinstance(obj, dict):
        raise ScenarioError(file, where, f"expected an object, got {kind(obj)}")
    if key not in obj:
        raise ScenarioError(file, f"{where}.{key}" if where else key, f"missing (expected {what})")
    value = obj[key]
    allowed = types if isinstance(types, tuple) else (types,)
    if not isinstance(value, allowed) or (isinstance(value, bool) and bool not in allowed):
        raise ScenarioError(file, f"{where}.{key}" if where else key, f"expected {what}, got {kind(value)}")
    return value


def lat_lon(file: str, where: str, lat: Any, lon: Any) -> tuple[float, float]:
    """A checked (lat, lon) in degrees: numbers, |lat| ≤ 90, |lon| ≤ 180."""
    lat, lon = number(file, where, lat), number(file, where, lon)
    if abs(lat) > LAT_LIMIT_DEG:
        raise ScenarioError(file, where, f"latitude {lat:g} is outside -{LAT_LIMIT_DEG:g}..{LAT_LIMIT_DEG:g} degrees")
    if abs(lon) > LON_LIMIT_DEG:
        raise ScenarioError(file, where, f"longitude {lon:g} is outside -{LON_LIMIT_DEG:g}..{LON_LIMIT_DEG:g} degrees")
    return lat, lon


def local_metres(lat_lon_deg: np.ndarray) -> np.ndarray:
    """(V, 2) (lat, lon) degrees → (V, 2) east, north metres on an equirectangular projection about the first
    vertex (longitudes unwrapped across the antimeridian): enough to judge a fence or zone ring's shape."""
    p = np.radians(np.asarray(lat_lon_deg, dtype=float).reshape(-1, 2))
    lat0, lon0 = p[0]
    dlon = (p[:, 1] - lon0 + math.pi) % (2.0 * math.pi) - math.pi
    return EARTH_RADIUS_M * np.stack([dlon * math.cos(lat0), p[:, 0] - lat0], axis=-1)


def ring(file: str, where: str, vertices: Sequence[tuple[float, float]]) -> tuple[tuple[float, float], ...]:
    """A polygon's checked (lat, lon) vertices, the closing duplicate (if any) dropped: at least three, and simple
    (:func:`planner.world.polygons.simplicity_problem` on the ring in local metres)."""
    v = list(vertices)
    if len(v) > 1 and v[0] == v[-1]:
        v = v[:-1]
    problem = simplicity_problem(local_metres(np.array(v))) if len(v) >= 3 else \
        f"{len(v)} vertices (a polygon needs at least 3)"
    if problem:
        raise ScenarioError(file, where, f"not a simple polygon: {problem}")
    return tuple(v)


def altitude(file: str, where: str, frame: int, value: float) -> Altitude:
    """A position item's altitude, its reference from the MAVLink frame."""
    if frame not in FRAME_REFS:
        raise ScenarioError(file, where, f"frame {frame} is not supported for a position (use 0 = AMSL, "
                            "3 = relative to home or 10 = above terrain)")
    return Altitude(value, FRAME_REFS[frame])


def check_band(file: str, where: str, floor: Altitude | None, ceiling: Altitude | None,
               names: tuple[str, str] = ("floor_m", "ceiling_m"), unit: str = "") -> None:
    """Refuse a zone whose floor is not below its ceiling when both use one reference (with different references
    only the scenario, knowing home and terrain, can compare them). ``names`` say the two in the file's words."""
    if floor is not None and ceiling is not None and floor.ref == ceiling.ref and floor.value >= ceiling.value:
        raise ScenarioError(file, where, f"{names[0]} {floor.value:g}{unit} is not below {names[1]} "
                            f"{ceiling.value:g}{unit} (both above {floor.ref})")


def located(lat: float, lon: float) -> bool:
    """Whether an item's latitude and longitude are a place: 0, 0 means "here" to ArduPilot (a LAND or a
    LOITER without a position acts where the vehicle is)."""
    return not (lat == 0.0 and lon == 0.0)


@dataclass(frozen=True)
class NavItem:
    """A mission item as the route reader needs it: where it is in the file, its command, and its position
    (None when it has none)."""

    where: str
    command: int
    point: GeoPoint | None


@dataclass(frozen=True)
class Route:
    """The operator's route: start, goal, vias between them, and the command the mission ends with."""

    start: GeoPoint | None
    goal: GeoPoint | None
    vias: tuple[GeoPoint, ...]
    end_command: str | None


def route_of(home: GeoPoint | None, items: Sequence[NavItem]) -> Route:
    """The route in the items: the start is ``home`` (or else the first position), the goal the last position
    item (a RETURN_TO_LAUNCH or a LAND without a position after it ends the mission but is not a place), and the
    positions between are vias. Items without a position (take-off, DO_* and CONDITION_* commands) are skipped,
    and consecutive items at one place count once, at the later one's altitude (a waypoint, then a loiter there)."""
    points: list[GeoPoint] = []
    for it in items:
        if it.point is None:
            continue
        if points and (points[-1].lat, points[-1].lon) == (it.point.lat, it.point.lon):
            points[-1] = it.point
        else:
            points.append(it.point)
    ends = [it for it in items if it.command in END_COMMANDS]
    end_command = END_COMMANDS[ends[-1].command] if ends else None
    start: GeoPoint | None
    if home is not None:
        start, rest = home, points
    else:
        start, rest = (points[0], points[1:]) if points else (None, [])
    goal = rest[-1] if rest else None
    return Route(start, goal, tuple(rest[:-1]), end_command)
