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
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from planner.problem import PlanningProblem
from planner.trajectory.checks import check_trajectory, obstacle_clearance, radar_clearance, smooth
from planner.trajectory.smoothing import flown_deviation, segment_samples
from planner.world.config import HazardConfig, PlannerSettings, VehicleLimits
from planner.world.environment import Cylinders, Environment, Radars, Spheres
from planner.world.geometry import cylinder_signed_distance, horizontal_turn

FAMILIES = ("gates", "dense", "maze", "ridge", "canyon")
BAND = (50.0, 300.0)  # altitude band above terrain, m
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


def generate(family: str, seed: int, **options: Any) -> HardMap:
    """Generate the map of ``family`` for ``seed``; every random draw comes from ``np.random.default_rng(seed)``,
    so the same seed gives the same text and route. ``options`` go to the family's generator."""
    if family not in _GENERATORS:
        raise ValueError(f"unknown family {family!r}; expected one of {FAMILIES}")
    return _GENERATORS[family](seed, np.random.default_rng(seed), **options)


ROADMAP_SECTION = """
# The paper's fusion (the default planner) fails on most maps like this one: their way through leaves the ±45°
# cone around the start->goal line (docs/results/robustness.md). Planned with the roadmap pipeline (method.md §15).
[planner.roadmap]
enabled = true
"""


def write_scenarios(directory: str | Path, families: Sequence[str] = FAMILIES, seeds: Iterable[int] = (0,),
                    roadmap: bool = False) -> list[Path]:
    """Write the map of every family and seed to ``directory`` (created if missing) as
    ``hardmap_{family}_{seed}.toml``, the text exactly ``HardMap.toml`` (``roadmap``: then :data:`ROADMAP_SECTION`,
    which plans it with the roadmap pipeline, as the shipped ones in sitl_scenarios/), so the bench and
    ``fuseplan plan`` can read them like any scenario; returns the paths in the order written (families outer,
    seeds inner)."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    seeds = tuple(seeds)
    paths = []
    for family in families:
        for seed in seeds:
            path = out / f"hardmap_{family}_{seed}.toml"
            path.write_text(generate(family, seed).toml + (ROADMAP_SECTION if roadmap else ""))
            paths.append(path)
    return paths


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
    """The checks of a planted route on the full map ``env``: flyable without obstacles (limits, band, bounds),
    its corridor clear of every solid obstacle, its tracking margin + buffer (the corridor less d_coll, which is
    for solids only) clear of every radar range, and flyable among them all (``route_violations``)."""
    if any(route_violations(route, _free_env(env.size_x, env.size_y), hazard).values()):
        return False
    points, need = corridor(route, hazard)
    if (obstacle_clearance(points, None, env, include_radars=False) < need).any():
        return False
    if (radar_clearance(points, env.radars) < need - hazard.d_coll).any():
        return False
    return not any(route_violations(route, env, hazard).values())


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
    kinds_l, rows = [], []
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
    body = []
    for k, (x, y, z, r) in zip(kinds_a, obs):
        if k == 0:
            body.append(f"\n[[cylinders]]\nx = {x:.2f}\ny = {y:.2f}\nradius = {r:.2f}\n")
        elif k == 1:
            body.append(f"\n[[spheres]]\nx = {x:.2f}\ny = {y:.2f}\nz = {z:.2f}\nradius = {r:.2f}\n")
        else:
            body.append(f"\n[[hemispheres]]\nx = {x:.2f}\ny = {y:.2f}\nradius = {r:.2f}\n")
    what = (f"{len(obs)} obstacles off a planted route: {len(cyl)} unlimited cylinders, {len(sph)} spheres and "
            f"hemispheres, some in {n_clusters} clumps")
    text = _header("dense", seed, size, size, route, hazard, what) + "".join(body)
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
        text = (_header("ridge", seed, size_x, size_y, route, hazard, what) + _toml_hemispheres(hemi)
                + _toml_radars(radars))
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


def _toml_cylinders(xy: np.ndarray, r: np.ndarray) -> str:
    """``[[cylinders]]`` entries (unlimited) for centres xy (K, 2) and radii r (K,)."""
    return "".join(f"\n[[cylinders]]\nx = {x:.2f}\ny = {y:.2f}\nradius = {rr:.2f}\n" for (x, y), rr in zip(xy, r))


def _toml_hemispheres(rows: np.ndarray) -> str:
    """``[[hemispheres]]`` entries for rows (K, 3) of x, y, radius."""
    return "".join(f"\n[[hemispheres]]\nx = {x:.2f}\ny = {y:.2f}\nradius = {r:.2f}\n" for x, y, r in rows)


def _toml_radars(rows: np.ndarray) -> str:
    """``[[radars]]`` entries with a given detection range for rows (K, 4) of x, y, z, r_det."""
    return "".join(f"\n[[radars]]\nx = {x:.2f}\ny = {y:.2f}\nz = {z:.2f}\nr_det = {r:.2f}\n"
                   for x, y, z, r in rows)


def _only_the_planted_way(route: np.ndarray, env: Environment, hazard: HazardConfig) -> bool:
    """The planted route passes every check on ``env`` (``_planted_ok``) and the straight line does not."""
    return _planted_ok(route, env, hazard) and _straight_blocked(route, env, hazard)


def _walled_env(size_x: float, size_y: float, xy: np.ndarray, r: np.ndarray) -> Environment:
    """A map of unlimited cylinders at centres xy (K, 2) with radii r (K,), in the hard maps' band."""
    return Environment(size_x, size_y, *BAND, cylinders=_cylinders(xy, r))


def _walled_map(family: str, seed: int, env: Environment, route: np.ndarray, hazard: HazardConfig, what: str,
                xy: np.ndarray, r: np.ndarray) -> HardMap:
    """The HardMap of a map of unlimited cylinders (``_walled_env``) and its planted route."""
    text = _header(family, seed, env.size_x, env.size_y, route, hazard, what) + _toml_cylinders(xy, r)
    return HardMap(family, seed, text, route, len(xy), _straight_blocked(route, env, hazard))


def _straight_blocked(route: np.ndarray, env: Environment, hazard: HazardConfig) -> bool:
    """True if the straight start→goal segment comes within d_coll of an obstacle (§12's collision test)."""
    t = np.linspace(0.0, 1.0, int(np.linalg.norm(route[-1] - route[0]) / CHORD_STEP_M) + 2)[:, None]
    pts = route[0] + t * (route[-1] - route[0])
    return bool((obstacle_clearance(pts, None, env) < hazard.d_coll).any())


def _header(family: str, seed: int, size_x: float, size_y: float, route: np.ndarray, hazard: HazardConfig,
            what: str) -> str:
    """Scenario text up to the obstacles (docs/scenario_format.md); default vehicle and planner settings."""
    s, g = (", ".join(f"{v:.2f}" for v in p) for p in (route[0], route[-1]))
    return (f'# Generated by planner.bench.hardmaps (issue 15): family "{family}", seed {seed}.\n'
            f"# A planted route ({len(route)} waypoints) is flyable; obstacles keep a corridor around it.\n"
            f'name = "hardmap_{family}_{seed}"\ndescription = "{what}"\n\n'
            f"[home]\nlat = {HOME[0]}\nlon = {HOME[1]}\nalt = {HOME[2]}\n\n"
            f"[bounds]\nx = {size_x:.2f}\ny = {size_y:.2f}\n\n"
            f"[altitude]\nmin = {BAND[0]:.2f}\nmax = {BAND[1]:.2f}\n\n"
            f"[route]\nstart = [{s}]\ngoal = [{g}]\n\n"
            f"[hazard]\nd_safe = {hazard.d_safe:.2f}\nd_coll = {hazard.d_coll:.2f}\n")


_GENERATORS: dict[str, Callable[..., HardMap]] = {"gates": _gates, "dense": _dense, "maze": _maze,
                                                   "ridge": _ridge, "canyon": _canyon}
