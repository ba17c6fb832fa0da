"""Hard maps with a known answer (issue 15): map families, each with a planted flyable route.

The route is drawn first and verified with the planner's own checker (docs/method.md §11 smoothing, §12 check);
the obstacles come second and leave a corridor around it, so a failure on these maps is the planner's, never the
map's. Families: ``gates`` (walls of no-fly cylinders with one gap each, on alternating sides) and ``dense``
(a random field of cylinders, spheres and hemispheres, docs/method.md §2).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.problem import PlanningProblem
from planner.trajectory.checks import check_trajectory, obstacle_clearance, smooth
from planner.trajectory.smoothing import flown_deviation, segment_samples
from planner.world.config import HazardConfig, PlannerSettings, VehicleLimits
from planner.world.environment import Cylinders, Environment, Spheres
from planner.world.geometry import cylinder_signed_distance, horizontal_turn

FAMILIES = ("gates", "dense")
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
    env = _free_env(size_x, size_y)
    for _ in range(MAX_ROUTE_DRAWS):
        y0, y1 = size_y / 2 + rng.uniform(-50.0, 50.0, 2)
        line_y = y0 + (y1 - y0) * (walls_x - 100.0) / (size_x - 200.0)
        side = rng.choice([-1.0, 1.0]) * (-1.0) ** np.arange(n)
        centres = np.round(line_y + side * rng.uniform(0.5 * gap + radius, 0.5 * gap + 2 * radius, n), 2)
        xy = np.concatenate([[[100.0, y0]], np.column_stack([np.repeat(walls_x, 2) + np.tile([-half, half], n),
                                                              np.repeat(centres, 2)]), [[size_x - 100.0, y1]]])
        z0, z1 = rng.uniform(80.0, 160.0, 2)
        route = np.round(np.column_stack([xy, _heights(xy, z0, z1)]), 2)
        if any(route_violations(route, env, hazard).values()):
            continue
        cyl = np.round(np.concatenate([_wall(x, c, gap, radius, size_y) for x, c in zip(walls_x, centres)]), 2)
        r = np.full(len(cyl), radius)
        env_full = Environment(size_x, size_y, *BAND, cylinders=_cylinders(cyl, r))
        points, need = corridor(route, hazard)
        if (obstacle_clearance(points, None, env_full) < need).any():
            continue
        if any(route_violations(route, env_full, hazard).values()):
            continue
        blocked = _straight_blocked(route, env_full, hazard)
        body = "".join(f"\n[[cylinders]]\nx = {x:.2f}\ny = {y:.2f}\nradius = {radius:.2f}\n" for x, y in cyl)
        text = _header("gates", seed, size_x, size_y, route, hazard,
                       f"{n} walls of unlimited cylinders, one {gap:g} m gap each on alternating sides") + body
        return HardMap("gates", seed, text, route, len(cyl), blocked)
    raise RuntimeError(f"gates: no flyable route in {MAX_ROUTE_DRAWS} draws (seed {seed})")


# --- dense --------------------------------------------------------------------------------------------------
def _planted_wiggle(rng: np.random.Generator, start: np.ndarray, goal: np.ndarray, n_legs: int,
                    amplitude: float, max_turn_deg: float) -> np.ndarray | None:
    """A route start→goal with lateral offset Σ a_i sin(iπt) (three harmonics) and a gentle height bump;
    None if a heading change exceeds ``max_turn_deg``."""
    t = np.linspace(0.0, 1.0, n_legs + 1)
    a = rng.uniform(-1.0, 1.0, 3) * amplitude / np.array([1.0, 2.0, 4.0])
    off = (a[:, None] * np.sin(np.arange(1, 4)[:, None] * np.pi * t)).sum(axis=0)
    d = (goal - start)[:2]
    normal = np.array([-d[1], d[0]]) / np.linalg.norm(d)
    xy = start[:2] + t[:, None] * d + off[:, None] * normal
    z = start[2] + t * (goal[2] - start[2]) + rng.uniform(0.0, 60.0) * np.sin(np.pi * t)
    route = np.round(np.column_stack([xy, z]), 2)
    if np.degrees(horizontal_turn(np.diff(route, axis=0))).max() > max_turn_deg:
        return None
    return route


def _dense(seed: int, rng: np.random.Generator, count: int = 150, size: float = 2000.0,
           radius: tuple[float, float] = (30.0, 70.0), sphere_z: tuple[float, float] = (60.0, 250.0),
           n_legs: int = 8, amplitude: float = 400.0, hazard: HazardConfig = HAZARD, batch: int = 256,
           max_batches: int = 400) -> HardMap:
    """About ``count`` cylinders, spheres and hemispheres by rejection sampling outside the planted route's
    corridor. Fewer if the sampler gives up after ``max_batches`` batches (``HardMap.n_obstacles`` tells)."""
    env = _free_env(size, size)
    for _ in range(MAX_ROUTE_DRAWS):
        start = np.array([150.0, 150.0, rng.uniform(80.0, 160.0)])
        goal = np.array([size - 150.0, size - 150.0, rng.uniform(80.0, 160.0)])
        route = _planted_wiggle(rng, start, goal, n_legs, amplitude, 40.0)
        if route is not None and not any(route_violations(route, env, hazard).values()):
            break
    else:
        raise RuntimeError(f"dense: no flyable route in {MAX_ROUTE_DRAWS} draws (seed {seed})")
    points, need = corridor(route, hazard)
    kinds, rows = [], []
    for _ in range(max_batches):
        if len(rows) >= count:
            break
        kind = rng.integers(0, 3, batch)  # 0 cylinder, 1 sphere, 2 hemisphere
        x, y = rng.uniform(0.0, size, (2, batch))
        r = rng.uniform(*radius, batch)
        z = np.where(kind == 1, rng.uniform(*sphere_z, batch), 0.0)
        cand = np.round(np.column_stack([x, y, z, r]), 2)
        col = (slice(None), None)
        cyl_clear = cylinder_signed_distance(points[None], cand[col + (0,)], cand[col + (1,)], cand[col + (3,)],
                                             np.inf)
        clear = np.where((kind == 0)[:, None], cyl_clear, sphere_clearance(points, cand[:, :3], cand[:, 3]))
        ok = np.flatnonzero((clear >= need).all(axis=1))[: count - len(rows)]
        kinds.extend(kind[ok].tolist())
        rows.extend(cand[ok].tolist())
    kinds_a, obs = np.array(kinds, dtype=int), np.array(rows).reshape(-1, 4)
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
    text = _header("dense", seed, size, size, route, hazard,
                   f"{len(obs)} random cylinders, spheres and hemispheres off a planted route") + "".join(body)
    return HardMap("dense", seed, text, route, len(obs), _straight_blocked(route, env_full, hazard))


# --- shared -------------------------------------------------------------------------------------------------
def _cylinders(xy: np.ndarray, r: np.ndarray) -> Cylinders:
    """Unlimited cylinders at centres xy (K, 2) with radii r (K,)."""
    return Cylinders(xy[:, 0], xy[:, 1], r, np.full(len(r), np.inf), np.zeros(len(r)))


def _spheres(rows: np.ndarray) -> Spheres:
    """Spheres from rows (K, 4) of x, y, z, radius."""
    return Spheres(rows[:, :3], rows[:, 3])


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


_GENERATORS: dict[str, Callable[..., HardMap]] = {"gates": _gates, "dense": _dense}
