"""OMPL's sampling planners as peers on fuseplan's problems (issue 15): same map, same clearances, same verdict.

A peer plans in R³ (the map bounds × the altitude band) with a state validity test built on the project's own
geometry: a state is valid when its clearance from every static obstacle (:func:`obstacle_clearance`) is at least
d_coll plus the tracking margin (half the acceptance radius: how far the flown curve may cut a corner) and it is
that margin outside every radar's detection range. Motions are checked by OMPL at ``RESOLUTION_M`` spacing. The
route it returns is judged by :func:`planner.bench.hardmaps.route_violations`, the verdict our own plans get.
Dynamic threats are not modelled (the peers are static planners).

Reproducibility: OMPL's RNG is seeded per solve. RRTConnect stops at its first solution, so with simplification
it gives the same route for the same seed, in one process or across processes; BIT* is anytime against the wall
clock, so how far it gets (and its route) varies from run to run.

OMPL (PyPI ``ompl`` ≥ 2.0.1, nanobind bindings) is the optional ``peers`` extra, never a core dependency;
without it :func:`solve` raises :class:`FuseplanError` saying how to install it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from types import ModuleType
from typing import Any

import numpy as np

from planner.bench.hardmaps import route_violations
from planner.errors import FuseplanError
from planner.problem import PlanningProblem
from planner.trajectory.checks import obstacle_clearance
from planner.world.environment import Cylinders, Environment, Prisms, Radars, Spheres, Threats

PLANNERS = ("rrtconnect", "bitstar")
INSTALL_HINT = "install the peers extra: pip install -e '.[peers]'"
RESOLUTION_M = 3.0  # motion checks every ~3 m along an edge: between two checked states a chord loses ≤ 1.5 m
CELL_M = 25.0  # cell of the free-space grid that spares most states the exact clearance call
MAX_CELLS = 250_000  # coarser cells on very large maps, to bound the grid's set-up

StateTest = Callable[[float, float, float], bool]
_NONE = np.zeros(0, dtype=np.intp)
_Reach = tuple[tuple[float, float, float, float], ...]  # (x, y, z, reach²) per obstacle
_Square = tuple[_Reach, _Reach, StateTest]  # a grid square: cylinders' and prisms' discs, balls, exact test


@dataclass
class PeerResult:
    """One peer run. ``found``: OMPL reports an exact solution; ``route`` (N, 3) ENU m, start and goal included,
    after simplification (None without an exact solution); ``raw_waypoints``: states of the planner's own path;
    ``time_s``: wall time of solve + simplify; ``length_m``: length of the waypoint polyline; ``flyable``: the
    route passes :func:`route_violations` with no violation (``violations`` per category, empty without a
    route). ``status`` is OMPL's PlannerStatus text, ``state_checks`` the validity calls made."""

    planner: str
    found: bool
    route: np.ndarray | None
    raw_waypoints: int
    time_s: float
    length_m: float
    flyable: bool
    violations: dict[str, int] = field(default_factory=dict)
    status: str = ""
    state_checks: int = 0


# --- OMPL, optional ----------------------------------------------------------------------------------------------
def _ompl() -> tuple[ModuleType, ModuleType, ModuleType]:
    """OMPL's base, geometric and util modules, or FuseplanError naming the extra to install."""
    try:
        from ompl import base, geometric, util
    except ImportError as exc:
        raise FuseplanError(f"OMPL peers need the ompl package ({exc}); {INSTALL_HINT}") from exc
    return base, geometric, util


def available() -> bool:
    """True if OMPL can be imported (the ``peers`` extra is installed)."""
    try:
        _ompl()
    except FuseplanError:
        return False
    return True


# --- state validity on the project's geometry --------------------------------------------------------------------
def tracking_margin(problem: PlanningProblem) -> float:
    """How far the flown curve may cut inside a waypoint chord: half the acceptance radius (as the hard-map
    corridor assumes), so clearance kept at the states survives the smoothing the verdict flies."""
    return 0.5 * problem.vehicle.acceptance_radius


def altitude_limits(env: Environment) -> tuple[float, float]:
    """z range of the state space: the band, lifted by the lowest and highest ground under it with terrain."""
    if env.terrain is None:
        return env.z_min, env.z_max
    h = env.terrain.heights
    return float(h.min()) + env.z_min, float(h.max()) + env.z_max


_Disc = tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]  # x, y, z (None: a cylinder's), reach


def _discs(env: Environment, need_solid: float, need_radar: float) -> dict[str, _Disc]:
    """Per family, centres (x, y, z) and reach (radius + need): a point farther than the reach from a sphere's
    or a radar's centre, or horizontally from a cylinder's axis, clears that obstacle. Both distances less the
    radius bound the exact clearance from below (for a cylinder with a finite top too); cylinders have no z."""
    cyl, sph, rad, pri = env.cylinders, env.spheres, env.radars, env.prisms
    return {
        "cylinders": (cyl.x, cyl.y, None, cyl.radius + need_solid),
        "spheres": (sph.center[:, 0], sph.center[:, 1], sph.center[:, 2], sph.radius + need_solid),
        "radars": (rad.center[:, 0], rad.center[:, 1], rad.center[:, 2], rad.r_det + need_radar),
        # a prism's disc holds its polygon; a keep-in polygon (no-fly outside it) reaches everywhere
        "prisms": (pri.cx, pri.cy, None, np.where(pri.keep_in, np.inf, pri.r + need_solid)),
    }


def _cell_members(x: np.ndarray, y: np.ndarray, reach: np.ndarray, cell: float, shape: tuple[int, int],
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(flat cell index, disc index) pairs where a disc reaches into a cell (rectangle–disc distance < reach).
    A loop over the discs (set-up only), each on the cells of its bounding box."""
    nx, ny = shape
    cells, owners = [np.zeros(0, dtype=np.intp)], [np.zeros(0, dtype=np.intp)]
    for k in range(len(x)):
        r = min(float(reach[k]), 4.0 * cell * (nx + ny))  # an unlimited reach covers every cell
        i0, i1 = max(int((x[k] - r) // cell), 0), min(int((x[k] + r) // cell), nx - 1)
        j0, j1 = max(int((y[k] - r) // cell), 0), min(int((y[k] + r) // cell), ny - 1)
        if i1 < i0 or j1 < j0:
            continue
        ii, jj = np.meshgrid(np.arange(i0, i1 + 1), np.arange(j0, j1 + 1), indexing="ij")
        dx = np.maximum(np.maximum(ii * cell - x[k], x[k] - (ii + 1) * cell), 0.0)
        dy = np.maximum(np.maximum(jj * cell - y[k], y[k] - (jj + 1) * cell), 0.0)
        hit = dx * dx + dy * dy < reach[k] ** 2
        cells.append((ii * ny + jj)[hit])
        owners.append(np.full(int(hit.sum()), k, dtype=np.intp))
    return np.concatenate(cells), np.concatenate(owners)


def _group(cells: np.ndarray, owners: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """(cell, sorted owner indices) for every cell in the (cell, owner) pairs."""
    order = np.lexsort((owners, cells))
    cells, owners = cells[order], owners[order]
    first = np.flatnonzero(np.diff(cells, prepend=-1))
    return list(zip(cells[first].tolist(), np.split(owners, first[1:])))


def _reach(disc: _Disc, idx: np.ndarray) -> _Reach:
    """(x, y, z, reach²) as plain floats for the listed members of one family (z 0 for cylinders, unused)."""
    x, y, z, reach = disc
    zs = np.zeros(len(idx)) if z is None else z[idx]
    return tuple(zip(x[idx].tolist(), y[idx].tolist(), zs.tolist(), (reach[idx] ** 2).tolist()))


def _sub_environment(env: Environment, cyl: np.ndarray, sph: np.ndarray, rad: np.ndarray,
                     pri: np.ndarray) -> Environment:
    """``env`` with only the listed cylinders, spheres, radars and prisms (and no threats)."""
    c, s, r, p = env.cylinders, env.spheres, env.radars, env.prisms
    return replace(env, cylinders=Cylinders(c.x[cyl], c.y[cyl], c.radius[cyl], c.top[cyl], c.z_ref[cyl]),
                   spheres=Spheres(s.center[sph], s.radius[sph]),
                   radars=Radars(r.center[rad], r.r_det[rad], r.soft_weight[rad]),
                   prisms=Prisms.from_polygons([p.polygon(k) for k in pri], p.floor[pri], p.ceiling[pri],
                                               p.keep_in[pri]), threats=Threats())


def _exact_test(env: Environment, need_solid: float, need_radar: float) -> StateTest:
    """Clearance test of one point on ``env`` (a cell's few obstacles) with the checker's own
    :func:`obstacle_clearance`: solids need ``need_solid``, radars ``need_radar`` beyond detection range."""
    solid = replace(env, radars=Radars.empty()) if len(env.cylinders) + len(env.spheres) + len(env.prisms) else None
    radar = (replace(env, cylinders=Cylinders.empty(), spheres=Spheres.empty(), prisms=Prisms.empty())
             if len(env.radars) else None)

    def test(x: float, y: float, z: float) -> bool:  # a Python bool: OMPL's callback cannot take numpy's
        p = np.array(((x, y, z),))
        if solid is not None and float(obstacle_clearance(p, None, solid, include_radars=False)[0]) < need_solid:
            return False
        return radar is None or float(obstacle_clearance(p, None, radar)[0]) >= need_radar

    return test


def state_validity(problem: PlanningProblem, cell: float = CELL_M) -> StateTest:
    """``valid(x, y, z)``: inside the bounds and the altitude band (above the ground with terrain), clear of
    every static obstacle by d_coll + tracking margin and of every radar's detection range by the margin.

    Built for OMPL's per-state calls (a light Python function, no numpy for most states): a grid of ``cell`` m
    squares lists the obstacles whose reach (:func:`_discs`) meets each square. A state within no listed
    obstacle's reach passes on plain arithmetic (a lower bound of its clearance); any other is decided by
    :func:`obstacle_clearance` on that square's few obstacles, the checker's exact geometry."""
    env = problem.env
    margin = tracking_margin(problem)
    need_solid, need_radar = problem.hazard.d_coll + margin, margin
    cell = max(cell, math.sqrt(env.size_x * env.size_y / MAX_CELLS))
    nx, ny = max(math.ceil(env.size_x / cell), 1), max(math.ceil(env.size_y / cell), 1)
    discs = _discs(env, need_solid, need_radar)
    near: dict[int, list[np.ndarray]] = {}
    for f, (x, y, _, reach) in enumerate(discs.values()):
        for i, idx in _group(*_cell_members(x, y, reach, cell, (nx, ny))):
            near.setdefault(i, [_NONE] * 4)[f] = idx
    table: list[_Square | None] = [None] * (nx * ny)
    cache: dict[tuple[bytes, ...], _Square] = {}
    for i, members in near.items():  # squares sharing their obstacles share one entry
        key = tuple(m.tobytes() for m in members)
        if key not in cache:
            cache[key] = (_reach(discs["cylinders"], members[0]) + _reach(discs["prisms"], members[3]),
                          _reach(discs["spheres"], members[1]) + _reach(discs["radars"], members[2]),
                          _exact_test(_sub_environment(env, *members), need_solid, need_radar))
        table[i] = cache[key]
    size_x, size_y, band_lo, band_hi = env.size_x, env.size_y, env.z_min, env.z_max
    inv, nx1, ny1 = 1.0 / cell, nx - 1, ny - 1
    ground = None if env.terrain is None else env.ground

    def valid(x: float, y: float, z: float) -> bool:
        if not (0.0 <= x <= size_x and 0.0 <= y <= size_y):
            return False
        h = z if ground is None else z - float(ground(x, y))
        if not band_lo <= h <= band_hi:
            return False
        square = table[min(int(x * inv), nx1) * ny + min(int(y * inv), ny1)]
        if square is None:
            return True
        rings, balls, exact = square  # plain arithmetic first: exact only within some obstacle's reach
        for cx, cy, _, r2 in rings:
            dx, dy = x - cx, y - cy
            if dx * dx + dy * dy < r2:
                return exact(x, y, z)
        for cx, cy, cz, r2 in balls:
            dx, dy, dz = x - cx, y - cy, z - cz
            if dx * dx + dy * dy + dz * dz < r2:
                return exact(x, y, z)
        return True

    return valid


# --- solving ---------------------------------------------------------------------------------------------------
def _seed_ompl(util: ModuleType, seed: int) -> None:
    """Seed OMPL's root RNG (every planner, sampler and simplifier made after this draws from it). OMPL wants a
    seed > 0 and logs an error when re-seeded after its first draw, though re-seeding still takes effect: the
    log is muted for the call."""
    level = util.getLogLevel()
    util.setLogLevel(util.LOG_NONE)
    try:
        util.RNG.setSeed(seed % (2**32 - 1) + 1)
    finally:
        util.setLogLevel(level)


def _state(space: Any, p: np.ndarray) -> Any:
    """An OMPL state of ``space`` at p (3,) (nanobind: ``allocState`` and indexing, no State constructor)."""
    s = space.allocState()
    for k in range(3):
        s[k] = float(p[k])
    return s


def _path_array(path: Any) -> np.ndarray:
    """States of an OMPL PathGeometric as an (N, 3) array."""
    return np.array([[path.getState(i)[k] for k in range(3)] for i in range(path.getStateCount())], dtype=float)


def _planner(geometric: ModuleType, name: str, si: Any) -> Any:
    """The OMPL planner called ``name``, at its default settings."""
    if name == "rrtconnect":
        return geometric.RRTConnect(si)
    if name == "bitstar":
        return geometric.BITstar(si)
    raise ValueError(f"unknown peer planner {name!r}; expected one of {PLANNERS}")


def _run(problem: PlanningProblem, planner: str, time_s: float, seed: int, simplify: bool, valid: StateTest,
         ) -> tuple[str, bool, np.ndarray | None, int, float, int]:
    """Plan with OMPL: (status, exact, route or None, raw state count, wall time, validity calls).

    Every OMPL object lives in this frame only: the validity callback holds no reference back to them, so
    nothing outlives the call in a reference cycle through C++ (which nanobind reports as leaks at exit)."""
    base, geometric, util = _ompl()
    util.setLogLevel(util.LOG_WARN)
    _seed_ompl(util, seed)
    env = problem.env
    space = base.RealVectorStateSpace(3)
    bounds = base.RealVectorBounds(3)
    for k, (lo, hi) in enumerate(((0.0, env.size_x), (0.0, env.size_y), altitude_limits(env))):
        bounds.setLow(k, lo)
        bounds.setHigh(k, hi)
    space.setBounds(bounds)
    ss = geometric.SimpleSetup(space)
    calls = [0]

    def checker(s: Any) -> bool:
        calls[0] += 1
        return valid(s[0], s[1], s[2])

    ss.setStateValidityChecker(checker)
    si = ss.getSpaceInformation()
    si.setStateValidityCheckingResolution(RESOLUTION_M / space.getMaximumExtent())
    ss.setStartAndGoalStates(_state(space, problem.start), _state(space, problem.goal))
    ss.setPlanner(_planner(geometric, planner, si))
    ss.setup()
    t0 = time.perf_counter()
    status = ss.solve(float(time_s))
    exact = bool(ss.haveExactSolutionPath())
    route, raw = None, 0
    if exact:
        path = ss.getSolutionPath()
        raw = int(path.getStateCount())
        if simplify:
            left = max(time_s - (time.perf_counter() - t0), 0.0)
            ss.getPathSimplifier().simplify(path, left)  # atLeastOnce: one full pass even with no time left
        route = _path_array(path)
    return str(status), exact, route, raw, time.perf_counter() - t0, calls[0]


def solve(problem: PlanningProblem, planner: str, time_s: float, seed: int, simplify: bool = True) -> PeerResult:
    """Run OMPL ``planner`` ("rrtconnect" or "bitstar") on ``problem`` for at most ``time_s`` seconds of
    planning, seeded with ``seed``; simplify the path (OMPL's PathSimplifier) in the time left if ``simplify``.

    RRTConnect stops at its first solution; BIT* is anytime and uses the whole ``time_s`` (then one
    simplification pass runs past it). Raises FuseplanError without the ``peers`` extra."""
    if planner not in PLANNERS:
        raise ValueError(f"unknown peer planner {planner!r}; expected one of {PLANNERS}")
    _ompl()
    valid = state_validity(problem)
    status, exact, route, raw, wall, calls = _run(problem, planner, time_s, seed, simplify, valid)
    if route is None:
        return PeerResult(planner, exact, None, raw, wall, math.nan, False, {}, status, calls)
    violations = route_violations(route, problem.env, problem.hazard, problem.vehicle)
    length = float(np.linalg.norm(np.diff(route, axis=0), axis=1).sum())
    return PeerResult(planner, exact, route, raw, wall, length, not any(violations.values()), violations, status,
                      calls)
