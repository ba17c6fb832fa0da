"""Planner parameters as frozen dataclasses: the one place each default, and each value's range, lives.

Scenario files are validated into these types (see ``planner.world.scenario``); the core then trusts them.
Angles are degrees here (file units) and exposed in radians through properties (docs/method.md §1.1).

Every number carries its physical range as pydantic metadata (:func:`within`), checked when a scenario is
validated: generous, but no further than a real vehicle, map or run goes, so a typo in ``--set`` is one line
naming the field rather than an overflow, a hang or an out-of-memory deep in the search. The comment by each
bound says what it is based on. Code that builds these dataclasses itself (the benches, tests) is trusted, but for
the few rules between two fields (``d_safe >= d_coll``), which ``__post_init__`` checks on every construction.
"""

from __future__ import annotations

import math
import typing
from dataclasses import dataclass, field
from typing import Annotated, Literal, TypeGuard

from pydantic import AfterValidator, ConfigDict

STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)
G0 = 9.80665  # standard gravity, m/s²
TERMS = ("J1", "J2", "J3", "J4", "J5")  # length, hazard, altitude, smoothness, destination (docs/method.md §4.1)
CATEGORIES = ("collision", "altitude", "bounds", "turn", "climb")  # constraint violations, cost and check alike


def show_number(value: float) -> str:
    """A number for a one-line message: ``%g`` for floats, digits for ints, and a size for an int too big for
    either (TOML's reader returns integers of any length)."""
    if isinstance(value, int) and not isinstance(value, bool):
        if abs(value) < 10**20:
            return str(value)
        return f"{'-' if value < 0 else ''}about 1e{int(abs(value).bit_length() * math.log10(2))}"
    return f"{value:g}"


def within(lo: float, hi: float, unit: str = "", *, open_lo: bool = False, open_hi: bool = False) -> AfterValidator:
    """Pydantic metadata for a field (``Annotated[float, within(0, 150, "m/s", open_lo=True)]``): the value lies
    in [lo, hi], ``open_lo``/``open_hi`` excluding an end. The message gives the value and the whole range, e.g.
    ``-5 must be > 0 and <= 150 m/s``; a scenario's loader adds the file and the dotted field."""
    suffix = f" {unit}" if unit else ""
    rule = f"{'>' if open_lo else '>='} {show_number(lo)} and {'<' if open_hi else '<='} {show_number(hi)}{suffix}"

    def check(value: float) -> float:
        low = value <= lo if open_lo else value < lo
        high = value >= hi if open_hi else value > hi
        if low or high:
            raise ValueError(f"{show_number(value)} must be {rule}")
        return value

    check.bounds = (lo, hi, open_lo, open_hi)  # type: ignore[attr-defined]  # for tests and docs to read
    return AfterValidator(check)


class RelationError(ValueError):
    """A rule between two fields of one dataclass is broken (``d_safe >= d_coll``): raised in ``__post_init__``,
    it names the field to blame, so the loader reports ``hazard.d_safe`` rather than the whole section."""

    def __init__(self, field_name: str, reason: str) -> None:
        super().__init__(f"{field_name}: {reason}")
        self.field_name = field_name
        self.reason = reason


# --- shared bounds ------------------------------------------------------------------------------------------------
MAX_SPEED = 150.0  # m/s, 540 km/h: faster than any multirotor or small fixed-wing (only jet target drones go faster)
MAX_THREAT_SPEED = 1000.0  # m/s, about Mach 3: above any aircraft a scripted threat or intruder stands for
MAX_HEIGHT = 25_000.0  # m: above the 21–23 km where high-altitude solar drones cruise
MAX_MAP = 100_000.0  # m per side of a map: at 100 km the local ENU plane is 0.8 km above the earth's surface
MAX_COORD = 1_000_000.0  # m: |x|, |y|, |z| of anything placed on a map, ten times the largest map
MAX_RADIUS = 100_000.0  # m: an obstacle, threat zone or clearance as wide as the largest map
MAX_POPULATION = 20_000  # particles or ants: 40 times the paper's swarm of 500
MAX_WAYPOINTS = 200  # interior waypoints: 25 times the scenarios' 8; a mission holds ~700 items on ArduPilot SITL
MAX_ITERATIONS = 100_000  # 500 times the paper's 200: iterations a search may run
MAX_PATIENCE = 10**9  # an iteration count that waits (stagnation, feasibility): large values switch the stop off
MAX_WEIGHT = 1e6  # cost weights and pheromone amounts: 1e4 times the largest default (b5 = 100)
MAX_PENALTY = 1e9  # a violation's penalty: 1e5 times the default constant; depth × rate stays far from overflow
MAX_COEFFICIENT = 10.0  # PSO/ACO coefficients and exponents: the literature stays below 4; τ^10 is still finite

Speed = Annotated[float, within(0, MAX_SPEED, "m/s", open_lo=True)]
Share = Annotated[float, within(0, 1)]
Coefficient = Annotated[float, within(0, MAX_COEFFICIENT)]
Weight = Annotated[float, within(0, MAX_WEIGHT)]
Penalty = Annotated[float, within(0, MAX_PENALTY)]
Population = Annotated[int, within(1, MAX_POPULATION)]
Iterations = Annotated[int, within(1, MAX_ITERATIONS)]
Patience = Annotated[int, within(1, MAX_PATIENCE)]


@dataclass(frozen=True)
class VehicleLimits:
    """Vehicle flight envelope and mission conventions (docs/method.md §14.1)."""

    __pydantic_config__ = STRICT

    type: Literal["plane", "copter"] = "plane"
    cruise_speed: Speed = 18.0  # m/s
    # bank and climb stop short of 90°: tan() of either is a divisor (R_min, the climb limit)
    max_bank_deg: Annotated[float, within(0, 90, "deg", open_lo=True, open_hi=True)] = 45.0
    max_climb_deg: Annotated[float, within(0, 90, "deg", open_lo=True, open_hi=True)] = 15.0
    # largest heading change at one waypoint
    max_turn_deg: Annotated[float, within(0, 180, "deg", open_lo=True)] = 60.0
    takeoff_alt: Annotated[float, within(0, MAX_HEIGHT, "m", open_lo=True)] = 50.0  # m above home
    # m; PX4's NAV_ACC_RAD stops at 200 m; 1 km leaves room for the fastest plane's turns
    acceptance_radius: Annotated[float, within(0, 1000, "m", open_lo=True)] = 20.0
    # m per radian of turn: how far past the new leg the vehicle's path-follower swings after a waypoint, on the
    # outside of the turn (docs/method.md §4.4); 0 for a vehicle that flies the smoothed curve. ArduPlane swings
    # 213 m/rad at 150 m/s with its default L1 period; 2 km/rad allows a period 9 times longer
    turn_overshoot: Annotated[float, within(0, 2000, "m per radian")] = 0.0
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

    d_safe: Annotated[float, within(0, MAX_RADIUS, "m", open_lo=True)] = 300.0  # soft cost starts below this
    d_coll: Annotated[float, within(0, MAX_RADIUS, "m")] = 50.0  # clearance below this is a violation

    def __post_init__(self) -> None:
        if self.d_safe < self.d_coll:
            raise RelationError("d_safe", f"{show_number(self.d_safe)} m must be >= d_coll "
                                f"({show_number(self.d_coll)} m)")


@dataclass(frozen=True)
class CostWeights:
    """b1…b5 of J = Σ b_i J_i (docs/method.md §4.1)."""

    __pydantic_config__ = STRICT

    length: Weight = 5.0
    hazard: Weight = 1.0
    altitude: Weight = 10.0
    smoothness: Weight = 5.0
    destination: Weight = 100.0

    def by_term(self) -> dict[str, float]:
        """Weights keyed by term name J1…J5."""
        return dict(zip(TERMS, (self.length, self.hazard, self.altitude, self.smoothness, self.destination)))


@dataclass(frozen=True)
class PenaltyConfig:
    """Violation penalty: ``constant + rate · depth`` per violation (docs/method.md §5.1: never inf)."""

    __pydantic_config__ = STRICT

    constant: Penalty = 1.0e4
    per_metre: Penalty = 1.0e3  # per metre past a distance limit (clearance, altitude band, bounds)
    per_radian: Penalty = 1.0e4  # per radian past an angle limit (turn, climb) or per unit of κ·R_min − 1


@dataclass(frozen=True)
class SPSOConfig:
    """Spherical PSO parameters (docs/method.md §3.2, §6, §7; paper Tables 2, 5, 6) and its ablation switches
    (paper Table 3, docs/method.md §6.3)."""

    __pydantic_config__ = STRICT

    n_waypoints: Annotated[int, within(1, MAX_WAYPOINTS)] = 8
    n_pop: Annotated[int, within(2, MAX_POPULATION)] = 500
    max_iter: Iterations = 200
    w0: Coefficient = 1.0
    w_damp: Annotated[float, within(0, 1, open_lo=True)] = 0.98
    w_max: Coefficient = 0.9
    w_min: Coefficient = 0.4  # <= w_max
    c1: Coefficient = 1.5
    c2: Coefficient = 1.5
    # α: |v_d| ≤ α (max_d − min_d); above 1 a particle can cross its whole range in one step
    velocity_limit: Annotated[float, within(0, MAX_COEFFICIENT, open_lo=True)] = 0.5
    # elevation bound before the vehicle's climb limit is applied
    psi_max_deg: Annotated[float, within(0, 90, "deg", open_lo=True)] = 45.0
    # directional-guidance half-angle around the S→G bearing
    cone_half_deg: Annotated[float, within(0, 180, "deg", open_lo=True)] = 45.0
    flyability_bound: bool = False  # raise r_min to 2 R_min sin(α_max) (docs/method.md §3.2, paper Property 4)
    encoding: Literal["spherical", "cartesian"] = "spherical"
    direction: Literal["cone", "full"] = "cone"
    reflection: bool = True
    damping: bool = True
    inertia: Literal["damped", "adaptive"] = "damped"
    stagnation_iters: Patience = 60  # stop after this many iterations without gbest improvement
    # ... improvement by less than this share of the cost (0: any improvement counts)
    stagnation_tol: Annotated[float, within(0, 1, open_hi=True)] = 0.0
    # stop when normalised swarm diversity σ² (at most 1 on the unit box) falls below this (0 = off)
    diversity_min: Share = 0.0
    # stop once gbest has been feasible for this many iterations (0 = off): a replan wants a safe route now, and the
    # roadmap pipeline then skips its colonies (docs/method.md §15.3)
    feasible_iters: Annotated[int, within(0, MAX_PATIENCE)] = 0
    # V2 init: perturbation around S→G as a fraction of ‖SG‖ (10: ten route lengths aside, past any map)
    cartesian_spread: Annotated[float, within(0, 10)] = 0.25

    def __post_init__(self) -> None:
        if self.w_min > self.w_max:
            raise RelationError("w_min", f"{show_number(self.w_min)} must not exceed w_max ({show_number(self.w_max)})")


@dataclass(frozen=True)
class ACOConfig:
    """Ant-colony refinement on a corridor lattice around the PSO route (docs/method.md §8, paper Tables 7, 8)."""

    __pydantic_config__ = STRICT

    n_ants: Population = 30
    max_iter: Iterations = 50
    alpha: Coefficient = 1.0  # pheromone exponent
    beta: Coefficient = 2.0  # distance-heuristic exponent
    gamma: Coefficient = 1.0  # smoothness-heuristic exponent
    rho: Annotated[float, within(0, 1, open_lo=True, open_hi=True)] = 0.08  # evaporation
    tau0: Annotated[float, within(0, MAX_WEIGHT, open_lo=True)] = 0.1  # baseline pheromone
    init: Literal["gkdm", "hard", "uniform"] = "gkdm"
    amplitude: Weight = 12.0  # GKDM A: peak τ0 (1 + A) = 1.3
    sigma: Annotated[float, within(0, MAX_RADIUS, "m", open_lo=True)] = 40.0  # GKDM kernel bandwidth, m
    hard_boost: Weight = 2.9  # hard init: τ0 + boost = 3.0 on the PSO route's edges
    update: Literal["classic", "enhanced"] = "enhanced"
    c1: Coefficient = 1.5  # enhanced rule (eq. 36): weight of the iteration-best deposit
    c2: Coefficient = 1.5  # and of the global-best deposit
    # enhanced rule: ω(t) falls linearly from 1 − ρ to this
    w_end: Annotated[float, within(0, 1, open_lo=True)] = 0.6
    # with a time budget, the share kept for the ACO phase
    budget_share: Annotated[float, within(0, 1, open_hi=True)] = 0.2
    deposit: Weight = 1.0  # Q: a path as good as the PSO route deposits Q on each of its edges
    # floor, so every edge keeps a chance (<= tau_max)
    tau_min: Annotated[float, within(0, MAX_WEIGHT, open_lo=True)] = 0.01
    # ceiling, so one path cannot freeze the colony
    tau_max: Annotated[float, within(0, MAX_WEIGHT, open_lo=True)] = 10.0
    smooth_floor: Annotated[float, within(0, 1, open_lo=True)] = 0.05  # ε in η_smooth = max(cos θ_turn, ε)
    # first lattice steps across the route and vertically, m (1 km: a corridor as wide as a large map)
    cross_step: Annotated[float, within(0, 1000, "m", open_lo=True)] = 1.0
    vert_step: Annotated[float, within(0, 1000, "m", open_lo=True)] = 1.0
    # each further step is this many times the previous (1 = uniform grid)
    lattice_growth: Annotated[float, within(1, 10)] = 2.0
    # nodes each side of the route across (11 across: ±1, 3, 7, 15, 31 m) and above and below (5 levels: ±1, 3 m);
    # the lattice has (2 cross_half + 1)² (2 vert_half + 1)² edges between two layers
    cross_half: Annotated[int, within(0, 20)] = 5
    vert_half: Annotated[int, within(0, 10)] = 2
    stagnation_iters: Patience = 50  # stop after this many iterations without improvement (50: run T_ACO)

    def __post_init__(self) -> None:
        if self.tau_min > self.tau_max:
            raise RelationError("tau_min", f"{show_number(self.tau_min)} must not exceed tau_max "
                                f"({show_number(self.tau_max)})")


def _auto_or_metres(value: float) -> float:
    if value != 0 and not 1 <= value <= MAX_MAP:
        raise ValueError(f"{show_number(value)} must be 0 (automatic) or >= 1 and <= {show_number(MAX_MAP)} m")
    return value


PAPER_MODE = "planner.roadmap.enabled=false"  # the override that selects paper mode (--paper; the paper benches)


@dataclass(frozen=True)
class RoadmapConfig:
    """The roadmap pipeline of the fusion (docs/method.md §15): a lattice roadmap of the static world gives
    diverse guide routes, the swarm searches around them in the guide-relative encoding, and the colony walks
    the roadmap. The default for every plan and replan; ``enabled = false`` is the paper mode: the paper's
    planners as published (docs/method.md §9), which the paper benches pin."""

    __pydantic_config__ = STRICT

    enabled: bool = True  # false: paper mode (the paper's fusion, SPSO and baselines as published)
    # horizontal lattice spacing, m (0: sqrt(area / 1600), at least 10 m); a finer one than 1 m resolves nothing
    # the cost does not
    spacing: Annotated[float, AfterValidator(_auto_or_metres)] = 0.0
    # altitude levels across the band, fewer when the vehicle climbs steeply enough
    max_levels: Annotated[int, within(1, 50)] = 8
    # clearance beyond d_coll and the tracking margin (A/2) on nodes and edges, m
    margin: Annotated[float, within(0, MAX_RADIUS, "m")] = 10.0
    n_routes: Annotated[int, within(1, 20)] = 3  # diverse guide routes (different corridors) seeded into the swarm
    # edge weight factor near a route already found, when looking for the next
    reuse_penalty: Annotated[float, within(1, MAX_WEIGHT)] = 3.0
    # roadmap edges climb at most this share of the vehicle's max climb angle
    climb_share: Annotated[float, within(0, 1, open_lo=True)] = 0.7
    # interior waypoints the guide may need (the swarm grows to fit it)
    max_guide_points: Annotated[int, within(1, MAX_WAYPOINTS)] = 40
    colony_iter: Iterations = 15  # iterations of the colony on the roadmap (n_ants and the update rule: [planner.aco])
    # the guided swarm, once feasible, counts a smaller relative gain as stagnation
    stagnation_tol: Annotated[float, within(0, 1, open_hi=True)] = 1e-3


@dataclass(frozen=True)
class QPSOConfig:
    """Quantum-behaved PSO (Sun et al. 2004): contraction–expansion coefficient β falls linearly."""

    __pydantic_config__ = STRICT

    beta_start: Coefficient = 1.0
    beta_end: Annotated[float, within(0, MAX_COEFFICIENT, open_lo=True)] = 0.5


@dataclass(frozen=True)
class PSOGSAConfig:
    """PSO–gravitational search hybrid (Mirjalili & Hashim 2010): G = G0 exp(−α t / T)."""

    __pydantic_config__ = STRICT

    g0: Annotated[float, within(0, 1000)] = 1.0  # the literature's G0 is 1 to 100
    alpha: Annotated[float, within(0, 1000)] = 20.0  # exp(−1000) is already 0: a larger α changes nothing
    c1: Coefficient = 0.5  # weight of the gravitational acceleration
    c2: Coefficient = 1.5  # weight of the social (gbest) term


@dataclass(frozen=True)
class BPSOConfig:
    """Binary PSO (Kennedy & Eberhart 1997) over a lattice of waypoint choices."""

    __pydantic_config__ = STRICT

    bits_cross: Annotated[int, within(1, 10)] = 5  # 32 cross-track positions per waypoint (10 bits: 1024)
    bits_alt: Annotated[int, within(1, 10)] = 4  # 16 altitude levels per waypoint
    # corridor half-width as a fraction of ‖SG‖
    corridor_frac: Annotated[float, within(0, 2, open_lo=True)] = 0.5
    # velocity clamp of the sigmoid transfer (sigmoid(100) is 1 to the last bit)
    v_max: Annotated[float, within(0, 100, open_lo=True)] = 4.0


# "aco": ant colony from scratch (uniform pheromone on the lattice around the straight S→G line, Table 7
# parameters; planner.search.aco.ColdColony), the cold-start arm of the GKDM bench
Algorithm = Literal["fusion", "spso", "pso", "qpso", "psogsa", "bpso", "aco"]
ALGORITHM_NAMES: tuple[str, ...] = typing.get_args(Algorithm)


def is_algorithm(name: str) -> TypeGuard[Algorithm]:
    """``name`` is one of :data:`ALGORITHM_NAMES`."""
    return name in ALGORITHM_NAMES


@dataclass(frozen=True)
class PlannerSettings:
    """The scenario's ``[planner]`` section: which algorithm and its parameters."""

    __pydantic_config__ = STRICT

    algorithm: Algorithm = "fusion"
    seed: Annotated[int, within(0, 2**63 - 1)] = 1  # a PLAN.json's seed is a signed 64-bit integer
    # m between checked samples of the smoothed trajectory: 0.1 m is finer than any autopilot's position; 1 km
    # still checks a route every kilometre (planner.workload limits the samples a plan may take)
    sample_spacing: Annotated[float, within(0.1, 1000, "m")] = 5.0
    pso: SPSOConfig = field(default_factory=SPSOConfig)  # also the shared budget of the PSO baselines
    aco: ACOConfig = field(default_factory=ACOConfig)
    roadmap: RoadmapConfig = field(default_factory=RoadmapConfig)
    qpso: QPSOConfig = field(default_factory=QPSOConfig)
    psogsa: PSOGSAConfig = field(default_factory=PSOGSAConfig)
    bpso: BPSOConfig = field(default_factory=BPSOConfig)
    weights: CostWeights = field(default_factory=CostWeights)
    penalty: PenaltyConfig = field(default_factory=PenaltyConfig)
