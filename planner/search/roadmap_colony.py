"""The ant colony on the roadmap (docs/method.md §15.4): ants walk the roadmap's graph from start to goal, so
unlike the corridor lattice (:mod:`planner.search.aco`) the colony can change corridor.

GKDM hands the swarm's knowledge over: the pheromone starts at τ0 (1 + A · max_k w_k exp(−d_k² / 2σ²)), d_k the
distance from an edge's midpoint to elite route k of the swarm (its distinct best personal bests, w_k = 1 for the
best and 1/2 for the others), σ one roadmap spacing. The heuristic of edge u→v is exp(−detour / spacing), the
detour being how much longer the best way to the goal gets by taking it (weight(u, v) + D(v) − D(u), with D the
clearance-weighted graph distance to the goal): zero along shortest paths, so ants make progress and prefer room.
An ant never revisits a node. Each ant's path, resampled to the swarm's waypoint count, is scored by the planning
cost itself; the pheromone update is the enhanced rule of the lattice colony (paper Eq. (36)).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from planner.deadline import NEVER, Deadline
from planner.problem import Evaluation, PlanningProblem
from planner.search.aco import enhanced_update
from planner.search.encoding import resample_paths
from planner.search.roadmap import Query, densify
from planner.search.swarm import take
from planner.search.termination import WallClock
from planner.world.config import ACOConfig

ELITE_WEIGHT = 0.5  # GKDM weight of the elite routes after the best
DETOUR_SCALE = 1.0  # spacings of detour that cost an ant a factor e^β in preference
SETUP_EDGE_S = 1e-6  # a colony's set-up per query edge (measured 0.5-0.7 µs on the hard maps, 2-core machine)
MAX_STEPS_FACTOR = 3  # an ant gives up after this many times the shortest path's node count


@dataclass
class ColonyResult:
    path: np.ndarray | None  # (M, 3) the best ant's roadmap path (nodes), None if no ant arrived
    route: np.ndarray | None  # (n_points, 3) that path as the cost scored it (resampled)
    evaluation: Evaluation | None
    cost: float
    iterations: int
    evaluations: int
    time_s: float
    arrived: float  # share of ants that reached the goal
    ant_paths: list[np.ndarray] = field(default_factory=list)  # the last iteration's arrived ants (figures)
    history: list[float] = field(default_factory=list)  # best cost after each iteration


@dataclass(frozen=True, eq=False)
class Adjacency:
    """Padded neighbour lists: ``nbr`` (N, D) node indices (−1 pad), ``eid`` (N, D) edge indices."""

    nbr: np.ndarray
    eid: np.ndarray


def adjacency(q: Query) -> Adjacency:
    """Neighbour lists of the query graph, each undirected edge listed from both ends."""
    n = len(q.points)
    e = q.edges
    src = np.concatenate([e[:, 0], e[:, 1]])
    dst = np.concatenate([e[:, 1], e[:, 0]])
    ids = np.concatenate([np.arange(len(e)), np.arange(len(e))])
    order = np.argsort(src, kind="stable")
    src, dst, ids = src[order], dst[order], ids[order]
    deg = np.bincount(src, minlength=n)
    width = max(int(deg.max()), 1)
    slot = np.arange(len(src)) - np.repeat(np.cumsum(deg) - deg, deg)
    nbr = np.full((n, width), -1, dtype=np.intp)
    eid = np.zeros((n, width), dtype=np.intp)
    nbr[src, slot] = dst
    eid[src, slot] = ids
    return Adjacency(nbr, eid)


def gkdm_pheromone(q: Query, elites: list[np.ndarray], cfg: ACOConfig, sigma: float) -> np.ndarray:
    """τ (E,) from the elite routes, best first (module docstring)."""
    mids = 0.5 * (q.points[q.edges[:, 0]] + q.points[q.edges[:, 1]])
    boost = np.zeros(len(mids))
    # the best route, then the others as one point set: they share a weight and the kernel falls with distance,
    # so their largest term is the one of the nearest point of any of them (the same numbers, one query, not k)
    groups = [elites[:1], elites[1:]]
    for weight, group in zip((1.0, ELITE_WEIGHT), groups):
        if not group:
            continue
        d = cKDTree(np.concatenate([densify(route, 0.5 * sigma) for route in group])).query(mids)[0]
        boost = np.maximum(boost, weight * np.exp(-(d**2) / (2.0 * sigma**2)))
    return cfg.tau0 * (1.0 + cfg.amplitude * boost)


def setup_s(q: Query) -> float:
    """Estimated seconds of a colony's set-up on query ``q`` before its first walk (adjacency, distances to the
    goal, the GKDM pheromone's two nearest-point queries over every edge); not interruptible, so a budgeted
    caller skips a colony it cannot afford."""
    return SETUP_EDGE_S * len(q.edges)


def walk(adj: Adjacency, tau: np.ndarray, weights: np.ndarray, to_goal: np.ndarray, scale: float, start: int,
         goal: int, n_ants: int, max_steps: int, cfg: ACOConfig, rng: np.random.Generator,
         ) -> tuple[np.ndarray, np.ndarray]:
    """All ants step together: node sequences (A, max_steps + 1) padded with −1 and whether each arrived.
    Edge u→v is chosen ∝ τ^α · exp(−detour / scale)^β, detour = weight + D(v) − D(u) (module docstring)."""
    n = adj.nbr.shape[0]
    ants = np.arange(n_ants)
    cur = np.full(n_ants, start)
    seq = np.full((n_ants, max_steps + 1), -1, dtype=np.intp)
    seq[:, 0] = start
    visited = np.zeros((n_ants, n), dtype=bool)
    visited[ants, start] = True
    active = np.ones(n_ants, dtype=bool)
    arrived = np.zeros(n_ants, dtype=bool)
    for step in range(1, max_steps + 1):  # a loop over steps; every ant moves in each
        nb = adj.nbr[cur]  # (A, D)
        safe = np.maximum(nb, 0)
        valid = (nb >= 0) & ~visited[ants[:, None], safe] & active[:, None] & np.isfinite(to_goal[safe])
        e = adj.eid[cur]
        detour = np.maximum(weights[e] + to_goal[safe] - to_goal[cur][:, None], 0.0)
        w = np.where(valid, tau[e] ** cfg.alpha * np.exp(-(cfg.beta / scale) * np.where(valid, detour, 0.0)), 0.0)
        total = w.sum(axis=1)
        active &= total > 0.0
        cdf = np.cumsum(w, axis=1)
        u = rng.random(n_ants) * total
        pick = np.minimum((cdf < u[:, None]).sum(axis=1), nb.shape[1] - 1)
        nxt = np.where(active, nb[ants, pick], cur)
        seq[active, step] = nxt[active]
        visited[ants, nxt] = True
        cur = nxt
        done = active & (cur == goal)
        arrived |= done
        active &= ~done
        if not active.any():
            break
    return seq, arrived


class RoadmapColony:
    """Ants on the roadmap (module docstring), refining nothing: they choose a corridor."""

    def __init__(self, cfg: ACOConfig, n_points: int, max_iter: int) -> None:
        self.cfg = cfg
        self.n_points = n_points
        self.max_iter = max_iter

    def run(self, q: Query, weights: np.ndarray, problem: PlanningProblem, elites: list[np.ndarray],
            rng: np.random.Generator, deadline: Deadline = NEVER, first_s: float = 0.0) -> ColonyResult:
        """Walk the ants until ``max_iter``, stagnation or ``deadline`` (checked before each walk against the
        longest recent one; ``first_s``: the caller's guess at the first, e.g. a swarm iteration's time)."""
        cfg = self.cfg
        t0 = time.perf_counter()
        wall = WallClock(deadline, first_s=first_s)  # the deadline counts the set-up below too
        adj = adjacency(q)
        to_goal = dijkstra(q.graph(weights), indices=q.goal)
        if not np.isfinite(to_goal[q.start]):
            return ColonyResult(None, None, None, np.inf, 0, 0, time.perf_counter() - t0, 0.0)
        spacing = q.roadmap.spacing
        tau = gkdm_pheromone(q, elites, cfg, spacing)
        hops = int(np.ceil(to_goal[q.start] / spacing)) + 2
        best_cost, best_path, best_nodes, best_route, best_eval = np.inf, None, None, None, None
        it, evals, arrived_total, stagnant = 0, 0, 0, 0
        last_paths: list[np.ndarray] = []
        history: list[float] = []  # best so far after each iteration
        wall.restart_lap()  # iterations are timed from here
        while it < self.max_iter and stagnant < cfg.stagnation_iters:
            if it:  # the iteration just ended (its body may `continue`)
                wall.lap()
            if wall.done():  # the next walk, as long as the longest recent one, would overrun
                break
            seq, arrived = walk(adj, tau, weights, to_goal, DETOUR_SCALE * spacing, q.start, q.goal, cfg.n_ants,
                                MAX_STEPS_FACTOR * hops, cfg, rng)
            it += 1
            arrived_total += int(arrived.sum())
            if not arrived.any():
                tau *= 1.0 - cfg.rho
                np.clip(tau, cfg.tau_min, cfg.tau_max, out=tau)
                stagnant += 1
                history.append(best_cost)
                continue
            paths = [q.points[s[s >= 0]] for s in seq[arrived]]
            last_paths = paths
            pts = np.concatenate([resample_paths(p[None], self.n_points) for p in paths])
            ev = problem.evaluate(pts)
            cost = ev.total
            evals += len(cost)
            ib = int(np.argmin(cost))
            nodes = seq[arrived][ib]
            nodes = nodes[nodes >= 0]
            if cost[ib] < best_cost:
                best_cost, best_path, best_nodes, stagnant = float(cost[ib]), paths[ib], nodes, 0
                best_route, best_eval = pts[ib], take(ev, ib)
            else:
                stagnant += 1
            omega, iter_amount, best_amount = enhanced_update(cfg, it - 1, self.max_iter, max(best_cost, 1e-9),
                                                              float(cost[ib]), best_cost, rng)
            tau *= omega
            tau[q.edge_ids(nodes)] += iter_amount
            assert best_nodes is not None  # the first iteration's best ant beat inf
            tau[q.edge_ids(best_nodes)] += best_amount
            np.clip(tau, cfg.tau_min, cfg.tau_max, out=tau)
            history.append(best_cost)
        return ColonyResult(best_path, best_route, best_eval, best_cost, it, evals, time.perf_counter() - t0,
                            arrived_total / max(it * cfg.n_ants, 1), last_paths, history)

