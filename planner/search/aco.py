"""Ant-colony refinement on a corridor lattice around a seed route, with GKDM pheromone initialisation
(docs/method.md §8; paper §4.3, §5.3, Tables 7, 8). See docs/design.md, "ACO refinement and the fusion", for
the lattice and its figure.

The lattice has one layer per waypoint of the seed route: layer 0 is the start, layer L−1 the goal, and
layer k (1 ≤ k ≤ L−2) a cross-track × vertical grid of nodes centred on the seed's waypoint k, oriented
across the route's local heading. An ant picks one node per layer, so every ant path has as many
waypoints as the seed and is scored by the same :class:`PlanningProblem` cost. The centre nodes
reproduce the seed route exactly. All ants of an iteration advance together as arrays.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from planner.deadline import NEVER, Deadline
from planner.problem import PlanningProblem
from planner.search.swarm import OptimiserResult, take
from planner.search.termination import AnyOf, MaxIterations, Progress, Stagnation, WallClock
from planner.world.config import ACOConfig
from planner.world.geometry import segment_point_distance

log = logging.getLogger(__name__)
BLOCKED_FACTOR = 1e-3  # heuristic multiplier of an edge that passes inside d_coll of a static obstacle
# a lattice colony's set-up, measured per edge (2-core machine, compiled kernel): 0.4–0.8 µs of heuristic and
# blocking check (terrain included), 60 ns per obstacle, 80 ns per seed segment of the GKDM pheromone
LATTICE_EDGE_S = 8e-7
LATTICE_PAIR_S = 6e-8
LATTICE_SEG_S = 8e-8


@dataclass(frozen=True, eq=False)
class CorridorLattice:
    """Nodes (L, M, 3) ENU metres; ``centre`` is the index of the seed route's node in every layer;
    ``offsets`` (M, 2) are each node's (cross, vertical) grid indices."""

    nodes: np.ndarray
    centre: int
    offsets: np.ndarray
    route: np.ndarray  # (L, 3) the seed route

    @property
    def n_layers(self) -> int:
        return self.nodes.shape[0]

    @property
    def edge_midpoints(self) -> np.ndarray:
        """(L−1, M, M, 3): midpoint of the edge from node i of layer k to node j of layer k+1."""
        return 0.5 * (self.nodes[:-1, :, None, :] + self.nodes[1:, None, :, :])


def lattice_offsets(index: np.ndarray, step: float, growth: float) -> np.ndarray:
    """Metres of grid index i: step·(g^|i| − 1)/(g − 1)·sign(i), geometric spacing (fine near the route for
    refinement, coarse outwards for exploration); growth 1 gives a uniform grid i·step."""
    i = np.abs(index).astype(float)
    span = i * step if growth == 1.0 else step * (growth**i - 1.0) / (growth - 1.0)
    return np.sign(index) * span


def build_lattice(route: np.ndarray, cfg: ACOConfig) -> CorridorLattice:
    """Corridor lattice around ``route`` (L, 3): cross-track axis ⟂ to the horizontal bisector of the
    route's incoming and outgoing legs at each interior waypoint, vertical axis up."""
    route = np.asarray(route, dtype=float)
    a_idx = np.arange(-cfg.cross_half, cfg.cross_half + 1)
    b_idx = np.arange(-cfg.vert_half, cfg.vert_half + 1)
    offsets = np.stack(np.meshgrid(a_idx, b_idx, indexing="ij"), axis=-1).reshape(-1, 2)
    centre = int(np.flatnonzero((offsets == 0).all(axis=1))[0])
    metres = np.stack([lattice_offsets(offsets[:, 0], cfg.cross_step, cfg.lattice_growth),
                       lattice_offsets(offsets[:, 1], cfg.vert_step, cfg.lattice_growth)], axis=-1)
    heading = route[2:, :2] - route[:-2, :2]  # bisector direction at interior waypoints
    norm = np.linalg.norm(heading, axis=-1, keepdims=True)
    heading = np.where(norm > 1e-9, heading / np.maximum(norm, 1e-12), [1.0, 0.0])
    cross = np.stack([-heading[:, 1], heading[:, 0], np.zeros(len(heading))], axis=-1)  # (L−2, 3)
    shift = (metres[:, 0, None] * cross[:, None, :]
             + metres[:, 1, None] * np.array([0.0, 0.0, 1.0]))  # (L−2, M, 3)
    nodes = np.empty((len(route), len(offsets), 3))
    nodes[0] = route[0]
    nodes[-1] = route[-1]
    nodes[1:-1] = route[1:-1, None, :] + shift
    return CorridorLattice(nodes, centre, offsets, route)


def initial_pheromone(lattice: CorridorLattice, cfg: ACOConfig, mode: str | None = None) -> np.ndarray:
    """τ at iteration 0, shape (L−1, M, M) (docs/method.md §8.2).

    gkdm:    τ0 (1 + A · max_k exp(−d_k² / 2σ²)), d_k = distance from the edge's midpoint to seed segment k;
    hard:    τ0 + boost on the seed route's own edges (centre → centre), τ0 elsewhere;
    uniform: τ0 everywhere.
    """
    mode = mode or cfg.init
    shape = lattice.nodes.shape[:1]
    n_edges = (shape[0] - 1, lattice.nodes.shape[1], lattice.nodes.shape[1])
    tau = np.full(n_edges, cfg.tau0)
    if mode == "uniform":
        return tau
    if mode == "hard":
        c = lattice.centre
        tau[:, c, c] += cfg.hard_boost
        return tau
    if mode != "gkdm":
        raise ValueError(f"unknown pheromone initialisation {mode!r}")
    route = lattice.route
    mid = lattice.edge_midpoints  # (L−1, M, M, 3)
    d = np.full(mid.shape[:-1], np.inf)
    for a, b in zip(route[:-1], route[1:]):  # one seed segment at a time: memory of one distance per edge
        np.minimum(d, segment_point_distance(a, b, mid), out=d)
    return cfg.tau0 * (1.0 + cfg.amplitude * np.exp(-(d**2) / (2.0 * cfg.sigma**2)))


@dataclass
class ColonyGraph:
    """Static per-edge data of a lattice: unit directions and the combined static heuristic."""

    direction: np.ndarray  # (L−1, M, M, 3) unit vectors
    eta: np.ndarray  # (L−1, M, M) η_dist^β × blocked factor


def colony_graph(lattice: CorridorLattice, problem: PlanningProblem, cfg: ACOConfig) -> ColonyGraph:
    """η_dist(i, j) = ‖SG‖ / (‖E_ij‖ + ‖G − n_j‖) (shorter edges that get closer to the goal score
    higher), raised to β, times BLOCKED_FACTOR for edges within d_coll of a static obstacle."""
    a = np.broadcast_to(lattice.nodes[:-1, :, None, :], (lattice.n_layers - 1, *lattice.nodes.shape[1:2],
                        lattice.nodes.shape[1], 3))
    b = np.broadcast_to(lattice.nodes[1:, None, :, :], a.shape)
    edge = b - a
    length = np.linalg.norm(edge, axis=-1)
    to_goal = np.linalg.norm(problem.goal - lattice.nodes[1:], axis=-1)[:, None, :]
    eta = (problem.direct_distance / np.maximum(length + to_goal, 1e-9)) ** cfg.beta
    eta = np.where(problem.segment_blocked(np.ascontiguousarray(a), np.ascontiguousarray(b)),
                   eta * BLOCKED_FACTOR, eta)
    return ColonyGraph(edge / np.maximum(length, 1e-9)[..., None], eta)


def construct(
    lattice: CorridorLattice, graph: ColonyGraph, tau: np.ndarray, cfg: ACOConfig, rng: np.random.Generator,
) -> np.ndarray:
    """Node choices (n_ants, L) of one iteration: p(i, j) ∝ τ^α η_dist^β η_smooth^γ (docs/method.md §8.3), all ants
    stepping through the layers together; η_smooth = max(cos θ_turn, ε) against the ant's last edge."""
    n_layers, m = lattice.nodes.shape[:2]
    ants = np.arange(cfg.n_ants)
    cur = np.full(cfg.n_ants, lattice.centre)
    prev = np.zeros((cfg.n_ants, 3))
    choice = np.empty((cfg.n_ants, n_layers), dtype=np.intp)
    choice[:, 0] = lattice.centre
    for k in range(n_layers - 2):  # a loop over layers; every ant moves in each step
        dirs = graph.direction[k, cur]  # (n_ants, M, 3)
        cos_turn = np.einsum("amd,ad->am", dirs, prev)
        smooth = np.where(np.any(prev != 0.0, axis=1)[:, None],
                          np.maximum(cos_turn, cfg.smooth_floor), 1.0)
        w = tau[k, cur] ** cfg.alpha * graph.eta[k, cur] * smooth**cfg.gamma
        cdf = np.cumsum(w, axis=1)
        u = rng.random(cfg.n_ants) * cdf[:, -1]
        nxt = np.minimum((cdf < u[:, None]).sum(axis=1), m - 1)
        prev = dirs[ants, nxt]
        cur = nxt
        choice[:, k + 1] = nxt
    choice[:, -1] = lattice.centre
    return choice


def deposit(tau: np.ndarray, choice: np.ndarray, amount: np.ndarray) -> None:
    """Add ``amount`` (n,) to every edge of each chosen path (n, L), in place."""
    k = np.broadcast_to(np.arange(choice.shape[1] - 1), (choice.shape[0], choice.shape[1] - 1))
    np.add.at(tau, (k, choice[:, :-1], choice[:, 1:]), np.broadcast_to(amount[:, None], k.shape))


class AntColony:
    """ACO refinement of a seed route (the fusion's phase II), or a cold colony with ``init="uniform"``."""

    def __init__(self, cfg: ACOConfig) -> None:
        self.cfg = cfg

    def run(
        self, problem: PlanningProblem, rng: np.random.Generator, route: np.ndarray, ref_cost: float,
        deadline: Deadline = NEVER, progress: Callable[[int, int, float], None] | None = None,
    ) -> OptimiserResult:
        """Refine ``route`` (L, 3); ``ref_cost`` (the seed's cost) scales deposits: a path of that cost
        deposits ``cfg.deposit`` per edge. History: best cost after each iteration, seed included. Within
        ``deadline``: no lattice is built that :func:`lattice_setup_s` says cannot be in time (the seed is the
        answer), and no iteration starts that would end after it (predicted by the seed's evaluation, then by
        the longest recent iteration)."""
        cfg = self.cfg
        t0 = time.perf_counter()
        wall = WallClock(deadline)
        stop = AnyOf([MaxIterations(cfg.max_iter), Stagnation(cfg.stagnation_iters), wall])
        if not wall.affords(lattice_setup_s(problem, cfg, len(route))):  # the set-up alone would overrun
            ev = problem.evaluate(np.asarray(route, dtype=float)[None])
            return OptimiserResult(np.asarray(route, dtype=float), float(ev.total[0]), ev, [], 0, wall.name,
                                   time.perf_counter() - t0, 1)
        lattice = build_lattice(route, cfg)
        graph = colony_graph(lattice, problem, cfg)
        tau = initial_pheromone(lattice, cfg)
        layers = np.arange(lattice.n_layers)
        ref = max(abs(ref_cost), 1e-9)
        # the seed route is the colony's first global best (elitist start): the global-best deposit
        # reinforces it from iteration 0, and any ant that beats it takes its place
        best_choice = np.full(lattice.n_layers, lattice.centre)
        t_seed = time.perf_counter()
        best_eval = problem.evaluate(route[None])
        best_cost = float(best_eval.total[0])
        history: list[float] = []
        stagnant = 0
        it = 0
        # iterations are timed from here; the seed's evaluation stands in for the first
        wall.first_s = time.perf_counter() - t_seed
        wall.restart_lap()
        while not wall.done():
            choice = construct(lattice, graph, tau, cfg, rng)
            paths = lattice.nodes[layers, choice]  # (n_ants, L, 3)
            ev = problem.evaluate(paths)
            ib = int(np.argmin(ev.total))
            if ev.total[ib] < best_cost:
                best_cost, best_choice, best_eval = float(ev.total[ib]), choice[ib].copy(), take(ev, ib)
                stagnant = 0
            else:
                stagnant += 1
            self._update(tau, choice, ev.total, ib, best_choice, best_cost, ref, it, rng)
            it += 1
            history.append(best_cost)
            if progress is not None:
                progress(it, cfg.max_iter, best_cost)
            wall.lap()
            if stop.done(Progress(it, best_cost, stagnant, 0.0, stop.elapsed())):
                break
        else:  # the budget ran out between the checks, or before the first ant moved (the lattice's set-up)
            stop.fired = "timeout"
        path = lattice.nodes[layers, best_choice]
        log.debug("aco stopped after %d iterations (%s), cost %.3f", it, stop.fired, best_cost)
        return OptimiserResult(path, best_cost, best_eval, history, it, stop.fired or "",
                               time.perf_counter() - t0, cfg.n_ants * it + 1)  # + the seed's evaluation

    def _update(self, tau: np.ndarray, choice: np.ndarray, costs: np.ndarray, ib: int, best_choice: np.ndarray,
                best_cost: float, ref: float, it: int, rng: np.random.Generator) -> None:
        """Classic (paper Eq. (35)) or enhanced (Eq. (36)) pheromone update, then clipping to [τ_min, τ_max]
        (docs/method.md §8.4)."""
        cfg = self.cfg
        if cfg.update == "classic":
            tau *= 1.0 - cfg.rho
            deposit(tau, choice, cfg.deposit * ref / np.maximum(costs, 1e-9))
        else:
            omega, iter_amount, best_amount = enhanced_update(cfg, it, cfg.max_iter, ref, costs[ib], best_cost, rng)
            tau *= omega
            deposit(tau, choice[ib : ib + 1], np.array([iter_amount]))
            deposit(tau, best_choice[None], np.array([best_amount]))
        np.clip(tau, cfg.tau_min, cfg.tau_max, out=tau)


def enhanced_update(cfg: ACOConfig, it: int, max_iter: int, ref: float, iter_cost: float, best_cost: float,
                    rng: np.random.Generator) -> tuple[float, float, float]:
    """The enhanced rule τ ← ω(t) τ + c1 r1 Δτ_iteration-best + c2 r2 Δτ_global-best (paper Eq. (36),
    docs/method.md §8.4) as (ω, iteration-best deposit, global-best deposit): ω falls linearly from 1 − ρ to
    ``w_end`` over ``max_iter`` iterations (``it`` 0-based); a path of cost ``ref`` deposits Q per edge."""
    w_start = 1.0 - cfg.rho
    omega = w_start + (cfg.w_end - w_start) * it / max(max_iter - 1, 1)
    r1, r2 = rng.random(2)
    return (omega, cfg.c1 * r1 * cfg.deposit * ref / max(iter_cost, 1e-9),
            cfg.c2 * r2 * cfg.deposit * ref / max(best_cost, 1e-9))


class ColdColony:
    """ACO from scratch (the ``aco`` algorithm, the fourth arm of the GKDM bench, paper §3.2 "cold start"):
    the same colony and Table 7 parameters, on the corridor lattice around the straight S→G line with
    n_waypoints interior points, pheromone uniform τ0 (no PSO seed). The straight line is only the lattice's
    axis; it is scored as the colony's first best like any seed route."""

    def __init__(self, cfg: ACOConfig, n_waypoints: int) -> None:
        from dataclasses import replace

        self.cfg = replace(cfg, init="uniform")
        self.n_waypoints = n_waypoints

    def run(
        self, problem: PlanningProblem, rng: np.random.Generator, initial_paths: np.ndarray | None = None,
        deadline: Deadline = NEVER, progress: Callable[[int, int, float], None] | None = None,
    ) -> OptimiserResult:
        s = np.linspace(0.0, 1.0, self.n_waypoints + 2)[:, None]
        line = problem.start + s * (problem.goal - problem.start)  # (n + 2, 3)
        ref = float(problem.evaluate(line[None]).total[0])
        return AntColony(self.cfg).run(problem, rng, line, ref, deadline=deadline, progress=progress)


def lattice_setup_s(problem: PlanningProblem, cfg: ACOConfig, n_points: int) -> float:
    """Estimated seconds a corridor-lattice colony spends before its first ant moves: the heuristic and the
    edges' check against the obstacles, and the GKDM pheromone against the seed's segments (neither is
    interruptible, so a budgeted colony does not start one it cannot afford). Measured 33–414 ms on the shipped
    scenarios against estimates of 51–457 ms."""
    m = (2 * cfg.cross_half + 1) * (2 * cfg.vert_half + 1)
    env = problem.env
    k = len(env.cylinders) + len(env.spheres) + len(env.radars) + len(env.prisms)
    edges = (n_points - 1) * m * m
    return edges * (LATTICE_EDGE_S + LATTICE_PAIR_S * k + LATTICE_SEG_S * (n_points - 1))
