"""Scenario files (``sitl_scenarios/*.toml``) → validated, frozen :class:`Scenario` objects (format:
docs/scenario_format.md; frames and units: docs/method.md §1.1; the reference scenarios: §14)."""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import re
import tomllib
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, TypeAdapter, ValidationError, model_validator
from typing_extensions import TypedDict

from planner.errors import ScenarioError
from planner.files import FileRefused, read_regular_file
from planner.world import dem
from planner.world.config import (
    MAX_COORD,
    MAX_HEIGHT,
    MAX_MAP,
    MAX_RADIUS,
    MAX_THREAT_SPEED,
    MAX_WEIGHT,
    HazardConfig,
    PlannerSettings,
    RelationError,
    VehicleLimits,
)
from planner.world.environment import (
    Cylinders,
    Environment,
    Prisms,
    Radars,
    Spheres,
    Threat,
    Threats,
    radar_detection_range,
)
from planner.world.geographic import LocalFrame, localise
from planner.world.home import Home
from planner.world.polygons import contains, simplicity_problem
from planner.world.terrain import Terrain


@dataclass(frozen=True)
class Intruder:
    """A scripted aircraft for the simulated autopilot (reported as ADSB_VEHICLE; companion issue)."""

    id: str
    icao: int
    waypoints: tuple[tuple[float, float, float], ...]  # ENU metres
    speed: float  # m/s
    start_time: float = 0.0  # s after mission start (unused with ``meet``)
    radius: float = 50.0  # m, protected radius
    meet: tuple[float, float, float] | None = None  # on its path; timed to be there as the vehicle passes


def _xyz(v: Sequence[float]) -> tuple[float, float, float]:
    """A validated 3-vector as a tuple."""
    x, y, z = v
    return x, y, z


def _points(points: Sequence[Sequence[float]]) -> np.ndarray:
    """``points`` as a read-only (k, 3) array of metres."""
    out = np.array(points, dtype=float).reshape(-1, 3)
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)
class Scenario:
    name: str
    source: Path
    home: Home
    environment: Environment
    start: np.ndarray  # (3,) ENU metres
    goal: np.ndarray  # (3,)
    vehicle: VehicleLimits
    hazard: HazardConfig
    planner: PlannerSettings
    intruders: tuple[Intruder, ...] = field(default=())
    description: str = ""
    # where the vehicle's home is, m east and north in the frame: the origin, unless the scenario is geographic
    # with a region (its frame's origin is then the region's south-west corner, ``home`` that corner)
    launch: tuple[float, float] = (0.0, 0.0)
    # (k, 3) ENU metres: points the route passes through in order between start and goal (route.vias)
    vias: np.ndarray = field(default_factory=lambda: _points([]))


# ---------------------------------------------------------------------------------------------------------------
# Loader: TOML → pydantic (shape, types, ranges) → frozen dataclasses → cross-field checks. Format documented in
# docs/scenario_format.md. Every user mistake leaves as ScenarioError(file, dotted.field, reason).
# ---------------------------------------------------------------------------------------------------------------

logger = logging.getLogger(__name__)

TOLERANCE = 1e-6  # m, slack for bounds, altitude band and obstacle surfaces
MAX_DRAWS = 1000  # redraws allowed per random obstacle before giving up
_STRICT_FILE = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True, frozen=True)
# What a scenario may hold, far beyond real use, so that a mistake is one line and not minutes of loading:
# bytes: the largest shipped scenario is 14 kB (257 obstacles), MAX_OBSTACLES cylinders about 5 MB; the largest
# file loads (and is refused for its obstacle count) in 8 s
MAX_SCENARIO_BYTES = 16 * 2**20
MAX_DEPTH = 16  # tables and arrays nested in each other: the format needs 4 (intruders[0].waypoints[1][2])
MAX_OBSTACLES = 100_000  # cylinders, spheres, hemispheres, radars and random ones: 400 times the largest map's 257
MAX_POLYGON_VERTICES = 10_000  # per prism: an airspace boundary digitised at 10 m around a 30 km zone
MAX_MOVERS = 1000  # threats, and intruders: more aircraft than an ADS-B receiver tracks at once
MAX_INTRUDER_WAYPOINTS = 10_000
# route.vias: each is the end of a leg planned on its own; 64 legs of the default 8 waypoints are 576 mission items,
# within the ~700 a mission holds on ArduPilot SITL
MAX_VIAS = 64
MAX_HILLS = 1000  # Gaussian hills of synthetic terrain (the shipped mountain map has 12)
MAX_TERRAIN_NODES = 2**24  # a 100 km map at 25 m (4001², finer than SRTM1's 30 m): 134 MB of heights
MAX_TERRAIN_HEIGHT = 9000.0  # m above home: Everest's summit stands 8849 m above the sea
MAX_TIME = 1e6  # s after mission start (11 days: longer than any drone flies)


def _ordered(pair: list[float]) -> list[float]:
    if pair[0] > pair[1]:
        raise ValueError(f"min ({pair[0]:g}) must not exceed max ({pair[1]:g})")
    return pair


# ranges on every number of the file (the bounds and what they are based on: planner.world.config)
_Coord = Annotated[float, Field(ge=-MAX_COORD, le=MAX_COORD)]  # m, any position on or around the map
_Positive = Annotated[float, Field(gt=0, le=MAX_RADIUS)]  # m, a radius or a width
_NonNegative = Annotated[float, Field(ge=0, le=MAX_RADIUS)]  # m, a clearance
_Height = Annotated[float, Field(ge=0, le=MAX_HEIGHT)]  # m above home or terrain
_Size = Annotated[float, Field(gt=0, le=MAX_MAP)]  # m, a side of the map
_Speed = Annotated[float, Field(gt=0, le=MAX_THREAT_SPEED)]  # m/s of a threat or an intruder
_Vec3 = Annotated[list[_Coord], Field(min_length=3, max_length=3)]
_PositiveRange = Annotated[list[_Positive], Field(min_length=2, max_length=2), AfterValidator(_ordered)]
_HeightRange = Annotated[list[_Height], Field(min_length=2, max_length=2), AfterValidator(_ordered)]
_Ident = Annotated[str, Field(min_length=1, max_length=4096)]  # a name, an id or a path
_Seed = Annotated[int, Field(ge=0, le=2**63 - 1)]
# m between terrain grid nodes (10 cm: finer than any survey); the grid's size is checked against the bounds
_GridSpacing = Annotated[float, Field(ge=0.1, le=MAX_MAP)]


def _strict_table(cls: type) -> type:
    """A TypedDict mirroring a config dataclass (all keys optional), so its table is checked strictly.

    The dataclasses carry their own lax pydantic config; validating the raw table against this mirror first
    rejects strings for numbers etc. with exact field paths, while every default stays in the dataclass.
    """
    hints = typing.get_type_hints(cls)
    fields = {
        f.name: _strict_table(hints[f.name]) if dataclasses.is_dataclass(hints[f.name]) else hints[f.name]
        for f in dataclasses.fields(cls)
    }
    table = TypedDict(f"{cls.__name__}Table", fields, total=False)  # type: ignore[misc]  # made at run time
    table.__pydantic_config__ = _STRICT_FILE  # type: ignore[attr-defined]  # pydantic reads it off the class
    return table


_VehicleTable = _strict_table(VehicleLimits)
_HazardTable = _strict_table(HazardConfig)
_PlannerTable = _strict_table(PlannerSettings)


class _Table(BaseModel):
    model_config = _STRICT_FILE


class _Home(_Table):
    lat: Annotated[float, Field(ge=-90, le=90)]
    lon: Annotated[float, Field(ge=-180, le=180)]
    alt: Annotated[float, Field(ge=-1000, le=MAX_HEIGHT)]  # m above sea level: the Dead Sea shore is at −430 m


class _Bounds(_Table):
    x: _Size
    y: _Size


class _Altitude(_Table):
    min: _Height
    max: Annotated[float, Field(gt=0, le=MAX_HEIGHT)]  # min < max is checked in load_scenario, to name the field


class _Route(_Table):
    start: _Vec3
    goal: _Vec3
    vias: Annotated[list[_Vec3], Field(max_length=MAX_VIAS)] = []


class _Cylinder(_Table):
    x: _Coord
    y: _Coord
    radius: _Positive
    top: Annotated[float, Field(gt=0, le=MAX_COORD)] | None = None  # None → unlimited
    z_ref: _Coord = 0.0  # drawing only


class _Prism(_Table):
    xy: Annotated[list[Annotated[list[_Coord], Field(min_length=2, max_length=2)]],
                  Field(min_length=3, max_length=MAX_POLYGON_VERTICES)]
    floor: _Coord | None = None  # m above home; None → from the ground
    ceiling: _Coord | None = None  # None → unlimited
    keep_in: bool = False  # the region to stay inside (an inclusion fence), at every height
    name: _Ident | None = None

    @model_validator(mode="after")
    def _slab(self) -> _Prism:
        if self.keep_in and (self.floor is not None or self.ceiling is not None):
            raise ValueError("a keep-in polygon has no floor or ceiling (it holds at every height)")
        if self.floor is not None and self.ceiling is not None and self.floor >= self.ceiling:
            raise ValueError(f"floor ({self.floor:g} m) must be below ceiling ({self.ceiling:g} m)")
        return self


class _Sphere(_Table):
    x: _Coord
    y: _Coord
    z: _Coord
    radius: _Positive


class _Hemisphere(_Table):
    x: _Coord
    y: _Coord
    radius: _Positive


RADAR_EQUATION = ("pt_w", "gain", "wavelength_m", "rcs_m2", "ts_k", "bn_hz", "loss", "snr_threshold")


class _Radar(_Table):
    x: _Coord
    y: _Coord
    z: _Coord
    soft_weight: Annotated[float, Field(ge=0, le=MAX_WEIGHT)] = 1.0
    r_det: _Positive | None = None
    # the radar equation's inputs, each bounded past any real radar so that the equation stays finite
    # W: 100 MW, ten times the largest early-warning radars' peak power
    pt_w: Annotated[float, Field(gt=0, le=1e8)] | None = None
    gain: Annotated[float, Field(gt=0, le=1e7)] | None = None  # 70 dBi: above the largest dish antennas
    wavelength_m: Annotated[float, Field(gt=0, le=100.0)] | None = None  # m: HF over-the-horizon radars use 10 to 100 m
    rcs_m2: Annotated[float, Field(gt=0, le=1e6)] | None = None  # m²: a large ship is about 1e4
    ts_k: Annotated[float, Field(gt=0, le=1e6)] | None = None  # K
    bn_hz: Annotated[float, Field(gt=0, le=1e10)] | None = None  # Hz: 10 GHz of bandwidth
    loss: Annotated[float, Field(gt=0, le=1e6)] | None = None  # 60 dB
    snr_threshold: Annotated[float, Field(gt=0, le=1e6)] | None = None  # 60 dB

    @model_validator(mode="after")
    def _one_range_source(self) -> _Radar:
        given = [n for n in RADAR_EQUATION if getattr(self, n) is not None]
        if self.r_det is not None and given:
            raise ValueError(f"give either r_det or the radar-equation parameters, not both (also got {given[0]})")
        if self.r_det is None and len(given) < len(RADAR_EQUATION):
            missing = [n for n in RADAR_EQUATION if n not in given]
            raise ValueError(f"give r_det or all radar-equation parameters (missing {', '.join(missing)})")
        if self.r_det is None:
            try:
                r_det = self.detection_range()
            except (ArithmeticError, ValueError):
                r_det = math.inf
            if not 0 < r_det <= MAX_RADIUS:
                raise ValueError(f"the radar equation gives a detection range of {r_det:g} m, outside (0, "
                                 f"{MAX_RADIUS:g}] m; check its parameters")
        return self

    def detection_range(self) -> float:
        """R_det in metres, given or from the radar equation."""
        if self.r_det is not None:
            return self.r_det
        return radar_detection_range(**{n: getattr(self, n) for n in RADAR_EQUATION})


class _RandomObstacles(_Table):
    seed: _Seed
    count: Annotated[int, Field(ge=0, le=MAX_OBSTACLES)]
    kinds: Annotated[list[Literal["sphere", "cylinder", "hemisphere"]], Field(min_length=1)] = [
        "sphere", "cylinder", "hemisphere"]
    radius: _PositiveRange
    height: _HeightRange  # sphere centre z; cylinder z_ref (drawing)
    clearance: _NonNegative = 150.0


class _FlatTerrain(_Table):
    kind: Literal["none"]


class _HillsTerrain(_Table):
    kind: Literal["hills"]
    seed: _Seed
    count: Annotated[int, Field(ge=1, le=MAX_HILLS)]
    max_height: Annotated[float, Field(gt=0, le=MAX_TERRAIN_HEIGHT)]
    sigma: _PositiveRange
    spacing: _GridSpacing = 25.0


class _FileTerrain(_Table):
    kind: Literal["file"]
    path: _Ident
    spacing: _GridSpacing = 30.0  # resampling grid for .hgt; ESRI grids keep their own cellsize


class _Loiter(_Table):
    kind: Literal["loiter"]
    id: _Ident
    radius: _Positive
    center: _Vec3
    circle_radius: _Positive
    speed: _Speed
    phase_deg: Annotated[float, Field(ge=-360, le=360)] | None = None
    direction: Literal["ccw", "cw"] | None = None

    def to_threat(self) -> Threat:
        optional: _LoiterOptions = {}
        if self.phase_deg is not None:
            optional["phase"] = math.radians(self.phase_deg)
        if self.direction is not None:
            optional["direction"] = 1.0 if self.direction == "ccw" else -1.0
        return Threat(self.id, "loiter", self.radius, _xyz(self.center), speed=self.speed,
                      circle_radius=self.circle_radius, **optional)


class _LoiterOptions(TypedDict, total=False):
    phase: float
    direction: float


class _Patrol(_Table):
    kind: Literal["patrol"]
    id: _Ident
    radius: _Positive
    a: _Vec3
    b: _Vec3
    speed: _Speed

    def to_threat(self) -> Threat:
        return Threat(self.id, "patrol", self.radius, _xyz(self.a), _xyz(self.b), speed=self.speed)


class _MeetOption(TypedDict, total=False):
    meet: tuple[float, float, float]


class _Intruder(_Table):
    id: _Ident
    icao: Annotated[int, Field(ge=0, le=0xFFFFFF)]
    waypoints: Annotated[list[_Vec3], Field(min_length=2, max_length=MAX_INTRUDER_WAYPOINTS)]
    speed: _Speed
    start_time: Annotated[float, Field(ge=0, le=MAX_TIME)] | None = None
    radius: _Positive | None = None
    meet: _Vec3 | None = None

    def to_intruder(self) -> Intruder:
        optional = self.model_dump(include={"start_time", "radius"}, exclude_none=True)
        meet: _MeetOption = {"meet": _xyz(self.meet)} if self.meet is not None else {}
        return Intruder(self.id, self.icao, tuple(_xyz(w) for w in self.waypoints), self.speed, **optional, **meet)


_TerrainTable = Annotated[_FlatTerrain | _HillsTerrain | _FileTerrain, Field(discriminator="kind")]
_ThreatTable = Annotated[_Loiter | _Patrol, Field(discriminator="kind")]
_UNION_TAGS = {"terrain": {"none", "hills", "file"}, "threats": {"loiter", "patrol"}}


class _ScenarioFile(_Table):
    name: _Ident | None = None
    description: Annotated[str, Field(max_length=10_000)] | None = None
    home: _Home
    bounds: _Bounds
    altitude: _Altitude
    route: _Route
    vehicle: _VehicleTable = Field(default_factory=dict)  # type: ignore[valid-type]  # a TypedDict made at run time
    hazard: _HazardTable = Field(default_factory=dict)  # type: ignore[valid-type]  # a TypedDict made at run time
    planner: _PlannerTable = Field(default_factory=dict)  # type: ignore[valid-type]  # a TypedDict made at run time
    cylinders: list[_Cylinder] = []
    prisms: list[_Prism] = []
    spheres: list[_Sphere] = []
    hemispheres: list[_Hemisphere] = []
    radars: list[_Radar] = []
    random_obstacles: _RandomObstacles | None = None
    terrain: _TerrainTable | None = None
    threats: Annotated[list[_ThreatTable], Field(max_length=MAX_MOVERS)] = []
    intruders: Annotated[list[_Intruder], Field(max_length=MAX_MOVERS)] = []


def _field_path(loc: tuple[int | str, ...]) -> str:
    """Pydantic ``loc`` → ``cylinders[2].radius`` (discriminator tags dropped)."""
    out = ""
    for i, item in enumerate(loc):
        if isinstance(item, int):
            out += f"[{item}]"
        elif i > 0 and item in _UNION_TAGS.get(str(loc[0]), ()) and (i == 1 or isinstance(loc[i - 1], int)):
            continue
        else:
            name = str(item)
            if not re.fullmatch(r"[A-Za-z0-9_-]+", name):  # a key TOML would have to quote: quote it, one line
                name = json.dumps(name)
            out += f".{name}" if out else name
    return out


def _reason(error: Mapping[str, Any]) -> str:
    """One short line for a pydantic error."""
    kind = error["type"]
    if kind in ("extra_forbidden", "unexpected_keyword_argument"):
        return "unknown key (not part of the scenario format; check the spelling)"
    if kind == "missing":
        return "required key is missing"
    msg = str(error["msg"]).removeprefix("Value error, ")
    value = error.get("input")
    if kind.endswith("_type") and isinstance(value, (str, int, float, bool)):
        msg += f" (got {type(value).__name__} {value!r})"
    return " ".join(msg.split())


def _from_validation_error(file: str, exc: ValidationError, prefix: tuple[int | str, ...] = ()) -> ScenarioError:
    first = exc.errors()[0]
    if len(exc.errors()) > 1:
        logger.debug("%s: %d validation errors, reporting the first", file, len(exc.errors()))
    relation = first.get("ctx", {}).get("error")
    if isinstance(relation, RelationError):  # a rule between two fields: blame the field it names
        return ScenarioError(file, _field_path(prefix + tuple(first["loc"]) + (relation.field_name,)),
                             relation.reason)
    return ScenarioError(file, _field_path(prefix + tuple(first["loc"])), _reason(first))


# --- nesting ---------------------------------------------------------------------------------------------------


def too_deep(value: Any, limit: int = MAX_DEPTH) -> tuple[int | str, ...] | None:
    """The path to a table or array nested more than ``limit`` levels deep in ``value`` (the outermost counts as
    one), or None. Iterative, so that a deep value cannot exhaust the stack here as it would in recursive code."""
    stack: list[tuple[tuple[int | str, ...], Any]] = [((), value)]
    while stack:
        path, node = stack.pop()
        if isinstance(node, (dict, list)):
            if len(path) >= limit:
                return path
            stack.extend((path + (k,), v) for k, v in (node.items() if isinstance(node, dict) else enumerate(node)))
    return None


def _toml(text: str) -> dict[str, Any]:
    """``tomllib.loads``, with its recursion on nested arrays and inline tables (about a thousand levels exhaust
    the stack) turned into a :class:`ValueError`; nesting within :data:`MAX_DEPTH` is checked by the caller."""
    try:
        return tomllib.loads(text)
    except RecursionError:
        raise ValueError(f"arrays or tables nested far deeper than {MAX_DEPTH} levels") from None


def _short(text: str, limit: int = 60) -> str:
    """``text`` quoted for a one-line message, cut to about ``limit`` characters."""
    return repr(text) if len(text) <= limit else repr(text[: limit - 3]) + "..."


# --- overrides -------------------------------------------------------------------------------------------------

_KEY_STEP = re.compile(r"([A-Za-z0-9_-]+)(?:\[(\d+)\])?")


def _parse_override(text: str) -> tuple[list[str | int], Any]:
    """``"planner.pso.n_pop=100"`` → (["planner", "pso", "n_pop"], 100); the value is read as a TOML value."""
    key, sep, value_text = text.partition("=")
    if not sep or not key.strip():
        raise ValueError(f"expected KEY=VALUE, got {_short(text)}")
    steps: list[str | int] = []
    parts = key.strip().split(".")
    if len(parts) > MAX_DEPTH:
        raise ValueError(f"key {_short(key.strip())} is nested deeper than {MAX_DEPTH} levels")
    for part in parts:
        match = _KEY_STEP.fullmatch(part.strip())
        if match is None:
            raise ValueError(f"bad key {_short(key.strip())} in {_short(text)} (use section.key or list[index].key)")
        steps.append(match[1])
        if match[2] is not None:
            steps.append(int(match[2]))
    value_text = value_text.strip()
    if not value_text or "\n" in value_text:
        raise ValueError(f"missing or multi-line value in {_short(text)}")
    try:
        value = _toml(f"v = {value_text}")["v"]
    except tomllib.TOMLDecodeError:
        value = value_text  # a bare word, e.g. vehicle.type=copter
    except ValueError as exc:
        raise ValueError(f"{exc} in the value of {_short(key.strip())}") from None
    if too_deep(value) is not None:
        raise ValueError(f"arrays or tables nested deeper than {MAX_DEPTH} levels in the value of "
                         f"{_short(key.strip())}")
    return steps, value


def _apply_override(raw: dict[str, Any], text: str) -> None:
    """Set one ``KEY=VALUE`` in the raw TOML dict, creating missing tables."""
    steps, value = _parse_override(text)
    node: Any = raw
    for depth, (step, nxt) in enumerate(zip(steps[:-1], steps[1:])):
        where = ".".join(str(s) for s in steps[: depth + 1])
        if isinstance(step, str):
            if not isinstance(node, dict):
                raise ValueError(f"{where} is not a table in {_short(text)}")
            if step not in node and isinstance(nxt, str):
                node[step] = {}
            if step not in node:
                raise ValueError(f"{where} does not exist in {_short(text)}")
            node = node[step]
        else:
            if not isinstance(node, list) or not -len(node) <= step < len(node):
                raise ValueError(f"index {step} out of range in {_short(text)}")
            node = node[step]
    last = steps[-1]
    if isinstance(last, str) and isinstance(node, dict):
        node[last] = value
    elif isinstance(last, int) and isinstance(node, list) and -len(node) <= last < len(node):
        node[last] = value
    else:
        raise ValueError(f"cannot set {steps[-1]!r} in {_short(text)}: parent is not a table or index out of range")


# --- building --------------------------------------------------------------------------------------------------


@dataclass
class _Obstacles:
    """Obstacle columns being assembled, with a human label per entry for error messages."""

    cyl: list[tuple[float, float, float, float, float]] = field(default_factory=list)  # x, y, r, top, z_ref
    cyl_labels: list[str] = field(default_factory=list)
    sph: list[tuple[float, float, float, float]] = field(default_factory=list)  # x, y, z, r
    sph_labels: list[str] = field(default_factory=list)


def _random_obstacles(
    spec: _RandomObstacles, size: tuple[float, float], keep_clear: np.ndarray, obstacles: _Obstacles, file: str,
) -> None:
    """Append ``spec.count`` seeded obstacles, redrawing any closer than ``clearance`` to ``keep_clear`` (k, 3) m."""
    rng = np.random.default_rng(spec.seed)
    for i in range(spec.count):
        kind = spec.kinds[int(rng.integers(len(spec.kinds)))]
        for _ in range(MAX_DRAWS):
            x, y = rng.uniform(0.0, size[0]), rng.uniform(0.0, size[1])
            (r_lo, r_hi), (h_lo, h_hi) = spec.radius, spec.height
            r, h = rng.uniform(r_lo, r_hi), rng.uniform(h_lo, h_hi)
            z = h if kind == "sphere" else 0.0
            if kind == "cylinder":
                gap = np.hypot(keep_clear[:, 0] - x, keep_clear[:, 1] - y) - r
            else:
                gap = np.linalg.norm(keep_clear - (x, y, z), axis=1) - r
            if gap.min() >= spec.clearance:
                break
        else:
            raise ScenarioError(file, "random_obstacles", f"could not place obstacle {i} {spec.clearance:g} m clear "
                                f"of start and goal in {MAX_DRAWS} draws; lower clearance, radius or count")
        label = f"random_obstacles #{i} ({kind} x={x:.0f}, y={y:.0f}, r={r:.0f})"
        if kind == "cylinder":
            obstacles.cyl.append((x, y, r, math.inf, h))
            obstacles.cyl_labels.append(label)
        else:
            obstacles.sph.append((x, y, z, r))
            obstacles.sph_labels.append(label)


def _build_terrain(spec: _FlatTerrain | _HillsTerrain | _FileTerrain | None, bounds: _Bounds, home: Home,
                   source: Path, file: str) -> Terrain | None:
    """The scenario's DEM in metres above home, or None for flat ground."""
    if spec is None or isinstance(spec, _FlatTerrain):
        return None
    nodes = dem.grid_nodes(bounds.x, bounds.y, spec.spacing)
    resampled = isinstance(spec, _HillsTerrain) or Path(spec.path).suffix.lower() == ".hgt"
    if resampled and nodes > MAX_TERRAIN_NODES:
        raise ScenarioError(file, "terrain.spacing", f"{spec.spacing:g} m on a {bounds.x:g} × {bounds.y:g} m map "
                            f"gives {nodes:.3g} terrain grid nodes (limit {MAX_TERRAIN_NODES:.3g}): raise "
                            "terrain.spacing or shrink the map")
    if isinstance(spec, _HillsTerrain):
        try:
            return dem.synthetic_hills(bounds.x, bounds.y, np.random.default_rng(spec.seed), spec.count,
                                       spec.max_height, (spec.sigma[0], spec.sigma[1]), spec.spacing)
        except ValueError as exc:
            raise ScenarioError(file, "terrain", str(exc)) from exc
    dem_path = Path(spec.path)
    if not dem_path.is_absolute():
        dem_path = source.parent / dem_path
    try:
        if dem_path.suffix.lower() == ".hgt":
            terrain = dem.read_hgt(dem_path, home, bounds.x, bounds.y, spec.spacing)
        elif dem_path.suffix.lower() in (".asc", ".txt"):
            terrain = dem.read_esri_ascii(dem_path, home)
        else:
            raise ValueError(f"{dem_path.name}: unknown DEM format (use an SRTM .hgt or an ESRI ASCII .asc file)")
    except ValueError as exc:
        raise ScenarioError(file, "terrain.path", str(exc)) from exc
    ny, nx = terrain.heights.shape
    x1, y1 = terrain.x0 + (nx - 1) * terrain.dx, terrain.y0 + (ny - 1) * terrain.dy
    if terrain.x0 > 0 or terrain.y0 > 0 or x1 < bounds.x or y1 < bounds.y:
        logger.warning("%s: terrain grid [%g, %g]×[%g, %g] m does not cover the bounds; edge heights extend",
                       file, terrain.x0, x1, terrain.y0, y1)
    return terrain


MIN_ROUTE_LENGTH = 10.0  # m between start and goal, and between consecutive points of the route through its vias


def _check_leg_lengths(file: str, start: np.ndarray, vias: np.ndarray, goal: np.ndarray) -> None:
    """Each leg (start → vias[0] → … → goal) at least MIN_ROUTE_LENGTH long: a leg is planned on its own."""
    names = ["route.start", *(f"route.vias[{i}]" for i in range(len(vias))), "route.goal"]
    points = np.vstack([start, vias, goal])
    for k in range(1, len(points)):
        if np.linalg.norm(points[k] - points[k - 1]) < MIN_ROUTE_LENGTH:
            raise ScenarioError(file, names[k], f"must be at least {MIN_ROUTE_LENGTH:g} m from {names[k - 1]}")


def _check_point(file: str, name: str, p: np.ndarray, env: Environment, obstacles: _Obstacles,
                 radar_labels: list[str], prism_labels: list[str]) -> None:
    """A route point (start, via, goal) must lie inside the bounds, inside the altitude band over terrain and outside
    every obstacle."""
    field_name = f"route.{name}"
    x, y, z = (float(v) for v in p)
    for axis, value, size in (("x", x, env.size_x), ("y", y, env.size_y)):
        if not -TOLERANCE <= value <= size + TOLERANCE:
            raise ScenarioError(file, field_name, f"{axis}={value:g} outside bounds [0, {size:g}] m")
    above = z - float(env.ground(x, y))
    if not env.z_min - TOLERANCE <= above <= env.z_max + TOLERANCE:
        raise ScenarioError(file, field_name, f"z={z:g} m is {above:.1f} m above terrain, outside the altitude "
                            f"band [{env.z_min:g}, {env.z_max:g}] m")
    cyl, sph, rad = env.cylinders, env.spheres, env.radars
    hits = (
        ((np.hypot(cyl.x - x, cyl.y - y) < cyl.radius - TOLERANCE) & (z < cyl.top), obstacles.cyl_labels),
        (np.linalg.norm(sph.center - p, axis=1) < sph.radius - TOLERANCE, obstacles.sph_labels),
        (np.linalg.norm(rad.center - p, axis=1) < rad.r_det - TOLERANCE, radar_labels),
    )
    for inside, labels in hits:
        if np.any(inside):
            raise ScenarioError(file, field_name, f"inside {labels[int(np.flatnonzero(inside)[0])]}")
    prisms = env.prisms
    for k in range(len(prisms)):
        within = bool(contains(prisms.polygon(k), p[:2]))
        if prisms.keep_in[k] and not within:
            raise ScenarioError(file, field_name, f"outside {prism_labels[k]}")
        if not prisms.keep_in[k] and within and prisms.floor[k] <= z <= prisms.ceiling[k]:
            raise ScenarioError(file, field_name, f"inside {prism_labels[k]}")


MEET_TOLERANCE_M = 1.0  # an intruder's meet point must lie this close to its path


def _check_meet_points(file: str, spec: _ScenarioFile) -> None:
    """An intruder timed by ``meet`` has no ``start_time``, and ``meet`` lies on its path."""
    for i, it in enumerate(spec.intruders):
        if it.meet is None:
            continue
        if it.start_time is not None:
            raise ScenarioError(file, f"intruders[{i}].start_time", "give start_time or meet, not both")
        pts, m = np.asarray(it.waypoints, dtype=float), np.asarray(it.meet, dtype=float)
        a, ab = pts[:-1], np.diff(pts, axis=0)
        u = np.clip(np.einsum("ij,ij->i", m - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12), 0, 1)
        off = float(np.min(np.linalg.norm(a + u[:, None] * ab - m, axis=1)))
        if off > MEET_TOLERANCE_M:
            raise ScenarioError(file, f"intruders[{i}].meet", f"must lie on the intruder's path ({off:.1f} m off it)")


def _check_obstacle_count(file: str, spec: _ScenarioFile) -> None:
    """At most MAX_OBSTACLES obstacles in all, blaming the key that holds most of them."""
    counts = {"cylinders": len(spec.cylinders), "prisms": len(spec.prisms), "spheres": len(spec.spheres),
              "hemispheres": len(spec.hemispheres),
              "radars": len(spec.radars),
              "random_obstacles.count": spec.random_obstacles.count if spec.random_obstacles is not None else 0}
    total = sum(counts.values())
    if total > MAX_OBSTACLES:
        raise ScenarioError(file, max(counts, key=counts.__getitem__), f"{total} obstacles in all (cylinders, "
                            f"prisms, spheres, hemispheres, radars and random ones) is more than the {MAX_OBSTACLES} a "
                            "scenario may hold")


def _check_unique_ids(file: str, spec: _ScenarioFile) -> None:
    """Threat and intruder ids share one namespace (the companion tracks both by id)."""
    seen: dict[str, str] = {}
    entries = [(f"threats[{i}].id", t.id) for i, t in enumerate(spec.threats)]
    entries += [(f"intruders[{i}].id", t.id) for i, t in enumerate(spec.intruders)]
    for where, ident in entries:
        if ident in seen:
            raise ScenarioError(file, where, f"duplicate id {ident!r} (also {seen[ident]})")
        seen[ident] = where.removesuffix(".id")


def read_scenario_bytes(path: Path) -> bytes:
    """The scenario file's bytes: a regular file of at most :data:`MAX_SCENARIO_BYTES`, else ``FILE: REASON``."""
    try:
        return read_regular_file(path, MAX_SCENARIO_BYTES, "scenario")
    except FileRefused as exc:
        raise ScenarioError(str(path), "", exc.reason) from None


def _read_toml(path: Path, file: str) -> dict[str, Any]:
    """The file's TOML; refused in one line when it is not a regular file of at most MAX_SCENARIO_BYTES, not
    UTF-8 TOML, or nested deeper than MAX_DEPTH (before any recursive code sees it)."""
    data = read_scenario_bytes(path)
    try:
        raw = _toml(data.decode("utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(file, "", f"malformed TOML: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise ScenarioError(file, "", f"not UTF-8 text ({exc.reason} at byte {exc.start})") from exc
    except ValueError as exc:
        raise ScenarioError(file, "", str(exc)) from None
    deep = too_deep(raw)
    if deep is not None:
        raise ScenarioError(file, _field_path(deep), f"arrays or tables nested deeper than {MAX_DEPTH} levels")
    return raw


def _raw_with_overrides(path: Path, overrides: Sequence[str]) -> dict[str, Any]:
    """The file's TOML as a dict with ``overrides`` applied in order (a bad one: ``FILE: --set: REASON``)."""
    raw = _read_toml(path, str(path))
    for text in overrides:
        try:
            _apply_override(raw, text)
        except ValueError as exc:
            raise ScenarioError(str(path), "--set", str(exc)) from exc
    return raw


def named_files(path: str | Path, overrides: Sequence[str] = ()) -> dict[str, Path]:
    """The files a scenario names (a terrain DEM), by the key that names them, resolved as :func:`load_scenario`
    resolves them: what a run needs beside the scenario's text on a machine without the file's folder."""
    path = Path(path)
    raw = _raw_with_overrides(path, overrides)
    terrain = raw.get("terrain")
    if not (isinstance(terrain, dict) and terrain.get("kind") == "file" and isinstance(terrain.get("path"), str)):
        return {}
    dem = Path(terrain["path"])
    return {"terrain.path": dem if dem.is_absolute() else path.parent / dem}


def _in_local_metres(raw: dict[str, Any], path: Path, file: str) -> tuple[dict[str, Any], LocalFrame | None]:
    """The raw scenario with its geographic values in local metres (:func:`planner.world.geographic.localise`),
    and its frame with the terrain built on it; the raw scenario as it is when its home or terrain is malformed
    (the full check names them)."""
    try:
        home_spec = _Home.model_validate(raw.get("home"))
        terrain_spec: _FlatTerrain | _HillsTerrain | _FileTerrain | None = \
            TypeAdapter(_TerrainTable | None).validate_python(raw.get("terrain"))
    except ValidationError:
        return raw, None
    home = Home(home_spec.lat, home_spec.lon, home_spec.alt)

    def ground(origin: Home, size_x: float, size_y: float) -> Terrain | None:
        try:
            bounds = _Bounds(x=size_x, y=size_y)
        except ValidationError as exc:
            raise _from_validation_error(file, exc, ("bounds",)) from exc
        return _build_terrain(terrain_spec, bounds, origin, path, file)

    return localise(raw, file, home, ground)


def _prisms(file: str, spec: _ScenarioFile) -> tuple[Prisms, list[str]]:
    """The scenario's prisms, each polygon checked to be simple, with a label per prism for messages."""
    labels = []
    for i, p in enumerate(spec.prisms):
        problem = simplicity_problem(np.asarray(p.xy, dtype=float))
        if problem is not None:
            raise ScenarioError(file, f"prisms[{i}].xy", f"not a simple polygon: {problem}")
        what = "keep-in polygon" if p.keep_in else "polygon"
        labels.append(f"prisms[{i}] ({what}{f' {p.name}' if p.name else ''}, {len(p.xy)} vertices)")
    prisms = Prisms.from_polygons([np.asarray(p.xy, dtype=float) for p in spec.prisms],
                                  [-math.inf if p.floor is None else p.floor for p in spec.prisms],
                                  [math.inf if p.ceiling is None else p.ceiling for p in spec.prisms],
                                  [p.keep_in for p in spec.prisms])
    return prisms, labels


def load_scenario(path: str | Path, overrides: Sequence[str] = ()) -> Scenario:
    """Read, validate and build a scenario; ``overrides`` are ``section.key=value`` strings applied before checks.

    Raises :class:`ScenarioError` (``FILE: FIELD: REASON``) for every problem in the file or an override.
    """
    path = Path(path)
    file = str(path)
    raw = _raw_with_overrides(path, overrides)
    raw, frame = _in_local_metres(raw, path, file)
    try:
        spec = _ScenarioFile.model_validate(raw)
    except ValidationError as exc:
        raise _from_validation_error(file, exc) from exc
    sections: dict[str, Any] = {}
    for key, cls in (("vehicle", VehicleLimits), ("hazard", HazardConfig), ("planner", PlannerSettings)):
        try:
            sections[key] = TypeAdapter(cls).validate_python(getattr(spec, key))
        except ValidationError as exc:
            raise _from_validation_error(file, exc, (key,)) from exc
    vehicle, hazard, planner = sections["vehicle"], sections["hazard"], sections["planner"]
    if spec.altitude.min >= spec.altitude.max:
        raise ScenarioError(file, "altitude.min", f"{spec.altitude.min:g} m must be below altitude.max "
                            f"({spec.altitude.max:g} m)")
    _check_unique_ids(file, spec)
    _check_meet_points(file, spec)
    _check_obstacle_count(file, spec)

    start = np.array(spec.route.start, dtype=float)
    goal = np.array(spec.route.goal, dtype=float)
    vias = _points(spec.route.vias)
    _check_leg_lengths(file, start, vias, goal)
    home = Home(spec.home.lat, spec.home.lon, spec.home.alt)
    obstacles = _Obstacles()
    for i, c in enumerate(spec.cylinders):
        obstacles.cyl.append((c.x, c.y, c.radius, math.inf if c.top is None else c.top, c.z_ref))
        obstacles.cyl_labels.append(f"cylinders[{i}] (x={c.x:g}, y={c.y:g}, r={c.radius:g})")
    for i, s in enumerate(spec.spheres):
        obstacles.sph.append((s.x, s.y, s.z, s.radius))
        obstacles.sph_labels.append(f"spheres[{i}] (x={s.x:g}, y={s.y:g}, z={s.z:g}, r={s.radius:g})")
    for i, h in enumerate(spec.hemispheres):
        obstacles.sph.append((h.x, h.y, 0.0, h.radius))
        obstacles.sph_labels.append(f"hemispheres[{i}] (x={h.x:g}, y={h.y:g}, r={h.radius:g})")
    if spec.random_obstacles is not None:
        _random_obstacles(spec.random_obstacles, (spec.bounds.x, spec.bounds.y), np.vstack([start, goal, vias]),
                          obstacles, file)
    prisms, prism_labels = _prisms(file, spec)
    r_det = [r.detection_range() for r in spec.radars]
    radar_labels = [f"radars[{i}] detection range (x={r.x:g}, y={r.y:g}, z={r.z:g}, r_det={d:.0f})"
                    for i, (r, d) in enumerate(zip(spec.radars, r_det))]

    cyl = np.array(obstacles.cyl, dtype=float).reshape(-1, 5)
    sph = np.array(obstacles.sph, dtype=float).reshape(-1, 4)
    environment = Environment(
        size_x=spec.bounds.x, size_y=spec.bounds.y, z_min=spec.altitude.min, z_max=spec.altitude.max,
        cylinders=Cylinders(cyl[:, 0], cyl[:, 1], cyl[:, 2], cyl[:, 3], cyl[:, 4]),
        spheres=Spheres(sph[:, :3], sph[:, 3]),
        radars=Radars([(r.x, r.y, r.z) for r in spec.radars], r_det, [r.soft_weight for r in spec.radars]),
        prisms=prisms,
        terrain=frame.terrain if frame is not None else _build_terrain(spec.terrain, spec.bounds, home, path, file),
        threats=Threats(tuple(t.to_threat() for t in spec.threats)),
    )
    named = [("start", start), *((f"vias[{i}]", v) for i, v in enumerate(vias)), ("goal", goal)]
    for name, point in named:
        _check_point(file, name, point, environment, obstacles, radar_labels, prism_labels)
    start.setflags(write=False)
    goal.setflags(write=False)
    optional = {"description": spec.description} if spec.description is not None else {}
    scenario = Scenario(
        name=spec.name or path.stem, source=path, home=home, environment=environment, start=start, goal=goal,
        vehicle=vehicle, hazard=hazard, planner=planner,
        intruders=tuple(i.to_intruder() for i in spec.intruders), **optional,
        launch=(0.0, 0.0) if frame is None else frame.home_xy, vias=vias,
    )
    logger.info("loaded scenario %s from %s: %d cylinders, %d prisms, %d spheres, %d radars, %d threats, "
                "%d intruders", scenario.name, file, len(environment.cylinders), len(environment.prisms),
                len(environment.spheres), len(environment.radars), len(environment.threats), len(scenario.intruders))
    return scenario
