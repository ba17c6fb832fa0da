"""Planner parameters as frozen dataclasses: the one place each default lives.

Scenario files are validated into these types (see ``planner.world.scenario``); the core then trusts them.
Angles are degrees here (file units) and exposed in radians through properties (docs/method.md §1.1).
"""

from __future__ import annotations

import math
import typing
from dataclasses import dataclass, field
from typing import Literal

from pydantic import ConfigDict

STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)
G0 = 9.80665  # standard gravity, m/s²
TERMS = ("J1", "J2", "J3", "J4", "J5")  # length, hazard, altitude, smoothness, destination (docs/method.md §4.1)
CATEGORIES = ("collision", "altitude", "bounds", "turn", "climb")  # constraint violations, cost and check alike


@dataclass(frozen=True)
class VehicleLimits:
    """Vehicle flight envelope and mission conventions (docs/method.md §14.1)."""

    __pydantic_config__ = STRICT

    type: Literal["plane", "copter"] = "plane"
    cruise_speed: float = 18.0  # m/s
    max_bank_deg: float = 45.0
    max_climb_deg: float = 15.0
    max_turn_deg: float = 60.0  # largest heading change at one waypoint
    takeoff_alt: float = 50.0  # m above home
    acceptance_radius: float = 20.0  # m
    # m per radian of turn: how far past the new leg the vehicle's path-follower swings after a waypoint, on the
    # outside of the turn (docs/method.md §4.4); 0 for a vehicle that flies the smoothed curve
    turn_overshoot: float = 0.0
    end_action: Literal["loiter", "rtl", "land"] = "loiter"

    @property
    def max_bank(self) -> float:
        return math.radians(self.max_bank_deg)

    @property
    def max_climb(self) -> float:
        return math.radians(self.max_climb_deg)

    @property
    def max_turn(self) -> float:
        return math.radians(self.max_turn_deg)

    @property
    def min_turn_radius(self) -> float:
        """R_min = v² / (g tan φ_bank,max) (docs/method.md §11.2)."""
        return self.cruise_speed**2 / (G0 * math.tan(self.max_bank))


@dataclass(frozen=True)
class HazardConfig:
    """Clearance thresholds of the hazard cost T_c (docs/method.md §4.3), metres from an obstacle's surface."""

    __pydantic_config__ = STRICT

    d_safe: float = 300.0  # soft cost starts below this clearance
    d_coll: float = 50.0  # clearance below this is a violation


@dataclass(frozen=True)
class CostWeights:
    """b1…b5 of J = Σ b_i J_i (docs/method.md §4.1)."""

    __pydantic_config__ = STRICT

    length: float = 5.0
    hazard: float = 1.0
    altitude: float = 10.0
    smoothness: float = 5.0
    destination: float = 100.0

    def by_term(self) -> dict[str, float]:
        """Weights keyed by term name J1…J5."""
        return dict(zip(TERMS, (self.length, self.hazard, self.altitude, self.smoothness, self.destination)))


@dataclass(frozen=True)
class PenaltyConfig:
    """Violation penalty: ``constant + rate · depth`` per violation (docs/method.md §5.1: never inf)."""

    __pydantic_config__ = STRICT

    constant: float = 1.0e4
    per_metre: float = 1.0e3  # per metre past a distance limit (clearance, altitude band, bounds)
    per_radian: float = 1.0e4  # per radian past an angle limit (turn, climb) or per unit of κ·R_min − 1


@dataclass(frozen=True)
class SPSOConfig:
    """Spherical PSO parameters (docs/method.md §3.2, §6, §7; paper Tables 2, 5, 6) and its ablation switches
    (paper Table 3, docs/method.md §6.3)."""

    __pydantic_config__ = STRICT

    n_waypoints: int = 8
    n_pop: int = 500
    max_iter: int = 200
    w0: float = 1.0
    w_damp: float = 0.98
    w_max: float = 0.9
    w_min: float = 0.4
    c1: float = 1.5
    c2: float = 1.5
    velocity_limit: float = 0.5  # α: |v_d| ≤ α (max_d − min_d)
    psi_max_deg: float = 45.0  # elevation bound before the vehicle's climb limit is applied
    cone_half_deg: float = 45.0  # directional-guidance half-angle around the S→G bearing
    flyability_bound: bool = False  # raise r_min to 2 R_min sin(α_max) (docs/method.md §3.2, paper Property 4)
    encoding: Literal["spherical", "cartesian"] = "spherical"
    direction: Literal["cone", "full"] = "cone"
    reflection: bool = True
    damping: bool = True
    inertia: Literal["damped", "adaptive"] = "damped"
    stagnation_iters: int = 60  # stop after this many iterations without gbest improvement
    stagnation_tol: float = 0.0  # ... improvement by less than this share of the cost (0: any improvement counts)
    diversity_min: float = 0.0  # stop when normalised swarm diversity σ² falls below this (0 = off)
    # stop once gbest has been feasible for this many iterations (0 = off): a replan wants a safe route now, and the
    # roadmap pipeline then skips its colonies (docs/method.md §15.3)
    feasible_iters: int = 0
    cartesian_spread: float = 0.25  # V2 init: perturbation around S→G as a fraction of ‖SG‖

    def __post_init__(self) -> None:
        for name in ("n_waypoints", "n_pop", "max_iter", "stagnation_iters"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1")
        if self.n_pop < 2:
            raise ValueError("n_pop must be >= 2")
        if self.feasible_iters < 0:
            raise ValueError("feasible_iters must be >= 0")


@dataclass(frozen=True)
class ACOConfig:
    """Ant-colony refinement on a corridor lattice around the PSO route (docs/method.md §8, paper Tables 7, 8)."""

    __pydantic_config__ = STRICT

    n_ants: int = 30
    max_iter: int = 50
    alpha: float = 1.0  # pheromone exponent
    beta: float = 2.0  # distance-heuristic exponent
    gamma: float = 1.0  # smoothness-heuristic exponent
    rho: float = 0.08  # evaporation
    tau0: float = 0.1  # baseline pheromone
    init: Literal["gkdm", "hard", "uniform"] = "gkdm"
    amplitude: float = 12.0  # GKDM A: peak τ0 (1 + A) = 1.3
    sigma: float = 40.0  # GKDM kernel bandwidth, m
    hard_boost: float = 2.9  # hard init: τ0 + boost = 3.0 on the PSO route's edges
    update: Literal["classic", "enhanced"] = "enhanced"
    c1: float = 1.5  # enhanced rule (eq. 36): weight of the iteration-best deposit
    c2: float = 1.5  # and of the global-best deposit
    w_end: float = 0.6  # enhanced rule: ω(t) falls linearly from 1 − ρ to this
    budget_share: float = 0.2  # with a time budget, the share kept for the ACO phase
    deposit: float = 1.0  # Q: a path as good as the PSO route deposits Q on each of its edges
    tau_min: float = 0.01  # floor, so every edge keeps a chance
    tau_max: float = 10.0  # ceiling, so one path cannot freeze the colony
    smooth_floor: float = 0.05  # ε in η_smooth = max(cos θ_turn, ε)
    cross_step: float = 1.0  # first lattice step across the route, m
    vert_step: float = 1.0  # first lattice step vertically, m
    lattice_growth: float = 2.0  # each further step is this many times the previous (1 = uniform grid)
    cross_half: int = 5  # nodes each side of the route across (11 across: ±1, 3, 7, 15, 31 m)
    vert_half: int = 2  # nodes above and below (5 levels: ±1, 3 m)
    stagnation_iters: int = 50  # stop after this many iterations without improvement (50: run T_ACO)


@dataclass(frozen=True)
class RoadmapConfig:
    """The roadmap pipeline of the fusion (docs/method.md §15): a lattice roadmap of the static world gives
    diverse guide routes, the swarm searches around them in the guide-relative encoding, and the colony walks
    the roadmap. ``enabled = false`` is the paper's fusion as published (docs/method.md §9)."""

    __pydantic_config__ = STRICT

    enabled: bool = False  # opt-in until the scripted-intruder encounters follow the route (docs/method.md §15)
    spacing: float = 0.0  # horizontal lattice spacing, m (0: sqrt(area / 1600), at least 10 m)
    max_levels: int = 8  # altitude levels across the band, fewer when the vehicle climbs steeply enough
    margin: float = 10.0  # clearance beyond d_coll and the tracking margin (A/2) on nodes and edges, m
    n_routes: int = 3  # diverse guide routes (different corridors) seeded into the swarm
    reuse_penalty: float = 3.0  # edge weight factor near a route already found, when looking for the next
    climb_share: float = 0.7  # roadmap edges climb at most this share of the vehicle's max climb angle
    max_guide_points: int = 40  # interior waypoints the guide may need (the swarm grows to fit it)
    colony_iter: int = 15  # iterations of the colony on the roadmap (n_ants and the update rule: [planner.aco])
    stagnation_tol: float = 1e-3  # the guided swarm, once feasible, counts a smaller relative gain as stagnation


@dataclass(frozen=True)
class QPSOConfig:
    """Quantum-behaved PSO (Sun et al. 2004): contraction–expansion coefficient β falls linearly."""

    __pydantic_config__ = STRICT

    beta_start: float = 1.0
    beta_end: float = 0.5


@dataclass(frozen=True)
class PSOGSAConfig:
    """PSO–gravitational search hybrid (Mirjalili & Hashim 2010): G = G0 exp(−α t / T)."""

    __pydantic_config__ = STRICT

    g0: float = 1.0
    alpha: float = 20.0
    c1: float = 0.5  # weight of the gravitational acceleration
    c2: float = 1.5  # weight of the social (gbest) term


@dataclass(frozen=True)
class BPSOConfig:
    """Binary PSO (Kennedy & Eberhart 1997) over a lattice of waypoint choices."""

    __pydantic_config__ = STRICT

    bits_cross: int = 5  # 32 cross-track positions per waypoint
    bits_alt: int = 4  # 16 altitude levels per waypoint
    corridor_frac: float = 0.5  # corridor half-width as a fraction of ‖SG‖
    v_max: float = 4.0  # velocity clamp of the sigmoid transfer


# "aco": ant colony from scratch (uniform pheromone on the lattice around the straight S→G line, Table 7
# parameters; planner.search.aco.ColdColony), the cold-start arm of the GKDM bench
Algorithm = Literal["fusion", "spso", "pso", "qpso", "psogsa", "bpso", "aco"]
ALGORITHM_NAMES: tuple[str, ...] = typing.get_args(Algorithm)


@dataclass(frozen=True)
class PlannerSettings:
    """The scenario's ``[planner]`` section: which algorithm and its parameters."""

    __pydantic_config__ = STRICT

    algorithm: Algorithm = "fusion"
    seed: int = 1
    sample_spacing: float = 5.0  # m between checked samples of the smoothed trajectory
    pso: SPSOConfig = field(default_factory=SPSOConfig)  # also the shared budget of the PSO baselines
    aco: ACOConfig = field(default_factory=ACOConfig)
    roadmap: RoadmapConfig = field(default_factory=RoadmapConfig)
    qpso: QPSOConfig = field(default_factory=QPSOConfig)
    psogsa: PSOGSAConfig = field(default_factory=PSOGSAConfig)
    bpso: BPSOConfig = field(default_factory=BPSOConfig)
    weights: CostWeights = field(default_factory=CostWeights)
    penalty: PenaltyConfig = field(default_factory=PenaltyConfig)
