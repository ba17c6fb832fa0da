"""What the kernel reads and which kernel runs: the environment variables that pick the kernel and its broad
phase, a problem's inputs as a typed KernelInputs (built once per problem: PlanningProblem.kernel_inputs), and
warm_up, which compiles everything before a flight."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from planner.errors import FuseplanError
from planner.kernel.jit import njit
from planner.kernel.swarm import decode_spherical, pso_step
from planner.trajectory.smoothing import PEAK_FACTOR, chord_sag
from planner.world.config import CostWeights, HazardConfig, PenaltyConfig, VehicleLimits
from planner.world.environment import LOITER, PATROL, Environment, Threats
from planner.world.geometry import GOLDEN_ITERS

ENV_VAR = "FUSEPLAN_KERNEL"
BROAD_ENV_VAR = "FUSEPLAN_BROAD_PHASE"
GRID_MIN_OBSTACLES = 16  # fewer obstacles: one cell (visiting a few obstacles costs less than finding them)
GRID_CELLS = 64  # broad-phase grid: at most this many cells along the map's longer side
SLOPE_BLOCK = 4  # terrain cells per side of a block of the local slope bounds (Terrain.slope_blocks)
KERNELS = ("compiled", "numpy")
PRISM_COLUMNS = ("floor", "ceiling", "keep_in", "cx", "cy", "r")  # KernelInputs.pri_rows: keep_in is 1.0 or 0.0
KEEP_IN_REACH = 1e300  # m: the broad-phase radius of a keep-in polygon (no-fly outside it: near every segment)


class KernelChoiceError(FuseplanError, ValueError):
    """FUSEPLAN_KERNEL or FUSEPLAN_BROAD_PHASE set to a value we do not know: one line (the CLI exits 2), not a
    traceback."""


def broad_phase() -> bool:
    """Whether the kernels visit only obstacles that can count (the default) or every obstacle
    (``FUSEPLAN_BROAD_PHASE=off``, for benches); the two give the same results bit for bit. The cost skips the
    obstacles out of reach of the swarm's box for each segment; segment_blocked finds obstacles in a uniform grid."""
    want = os.environ.get(BROAD_ENV_VAR, "on").strip().lower() or "on"
    if want not in ("on", "off"):
        raise KernelChoiceError(f"{BROAD_ENV_VAR}={want!r}: expected on or off")
    return want == "on"


def chosen() -> str:
    """The kernel evaluations use: ``compiled`` unless FUSEPLAN_KERNEL says ``numpy`` or numba is missing."""
    want = os.environ.get(ENV_VAR, "compiled").strip().lower() or "compiled"
    if want not in KERNELS:
        raise KernelChoiceError(f"{ENV_VAR}={want!r}: expected one of {', '.join(KERNELS)}")
    return "compiled" if want == "compiled" and njit is not None else "numpy"


def _threat_rows(thr: Threats) -> np.ndarray:
    """Threats (K, 12): kind, radius, radius growth, t_ref, p0, then per kind the law's constants, computed as
    Threats.positions computes them (so the kernel's centres match the reference's to the last bit)."""
    rows = np.zeros((len(thr), 12))
    rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3] = thr.kind, thr.radius, thr.radius_growth, thr.t_ref
    rows[:, 4:7] = thr.p0
    for k in range(len(thr)):  # a handful of threats, once per problem
        if thr.kind[k] == LOITER:
            r = thr.circle_radius[k]
            rows[k, 7:10] = r, thr.direction[k] * thr.speed[k] / (r if r > 0 else 1.0), thr.phase[k]
        elif thr.kind[k] == PATROL:
            ab = thr.p1[k] - thr.p0[k]
            length = float(np.linalg.norm(ab))
            safe = length if length > 0 else 1.0
            rows[k, 7:12] = *(ab / safe), safe, thr.speed[k]
        else:
            rows[k, 7:10] = thr.p1[k]
    return rows


def _f64(a, shape: tuple[int, ...] = (-1,)) -> np.ndarray:
    """A contiguous, writeable float64 copy: one compiled signature for every problem."""
    return np.array(a, dtype=np.float64, order="C").reshape(shape)


@dataclass(frozen=True, eq=False)
class ObstacleGrid:
    """The broad phase's uniform grid over the map (cells of ``cell`` metres from x0, y0) and, per cell, the
    obstacles (cylinders, then spheres) whose plan-view discs reach it; one cell holding everything when off."""

    x0: float
    y0: float
    cell: float
    nx: int
    ny: int
    start: np.ndarray  # (nx·ny + 1,) int64: cell c holds items[start[c]:start[c + 1]], ascending
    items: np.ndarray  # int64 indices into KernelInputs.ob_x, ob_y, ob_r

    @classmethod
    def over(cls, size_x: float, size_y: float, x: np.ndarray, y: np.ndarray, r: np.ndarray,
             on: bool) -> ObstacleGrid:
        """The grid for obstacles of plan-view centres x, y and radii r on a size_x × size_y map. About one
        obstacle per cell (cells of √(area / obstacles)), at most GRID_CELLS along the longer side: finer cells
        cost more cell visits per segment than the distances they save. Off-map parts go to the edge cells, as
        the query clamps too."""
        if not on or len(x) < GRID_MIN_OBSTACLES:
            ox, oy, cell, nx, ny = 0.0, 0.0, 1e300, 1, 1
        else:
            ox, oy = 0.0, 0.0
            cell = max(max(size_x, size_y, 1.0) / GRID_CELLS, math.sqrt(max(size_x * size_y, 1.0) / len(x)))
            nx, ny = max(math.ceil(size_x / cell), 1), max(math.ceil(size_y / cell), 1)
        lists: list[list[int]] = [[] for _ in range(nx * ny)]
        for k in range(len(x)):  # once per problem, over the obstacles
            i0, i1 = (min(max(int(math.floor((v - ox) / cell)), 0), nx - 1) for v in (x[k] - r[k], x[k] + r[k]))
            j0, j1 = (min(max(int(math.floor((v - oy) / cell)), 0), ny - 1) for v in (y[k] - r[k], y[k] + r[k]))
            for j in range(j0, j1 + 1):
                for i in range(i0, i1 + 1):
                    lists[j * nx + i].append(k)
        start = np.zeros(nx * ny + 1, dtype=np.int64)
        start[1:] = np.cumsum([len(c) for c in lists])
        items = np.array([k for c in lists for k in c], dtype=np.int64)
        return cls(ox, oy, float(cell), int(nx), int(ny), start, items)


@dataclass(frozen=True, eq=False)
class KernelInputs:
    """Everything the compiled kernel reads of one problem, by name, made once per problem
    (:attr:`planner.problem.PlanningProblem.kernel_inputs`): arrays contiguous and writeable, so that every
    problem runs the same compiled code, and the sample parameters and tables the reference uses."""

    # the vehicle (VehicleLimits)
    acceptance_radius: float
    turn_overshoot: float  # m per radian of turn
    max_turn: float
    min_turn_radius: float
    max_climb: float
    cruise_speed: float
    # clearances and the penalty (HazardConfig, PenaltyConfig)
    d_safe: float
    d_coll: float
    penalty_constant: float
    penalty_per_metre: float
    penalty_per_radian: float
    # b1…b5 (CostWeights): the total adds them in this order, as the reference does
    weight_length: float
    weight_hazard: float
    weight_altitude: float
    weight_smoothness: float
    weight_destination: float
    # the map and the route
    z_min: float
    z_max: float
    size_x: float
    size_y: float
    direct_distance: float
    has_heading: bool
    heading: np.ndarray  # (3,) the start heading; zeros without one
    # moving threats, met in time only when timed (PlanningProblem.timed_threats)
    timed: bool
    start_time: float  # s; 0 when not timed
    threat_max_speed: float
    threats: np.ndarray  # (K, 12): see _threat_rows
    # terrain (terrain.Terrain); a flat ground without
    has_terrain: bool
    terrain_x0: float
    terrain_y0: float
    terrain_dx: float
    terrain_dy: float
    # Terrain.slope_blocks(SLOPE_BLOCK): local bounds of how far the ground departs from a chord between its ends
    terrain_slopes: np.ndarray  # (nby, nbx); zeros (1, 1) without terrain
    terrain_slope: float  # Terrain.max_slope (0 without terrain)
    terrain_sag: float  # smoothing.chord_sag(terrain_t): how far a chord strays from its curve per second difference
    terrain_heights: np.ndarray  # (ny, nx); zeros (2, 2) without terrain
    # static obstacles
    cyl_x: np.ndarray
    cyl_y: np.ndarray
    cyl_r: np.ndarray
    cyl_top: np.ndarray
    sph_c: np.ndarray  # (K, 3)
    sph_r: np.ndarray
    rad_c: np.ndarray  # (K, 3)
    rad_det: np.ndarray
    rad_w: np.ndarray
    # polygon prisms (environment.Prisms), in three arrays (each argument costs the compiled call its unboxing):
    # packed counter-clockwise vertices, a start index each, and a row each of PRISM_COLUMNS
    pri_v: np.ndarray  # (V, 2)
    pri_start: np.ndarray  # (K + 1,) int64
    pri_rows: np.ndarray  # (K, 6)
    # the broad phase: cylinders, spheres, then prisms in plan view (a keep-in polygon's disc reaches everywhere),
    # and their grids (FUSEPLAN_BROAD_PHASE on, off)
    ob_x: np.ndarray
    ob_y: np.ndarray
    ob_r: np.ndarray
    grid: ObstacleGrid
    one_cell: ObstacleGrid
    # what the reference samples and tabulates, shared so that the two compute the same thing
    peak_table: np.ndarray  # smoothing.PEAK_FACTOR: G(cos θ)
    threat_t: np.ndarray  # sample parameters per segment for the moving threats
    terrain_t: np.ndarray  # and for the terrain
    golden_iters: int  # geometry.GOLDEN_ITERS

    @classmethod
    def build(cls, env: Environment, vehicle: VehicleLimits, hazard: HazardConfig, penalty: PenaltyConfig,
              weights: CostWeights, direct_distance: float, start_time: float | None,
              start_heading: np.ndarray | None, threat_t: np.ndarray, terrain_t: np.ndarray) -> KernelInputs:
        """The inputs of a problem; ``start_time`` None when moving threats do not count (none, or no time)."""
        ter, cyl, sph, rad = env.terrain, env.cylinders, env.spheres, env.radars
        slopes = ter.slope_blocks(SLOPE_BLOCK) if ter is not None else np.zeros((1, 1))
        pri = env.prisms
        # cylinders, spheres, then prisms: one grid for all (a keep-in polygon, no-fly outside it, in every cell)
        ob_x = _f64(np.concatenate([cyl.x, sph.center[:, 0], pri.cx]))
        ob_y = _f64(np.concatenate([cyl.y, sph.center[:, 1], pri.cy]))
        ob_r = _f64(np.concatenate([cyl.radius, sph.radius, np.where(pri.keep_in, KEEP_IN_REACH, pri.r)]))
        return cls(
            acceptance_radius=float(vehicle.acceptance_radius), turn_overshoot=float(vehicle.turn_overshoot),
            max_turn=float(vehicle.max_turn), min_turn_radius=float(vehicle.min_turn_radius),
            max_climb=float(vehicle.max_climb), cruise_speed=float(vehicle.cruise_speed),
            d_safe=float(hazard.d_safe), d_coll=float(hazard.d_coll), penalty_constant=float(penalty.constant),
            penalty_per_metre=float(penalty.per_metre), penalty_per_radian=float(penalty.per_radian),
            weight_length=float(weights.length), weight_hazard=float(weights.hazard),
            weight_altitude=float(weights.altitude), weight_smoothness=float(weights.smoothness),
            weight_destination=float(weights.destination),
            z_min=float(env.z_min), z_max=float(env.z_max), size_x=float(env.size_x), size_y=float(env.size_y),
            direct_distance=float(direct_distance),
            has_heading=start_heading is not None,
            heading=_f64(start_heading if start_heading is not None else np.zeros(3)),
            timed=start_time is not None, start_time=float(start_time) if start_time is not None else 0.0,
            threat_max_speed=float(env.threats.max_speed), threats=_threat_rows(env.threats),
            has_terrain=ter is not None,
            terrain_x0=float(ter.x0) if ter is not None else 0.0, terrain_y0=float(ter.y0) if ter is not None else 0.0,
            terrain_dx=float(ter.dx) if ter is not None else 1.0, terrain_dy=float(ter.dy) if ter is not None else 1.0,
            terrain_slopes=_f64(slopes, slopes.shape),
            terrain_slope=float(ter.max_slope) if ter is not None else 0.0, terrain_sag=chord_sag(terrain_t),
            terrain_heights=_f64(ter.heights, ter.heights.shape) if ter is not None else np.zeros((2, 2)),
            cyl_x=_f64(cyl.x), cyl_y=_f64(cyl.y), cyl_r=_f64(cyl.radius), cyl_top=_f64(cyl.top),
            sph_c=_f64(sph.center, (-1, 3)), sph_r=_f64(sph.radius),
            rad_c=_f64(rad.center, (-1, 3)), rad_det=_f64(rad.r_det), rad_w=_f64(rad.soft_weight),
            pri_v=_f64(pri.vertices, (-1, 2)), pri_start=np.array(pri.start, dtype=np.int64),
            pri_rows=_f64(np.column_stack([pri.floor, pri.ceiling, pri.keep_in, pri.cx, pri.cy, pri.r]), (-1, 6)),
            ob_x=ob_x, ob_y=ob_y, ob_r=ob_r,
            grid=ObstacleGrid.over(env.size_x, env.size_y, ob_x, ob_y, ob_r, True),
            one_cell=ObstacleGrid.over(env.size_x, env.size_y, ob_x, ob_y, ob_r, False),
            peak_table=_f64(PEAK_FACTOR), threat_t=_f64(threat_t), terrain_t=_f64(terrain_t),
            golden_iters=int(GOLDEN_ITERS),
        )


def warm_up(problem) -> None:
    """Compile (first run on a machine) or load from the disk cache every compiled function, on ``problem``'s
    arrays: the replan worker calls it before the flight so that no replan pays for it."""
    if chosen() != "compiled":
        return
    line = np.linspace(problem.start, problem.goal, 4)[None]
    problem.evaluate(line)  # through the problem, which builds its KernelInputs
    problem.segment_blocked(line[:, :-1], line[:, 1:])
    x = np.zeros((1, 2, 3))
    decode_spherical(x, problem.start, problem.goal)
    box = np.ones((2, 3))
    pso_step(x, x, x, x[0], 0.5, 1.0, 1.0, -box, box, box, True, x, x)
