"""A roadmap of the static world (docs/method.md §15.1): a lattice graph of free space, built once per map, whose
shortest paths are guide routes for the swarm and whose edges the colony walks.

Nodes sit on a horizontal grid at a few heights above the terrain; an edge joins grid neighbours up to two cells
apart (16 directions) on one level, or on adjacent levels where the climb stays within the vehicle's limit. Every
node and edge keeps ``d_coll + A/2 + margin`` from obstacle surfaces and ``A/2 + margin`` from radar detection
ranges: the clearance the cost demands plus what the autopilot's corner cutting takes (docs/method.md §4.4, §12).

Clearance is 1-Lipschitz along a segment, so an edge whose end nodes have clearances c_a, c_b keeps at least
(c_a + c_b − L)/2 everywhere; only edges that this bound does not clear are checked exactly, with the cost's
own segment geometry (:meth:`PlanningProblem.static_clearances`). Moving threats never change the graph: they
raise the weight of edges the vehicle would fly near a threat at the time it gets there (:func:`timed_weights`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import time
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from planner.deadline import NEVER, Deadline
from planner.problem import PlanningProblem
from planner.search.termination import WallClock
from planner.trajectory.checks import CHUNK_PAIRS, obstacle_clearance, radar_clearance
from planner.trajectory.smoothing import deviation_bound, peak_curvature, peak_factor, segment_samples
from planner.world.config import RoadmapConfig
from planner.world.environment import TRACK
from planner.world.geometry import horizontal_turn

TARGET_COLUMNS = 1600  # grid columns of the automatic spacing
MAX_COLUMNS = 40_000  # the finest grid a configured spacing may ask for (about 10^6 edges per level)
MIN_SPACING_M = 10.0
OFFSETS = np.array([(i, j) for i in range(-2, 3) for j in range(-2, 3)
                    if 0 < i * i + j * j <= 5 and (i, j) > (0, 0)])  # half of the 20 neighbours: each edge once
BLOCKED_WEIGHT = 1e4  # weight factor of an edge a moving threat occupies when the vehicle would be there
_CACHE: list[tuple[str, Roadmap]] = []
_CACHE_SIZE = 8


@dataclass(frozen=True, eq=False)
class Roadmap:
    """Nodes (N, 3) ENU m with their clearance slack (N,) (metres beyond what is required), edges (E, 2) with
    lengths (E,), the symmetric weighted graph, and the lattice spacing (the roadmap's resolution)."""

    nodes: np.ndarray
    slack: np.ndarray
    edges: np.ndarray
    length: np.ndarray
    spacing: float
    need: float  # clearance required from obstacle surfaces, m
    build_s: float = 0.0

    @property
    def n_nodes(self) -> int:
        return len(self.nodes)

    @cached_property
    def _cells(self) -> tuple[np.ndarray, int, int]:
        """The horizontal grid cell (of one spacing) of every edge's midpoint, and the grid's shape."""
        mid = 0.5 * (self.nodes[self.edges[:, 0], :2] + self.nodes[self.edges[:, 1], :2])
        ij = np.floor(mid / self.spacing).astype(np.intp)
        nx, ny = int(ij[:, 0].max(initial=0)) + 1, int(ij[:, 1].max(initial=0)) + 1
        return ij[:, 0] * ny + ij[:, 1], nx, ny

    def edges_near(self, points: np.ndarray, radius: float) -> np.ndarray:
        """Indices of the edges whose midpoint lies horizontally within about ``radius`` of a point (M, ≥2):
        every cell that a disc of radius + one cell diagonal around a point touches is marked (a superset)."""
        cell, nx, ny = self._cells
        r = int(math.ceil(radius / self.spacing)) + 1
        di, dj = np.meshgrid(np.arange(-r, r + 1), np.arange(-r, r + 1), indexing="ij")
        disc = (di**2 + dj**2) <= r * r
        di, dj = di[disc], dj[disc]
        c = np.floor(np.asarray(points)[:, :2] / self.spacing).astype(np.intp)
        i = (c[:, 0, None] + di).ravel()
        j = (c[:, 1, None] + dj).ravel()
        ok = (i >= 0) & (i < nx) & (j >= 0) & (j < ny)
        marked = np.zeros(nx * ny, dtype=bool)
        marked[i[ok] * ny + j[ok]] = True
        return np.flatnonzero(marked[cell])

    @cached_property
    def pattern(self) -> csr_matrix:
        """The graph's sparsity pattern, two rows more for a start and a goal; entries are edge index + 1."""
        return _symmetric(self.edges, np.arange(1.0, len(self.edges) + 1.0), self.n_nodes + 2)

    @cached_property
    def node_tree(self) -> cKDTree:
        """The nodes' horizontal positions, to attach a start and a goal."""
        return cKDTree(self.nodes[:, :2])


def _symmetric(edges: np.ndarray, values: np.ndarray, n: int) -> csr_matrix:
    """An n × n CSR matrix holding ``values`` (E,) at both (u, v) and (v, u) of every edge (E, 2)."""
    rows = np.concatenate([edges[:, 0], edges[:, 1]])
    cols = np.concatenate([edges[:, 1], edges[:, 0]])
    return coo_matrix((np.concatenate([values, values]), (rows, cols)), shape=(n, n)).tocsr()


def _extra(problem: PlanningProblem, margin: float) -> float:
    """Clearance the roadmap keeps beyond d_coll (and beyond radar ranges): the tracking margin A/2 + ``margin``."""
    return 0.5 * problem.vehicle.acceptance_radius + margin


def _swing_room(length: np.ndarray | float, problem: PlanningProblem, margin: float) -> np.ndarray | float:
    """Slack a leg of ``length`` needs beyond the roadmap's clearance for its smoothed curve to swing off it at
    the worst turn (docs/method.md §4.4: the Bézier bound (4/27) L), less what the clearance already covers."""
    return deviation_bound(length, 0.0) - _extra(problem, margin)


def clearance_slack(problem: PlanningProblem, points: np.ndarray, margin: float) -> np.ndarray:
    """Metres (M,) by which each point exceeds the roadmap's clearance: d_coll + A/2 + margin from obstacle
    surfaces, A/2 + margin from radar detection ranges (negative: too close)."""
    env = problem.env
    solid = obstacle_clearance(points, None, env, include_radars=False) - problem.hazard.d_coll
    return np.minimum(solid, radar_clearance(points, env.radars)) - _extra(problem, margin)


def segment_slack(problem: PlanningProblem, a: np.ndarray, b: np.ndarray, margin: float) -> np.ndarray:
    """As :func:`clearance_slack` for segments a→b (E, 3), exactly (the cost's segment geometry)."""
    out = np.full(len(a), np.inf)
    if not len(a):
        return out
    cyl_c, sph_c, radar_d = problem.static_clearances(a, b)
    for c in (cyl_c, sph_c, problem.prism_clearances(a, b)):
        if c is not None:
            out = np.minimum(out, c.min(axis=0) - problem.hazard.d_coll)
    if radar_d is not None:
        out = np.minimum(out, (radar_d - problem.env.radars.r_det[:, None]).min(axis=0))
    return out - _extra(problem, margin)


def band_ok(problem: PlanningProblem, a: np.ndarray, b: np.ndarray, margin: float) -> np.ndarray:
    """True where segment a→b (E, 3) stays inside the altitude band (less ``margin``) over the terrain, exactly
    (:meth:`Environment.band_depth`, the checker's test), and inside the region."""
    env = problem.env
    ok = env.band_depth(a, b) <= -margin + 1e-9
    inside = ((np.minimum(a[:, :2], b[:, :2]) >= 0.0).all(axis=1)
              & (np.maximum(a[:, 0], b[:, 0]) <= env.size_x) & (np.maximum(a[:, 1], b[:, 1]) <= env.size_y))
    return ok & inside


def climb_ok(problem: PlanningProblem, a: np.ndarray, b: np.ndarray, share: float | np.ndarray) -> np.ndarray:
    """True where the climb angle of a→b (E, 3) is within ``share`` of the vehicle's limit."""
    horiz = np.hypot(b[:, 0] - a[:, 0], b[:, 1] - a[:, 1])
    return np.abs(b[:, 2] - a[:, 2]) <= horiz * np.tan(share * problem.vehicle.max_climb) + 1e-9


def auto_spacing(problem: PlanningProblem, cfg: RoadmapConfig) -> float:
    """The configured spacing (never finer than MAX_COLUMNS grid columns), or sqrt(area / TARGET_COLUMNS) (at
    least MIN_SPACING_M)."""
    area = problem.env.size_x * problem.env.size_y
    if cfg.spacing > 0:  # never finer than MAX_COLUMNS grid columns: memory grows with nodes × levels × edges
        return max(cfg.spacing, math.sqrt(area / MAX_COLUMNS))
    return max(MIN_SPACING_M, math.sqrt(area / TARGET_COLUMNS))


def _levels(problem: PlanningProblem, cfg: RoadmapConfig, h: float) -> tuple[int, float, float]:
    """Altitude levels of the lattice at spacing ``h``, with the band they span and the level step a two-cell
    (knight) edge can climb within the limit: the levels are close enough for it where the band allows."""
    margin_z = 0.5 * problem.vehicle.acceptance_radius
    band = problem.env.z_max - problem.env.z_min - 2 * margin_z
    dz_fit = math.sqrt(5.0) * h * math.tan(cfg.climb_share * problem.vehicle.max_climb)
    return int(min(cfg.max_levels, max(1, math.floor(band / max(dz_fit, 1e-9)) + 1))), band, dz_fit


def grid_nodes(problem: PlanningProblem, cfg: RoadmapConfig) -> int:
    """Nodes of the lattice :func:`build` lays (columns × levels, before any is dropped), without laying it."""
    h = auto_spacing(problem, cfg)
    columns = math.ceil((problem.env.size_x - 0.5 * h) / h) * math.ceil((problem.env.size_y - 0.5 * h) / h)
    return max(columns, 0) * _levels(problem, cfg, h)[0]


def build(problem: PlanningProblem, cfg: RoadmapConfig) -> Roadmap:
    """The roadmap of ``problem``'s static world (its threats, start and goal play no part)."""
    t0 = time.perf_counter()
    env = problem.env
    h = auto_spacing(problem, cfg)
    margin_z = 0.5 * problem.vehicle.acceptance_radius
    xs = np.arange(0.5 * h, env.size_x, h)
    ys = np.arange(0.5 * h, env.size_y, h)
    n_lev, band, dz_fit = _levels(problem, cfg, h)
    levels = (np.array([env.z_min + margin_z + 0.5 * band]) if n_lev == 1
              else np.linspace(env.z_min + margin_z, env.z_max - margin_z, n_lev))
    gx, gy = (g.ravel() for g in np.meshgrid(np.arange(len(xs)), np.arange(len(ys)), indexing="ij"))
    ground = env.ground(xs[gx], ys[gy])
    nx, ny, nl = len(xs), len(ys), len(levels)

    def index(i: np.ndarray, j: np.ndarray, k: np.ndarray) -> np.ndarray:
        return (k * nx + i) * ny + j

    kk = np.repeat(np.arange(nl), len(gx))
    ii, jj = np.tile(gx, nl), np.tile(gy, nl)
    nodes = np.column_stack([xs[ii], ys[jj], np.tile(ground, nl) + levels[kk]])
    slack = clearance_slack(problem, nodes, cfg.margin)
    alive = slack >= 0.0
    # candidate edges: each grid offset, same level and one level up (and down, for the reverse direction)
    # level changes stretch the offsets so the climb fits when the levels are further apart than dz_fit
    stretch = 1 if nl == 1 else max(1, math.ceil((levels[1] - levels[0]) / max(dz_fit, 1e-9) - 1e-9))
    cand = []
    for di, dj in OFFSETS:
        for dk in (0, 1, -1):
            m = 1 if dk == 0 else stretch
            i2, j2, k2 = ii + m * di, jj + m * dj, kk + dk
            ok = (i2 >= 0) & (i2 < nx) & (j2 >= 0) & (j2 < ny) & (k2 >= 0) & (k2 < nl) & alive
            src = np.flatnonzero(ok)
            dst = index(i2[src], j2[src], k2[src])
            keep = alive[dst]
            cand.append(np.column_stack([src[keep], dst[keep]]))
    e = np.concatenate(cand)  # (a level change on one column is never an edge: no vertical climbs)
    a, b = nodes[e[:, 0]], nodes[e[:, 1]]
    ok = climb_ok(problem, a, b, cfg.climb_share) & band_ok(problem, a, b, margin_z)
    e, a, b = e[ok], a[ok], b[ok]
    length = np.linalg.norm(b - a, axis=1)
    bound = 0.5 * (slack[e[:, 0]] + slack[e[:, 1]] - length)  # Lipschitz lower bound of the edge's slack
    check = np.flatnonzero(bound < 0.0)
    good = np.ones(len(e), dtype=bool)
    pairs = len(env.cylinders) + len(env.spheres) + len(env.radars) + 6 * env.prisms.padded[0].size  # 6 knots/edge
    per_chunk = max(1, min(20000, CHUNK_PAIRS // (pairs + 1)))
    for chunk in np.array_split(check, max(1, len(check) // per_chunk)):  # bounded temporaries
        good[chunk] = segment_slack(problem, a[chunk], b[chunk], cfg.margin) >= 0.0
    e, length = e[good], length[good]
    used = np.unique(e)  # drop isolated nodes, renumber
    remap = np.full(len(nodes), -1)
    remap[used] = np.arange(len(used))
    return Roadmap(nodes[used], slack[used], remap[e], length, h, problem.hazard.d_coll + _extra(problem, cfg.margin),
                   time.perf_counter() - t0)


def _fingerprint(*parts: object) -> str:
    """A digest of the static world's arrays and numbers: equal worlds share a roadmap even when they are
    different objects (a replan's problem is built afresh, and pickled into the planner's process)."""
    h = hashlib.sha1()
    for part in parts:
        if dataclasses.is_dataclass(part):
            h.update(_fingerprint(*(getattr(part, f.name) for f in dataclasses.fields(part))).encode())
        elif isinstance(part, np.ndarray):
            h.update(str(part.shape).encode())
            h.update(np.ascontiguousarray(part).tobytes())
        else:
            h.update(repr(part).encode())
    return h.hexdigest()


def cached(problem: PlanningProblem, cfg: RoadmapConfig) -> Roadmap:
    """:func:`build`, reused while the static world, the clearance and the vehicle's limits are the same (a
    replan's problem keeps the scenario's obstacles and swaps only its threats and start)."""
    key = _cache_key(problem, cfg)
    for k, rm in _CACHE:
        if k == key:
            return rm
    rm = build(problem, cfg)
    _CACHE.append((key, rm))
    del _CACHE[:-_CACHE_SIZE]
    return rm


def _cache_key(problem: PlanningProblem, cfg: RoadmapConfig) -> str:
    env = problem.env
    return _fingerprint(env.cylinders, env.spheres, env.radars, env.prisms, env.terrain, env.size_x, env.size_y,
                        env.z_min, env.z_max, problem.hazard, problem.vehicle.acceptance_radius,
                        problem.vehicle.max_climb, problem.vehicle.max_turn, cfg)


def _build_estimate_s(problem: PlanningProblem, cfg: RoadmapConfig, known: Roadmap) -> float:
    """Seconds :func:`cached` will take to have the roadmap for ``cfg``: 0 when it is cached, else ``known``'s
    build time scaled by the number of grid columns (a budgeted plan skips a build it cannot afford)."""
    key = _cache_key(problem, cfg)
    if any(k == key for k, _ in _CACHE):
        return 0.0
    return known.build_s * (known.spacing / auto_spacing(problem, cfg)) ** 2


# --- queries ------------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Query:
    """The roadmap with the start and goal attached: node N is the start, N + 1 the goal."""

    roadmap: Roadmap
    points: np.ndarray  # (N + 2, 3)
    edges: np.ndarray  # (E', 2), the roadmap's and the attachments
    length: np.ndarray  # (E',)

    @cached_property
    def _csr(self) -> tuple[csr_matrix, np.ndarray, np.ndarray]:
        """The roadmap's pattern plus the attachments, which edge each stored entry is, and each entry's key
        row × (N + 2) + column (ascending: rows in order, columns sorted within a row)."""
        n = len(self.points)
        base = len(self.roadmap.edges)
        att = _symmetric(self.edges[base:], np.arange(base + 1.0, len(self.edges) + 1.0), n)
        g = (self.roadmap.pattern + att).tocsr()
        g.sort_indices()
        keys = np.repeat(np.arange(n), np.diff(g.indptr)) * n + g.indices
        return g, g.data.astype(np.intp) - 1, keys

    def graph(self, weights: np.ndarray) -> csr_matrix:
        """The symmetric graph with edge ``weights`` (E',) (the pattern with new data)."""
        g, edge, _ = self._csr  # the pattern's index arrays shared, not copied: only the data is new
        return csr_matrix((weights[edge], g.indices, g.indptr), shape=g.shape, copy=False)

    def edge_ids(self, path: np.ndarray) -> np.ndarray:
        """Indices into ``edges`` of the consecutive node pairs of ``path`` (each pair is an edge)."""
        _, edge, keys = self._csr
        return edge[np.searchsorted(keys, path[:-1] * len(self.points) + path[1:])]

    @property
    def start(self) -> int:
        return self.roadmap.n_nodes

    @property
    def goal(self) -> int:
        return self.roadmap.n_nodes + 1


def attach(rm: Roadmap, problem: PlanningProblem, cfg: RoadmapConfig, reach: float = 3.0) -> Query:
    """Join the start and the goal to the roadmap nodes within ``reach`` spacings whose edges keep d_coll
    (the start may sit closer to an obstacle than the roadmap's margin: the vehicle is there already), the
    climb limit and the band over the terrain; the straight start→goal edge too, when it is clear. With a start
    heading, the start's edges
    turn at most the vehicle's max turn from it."""
    pts = np.concatenate([rm.nodes, problem.start[None], problem.goal[None]])
    n = rm.n_nodes
    extra = []
    for end in (n, n + 1):
        near = np.asarray(rm.node_tree.query_ball_point(pts[end, :2], reach * rm.spacing), dtype=np.intp)
        extra.append(np.column_stack([np.full(len(near), end), near]))
    extra.append(np.array([[n, n + 1]]))
    e = np.concatenate(extra)
    a, b = pts[e[:, 0]], pts[e[:, 1]]
    relax = rm.need - problem.hazard.d_coll  # attachments need only d_coll
    # and the band over the terrain, left no further than an end already is (a start may sit at its edge)
    ends_out = np.maximum(problem.env.band_depth(a, a), problem.env.band_depth(b, b)).clip(0.0)
    ok = ((segment_slack(problem, a, b, cfg.margin) >= -relax) & climb_ok(problem, a, b, 1.0)
          & (problem.env.band_depth(a, b) <= ends_out + 1e-9))
    if problem.start_heading is not None:  # leave the start within the turn limit of the way the vehicle flies
        out = e[:, 0] == n
        turn = horizontal_turn(np.stack([np.broadcast_to(problem.start_heading, b.shape), b - a], axis=1))[:, 0]
        ok &= ~out | (turn <= problem.vehicle.max_turn)
    e = e[ok]
    length = np.linalg.norm(pts[e[:, 1]] - pts[e[:, 0]], axis=1)
    return Query(rm, pts, np.concatenate([rm.edges, e]), np.concatenate([rm.length, length]))


def clearance_weights(q: Query, problem: PlanningProblem) -> np.ndarray:
    """Edge lengths (E',) × (1 + (1 − s/S)²) for edges whose end nodes keep only s < S metres of slack,
    S = max(d_safe − d_coll, 2 spacings): like the cost's hazard term (docs/method.md §4.3), shortest paths
    keep to the middle of a gap rather than graze its sides."""
    slack = np.concatenate([q.roadmap.slack, [np.inf, np.inf]])
    s = np.minimum(slack[q.edges[:, 0]], slack[q.edges[:, 1]])
    scale = max(problem.hazard.d_safe - problem.hazard.d_coll, 2.0 * q.roadmap.spacing)
    return q.length * (1.0 + np.clip(1.0 - s / scale, 0.0, 1.0) ** 2)


def timed_weights(q: Query, problem: PlanningProblem, weights: np.ndarray) -> np.ndarray:
    """Edge weights (E',) raised by BLOCKED_WEIGHT where a moving threat could be within the roadmap's clearance
    of the edge while the vehicle flies it (docs/method.md §15.1). The vehicle is at a node at its shortest
    distance from the start at cruise speed. Each point of an edge is within L/2 of an end x, and the vehicle is
    there within max(L/v, |t_a − t_b|) − L/2v of t_x (whether it flies the edge at cruise speed from the earlier
    end or between its ends' times); so with g the least clearance of the ends from the threats' surfaces at
    their times, the edge keeps at least g − L/2 − s·(max(L/v, |t_a − t_b|) − L/2v), s the fastest a surface
    moves (speed plus radius growth). One threat position per node, not per edge and time sample."""
    env = problem.env
    if not problem.timed_threats or problem.start_time is None:  # timed threats have a start time
        return weights
    v = problem.vehicle.cruise_speed
    dist = dijkstra(q.graph(weights), indices=q.start)
    reach = np.isfinite(dist)
    t_node = problem.start_time + np.where(reach, dist, 0.0) / v
    gap = (np.linalg.norm(q.points[None] - env.threats.positions(t_node), axis=-1)
           - env.threats.radii(t_node)).min(axis=0)  # (N + 2,)
    growth = np.where(env.threats.kind == TRACK, env.threats.radius_growth, 0.0)
    s = env.threats.max_speed + float(growth.max(initial=0.0))
    ea, eb = q.edges[:, 0], q.edges[:, 1]
    duration = np.maximum(q.length / v, np.abs(t_node[ea] - t_node[eb]))
    slack = np.minimum(gap[ea], gap[eb]) - q.roadmap.need - 0.5 * q.length - s * (duration - 0.5 * q.length / v)
    out = weights.copy()
    out[(slack < 0.0) & reach[ea]] *= BLOCKED_WEIGHT
    return out


def shortest(q: Query, weights: np.ndarray) -> np.ndarray | None:
    """Node indices of the lightest start→goal path, or None when the goal is unreachable."""
    _, pred = dijkstra(q.graph(weights), indices=q.start, return_predecessors=True)
    if pred[q.goal] < 0:
        return None
    path = [q.goal]
    while path[-1] != q.start:  # walk the predecessor tree back: one step per node of the path
        path.append(int(pred[path[-1]]))
    return np.array(path[::-1])


def shortcut(points: np.ndarray, problem: PlanningProblem, cfg: RoadmapConfig, relax_ends: float,
             room: float) -> np.ndarray:
    """Drop the nodes a straight leg can skip (greedy, farthest first): a leg kept has ``room`` metres of slack
    beyond the roadmap's clearance, more on a long leg whose smoothed curve may swing further (the first and last
    only need d_coll, ``relax_ends`` less), stays in the band within the climb limit, and turns at most the
    vehicle's max turn from the previous leg (the first leg from the start heading, if any). The room is where
    the smoothed curve swings inside a corner (docs/method.md §4.4); the swarm makes the corners flyable."""
    veh = problem.vehicle
    keep = [0]
    i = 0
    m = len(points)
    flown = 0.0  # metres along the shortcut route to points[i]
    while i < m - 1:
        j = np.arange(i + 1, m)
        a = np.broadcast_to(points[i], (len(j), 3))
        b = points[j]
        slack = segment_slack(problem, a, b, cfg.margin)
        ends = (i == 0) | (j == m - 1)
        swing = _swing_room(np.linalg.norm(b - a, axis=1), problem, cfg.margin)
        ok = ((slack >= np.maximum(np.where(ends, -relax_ends, room), swing))
              & band_ok(problem, a, b, 0.5 * veh.acceptance_radius)
              & climb_ok(problem, a, b, np.where(ends, 1.0, cfg.climb_share))
              & (threat_slack(problem, a, b, flown, cfg.margin) >= 0.0))
        prev = (points[i] - points[keep[-2]] if len(keep) > 1
                else problem.start_heading)  # the first leg turns from the way the vehicle flies (if known)
        if prev is not None:
            prev = np.broadcast_to(prev, b.shape)
            ok &= horizontal_turn(np.stack([prev, b - a], axis=1))[:, 0] <= veh.max_turn
        ok[0] = True  # the roadmap's own edge
        nxt = int(j[np.flatnonzero(ok)[-1]])
        flown += float(np.linalg.norm(points[nxt] - points[i]))
        i = nxt
        keep.append(i)
    return points[keep]


def round_corners(route: np.ndarray, problem: PlanningProblem, cfg: RoadmapConfig, relax_ends: float,
                  min_turn_deg: float = 30.0) -> np.ndarray:
    """Cut each corner that turns more than ``min_turn_deg`` into two half turns, as a pilot would: the vertex V
    becomes A = V − d u_in and B = V + d u_out. d is what the chord AB needs to stay under 1/R_min on its
    Bézier (docs/method.md §11.2: κ = G(cos θ/2) sin(θ/2) / (2 d cos(θ/2))), at most 0.45 of either leg; a cut
    whose chord comes closer to an obstacle than the roadmap's clearance, leaves the band over the terrain or climbs
    steeper than the roadmap's edges, keeps the corner."""
    veh = problem.vehicle
    pts = [route[0]]
    for k in range(1, len(route) - 1):  # the guide's corners, once per plan: not a hot path
        v, prev, nxt = route[k], pts[-1], route[k + 1]
        u_in, u_out = v - prev, nxt - v
        l_in, l_out = float(np.linalg.norm(u_in)), float(np.linalg.norm(u_out))
        if min(l_in, l_out) < 1e-6:
            continue
        u_in, u_out = u_in / l_in, u_out / l_out
        theta = math.acos(float(np.clip(u_in @ u_out, -1.0, 1.0)))
        if theta <= math.radians(min_turn_deg):
            pts.append(v)
            continue
        g = float(peak_factor(np.array(math.cos(theta / 2))))
        d = min(0.55 * veh.min_turn_radius * g * math.tan(theta / 2), 0.45 * min(l_in, l_out))
        a, b = v - d * u_in, v + d * u_out
        if (segment_slack(problem, a[None], b[None], cfg.margin)[0] >= -relax_ends * (k in (1, len(route) - 2))
                and band_ok(problem, a[None], b[None], 0.5 * veh.acceptance_radius)[0]
                and climb_ok(problem, a[None], b[None], cfg.climb_share)[0]):
            pts += [a, b]
        else:
            pts.append(v)
    pts.append(route[-1])
    return _drop_tight_vertices(np.array(pts), problem, cfg)


def _drop_tight_vertices(route: np.ndarray, problem: PlanningProblem, cfg: RoadmapConfig,
                         passes: int = 3) -> np.ndarray:
    """Remove a vertex whose incoming leg is too short for the turn at it (its Bézier would curve tighter than
    R_min, docs/method.md §11.2) when the leg that skips it keeps the roadmap's clearance and room to swing, the band
    over the terrain and the climb limit."""
    veh = problem.vehicle
    for _ in range(passes):  # a few sweeps over one guide's vertices
        seg = np.diff(route, axis=0)
        length = np.linalg.norm(seg, axis=1)
        u = seg / np.maximum(length, 1e-9)[:, None]
        cos_turn = np.sum(u[:-1] * u[1:], axis=1)
        tight = np.flatnonzero(peak_curvature(length[:-1], cos_turn) * veh.min_turn_radius > 1.0) + 1
        if not len(tight):
            break
        keep = np.ones(len(route), dtype=bool)
        for k in tight:  # drop one of two neighbours at most, so each skip is checked against kept points
            if not keep[k - 1] or k + 1 >= len(route):
                continue
            a, b = route[k - 1], route[k + 1]
            swing = _swing_room(float(np.linalg.norm(b - a)), problem, cfg.margin)
            if (segment_slack(problem, a[None], b[None], cfg.margin)[0] >= max(swing, 0.0)
                    and band_ok(problem, a[None], b[None], 0.5 * veh.acceptance_radius)[0]
                    and climb_ok(problem, a[None], b[None], cfg.climb_share)[0]):
                keep[k] = False
        if keep.all():
            break
        route = route[keep]
    return route


def threat_slack(problem: PlanningProblem, a: np.ndarray, b: np.ndarray, flown: float, margin: float,
                 samples: int = 11) -> np.ndarray:
    """Least clearance (E,) of segments a→b from the moving threats beyond d_coll + A/2 + ``margin``, the vehicle
    reaching a at ``flown`` metres from the start at cruise speed (docs/method.md §4.6); +inf without timed threats.
    Between samples the vehicle and the threat both move: half a sample gap at each one's speed is subtracted."""
    env = problem.env
    if not problem.timed_threats or not len(a):
        return np.full(len(a), np.inf)
    v = problem.vehicle.cruise_speed
    f = np.linspace(0.0, 1.0, samples)[:, None]
    length = np.linalg.norm(b - a, axis=1)
    p = a[None] + f[..., None] * (b - a)[None]  # (m, E, 3)
    t = problem.start_time + (flown + f * length) / v
    d = np.linalg.norm(p[None] - env.threats.positions(t), axis=-1) - env.threats.radii(t)  # (k, m, E)
    gap = length / (samples - 1)
    need = problem.hazard.d_coll + _extra(problem, margin)
    return d.min(axis=(0, 1)) - need - 0.5 * gap * (1.0 + env.threats.max_speed / v)


def guide(points: np.ndarray, rm: Roadmap, problem: PlanningProblem, cfg: RoadmapConfig) -> np.ndarray:
    """A roadmap path (M, 3) made a guide route (docs/method.md §15.2): :func:`shortcut` with half a spacing of
    room, then :func:`round_corners`; its first and last legs need only d_coll (the ends are where they are)."""
    relax = rm.need - problem.hazard.d_coll
    return round_corners(shortcut(points, problem, cfg, relax, 0.5 * rm.spacing), problem, cfg, relax)


def diverse_routes(rm: Roadmap, problem: PlanningProblem, cfg: RoadmapConfig, q: Query | None = None,
                   weights: np.ndarray | None = None, deadline: Deadline = NEVER) -> list[np.ndarray]:
    """Up to ``cfg.n_routes`` start→goal routes (M_k, 3) in different corridors, best first, shortcut: after
    each, edges within three spacings of it weigh ``reuse_penalty`` times more and the search repeats; a roadmap
    path within one spacing (mean distance) of an earlier one is dropped before it is made a guide.
    ``q``/``weights``: the attached query and its
    edge weights (default: :func:`attach`, clearance and threat weights). Empty: no route at this resolution.
    ``deadline``: a route after the first is searched only when one more (as long as the longest so far) fits in
    it."""
    if q is None:
        q = attach(rm, problem, cfg)
    if weights is None:
        weights = timed_weights(q, problem, clearance_weights(q, problem))
    base = weights
    wall = WallClock(deadline)
    routes: list[np.ndarray] = []
    found: list[np.ndarray] = []  # the roadmap paths of the routes kept
    for k in range(cfg.n_routes):
        if k:
            wall.lap()  # the route before this one
            if wall.done():
                break
        path = shortest(q, weights)
        if path is None:
            break
        ids = q.edge_ids(path)
        if routes and np.any(base[ids] >= 0.999 * BLOCKED_WEIGHT * q.length[ids]):
            break  # only ways through a moving threat are left
        if not any(mean_distance(q.points[path], f) < rm.spacing for f in found):  # a new corridor: its guide
            found.append(q.points[path])
            routes.append(guide(q.points[path], rm, problem, cfg))
        dense = densify(q.points[path], 0.5 * rm.spacing)
        weights = weights.copy()
        weights[rm.edges_near(dense, 3.0 * rm.spacing)] *= cfg.reuse_penalty
    return routes


def routes(problem: PlanningProblem, cfg: RoadmapConfig, deadline: Deadline = NEVER,
           ) -> tuple[Roadmap, Query, np.ndarray, list[np.ndarray], RoadmapConfig]:
    """:func:`diverse_routes` on the cached roadmap; when it finds none, again without the extra margin, then at
    half the spacing (a finer roadmap, built once and cached too). Returns the roadmap, query, edge weights and
    routes of the last attempt and the settings it used; no routes: none at the finest resolution tried.
    ``deadline``: a fallback is tried only when it (as long as the longest attempt so far, plus a roadmap build
    if it needs one) fits in what is left, and further routes only while one more fits (:func:`diverse_routes`)."""
    h = auto_spacing(problem, cfg)
    wall = WallClock(deadline)
    first: Roadmap | None = None
    for c in (cfg, replace(cfg, margin=0.0), replace(cfg, margin=0.0, spacing=0.5 * h)):
        if first is not None:
            wall.lap()
            if not wall.affords(wall.predicted_s() + _build_estimate_s(problem, c, first)):
                break
        rm = cached(problem, c)
        first = first or rm
        q = attach(rm, problem, c)
        weights = timed_weights(q, problem, clearance_weights(q, problem))
        found = diverse_routes(rm, problem, c, q, weights, deadline)
        if found:
            break
    return rm, q, weights, found, c


def densify(points: np.ndarray, step: float) -> np.ndarray:
    """Points along a polyline (M, 3) every ``step`` metres or closer, vertices kept."""
    seg = np.diff(points, axis=0)
    counts = np.maximum(np.ceil(np.linalg.norm(seg, axis=1) / step).astype(int), 1)
    idx, t = segment_samples(counts)
    return np.concatenate([points[idx] + t[:, None] * seg[idx], points[-1:]])


def mean_distance(p: np.ndarray, q: np.ndarray) -> float:
    """Mean distance from samples of polyline ``p`` to the nearest sample of ``q`` (symmetrised)."""
    dp, dq = densify(p, 10.0), densify(q, 10.0)
    return 0.5 * (cKDTree(dq).query(dp)[0].mean() + cKDTree(dp).query(dq)[0].mean())
