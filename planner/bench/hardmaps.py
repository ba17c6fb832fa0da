"""Hard maps with a known answer (issue 15): map families, each with a planted flyable route.

The route is drawn first and verified with the planner's own checker (docs/method.md §11 smoothing, §12 check);
the obstacles come second and leave a corridor around it, so a failure on these maps is the planner's, never the
map's. Families (docs/method.md §2 for the obstacle kinds):

- ``gates``: walls of no-fly cylinders with one gap each, on alternating sides;
- ``dense``: a clustered field of mostly unlimited cylinders, with spheres and hemispheres at route heights;
- ``maze``: a perfect maze whose walls are chains of unlimited cylinders; the route is its unique solution;
- ``ridge``: a ridge of hemispherical peaks above the altitude band with one saddle, and radars on the summits
  flanking it, so the only way across is through the saddle, low;
- ``canyon``: a narrow meandering channel between two chains of unlimited cylinders running edge to edge.

Terrain families (issue 34): the ground is a DEM, an ESRI ASCII grid written beside the scenario
(``HardMap.dem``, ``[terrain] kind = "file"``), and the altitude band (:data:`TERRAIN_BAND`, above the ground) is
lower than the terrain it must get past, so the barrier is the climb limit, not an obstacle:

- ``valley``: a winding valley cut into a plateau, edge to edge; its walls rise far above the band's ceiling,
  too steep to spiral up and too high to climb along, so the only way is along the valley floor;
- ``saddle``: a ridge across the start→goal direction, too high and steep to cross but at one saddle (a pass);
- ``saddle_radar``: the same with radars on the two summits flanking the saddle, which cap the pass from above;
- ``mixed``: rolling hills with steep mountains off the planted route, unlimited cylinders and a radar.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from planner.problem import PlanningProblem
from planner.search.roadmap import densify
from planner.trajectory.checks import check_trajectory, obstacle_clearance, radar_clearance, smooth
from planner.trajectory.smoothing import flown_deviation, segment_samples
from planner.world.config import HazardConfig, PlannerSettings, VehicleLimits
from planner.world.dem import grid_axis, parse_esri_ascii
from planner.world.environment import Cylinders, Environment, Radars, Spheres
from planner.world.geometry import cylinder_signed_distance, horizontal_turn
from planner.world.home import Home
from planner.world.terrain import Terrain
from planner.world.toml_text import Fixed, Table, dumps

OBSTACLE_FAMILIES = ("gates", "dense", "maze", "ridge", "canyon")
TERRAIN_FAMILIES = ("valley", "saddle", "saddle_radar", "mixed")
FAMILIES = OBSTACLE_FAMILIES + TERRAIN_FAMILIES
BAND = (50.0, 300.0)  # altitude band above terrain, m
TERRAIN_BAND = (30.0, 150.0)  # the terrain families' band, m above the ground: low, under the terrain around
DEM_CELL_M = 25.0  # node spacing of the terrain families' DEM (heights written to 0.1 m)
DEM_NOTE = "ESRI ASCII grid beside this file: ENU metres from home, heights m AMSL (docs/scenario_format.md)"
HAZARD = HazardConfig(d_safe=60.0, d_coll=15.0)  # as sitl_scenarios/large_obstacle_field.toml
BUFFER_M = 10.0  # extra corridor beyond d_coll and the tracking margin
CHORD_STEP_M = 5.0  # spacing of the samples on the waypoint chords
MAX_ROUTE_DRAWS = 200
HOME = (-35.363261, 149.165230, 584.0)  # ArduPilot SITL's default site, as in sitl_scenarios/
_SPACING = PlannerSettings().sample_spacing  # the checker's sample spacing


@dataclass(frozen=True, eq=False)
class HardMap:
    """A generated scenario (``toml``, the full file text) and its planted route ``planted`` (N, 3), ENU m,
    start and goal included. ``straight_blocked``: the straight start→goal segment comes within d_coll of an
    obstacle (the map is not trivial)."""

    family: str
    seed: int
    toml: str
    planted: np.ndarray
    n_obstacles: int
    straight_blocked: bool
    dem: str = ""  # the terrain families' DEM: the text of the ESRI ASCII grid the scenario names ("" for none)
    dem_name: str = ""  # its file name, beside the scenario ([terrain] path)

    @property
    def name(self) -> str:
        return f"hardmap_{self.family}_{self.seed}"

    def write(self, directory: str | Path) -> Path:
        """Write the scenario to ``directory`` as ``{name}.toml`` (its text) and its DEM beside it,
        the DEM first (a scenario file on disk has its DEM); returns the scenario's path."""
        out = Path(directory)
        if self.dem:
            (out / self.dem_name).write_text(self.dem, encoding="ascii")
        path = out / f"{self.name}.toml"
        path.write_text(self.toml)
        return path


def generate(family: str, seed: int, **options: Any) -> HardMap:
    """Generate the map of ``family`` for ``seed``; every random draw comes from ``np.random.default_rng(seed)``,
    so the same seed gives the same text and route. ``options`` go to the family's generator."""
    if family not in _GENERATORS:
        raise ValueError(f"unknown family {family!r}; expected one of {FAMILIES}")
    return _GENERATORS[family](seed, np.random.default_rng(seed), **options)


def write_scenarios(directory: str | Path, families: Sequence[str] = FAMILIES, seeds: Iterable[int] = (0,),
                    ) -> list[Path]:
    """Write the map of every family and seed to ``directory`` (created if missing) as
    ``hardmap_{family}_{seed}.toml``, the text exactly ``HardMap.toml`` (as the shipped ones in sitl_scenarios/;
    the default planner, the roadmap pipeline, plans them), and the terrain families'
    DEM beside it as ``hardmap_{family}_{seed}.asc`` (``HardMap.write``), so the bench and ``fuseplan plan`` can
    read them like any scenario; returns the scenario paths in the order written (families outer, seeds inner)."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    seeds = tuple(seeds)
    return [generate(family, seed).write(out)
            for family in families for seed in seeds]


# --- route verification (docs/method.md §11, §12) ------------------------------------------------------------
def route_violations(route: np.ndarray, env: Environment, hazard: HazardConfig = HAZARD,
                     vehicle: VehicleLimits = VehicleLimits()) -> dict[str, int]:
    """Violations of ``route`` per category: the checker's verdict on the smoothed samples plus the cost's own
    count (docs/method.md §5.2), summed; all zero means both the checker and the cost call it flyable."""
    traj = smooth(route, _SPACING, vehicle.cruise_speed)
    counts = dict(check_trajectory(traj, route, env, hazard, vehicle).counts)
    ev = PlanningProblem(env, route[0], route[-1], vehicle, hazard).evaluate(route[None])
    return {k: counts[k] + int(v[0]) for k, v in ev.violations.items()}


def corridor(route: np.ndarray, hazard: HazardConfig = HAZARD, vehicle: VehicleLimits = VehicleLimits(),
             buffer: float = BUFFER_M) -> tuple[np.ndarray, np.ndarray]:
    """Points (M, 3) and the clearance (M,) each must keep from every obstacle surface.

    Smoothed samples need d_coll + tracking margin + buffer, the tracking margin being the largest corner cut of
    an autopilot taking waypoints at its acceptance radius (A/2). Chord samples need d_coll + buffer + the
    segment's deviation bound, which is what the cost subtracts from a chord's clearance (docs/method.md §4.4).
    """
    traj = smooth(route, _SPACING, vehicle.cruise_speed)
    seg = np.diff(route, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    u = seg / seg_len[:, None]
    cos_turn = np.sum(u * np.concatenate([u[1:], u[-1:]]), axis=1)
    dev = flown_deviation(seg_len, cos_turn, vehicle.acceptance_radius)
    idx, t = segment_samples(np.maximum(np.ceil(seg_len / CHORD_STEP_M).astype(int), 1))
    chord = route[idx] + t[:, None] * seg[idx]
    tracking = 0.5 * vehicle.acceptance_radius
    points = np.concatenate([traj.points, chord, route[-1:]])
    need = np.concatenate([np.full(len(traj.points), hazard.d_coll + tracking + buffer),
                           hazard.d_coll + buffer + dev[idx], [hazard.d_coll + tracking + buffer]])
    return points, need


def sphere_clearance(points: np.ndarray, centre: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Distance (K, M) from points (M, 3) to the surfaces of K spheres (hemispheres: centre on z = 0) (§2)."""
    return np.linalg.norm(points[None] - centre[:, None], axis=-1) - r[:, None]


def free_section(env: Environment, x: float, hazard: HazardConfig = HAZARD, step: float = 5.0) -> np.ndarray:
    """Points (M, 2) of (y, z), every ``step`` m, of the vertical plane at ``x`` where the vehicle may be: inside
    the bounds and the altitude band, at least d_coll from every obstacle and outside every radar's range (§12).
    Every route from x < ``x`` to x > ``x`` crosses this plane, so these are all the ways across."""
    y = np.arange(0.0, env.size_y + 1e-9, step)
    h = np.arange(env.z_min, env.z_max + 1e-9, step)
    yy, hh = (a.ravel() for a in np.meshgrid(y, h, indexing="ij"))
    xx = np.full(yy.size, float(x))
    pts = np.column_stack([xx, yy, env.ground(xx, yy) + hh])
    free = ((obstacle_clearance(pts, None, env, include_radars=False) >= hazard.d_coll)
            & (radar_clearance(pts, env.radars) >= 0.0))
    return pts[free, 1:]


def _planted_ok(route: np.ndarray, env: Environment, hazard: HazardConfig) -> bool:
    """The checks of a planted route on the full map ``env``: flyable without obstacles (limits, band, bounds;
    over the terrain if any), its corridor clear of every solid obstacle, its tracking margin + buffer (the corridor
    less d_coll, which is for solids only) clear of every radar range, with terrain its corridor inside the band
    with a margin (``band_margin_ok``), and flyable among them all (``route_violations``)."""
    bare = replace(env, cylinders=Cylinders.empty(), spheres=Spheres.empty(), radars=Radars.empty())
    if any(route_violations(route, bare, hazard).values()):
        return False
    points, need = corridor(route, hazard)
    if (obstacle_clearance(points, None, env, include_radars=False) < need).any():
        return False
    if (radar_clearance(points, env.radars) < need - hazard.d_coll).any():
        return False
    if env.terrain is not None and not band_margin_ok(points, env):
        return False
    return not any(route_violations(route, env, hazard).values())


def band_margin_ok(points: np.ndarray, env: Environment, vehicle: VehicleLimits = VehicleLimits(),
                   buffer: float = BUFFER_M) -> bool:
    """True if every point (M, 3) keeps ``buffer`` m inside the altitude band over every ground within the tracking
    margin + buffer (A/2 + buffer) of it horizontally (sampled at its centre and four points on that circle): where
    the autopilot cuts a corner over sloping ground, the ground under it differs from the ground under the plan."""
    reach = 0.5 * vehicle.acceptance_radius + buffer
    offsets = ((0.0, 0.0), (reach, 0.0), (-reach, 0.0), (0.0, reach), (0.0, -reach))
    g = np.stack([env.ground(points[:, 0] + dx, points[:, 1] + dy) for dx, dy in offsets])
    return bool(((points[:, 2] - g.max(axis=0) >= env.z_min + buffer)
                 & (points[:, 2] - g.min(axis=0) <= env.z_max - buffer)).all())


def _free_env(size_x: float, size_y: float) -> Environment:
    return Environment(size_x, size_y, *BAND)


def _heights(xy: np.ndarray, z0: float, z1: float) -> np.ndarray:
    """Heights from z0 to z1 in proportion to the horizontal distance flown: a constant, gentle climb."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    return z0 + (z1 - z0) * s / s[-1]


# --- gates --------------------------------------------------------------------------------------------------
def _wall(x: float, gap_centre: float, gap: float, radius: float, size_y: float) -> np.ndarray:
    """Centres (K, 2) of overlapping cylinders along x = ``x`` across [0, size_y], leaving one gap of ``gap`` m
    between cylinder surfaces around ``gap_centre``; neighbours overlap (step 1.5 R) so nothing passes between."""
    step = 1.5 * radius
    first = 0.5 * gap + radius
    up = gap_centre + first + step * np.arange(int(np.ceil((size_y - gap_centre) / step)) + 1)
    down = gap_centre - first - step * np.arange(int(np.ceil(gap_centre / step)) + 1)
    y = np.concatenate([down[down + radius > 0.0][::-1], up[up - radius < size_y]])
    return np.column_stack([np.full(len(y), x), y])


def _gates(seed: int, rng: np.random.Generator, n_walls: int | None = None, spacing: float = 400.0,
           gap: float = 180.0, radius: float = 40.0, size_y: float = 2000.0, hazard: HazardConfig = HAZARD,
           ) -> HardMap:
    """Walls across the start→goal direction (x), one gap each on alternating sides of the straight line.

    Gap centres first, then the route through them: it crosses each wall square-on along a short straight
    (entry and exit ``spacing``/5 either side of the wall) and runs diagonally between walls."""
    n = int(rng.integers(4, 7)) if n_walls is None else n_walls
    size_x = 200.0 + (n + 1) * spacing
    walls_x = 100.0 + spacing * np.arange(1, n + 1)
    half = 0.2 * spacing
    for _ in range(MAX_ROUTE_DRAWS):
        y0, y1 = size_y / 2 + rng.uniform(-50.0, 50.0, 2)
        line_y = y0 + (y1 - y0) * (walls_x - 100.0) / (size_x - 200.0)
        side = rng.choice([-1.0, 1.0]) * (-1.0) ** np.arange(n)
        centres = np.round(line_y + side * rng.uniform(0.5 * gap + radius, 0.5 * gap + 2 * radius, n), 2)
        xy = np.concatenate([[[100.0, y0]], np.column_stack([np.repeat(walls_x, 2) + np.tile([-half, half], n),
                                                              np.repeat(centres, 2)]), [[size_x - 100.0, y1]]])
        z0, z1 = rng.uniform(80.0, 160.0, 2)
        route = np.round(np.column_stack([xy, _heights(xy, z0, z1)]), 2)
        cyl = np.round(np.concatenate([_wall(x, c, gap, radius, size_y) for x, c in zip(walls_x, centres)]), 2)
        r = np.full(len(cyl), radius)
        env_full = _walled_env(size_x, size_y, cyl, r)
        if not _planted_ok(route, env_full, hazard):
            continue
        what = f"{n} walls of unlimited cylinders, one {gap:g} m gap each on alternating sides"
        return _walled_map("gates", seed, env_full, route, hazard, what, cyl, r)
    raise RuntimeError(f"gates: no flyable route in {MAX_ROUTE_DRAWS} draws (seed {seed})")


# --- dense --------------------------------------------------------------------------------------------------
def _planted_wiggle(rng: np.random.Generator, start: np.ndarray, goal: np.ndarray, n_legs: int,
                    amplitude: float, max_turn_deg: float, divisors: Sequence[float] = (1.0, 2.0, 4.0),
                    ) -> np.ndarray | None:
    """A route start→goal with lateral offset Σ a_i sin(iπt), |a_i| ≤ ``amplitude``/``divisors[i-1]`` (one
    harmonic per divisor), and a gentle height bump; None if a heading change exceeds ``max_turn_deg``."""
    t = np.linspace(0.0, 1.0, n_legs + 1)
    k = np.arange(1, len(divisors) + 1)
    a = rng.uniform(-1.0, 1.0, len(divisors)) * amplitude / np.asarray(divisors)
    off = (a[:, None] * np.sin(k[:, None] * np.pi * t)).sum(axis=0)
    d = (goal - start)[:2]
    normal = np.array([-d[1], d[0]]) / np.linalg.norm(d)
    xy = start[:2] + t[:, None] * d + off[:, None] * normal
    z = start[2] + t * (goal[2] - start[2]) + rng.uniform(0.0, 60.0) * np.sin(np.pi * t)
    route = np.round(np.column_stack([xy, z]), 2)
    if np.degrees(horizontal_turn(np.diff(route, axis=0))).max() > max_turn_deg:
        return None
    return route


def _dense(seed: int, rng: np.random.Generator, count: int = 250, size: float = 2000.0,
           radius: tuple[float, float] = (50.0, 100.0), dome_radius: tuple[float, float] = (80.0, 180.0),
           sphere_z: tuple[float, float] = (60.0, 250.0), kinds: tuple[float, float, float] = (0.8, 0.1, 0.1),
           n_clusters: int = 10, clustered: float = 0.25, spread: float = 120.0, n_legs: int = 16,
           amplitude: float = 600.0, divisors: Sequence[float] = (1.0, 1.0, 1.5, 2.0, 2.5, 3.0),
           max_turn_deg: float = 55.0, hazard: HazardConfig = HAZARD, batch: int = 256, max_batches: int = 400,
           ) -> HardMap:
    """About ``count`` obstacles by rejection sampling outside the corridor of a winding planted route.

    The route weaves: ``n_legs`` legs, a lateral offset of ``len(divisors)`` harmonics up to ``amplitude`` m and
    turns up to ``max_turn_deg`` (``_planted_wiggle``). The field is dense enough (about 30 % of the plan view
    stays free at route height) that its corridor is about the only way through, so a route must weave too.
    Most obstacles are unlimited cylinders (fraction ``kinds[0]``), which no route can climb over; spheres sit at
    route heights (``sphere_z``) and hemispheres are tall enough (``dome_radius``) to reach them, so none is
    trivially overflown. A fraction ``clustered`` is drawn around ``n_clusters`` centres (Gaussian, ``spread``
    m), half of them on the straight start→goal line, which they block; the rest is uniform. Fewer obstacles if
    the sampler gives up after ``max_batches`` batches (``HardMap.n_obstacles`` tells)."""
    env = _free_env(size, size)
    for _ in range(MAX_ROUTE_DRAWS):
        start = np.array([150.0, 150.0, rng.uniform(80.0, 160.0)])
        goal = np.array([size - 150.0, size - 150.0, rng.uniform(80.0, 160.0)])
        route = _planted_wiggle(rng, start, goal, n_legs, amplitude, max_turn_deg, divisors)
        if route is not None and not any(route_violations(route, env, hazard).values()):
            break
    else:
        raise RuntimeError(f"dense: no flyable route in {MAX_ROUTE_DRAWS} draws (seed {seed})")
    points, need = corridor(route, hazard)
    n_line = n_clusters // 2
    centres = np.concatenate([start[:2] + rng.uniform(0.15, 0.85, (n_line, 1)) * (goal - start)[:2],
                              rng.uniform(0.0, size, (n_clusters - n_line, 2))])
    kinds_l: list[int] = []
    rows: list[list[float]] = []
    for _ in range(max_batches):
        if len(rows) >= count:
            break
        kind = rng.choice(3, batch, p=kinds)  # 0 cylinder, 1 sphere, 2 hemisphere
        near = rng.random(batch) < clustered
        clump = centres[rng.integers(0, n_clusters, batch)] + rng.normal(0.0, spread, (batch, 2))
        xy = np.clip(np.where(near[:, None], clump, rng.uniform(0.0, size, (batch, 2))), 0.0, size)
        r = np.where(kind == 2, rng.uniform(*dome_radius, batch), rng.uniform(*radius, batch))
        z = np.where(kind == 1, rng.uniform(*sphere_z, batch), 0.0)
        cand = np.round(np.column_stack([xy, z, r]), 2)
        col = (slice(None), None)
        cyl_clear = cylinder_signed_distance(points[None], cand[col + (0,)], cand[col + (1,)], cand[col + (3,)],
                                             np.inf)
        clear = np.where((kind == 0)[:, None], cyl_clear, sphere_clearance(points, cand[:, :3], cand[:, 3]))
        ok = np.flatnonzero((clear >= need).all(axis=1))[: count - len(rows)]
        kinds_l.extend(kind[ok].tolist())
        rows.extend(cand[ok].tolist())
    kinds_a, obs = np.array(kinds_l, dtype=int), np.array(rows).reshape(-1, 4)
    cyl, sph = obs[kinds_a == 0], obs[kinds_a != 0]
    env_full = Environment(size, size, *BAND, cylinders=_cylinders(cyl[:, :2], cyl[:, 3]),
                           spheres=_spheres(sph))
    if any(route_violations(route, env_full, hazard).values()):  # the corridor guarantees it; check anyway
        raise RuntimeError(f"dense: planted route not flyable after placing obstacles (seed {seed})")
    entries = []  # in the order drawn, the kinds interleaved
    for k, (x, y, z, r) in zip(kinds_a, obs):
        if k == 0:
            entries += _entries("cylinders", [[x, y, r]], ("x", "y", "radius"))
        elif k == 1:
            entries += _entries("spheres", [[x, y, z, r]], ("x", "y", "z", "radius"))
        else:
            entries += _entries("hemispheres", [[x, y, r]], ("x", "y", "radius"))
    what = (f"{len(obs)} obstacles off a planted route: {len(cyl)} unlimited cylinders, {len(sph)} spheres and "
            f"hemispheres, some in {n_clusters} clumps")
    text = _scenario_text("dense", seed, size, size, route, hazard, what, entries)
    return HardMap("dense", seed, text, route, len(obs), _straight_blocked(route, env_full, hazard))


# --- maze ---------------------------------------------------------------------------------------------------
_SIDES = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]])  # the sides E, N, W, S of a cell as (i, j) steps


def _backtracker(rng: np.random.Generator, nx: int, ny: int) -> np.ndarray:
    """A perfect maze on nx × ny cells by random depth-first search (the "recursive backtracker", iterative):
    ``passage[c, k]`` is True where side k (E, N, W, S) of cell c = i + nx·j is open. The passages form a
    spanning tree, so exactly one path joins any two cells, and its corridors are long and winding."""
    passage = np.zeros((nx * ny, 4), dtype=bool)
    seen = np.zeros(nx * ny, dtype=bool)
    seen[0] = True
    stack = [0]
    while stack:
        c = stack[-1]
        ij = np.array([c % nx, c // nx]) + _SIDES
        inside = (ij[:, 0] >= 0) & (ij[:, 0] < nx) & (ij[:, 1] >= 0) & (ij[:, 1] < ny)
        nbr = np.where(inside, ij[:, 0] + nx * ij[:, 1], 0)
        new = np.flatnonzero(inside & ~seen[nbr])
        if not new.size:
            stack.pop()
            continue
        k = int(new[rng.integers(new.size)])
        n = int(nbr[k])
        passage[c, k] = passage[n, (k + 2) % 4] = True
        seen[n] = True
        stack.append(n)
    return passage


def _tree_path(passage: np.ndarray, nx: int, start: int, goal: int) -> np.ndarray:
    """Cells (M,) of the unique path start→goal through a perfect maze (breadth-first search)."""
    step = _SIDES[:, 0] + nx * _SIDES[:, 1]
    parent = np.full(len(passage), -1)
    parent[start] = start
    queue = [start]
    for c in queue:  # the queue grows while it is read
        for n in c + step[passage[c]]:
            if parent[n] < 0:
                parent[n] = c
                queue.append(int(n))
    path = [goal]
    while path[-1] != start:
        path.append(int(parent[path[-1]]))
    return np.array(path[::-1])


def _maze_walls(passage: np.ndarray, nx: int, ny: int, cell: float, radius: float) -> np.ndarray:
    """Centres (K, 2) of the cylinders on every closed inner wall, each a gap-free chain (``_chain``) from corner
    to corner, so walls meeting at a corner share its post. The map's edge is the outer wall."""
    c = np.arange(nx * ny)
    i, j = c % nx, c // nx
    east = ~passage[:, 0] & (i < nx - 1)
    north = ~passage[:, 1] & (j < ny - 1)
    a = np.concatenate([np.column_stack([i + 1, j])[east], np.column_stack([i, j + 1])[north]]) * cell
    b = np.concatenate([np.column_stack([i + 1, j + 1])[east], np.column_stack([i + 1, j + 1])[north]]) * cell
    chains = [_chain(np.stack([p, q]), radius) for p, q in zip(a, b)]
    return np.unique(np.round(np.concatenate(chains), 2), axis=0)


def _chamfer(xy: np.ndarray, cut: float) -> np.ndarray:
    """Waypoints (N, 2) through the points xy (M, 2) of a path with right-angle corners, each corner replaced by
    the points ``cut`` m before and after it: two 45° turns joined by a leg of √2·cut. A 45° turn needs a leg of
    G(cos 45°)·sin 45°·R_min ≈ 3 R_min before it (§11.2), ≈ 100 m for the default vehicle; one of 90° none at
    all within the 60° waypoint limit."""
    u = np.diff(xy, axis=0)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    corner = np.sum(u[:-1] * u[1:], axis=1) < 0.5
    inner = xy[1:-1]
    pairs = np.stack([inner - cut * u[:-1] * corner[:, None], inner + cut * u[1:] * corner[:, None]], axis=1)
    keep = np.column_stack([np.ones(len(inner), dtype=bool), corner]).ravel()
    return np.concatenate([xy[:1], pairs.reshape(-1, 2)[keep], xy[-1:]])


def _maze(seed: int, rng: np.random.Generator, cells: tuple[int, int] = (7, 7), cell: float = 350.0,
          radius: float = 35.0, cut: float = 90.0, hazard: HazardConfig = HAZARD) -> HardMap:
    """A perfect maze (``_backtracker``) of ``cells`` square cells of ``cell`` m; its closed walls are chains of
    unlimited cylinders of ``radius``, its corridors ``cell`` − 2·``radius`` m wide between wall surfaces. Start
    and goal are the centres of the south-west and north-east cells. The planted route is the maze's unique
    solution through the cell centres, a waypoint in every cell and the corners cut by ``cut`` m (``_chamfer``):
    it keeps ``cell``/2 − ``radius`` m from the side walls and about 150 m from the post inside a corner."""
    nx, ny = cells
    size_x, size_y = nx * cell, ny * cell
    for _ in range(MAX_ROUTE_DRAWS):
        passage = _backtracker(rng, nx, ny)
        path = _tree_path(passage, nx, 0, nx * ny - 1)
        xy = _chamfer((np.column_stack([path % nx, path // nx]) + 0.5) * cell, cut)
        z0, z1 = rng.uniform(80.0, 200.0, 2)
        route = np.round(np.column_stack([xy, _heights(xy, z0, z1)]), 2)
        cyl = _maze_walls(passage, nx, ny, cell, radius)
        r = np.full(len(cyl), radius)
        env_full = _walled_env(size_x, size_y, cyl, r)
        if not _only_the_planted_way(route, env_full, hazard):
            continue
        what = (f"{nx}x{ny} maze of {cell:g} m cells, walls of unlimited cylinders; the solution runs through "
                f"{len(path)} cells")
        return _walled_map("maze", seed, env_full, route, hazard, what, cyl, r)
    raise RuntimeError(f"maze: no flyable route in {MAX_ROUTE_DRAWS} draws (seed {seed})")


# --- ridge --------------------------------------------------------------------------------------------------
def _ridge_peaks(rng: np.random.Generator, first: tuple[float, float], direction: float, size_y: float,
                 peak_radius: tuple[float, float], crest: float) -> list[tuple[float, float]]:
    """Peaks (y, R) of a ridge from ``first`` towards ``direction`` (±1 in y) until one stands past the map's
    edge. Neighbours stand 80-95 % of the distance at which their spheres would meet exactly at ``crest`` m, so
    in the ridge's plane the line where they meet, and everything below it, is higher than ``crest``."""
    peaks = [first]
    while 0.0 <= peaks[-1][0] <= size_y:
        y, r = peaks[-1]
        r2 = rng.uniform(*peak_radius)
        d = rng.uniform(0.8, 0.95) * (np.sqrt(r * r - crest * crest) + np.sqrt(r2 * r2 - crest * crest))
        peaks.append((y + direction * d, r2))
    return peaks


def _ridge(seed: int, rng: np.random.Generator, size: float = 2400.0,
           peak_radius: tuple[float, float] = (420.0, 480.0), crest: float = 330.0,
           gap: tuple[float, float] = (40.0, 60.0), saddle_radius: tuple[float, float] = (70.0, 95.0),
           pass_height: tuple[float, float] = (55.0, 70.0), ceiling: tuple[float, float] = (50.0, 70.0),
           offset: tuple[float, float] = (600.0, 950.0), hazard: HazardConfig = HAZARD) -> HardMap:
    """A ridge across the start→goal direction with one saddle, and a radar on each summit flanking it.

    A scenario cannot give terrain inline (``[terrain]`` is flat, seeded random hills or a DEM file beside the
    scenario, docs/scenario_format.md), so the ridge is a row of hemispheres of ``peak_radius`` m (summits above
    the band's 300 m ceiling; neighbours meet above ``crest`` m) centred on the line x = x_r, across the whole
    map. The saddle is a gap of ``gap`` m at ground level between the two flanking peaks, floored by a low
    hemisphere of ``saddle_radius`` m. A radar's range is a sphere of fixed r_det around the site whatever the
    target's altitude (§2.4: no terrain masking, constant RCS), so the cover from above comes from geometry:
    the ranges of the radars on the two flanking summits meet ``ceiling`` m above the pass height in the middle
    of the saddle and lower off it. The only way across is thus through the saddle, low: above its floor, under
    the radar cover (``free_section`` at x_r; the generator checks that no free point lies higher or elsewhere).

    Start and goal are high (200-280 m), and the straight line between them crosses the ridge ``offset`` m from
    the saddle (at least offset[0] − 50 m), through a peak. The planted route comes down from the start and
    crosses square-on at the pass height, ``pass_height`` m above the saddle's floor, keeping the corridor
    clearance from every peak and the floor and its tracking margin + buffer from the radar ranges."""
    size_x = size_y = size
    for _ in range(MAX_ROUTE_DRAWS):
        xr = 0.5 * size_x + rng.uniform(-150.0, 150.0)
        ys = rng.uniform(700.0, size_y - 700.0)
        r_lo, r_hi = rng.uniform(*peak_radius, 2)
        g_lo, g_hi = rng.uniform(*gap, 2)
        south = _ridge_peaks(rng, (ys - r_lo - g_lo, r_lo), -1.0, size_y, peak_radius, crest)
        north = _ridge_peaks(rng, (ys + r_hi + g_hi, r_hi), 1.0, size_y, peak_radius, crest)
        r_s = rng.uniform(*saddle_radius)
        h_pass = r_s + rng.uniform(*pass_height)
        h_cover = h_pass + rng.uniform(*ceiling)
        summits = np.array([south[0], north[0]])  # (2, 2): y, height
        y_cross = ys + rng.choice([-1.0, 1.0]) * rng.uniform(*offset)
        if not 250.0 <= y_cross <= size_y - 250.0:
            y_cross = 2.0 * ys - y_cross
        y0, y1 = np.clip(y_cross + rng.uniform(-200.0, 200.0, 2), 100.0, size_y - 100.0)
        x0, x1 = 150.0, size_x - 150.0
        if abs(y0 + (y1 - y0) * (xr - x0) / (x1 - x0) - ys) < offset[0] - 50.0:
            continue
        z0, z1 = rng.uniform(200.0, 280.0, 2)
        half = rng.uniform(330.0, 420.0)
        start, a, b, goal = (np.array(p) for p in ([x0, y0, z0], [xr - half, ys, h_pass], [xr + half, ys, h_pass],
                                                   [x1, y1, z1]))
        inner = np.array([[xr - 150.0, ys, h_pass], [xr + 150.0, ys, h_pass]])  # no turn in the pass
        route = np.round(np.vstack([start, 0.5 * (start + a), a, inner, b, 0.5 * (b + goal), goal]), 2)
        peaks = np.array(south[::-1] + north)
        hemi = np.round(np.column_stack([np.full(len(peaks) + 1, xr), np.append(peaks[:, 0], ys),
                                         np.append(peaks[:, 1], r_s)]), 2)  # x, y, radius
        radars = np.round(np.column_stack([np.full(2, xr), summits, np.hypot(summits[:, 0] - ys,
                                                                              summits[:, 1] - h_cover)]), 2)
        env_full = Environment(size_x, size_y, *BAND, spheres=_spheres(np.insert(hemi, 2, 0.0, axis=1)),
                               radars=Radars(radars[:, :3], radars[:, 3], np.ones(2)))
        if not _only_the_planted_way(route, env_full, hazard):
            continue
        way = free_section(env_full, float(hemi[0, 0]), hazard)
        if not len(way) or way[:, 1].max() > h_cover + 1.0 or np.abs(way[:, 0] - ys).max() > max(gap) + 200.0:
            continue
        what = (f"a ridge of {len(peaks)} hemispherical peaks with one saddle (floor {r_s:.0f} m) and radars on "
                f"its two flanking summits covering the pass above {way[:, 1].max():.0f} m")
        text = _scenario_text("ridge", seed, size_x, size_y, route, hazard, what,
                              _hemisphere_entries(hemi) + _radar_entries(radars))
        return HardMap("ridge", seed, text, route, len(hemi) + len(radars), True)
    raise RuntimeError(f"ridge: no flyable route in {MAX_ROUTE_DRAWS} draws (seed {seed})")


# --- canyon -------------------------------------------------------------------------------------------------
def _meander(psi: float, wavelength: float, phase: float, x0: float, x1: float, ds: float = 5.0,
             ) -> tuple[np.ndarray, np.ndarray]:
    """A sine-generated curve, the classic model of a river's meanders: heading ψ(s) = ``psi``·sin(2πs/λ + φ)
    along the arc length s, from (x0, 0) until it passes x = x1 → points (M, 2) every ``ds`` m and their headings
    (M,). Its curvature dψ/ds is at most 2π·psi/λ; with psi < 90° it always heads east, so it is a graph over x
    (no bend folds back) and its y stays bounded (sin ψ averages to zero over a wavelength)."""
    s = np.arange(0.0, (x1 - x0) / np.cos(psi) + 2.0 * ds, ds)  # cos ψ ≥ cos psi: x1 is passed by the end
    mid = psi * np.sin(2.0 * np.pi * (s[:-1] + 0.5 * ds) / wavelength + phase)
    xy = np.vstack([[0.0, 0.0], ds * np.cumsum(np.column_stack([np.cos(mid), np.sin(mid)]), axis=0)])
    xy[:, 0] += x0
    n = int(np.argmax(xy[:, 0] >= x1)) + 1
    return xy[:n], psi * np.sin(2.0 * np.pi * s[:n] / wavelength + phase)


def _canyon(seed: int, rng: np.random.Generator, size_x: float = 2500.0,
            width: tuple[float, float] = (120.0, 160.0), radius: float = 40.0,
            sinuosity_deg: tuple[float, float] = (55.0, 75.0), wavelength: tuple[float, float] = (1300.0, 1800.0),
            step: float = 70.0, hazard: HazardConfig = HAZARD) -> HardMap:
    """A winding canyon from the west edge to the east edge, ``width`` m wide between its walls.

    The centre line is a meander (``_meander``: heading swinging ±``sinuosity_deg`` about east, ``wavelength``
    m of channel per swing); the walls are two gap-free chains of unlimited cylinders of ``radius`` offset along
    its normals by width/2 + radius (the tightest bend, λ/(2π·psi), ≥ 158 m at the defaults, must exceed that
    offset, or the inner wall would fold). Both walls run from edge to edge, so with the bounds they cut the
    region outside the canyon off from start and goal: the only way is through it. Start and goal lie on the
    centre line 100 m inside the edges; the planted route follows it with a waypoint every ``step`` m of arc
    length (a turn of step·κ ≤ 25° at each, on legs long enough for the Bézier curvature, §11.2) and keeps about
    width/2 from both walls (the generator checks that the whole centre line keeps width/2 − 1 m)."""
    for _ in range(MAX_ROUTE_DRAWS):
        psi = np.radians(rng.uniform(*sinuosity_deg))
        lam = rng.uniform(*wavelength)
        w = rng.uniform(*width)
        offset = 0.5 * w + radius
        xy, heading = _meander(psi, lam, rng.uniform(0.0, 2.0 * np.pi), -150.0, size_x + 150.0)
        z0, z1 = rng.uniform(80.0, 220.0, 2)
        if lam / (2.0 * np.pi * psi) < offset + 10.0:  # the inner wall would fold at the tightest bend
            continue
        size_y = float(np.ceil(max(2000.0, np.ptp(xy[:, 1]) + 2.0 * offset + 400.0) / 10.0) * 10.0)
        xy[:, 1] += 0.5 * (size_y - xy[:, 1].min() - xy[:, 1].max())
        normal = np.column_stack([-np.sin(heading), np.cos(heading)])
        cyl = np.round(np.concatenate([_chain(xy + side * offset * normal, radius) for side in (1.0, -1.0)]), 2)
        cyl = cyl[(cyl[:, 0] >= -radius) & (cyl[:, 0] <= size_x + radius)]
        r = np.full(len(cyl), radius)
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
        inside = np.flatnonzero((xy[:, 0] >= 100.0) & (xy[:, 0] <= size_x - 100.0))
        at = np.linspace(s[inside[0]], s[inside[-1]], max(int(round((s[inside[-1]] - s[inside[0]]) / step)), 2) + 1)
        wp = np.column_stack([np.interp(at, s, xy[:, 0]), np.interp(at, s, xy[:, 1])])
        route = np.round(np.column_stack([wp, _heights(wp, z0, z1)]), 2)
        env_full = _walled_env(size_x, size_y, cyl, r)
        if not _only_the_planted_way(route, env_full, hazard):
            continue
        mid = xy[(xy[:, 0] >= 0.0) & (xy[:, 0] <= size_x)]  # the channel is ≥ w wide all along
        if obstacle_clearance(np.column_stack([mid, np.full(len(mid), z0)]), None, env_full).min() < 0.5 * w - 1.0:
            continue
        what = (f"a canyon {w:.0f} m wide between walls of unlimited cylinders, meandering ±{np.degrees(psi):.0f} deg "
                f"every {lam:.0f} m from the west edge to the east edge")
        return _walled_map("canyon", seed, env_full, route, hazard, what, cyl, r)
    raise RuntimeError(f"canyon: no flyable route in {MAX_ROUTE_DRAWS} draws (seed {seed})")


# --- terrain (issue 34) -------------------------------------------------------------------------------------
def profile_flyable(xy: np.ndarray, env: Environment, vehicle: VehicleLimits = VehicleLimits(),
                    z0: float | None = None, z1: float | None = None, step: float = CHORD_STEP_M) -> bool:
    """True if some height profile along the horizontal polyline ``xy`` (N, 2) stays inside the altitude band over
    the terrain at every sample (``step`` m apart) and climbs or descends no steeper than the vehicle's limit,
    starting at ``z0`` and ending at ``z1`` when given (obstacles aside). A sweep of the interval of heights the
    vehicle can be at (an interval stays one: the band is one and the climb limit widens it evenly). False means
    that no route flying this plan view can keep the band, whatever its heights: the terrain is a barrier to it."""
    xy = np.asarray(xy, dtype=float)
    seg = np.diff(xy, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    idx, t = segment_samples(np.maximum(np.ceil(seg_len / step).astype(int), 1))
    pts = np.vstack([xy[idx] + t[:, None] * seg[idx], xy[-1:]])
    ds = np.linalg.norm(np.diff(pts, axis=0), axis=1) * math.tan(vehicle.max_climb)
    ground = env.ground(pts[:, 0], pts[:, 1])
    lo_band, hi_band = ground + env.z_min - 1e-6, ground + env.z_max + 1e-6
    lo, hi = (lo_band[0], hi_band[0]) if z0 is None else (z0, z0)
    if not lo_band[0] <= lo <= hi <= hi_band[0]:
        return False
    for k in range(1, len(pts)):
        lo, hi = max(lo - ds[k - 1], lo_band[k]), min(hi + ds[k - 1], hi_band[k])
        if lo > hi:
            return False
    return z1 is None or lo <= z1 <= hi


def _dem(heights: np.ndarray, cell: float) -> tuple[str, Terrain]:
    """The ESRI ASCII text of ``heights`` (ny, nx), m above home on the nodes (i·cell, j·cell) with row j running
    north (written m AMSL to 0.1 m, rows north to south), and the Terrain the scenario loader makes of that text."""
    ny, nx = heights.shape
    rows = "\n".join(" ".join(f"{v:.1f}" for v in row) for row in (HOME[2] + heights)[::-1])
    text = f"ncols {nx}\nnrows {ny}\nxllcenter 0\nyllcenter 0\ncellsize {cell:g}\nNODATA_value -9999\n{rows}\n"
    return text, parse_esri_ascii(text, Home(*HOME))


def _grid(size_x: float, size_y: float, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Node coordinates (ny, nx) x and y of a DEM covering [0, size_x] × [0, size_y] (``grid_axis``)."""
    return np.meshgrid(grid_axis(size_x, cell), grid_axis(size_y, cell))


def _smoothstep(t: np.ndarray) -> np.ndarray:
    """3t² − 2t³ on t clipped to [0, 1]: 0 → 1 with zero slope at both ends, steepest (1.5) at t = 1/2."""
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _wall_rise(contour: float, run: float, band: tuple[float, float] = TERRAIN_BAND,
               vehicle: VehicleLimits = VehicleLimits()) -> float:
    """The least height a wall rising on a smoothstep over ``run`` m must have for its top to be out of the
    vehicle's reach from its foot, when its contours are at most ``contour`` m long.

    Where the wall's slope exceeds (band width + tan γ·π R_min) / (2 R_min) (2.24 for the default plane in
    :data:`TERRAIN_BAND`), a plane cannot turn on it: a U-turn sweeps 2 R_min across the slope, climbing at most
    tan γ·π R_min, and the band cannot hold the change of ground. On that steep part it can only climb along the
    wall one way, tan γ per metre, at most tan γ × ``contour``; it enters it at most a band's ceiling above the
    gentle foot, whose height δ (and the gentle top's) the smoothstep gives. So the top is out of reach if the rise
    exceeds band width + 2δ + tan γ × contour, which this returns (δ itself shrinks as the wall grows steeper)."""
    width, tan = band[1] - band[0], math.tan(vehicle.max_climb)
    r = vehicle.min_turn_radius
    need = (width + tan * math.pi * r) / (2.0 * r)
    rise = width + tan * contour
    for _ in range(100):
        m = rise / run  # mean slope; the smoothstep's is 6t(1 − t)·m
        if need / (6.0 * m) >= 0.2:  # hardly anywhere steep enough: steepen
            rise *= 1.5
            continue
        t = 0.5 - math.sqrt(0.25 - need / (6.0 * m))
        new = width + tan * contour + 2.0 * float(_smoothstep(np.array(t))) * rise
        if abs(new - rise) < 0.01:
            break
        rise = new
    return rise


def _contour_length(xy: np.ndarray, offsets: Iterable[float], size_x: float) -> float:
    """Longest of the curves offset from the polyline ``xy`` (M, 2) by each of ``offsets`` m along its normals,
    within x ∈ [0, size_x]: the wall contours of a valley along it (an offset curve that folds at a tight bend
    only counts longer)."""
    d = np.diff(xy, axis=0)
    tangent = np.vstack([d[:1], 0.5 * (d[1:] + d[:-1]), d[-1:]])
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0]]) / np.linalg.norm(tangent, axis=1)[:, None]
    longest = 0.0
    for off in offsets:
        c = xy + off * normal
        c = c[(c[:, 0] >= 0.0) & (c[:, 0] <= size_x)]
        longest = max(longest, float(np.linalg.norm(np.diff(c, axis=0), axis=1).sum()))
    return longest


def _route_over(xy: np.ndarray, env: Environment, rng: np.random.Generator, ends: tuple[float, float],
                above: tuple[float, float], vehicle: VehicleLimits) -> np.ndarray | None:
    """The planted route (N, 3) over plan-view points ``xy``: its ends ``ends`` m above the ground (drawn), the rest
    :func:`_ground_heights` at a drawn height ``above`` within half the climb limit; None when none fits."""
    z_ends = rng.uniform(*ends, 2) + env.ground(xy[[0, -1], 0], xy[[0, -1], 1])
    z = _ground_heights(xy, env, rng.uniform(*above), 0.5 * math.tan(vehicle.max_climb),
                        fixed={0: float(z_ends[0]), len(xy) - 1: float(z_ends[1])})
    return None if z is None else np.round(np.column_stack([xy, z]), 2)


def _ground_heights(xy: np.ndarray, env: Environment, above: float, slope: float, margin: float = 15.0,
                    reach: float = 30.0, fixed: dict[int, float] | None = None) -> np.ndarray | None:
    """Heights (N,) of horizontal waypoints xy (N, 2) over the terrain of ``env``: ``above`` m over the highest
    ground within ``reach`` m of the legs either side of the waypoint (its chord and two parallels), but not above
    the band less ``margin`` over the lowest; then raised where a leg would climb or descend steeper than ``slope``
    (rise per metre; one backward and one forward pass, raising only). ``fixed``: heights given (index → z), kept.
    None if a height ends outside [band floor + margin over the highest, ceiling − margin over the lowest ground]."""
    seg = np.diff(xy, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    n = np.maximum(np.ceil(seg_len / CHORD_STEP_M).astype(int), 1)
    idx, t = segment_samples(n)
    idx, t = np.append(idx, len(seg) - 1), np.append(t, 1.0)
    pts = xy[idx] + t[:, None] * seg[idx]
    normal = np.column_stack([-seg[:, 1], seg[:, 0]]) / seg_len[:, None]
    g = np.stack([env.ground(*(pts + k * reach * normal[idx]).T) for k in (-1.0, 0.0, 1.0)])
    leg_hi = np.full(len(seg), -np.inf)
    leg_lo = np.full(len(seg), np.inf)
    np.maximum.at(leg_hi, idx, g.max(axis=0))
    np.minimum.at(leg_lo, idx, g.min(axis=0))
    ground_hi = np.maximum(np.append(leg_hi, -np.inf), np.insert(leg_hi, 0, -np.inf))
    ground_lo = np.minimum(np.append(leg_lo, np.inf), np.insert(leg_lo, 0, np.inf))
    lo, hi = ground_hi + env.z_min + margin, ground_lo + env.z_max - margin
    z = np.minimum(ground_hi + above, hi)
    for i, v in (fixed or {}).items():
        z[i] = v
    step = slope * seg_len
    for i in range(len(z) - 2, -1, -1):  # no leg climbs steeper than slope
        z[i] = max(z[i], z[i + 1] - step[i])
    for i in range(1, len(z)):  # nor descends
        z[i] = max(z[i], z[i - 1] - step[i - 1])
    if fixed and any(abs(z[i] - v) > 1e-9 for i, v in fixed.items()):
        return None
    if (z < lo - 1e-9).any() or (z > hi + 1e-9).any():
        return None
    return z


def _terrain_env(size_x: float, size_y: float, terrain: Terrain, **obstacles: Any) -> Environment:
    """A map in the terrain families' band over ``terrain``, with ``obstacles`` (cylinders, spheres, radars)."""
    return Environment(size_x, size_y, *TERRAIN_BAND, terrain=terrain, **obstacles)


def _terrain_map(family: str, seed: int, env: Environment, route: np.ndarray, hazard: HazardConfig, what: str,
                 dem: str, obstacles: list[Entry] | None = None, n_obstacles: int = 0) -> HardMap:
    """The HardMap of a terrain family: its scenario naming its DEM ``hardmap_{family}_{seed}.asc``, with
    ``obstacles`` (array-of-tables entries)."""
    name = f"hardmap_{family}_{seed}.asc"
    text = _scenario_text(family, seed, env.size_x, env.size_y, route, hazard, what, obstacles or [], TERRAIN_BAND,
                          name)
    return HardMap(family, seed, text, route, n_obstacles, _straight_blocked(route, env, hazard), dem, name)


def _valley(seed: int, rng: np.random.Generator, size_x: float = 2200.0,
            floor_width: tuple[float, float] = (170.0, 230.0), wall_run: tuple[float, float] = (280.0, 340.0),
            sinuosity_deg: tuple[float, float] = (55.0, 70.0), wavelength: tuple[float, float] = (1500.0, 2000.0),
            floor_height: tuple[float, float] = (0.0, 80.0), above: tuple[float, float] = (60.0, 90.0),
            step: float = 70.0, cell: float = DEM_CELL_M, hazard: HazardConfig = HAZARD) -> HardMap:
    """A winding valley cut into a plateau from the west edge to the east edge (issue 34).

    The valley's centre line is a meander (``_meander``, as the canyon's: heading swinging ±``sinuosity_deg`` about
    east, ``wavelength`` m of valley per swing; its tightest bend, λ/(2π·psi) ≥ 195 m at the defaults, is 6 R_min of the
    default plane). Its floor, ``floor_width`` m wide, is flat across and rises or falls evenly along the valley between
    two heights drawn from ``floor_height``; the walls rise from its edges to a flat plateau on a smoothstep over
    ``wall_run`` m. The plateau stands out of a vehicle's reach (``_wall_rise``: the walls are too steep to turn on, so
    a climb out runs one way along a wall, at most tan γ × its longest contour, ``_contour_length``) plus a margin of
    30-80 m: 1.2-1.4 km above the floor at the defaults, where the band (:data:`TERRAIN_BAND`) ends 150 m above the
    ground. Start and goal lie on the centre line 100 m inside the edges, the planted route follows it with a waypoint
    every ``step`` m of valley (as the canyon's) ``above`` m above its floor, and the straight line between them crosses
    the walls: no height profile along it keeps the band (``profile_flyable``)."""
    vehicle = VehicleLimits()
    for _ in range(MAX_ROUTE_DRAWS):
        psi = np.radians(rng.uniform(*sinuosity_deg))
        lam = rng.uniform(*wavelength)
        half = 0.5 * rng.uniform(*floor_width)
        run = rng.uniform(*wall_run)
        f0, f1 = rng.uniform(*floor_height, 2)
        h_above = rng.uniform(*above)
        xy, _ = _meander(psi, lam, rng.uniform(0.0, 2.0 * np.pi), -150.0, size_x + 150.0)
        margin = rng.uniform(30.0, 80.0)
        if lam / (2.0 * np.pi * psi) < half + 50.0:  # the floor would pinch at the tightest bend
            continue
        size_y = float(np.ceil((np.ptp(xy[:, 1]) + 2.0 * (half + run) + 300.0) / 10.0) * 10.0)
        xy[:, 1] += 0.5 * (size_y - xy[:, 1].min() - xy[:, 1].max())
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
        inside = np.flatnonzero((xy[:, 0] >= 0.0) & (xy[:, 0] <= size_x))
        floor = f0 + (f1 - f0) * (s - s[inside[0]]) / (s[inside[-1]] - s[inside[0]])
        off = half + run * np.linspace(0.0, 1.0, 5)
        contour = _contour_length(xy, np.concatenate([off, -off]), size_x)
        plateau = float(np.ceil((max(f0, f1) + _wall_rise(contour, run) + margin) / 10.0) * 10.0)
        gx, gy = _grid(size_x, size_y, cell)
        dist, near = cKDTree(xy).query(np.column_stack([gx.ravel(), gy.ravel()]))
        wall = _smoothstep((dist - half) / run)
        heights = (floor[near] + (plateau - floor[near]) * wall).reshape(gx.shape)
        dem, terrain = _dem(heights, cell)
        env = _terrain_env(size_x, size_y, terrain)
        s0 = np.interp(100.0, xy[:, 0], s)  # the valley's arc length at x = 100 and x = size_x - 100
        s1 = np.interp(size_x - 100.0, xy[:, 0], s)
        at = np.linspace(s0, s1, max(int(round((s1 - s0) / step)), 2) + 1)
        wp = np.column_stack([np.interp(at, s, xy[:, 0]), np.interp(at, s, xy[:, 1])])
        z = _ground_heights(wp, env, h_above, 0.5 * math.tan(vehicle.max_climb))
        if z is None:
            continue
        route = np.round(np.column_stack([wp, z]), 2)
        if not _planted_ok(route, env, hazard) or not straight_fails(route, env, hazard):
            continue
        if profile_flyable(route[[0, -1], :2], env, vehicle):
            continue
        what = (f"a valley {2 * half:.0f} m wide at the floor winding ±{np.degrees(psi):.0f} deg every {lam:.0f} m "
                f"from the west edge to the east edge, its walls rising over {run:.0f} m to a plateau "
                f"{plateau - max(f0, f1):.0f}-{plateau - min(f0, f1):.0f} m above the floor")
        return _terrain_map("valley", seed, env, route, hazard, what, dem)
    raise RuntimeError(f"valley: no flyable route in {MAX_ROUTE_DRAWS} draws (seed {seed})")


def _s_curve(p: np.ndarray, q: np.ndarray, step: float) -> np.ndarray:
    """Waypoints (K, 2) from p to q (2,), about ``step`` m apart in x, whose y moves from p's to q's on a
    smoothstep of x: heading east at both ends, the turns spread over many small ones (none past 60° for a
    lateral move up to 2.2 × the forward one)."""
    n = max(int(np.ceil(abs(q[0] - p[0]) / step)), 3)
    x = np.linspace(p[0], q[0], n + 1)
    return np.column_stack([x, p[1] + (q[1] - p[1]) * _smoothstep((x - p[0]) / (q[0] - p[0]))])


def _saddle(seed: int, rng: np.random.Generator, radars: bool = False, size_x: float = 2600.0,
            size_y: float = 1800.0, crest_half: tuple[float, float] = (30.0, 60.0),
            flank_run: tuple[float, float] = (280.0, 340.0), pass_half: tuple[float, float] = (70.0, 100.0),
            pass_run: tuple[float, float] = (220.0, 300.0), pass_height: tuple[float, float] = (30.0, 60.0),
            above: tuple[float, float] = (50.0, 70.0), offset: tuple[float, float] = (500.0, 750.0),
            ceiling: tuple[float, float] = (40.0, 55.0), step: float = 80.0, cell: float = DEM_CELL_M,
            hazard: HazardConfig = HAZARD) -> HardMap:
    """A terrain ridge across the start→goal direction (x) from the south edge to the north edge, with one saddle
    (issue 34); ``radars``: with a radar on each summit flanking the saddle (``saddle_radar``).

    The plain is flat at home's height. The ridge runs along x = x_r: a crest ``crest_half`` m either side of it, flanks
    falling on a smoothstep over ``flank_run`` m. The pass is a notch cut through it around y = y_s: a floor at
    ``pass_height`` m (below the band's ceiling over the plain, so a plane crosses it without climbing) 2·``pass_half``
    m wide, its walls rising on a smoothstep over ``pass_run`` m (the ground is the lower of the ridge and the notch).
    The crest stands out of reach (``_wall_rise``: flanks and notch walls too steep to turn on; the longest contour runs
    up one flank, round the notch and down the other; then a margin of 30-80 m): 1.1-1.25 km above the plain at the
    defaults. Start and goal lie on the plain, 150 m inside the west and east edges, where the straight line between
    them crosses the ridge ``offset`` m from the saddle, at the crest: no height profile along it keeps the band
    (``profile_flyable``). The planted route swings over to y_s (``_s_curve``), crosses the pass square-on and swings
    back to the goal, a waypoint at least every ``step`` m (the cost's terrain margin grows with a leg's length and the
    DEM's steepest slope, docs/method.md §5.2), ``above`` m above the highest ground near its legs
    (``_ground_heights``).
    With ``radars`` each flanking summit (on the crest 50-150 m past the notch's walls, 10 m above the ground)
    carries a radar whose range meets ``ceiling`` m above the route's pass height in the middle of the saddle (as
    ``ridge``'s), lower off it: the way through is low, and the generator checks with ``free_section`` that nothing
    in the notch is free above that cover."""
    vehicle = VehicleLimits()
    for _ in range(MAX_ROUTE_DRAWS):
        xr = 0.5 * size_x + rng.uniform(-150.0, 150.0)
        ys = rng.uniform(600.0, size_y - 600.0)
        top, run = rng.uniform(*crest_half), rng.uniform(*flank_run)
        p_half, p_run, p_h = rng.uniform(*pass_half), rng.uniform(*pass_run), rng.uniform(*pass_height)
        margin = rng.uniform(30.0, 80.0)
        contour = 2.0 * max(ys, size_y - ys) + 2.0 * (top + run) + 2.0 * p_run  # one flank, the notch, the other
        crest = float(np.ceil((_wall_rise(contour, max(run, p_run)) + margin) / 10.0) * 10.0)
        gx, gy = _grid(size_x, size_y, cell)
        ridge = crest * (1.0 - _smoothstep((np.abs(gx - xr) - top) / run))
        notch = p_h + (crest - p_h) * _smoothstep((np.abs(gy - ys) - p_half) / p_run)
        dem, terrain = _dem(np.minimum(ridge, notch), cell)
        side = rng.choice([-1.0, 1.0])
        y_cross = ys + side * rng.uniform(*offset)
        if not 200.0 <= y_cross <= size_y - 200.0:
            y_cross = 2.0 * ys - y_cross
        y0, y1 = np.clip(y_cross + rng.uniform(-150.0, 150.0, 2), 100.0, size_y - 100.0)
        x0, x1 = 150.0, size_x - 150.0
        reach = top + run + 100.0  # the pass straight runs 100 m past the flanks' feet
        a, b = np.array([xr - reach, ys]), np.array([xr + reach, ys])
        xy = densify(np.vstack([_s_curve(np.array([x0, y0]), a, step)[:-1],
                                 np.linspace(a, b, int(np.ceil(2.0 * reach / step)) + 1)[:-1],
                                 _s_curve(b, np.array([x1, y1]), step)]), step)
        env = _terrain_env(size_x, size_y, terrain)
        route = _route_over(xy, env, rng, (70.0, 110.0), above, vehicle)
        if route is None:
            continue
        obstacles, n_obstacles = [], 0
        if radars:
            in_pass = np.abs(route[:, 0] - xr) <= top + run
            h_cover = float(route[in_pass, 2].max()) + rng.uniform(*ceiling)
            dy = p_half + p_run + rng.uniform(50.0, 150.0)
            sites = np.array([[xr, ys - dy], [xr, ys + dy]])
            zs = env.ground(sites[:, 0], sites[:, 1]) + 10.0
            rows = np.round(np.column_stack([sites, zs, np.hypot(dy, zs - h_cover)]), 2)
            env = replace(env, radars=Radars(rows[:, :3], rows[:, 3], np.ones(2)))
            obstacles, n_obstacles = _radar_entries(rows), 2
        if not _planted_ok(route, env, hazard) or not straight_fails(route, env, hazard):
            continue
        if profile_flyable(route[[0, -1], :2], env, vehicle):
            continue
        if radars:
            way = free_section(env, xr, hazard)
            notch_way = way[np.abs(way[:, 0] - ys) <= p_half + p_run]
            if not len(notch_way) or notch_way[:, 1].max() > h_cover + 1.0:
                continue
        what = (f"a ridge {crest:.0f} m high across the map with one saddle {2 * p_half:.0f} m wide at "
                f"{p_h:.0f} m" + (f", radars on its two flanking summits covering the pass above {h_cover:.0f} m"
                                  if radars else ""))
        return _terrain_map("saddle_radar" if radars else "saddle", seed, env, route, hazard, what, dem, obstacles,
                            n_obstacles)
    raise RuntimeError(f"saddle: no flyable route in {MAX_ROUTE_DRAWS} draws (seed {seed})")


def _saddle_radar(seed: int, rng: np.random.Generator, **options: Any) -> HardMap:
    """``_saddle`` with radars on the summits flanking the saddle."""
    return _saddle(seed, rng, radars=True, **options)


def _gaussians(gx: np.ndarray, gy: np.ndarray, centre: np.ndarray, sigma: np.ndarray, peak: np.ndarray
               ) -> np.ndarray:
    """Sum over K Gaussian hills (centres (K, 2), widths σ (K,), peaks (K,)) on the grid (ny, nx)."""
    h = np.zeros(gx.shape)
    for (cx, cy), s, p in zip(centre, sigma, peak):
        h += p * np.exp(-0.5 * ((gx - cx) ** 2 + (gy - cy) ** 2) / (s * s))
    return h


def _polyline_distance(points: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Plan-view distance (M,) from points (M, 2) to the polyline xy (N, 2)."""
    near = np.full(len(points), np.inf)
    for p, q in zip(xy[:-1], xy[1:]):
        d = q - p
        t = np.clip(((points - p) @ d) / max(float(d @ d), 1e-12), 0.0, 1.0)
        near = np.minimum(near, np.linalg.norm(points - (p + t[:, None] * d), axis=1))
    return near


def _mixed(seed: int, rng: np.random.Generator, size: float = 2400.0, hills: tuple[int, int] = (6, 10),
           hill_height: tuple[float, float] = (80.0, 150.0), hill_sigma: tuple[float, float] = (250.0, 450.0),
           mountains: tuple[int, int] = (3, 5), mountain_height: tuple[float, float] = (350.0, 600.0),
           mountain_sigma: tuple[float, float] = (120.0, 200.0), cylinders: tuple[int, int] = (25, 35),
           radius: tuple[float, float] = (40.0, 80.0), radar_range: tuple[float, float] = (150.0, 250.0),
           n_legs: int = 12, amplitude: float = 500.0, max_turn_deg: float = 40.0,
           divisors: Sequence[float] = (1.0, 2.0, 3.0), above: tuple[float, float] = (50.0, 70.0),
           step: float = 120.0, cell: float = DEM_CELL_M, hazard: HazardConfig = HAZARD) -> HardMap:
    """Terrain, cylinders and a radar together (issue 34), around a planted route from the south-west corner to the
    north-east one.

    The ground is rolling hills (``hills`` Gaussians of ``hill_sigma`` m, scaled to a highest node of
    ``hill_height``) and ``mountains`` steep Gaussian peaks of ``mountain_height`` and ``mountain_sigma`` m, far
    above the band's ceiling. The route's plan view weaves first (``_planted_wiggle``: ``n_legs`` legs, turns up to
    ``max_turn_deg``), then the mountains stand off it, every one at least 3σ + 50 m from it and half of them
    centred on the straight start→goal line; the route, its legs cut to ``step`` m, takes heights ``above`` m over
    the highest ground near them (``_ground_heights``). Unlimited cylinders of ``radius`` m (half near the straight
    line) and one radar on the ground near the line (range ``radar_range``) come last, outside the route's
    corridor. The straight route fails the checker (the generator checks)."""
    vehicle = VehicleLimits()
    gx, gy = _grid(size, size, cell)
    start2, goal2 = np.array([150.0, 150.0]), np.array([size - 150.0, size - 150.0])
    for _ in range(MAX_ROUTE_DRAWS):
        wiggle = _planted_wiggle(rng, np.append(start2, 0.0), np.append(goal2, 0.0), n_legs, amplitude,
                                 max_turn_deg, divisors)
        if wiggle is None or (wiggle[:, :2] < 100.0).any() or (wiggle[:, :2] > size - 100.0).any():
            continue
        xy = densify(wiggle[:, :2], step)
        k = int(rng.integers(hills[0], hills[1] + 1))
        base = _gaussians(gx, gy, rng.uniform(0.0, size, (k, 2)), rng.uniform(*hill_sigma, k),
                          rng.uniform(0.3, 1.0, k))
        base *= rng.uniform(*hill_height) / base.max()
        n_m = int(rng.integers(mountains[0], mountains[1] + 1))
        peaks: list[tuple[float, float, float, float]] = []  # x, y, sigma, height
        for _ in range(50 * n_m):
            if len(peaks) == n_m:
                break
            on_line = len(peaks) < (n_m + 1) // 2
            c = start2 + rng.uniform(0.15, 0.85) * (goal2 - start2) if on_line else rng.uniform(0.0, size, 2)
            sigma, height = rng.uniform(*mountain_sigma), rng.uniform(*mountain_height)
            if (_polyline_distance(c[None], xy)[0] >= 3.0 * sigma + 50.0
                    and min(np.linalg.norm(c - start2), np.linalg.norm(c - goal2)) >= 3.0 * sigma + 50.0):
                peaks.append((float(c[0]), float(c[1]), sigma, height))
        if len(peaks) < n_m:
            continue
        pk = np.array(peaks)
        dem, terrain = _dem(base + _gaussians(gx, gy, pk[:, :2], pk[:, 2], pk[:, 3]), cell)
        env = _terrain_env(size, size, terrain)
        route = _route_over(xy, env, rng, (60.0, 100.0), above, vehicle)
        if route is None:
            continue
        points, need = corridor(route, hazard)
        n_c = int(rng.integers(cylinders[0], cylinders[1] + 1))
        cand = np.where((rng.random(20 * n_c) < 0.5)[:, None],
                        start2 + rng.uniform(0.1, 0.9, (20 * n_c, 1)) * (goal2 - start2)
                        + rng.normal(0.0, 120.0, (20 * n_c, 2)), rng.uniform(0.0, size, (20 * n_c, 2)))
        r = rng.uniform(*radius, 20 * n_c)
        clear = cylinder_signed_distance(points[None], cand[:, 0, None], cand[:, 1, None], r[:, None], np.inf)
        ok = np.flatnonzero((clear >= need).all(axis=1) & (cand >= 0.0).all(axis=1) & (cand <= size).all(axis=1))
        cyl, rc = np.round(cand[ok[:n_c]], 2), np.round(r[ok[:n_c]], 2)
        site = start2 + rng.uniform(0.3, 0.7, (30, 1)) * (goal2 - start2) + rng.uniform(-100.0, 100.0, (30, 2))
        site_z = env.ground(site[:, 0], site[:, 1]) + 10.0
        r_det = rng.uniform(*radar_range, 30)
        rad_clear = np.linalg.norm(points[None] - np.column_stack([site, site_z])[:, None], axis=-1) - r_det[:, None]
        fits = np.flatnonzero((rad_clear >= need - hazard.d_coll).all(axis=1))
        if len(cyl) < n_c or not len(fits):
            continue
        radar = np.round(np.append(np.column_stack([site, site_z])[fits[0]], r_det[fits[0]]), 2)[None]
        env = replace(env, cylinders=_cylinders(cyl, rc), radars=Radars(radar[:, :3], radar[:, 3], np.ones(1)))
        if not _planted_ok(route, env, hazard) or not straight_fails(route, env, hazard):
            continue
        what = (f"{n_m} mountains {pk[:, 3].min():.0f}-{pk[:, 3].max():.0f} m high off a planted route over hills up "
                f"to {base.max():.0f} m, {len(cyl)} unlimited cylinders and a radar (range {radar[0, 3]:.0f} m)")
        return _terrain_map("mixed", seed, env, route, hazard, what, dem, _cylinder_entries(cyl, rc)
                            + _radar_entries(radar), len(cyl) + 1)
    raise RuntimeError(f"mixed: no flyable route in {MAX_ROUTE_DRAWS} draws (seed {seed})")


# --- shared -------------------------------------------------------------------------------------------------
def _cylinders(xy: np.ndarray, r: np.ndarray) -> Cylinders:
    """Unlimited cylinders at centres xy (K, 2) with radii r (K,)."""
    return Cylinders(xy[:, 0], xy[:, 1], r, np.full(len(r), np.inf), np.zeros(len(r)))


def _spheres(rows: np.ndarray) -> Spheres:
    """Spheres from rows (K, 4) of x, y, z, radius."""
    return Spheres(rows[:, :3], rows[:, 3])


def _chain(poly: np.ndarray, radius: float) -> np.ndarray:
    """Centres (K, 2) of overlapping cylinders along a polyline (M, 2), both ends included, at most 1.5 R apart
    along it (as ``_wall``): the chain is a wall nothing passes, however it bends."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poly, axis=0), axis=1))])
    at = np.linspace(0.0, s[-1], int(np.ceil(s[-1] / (1.5 * radius))) + 1)
    return np.column_stack([np.interp(at, s, poly[:, 0]), np.interp(at, s, poly[:, 1])])


Entry = tuple[str, dict[str, Fixed]]  # an array-of-tables entry for toml_text.dumps: ("cylinders", {"x": ...})


def _entries(name: str, rows: Iterable[Sequence[float]], keys: Sequence[str]) -> list[Entry]:
    """``[[name]]`` entries, one a row, its values under ``keys`` to 0.01 m (the generator's precision)."""
    return [(name, {k: Fixed(float(v)) for k, v in zip(keys, row)}) for row in rows]


def _cylinder_entries(xy: np.ndarray, r: np.ndarray) -> list[Entry]:
    """``[[cylinders]]`` entries (unlimited) for centres xy (K, 2) and radii r (K,)."""
    return _entries("cylinders", np.column_stack([xy, r]), ("x", "y", "radius"))


def _hemisphere_entries(rows: np.ndarray) -> list[Entry]:
    """``[[hemispheres]]`` entries for rows (K, 3) of x, y, radius."""
    return _entries("hemispheres", rows, ("x", "y", "radius"))


def _radar_entries(rows: np.ndarray) -> list[Entry]:
    """``[[radars]]`` entries with a given detection range for rows (K, 4) of x, y, z, r_det."""
    return _entries("radars", rows, ("x", "y", "z", "r_det"))


def _only_the_planted_way(route: np.ndarray, env: Environment, hazard: HazardConfig) -> bool:
    """The planted route passes every check on ``env`` (``_planted_ok``) and the straight line does not."""
    return _planted_ok(route, env, hazard) and _straight_blocked(route, env, hazard)


def _walled_env(size_x: float, size_y: float, xy: np.ndarray, r: np.ndarray) -> Environment:
    """A map of unlimited cylinders at centres xy (K, 2) with radii r (K,), in the hard maps' band."""
    return Environment(size_x, size_y, *BAND, cylinders=_cylinders(xy, r))


def _walled_map(family: str, seed: int, env: Environment, route: np.ndarray, hazard: HazardConfig, what: str,
                xy: np.ndarray, r: np.ndarray) -> HardMap:
    """The HardMap of a map of unlimited cylinders (``_walled_env``) and its planted route."""
    text = _scenario_text(family, seed, env.size_x, env.size_y, route, hazard, what, _cylinder_entries(xy, r))
    return HardMap(family, seed, text, route, len(xy), _straight_blocked(route, env, hazard))


def _straight_blocked(route: np.ndarray, env: Environment, hazard: HazardConfig) -> bool:
    """True if the straight start→goal segment comes within d_coll of an obstacle (§12's collision test) or, over
    terrain, leaves the altitude band (flat ground: start and goal lie in the band, so the segment does too)."""
    t = np.linspace(0.0, 1.0, int(np.linalg.norm(route[-1] - route[0]) / CHORD_STEP_M) + 2)[:, None]
    pts = route[0] + t * (route[-1] - route[0])
    h = pts[:, 2] - env.ground(pts[:, 0], pts[:, 1])
    return bool((obstacle_clearance(pts, None, env) < hazard.d_coll).any()
                or ((h < env.z_min) | (h > env.z_max)).any())


def straight_fails(route: np.ndarray, env: Environment, hazard: HazardConfig = HAZARD) -> bool:
    """True if the straight start→goal route (two waypoints) fails the checker or the cost (``route_violations``):
    the map is not trivial."""
    return any(route_violations(route[[0, -1]], env, hazard).values())


def _scenario_text(family: str, seed: int, size_x: float, size_y: float, route: np.ndarray, hazard: HazardConfig,
                   what: str, obstacles: list[Entry], band: tuple[float, float] = BAND, dem_name: str = "") -> str:
    """The scenario's text (docs/scenario_format.md), its ``obstacles`` last; default vehicle and planner settings;
    with ``dem_name`` a ``[terrain]`` table naming that DEM beside the scenario."""
    keeps = "the terrain and obstacles keep" if dem_name else "obstacles keep"
    header = (f'Generated by planner.bench.hardmaps (issue {34 if dem_name else 15}): family "{family}", seed {seed}.\n'
              f"A planted route ({len(route)} waypoints) is flyable; {keeps} a corridor around it.")
    raw = {"name": f"hardmap_{family}_{seed}", "description": what,
           "home": Table(lat=HOME[0], lon=HOME[1], alt=HOME[2]),
           "bounds": {"x": Fixed(size_x), "y": Fixed(size_y)},
           "altitude": {"min": Fixed(band[0]), "max": Fixed(band[1])},
           "terrain": {"kind": "file", "path": dem_name} if dem_name else None,
           "route": {"start": [Fixed(float(v)) for v in route[0]], "goal": [Fixed(float(v)) for v in route[-1]]},
           "hazard": {"d_safe": Fixed(hazard.d_safe), "d_coll": Fixed(hazard.d_coll)}}
    return dumps(raw, header, {"terrain": DEM_NOTE}, obstacles)


_GENERATORS: dict[str, Callable[..., HardMap]] = {"gates": _gates, "dense": _dense, "maze": _maze,
                                                   "ridge": _ridge, "canyon": _canyon,
                                                   "valley": _valley, "saddle": _saddle,
                                                   "saddle_radar": _saddle_radar, "mixed": _mixed}
