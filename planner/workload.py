"""What a plan will ask of the machine, estimated from its settings before anything is allocated (issue 33).

Each setting has a physical range (planner.world.config), but their products do not: 20 000 particles × 100 000
iterations, a 0.1 m sample spacing on a 50 km route or a 50-level roadmap at 12 m are each in range and together
hours of work or gigabytes of memory. :func:`check_workload` refuses such a job in one line that names the setting
to change, before :func:`planner.plan.plan` starts; it costs a few arithmetic operations.

Two kinds of limit, each set far above the largest legitimate job (the shipped scenarios and the paper's benches
in planner/bench, measured on the 2-core reference machine; the numbers are by each constant):

- memory: trajectory samples, corridor-lattice edges, roadmap lattice nodes, and the numpy reference kernel's
  (particles × segments × obstacles) temporaries, each against its own limit;
- time: the search's segment–obstacle checks, the lattice's and the roadmap's set-up and the trajectory check,
  at rates measured without the kernel's broad phase (so an upper estimate), summed against :data:`MAX_PLAN_S`.
  A plan with a time budget bounds its own search, so its search is left out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from planner import kernel
from planner.errors import FuseplanError
from planner.problem import THREAT_SAMPLES, PlanningProblem
from planner.search import roadmap
from planner.search.aco import lattice_setup_s
from planner.world.config import PlannerSettings

# --- memory -------------------------------------------------------------------------------------------------
# Trajectory samples (a route ROUTE_STRETCH times the straight line, one every sample_spacing): a PLAN.json holds
# ~100 bytes per sample, so 2e5 samples are 20 MB (a PLAN.json is read back up to 64 MB). Shipped: at most 1444.
MAX_SAMPLES = 200_000
# Corridor-lattice edges, (L − 1) layers × M² with M = (2 cross_half + 1)(2 vert_half + 1): measured 160–190 bytes
# an edge at the peak of its set-up, so 4e6 edges are ~750 MB. Shipped: at most 124 025 (a hard map's roadmap guide
# of 40 points, 41 legs; 102 850 measured on hardmap_canyon_0).
MAX_LATTICE_EDGES = 4_000_000
# Roadmap lattice nodes (columns × levels, before blocked ones are dropped): 2.5 kB a node at the peak of a build
# (320 000 nodes, 820 MB, 9 s on hardmap_maze_0 at the finest spacing), so 4e5 are ~1 GB. Shipped: 12 800.
MAX_ROADMAP_NODES = 400_000
# FUSEPLAN_KERNEL=numpy holds (obstacles, particles, segments) arrays: measured 34 bytes an element at the peak of
# one evaluation, so 5e7 elements are ~1.7 GB. Benches on it: at most 1.7e6 (bench speed's scaling, 1000 particles);
# a hard map with its roadmap guide of 41 legs, 5.3e6.
MAX_NUMPY_BATCH = 50_000_000

# --- time ---------------------------------------------------------------------------------------------------
# Upper estimate of a whole plan on the 2-core reference machine. The slowest legitimate plans estimate 12 s (the
# hard maps with the roadmap, as shipped and in the benches) and run in 1–2 s; every other bench row under 2 s.
MAX_PLAN_S = 3600.0
# Compiled kernel: 0.6–1.8 ns per segment–obstacle check measured from 100 to 1e5 obstacles with the broad phase off
# (the broad phase only ever skips checks), and up to 0.6 µs a segment for terrain samples or timed threats.
PAIR_S = {"compiled": 2e-9, "numpy": 1e-7}  # numpy reference: 40–90 ns measured
SEGMENT_S = {"compiled": 6e-7, "numpy": 6e-6}
# Roadmap build: 8.9 s for 320 000 nodes × 258 (257 obstacles and the terrain) on hardmap_maze_0: 1.1e-7 s each.
ROADMAP_PAIR_S = 1.1e-7
# What a plan does after its search (merging, smoothing, the trajectory check), which a budgeted plan keeps time
# for: measured 0.6–16 ms on the shipped scenarios, about 5e-8 s per trajectory sample and obstacle on a 2-core
# machine (maze: 1220 samples × 257 obstacles, 16 ms); the estimate doubles that rate and assumes a route twice as
# long as the straight line, so it errs long (a few ms of search) rather than late.
POST_BASE_S = 0.002
POST_PAIR_S = 1e-7
ROUTE_STRETCH = 2.0


def _n(x: float) -> str:
    """A count for a message: 12800, 1.24e6."""
    return f"{x:.3g}".replace("e+0", "e").replace("e+", "e")


class JobTooLarge(FuseplanError):
    """A plan whose settings ask for more memory or time than any real job needs: one line naming the setting."""


@dataclass(frozen=True)
class Part:
    """One thing a plan computes: how much (``amount``, in its own unit, or seconds for time parts), how that
    arises from the settings (``detail``) and what to change (``advice``)."""

    amount: float
    detail: str
    advice: str


def uses_roadmap(settings: PlannerSettings) -> bool:
    """True when the chosen optimiser runs the roadmap pipeline (docs/method.md §15): fusion and spso with
    ``planner.roadmap.enabled``; the baselines never do."""
    return settings.roadmap.enabled and settings.algorithm in ("fusion", "spso")


def post_reserve_s(problem: PlanningProblem, settings: PlannerSettings) -> float:
    """Seconds a budgeted plan keeps for what follows its search (see POST_PAIR_S): the smoothed route's
    samples (a route ROUTE_STRETCH times the straight line, every ``sample_spacing`` metres) times the
    obstacles and threats they are checked against."""
    env = problem.env
    samples = ROUTE_STRETCH * problem.direct_distance / settings.sample_spacing
    checked = len(env.cylinders) + len(env.spheres) + len(env.radars) + len(env.prisms) + len(env.threats) + 1
    return POST_BASE_S + POST_PAIR_S * samples * checked


def obstacles(problem: PlanningProblem) -> int:
    """Static obstacles and radars every segment or sample is checked against (a prism counts once)."""
    env = problem.env
    return len(env.cylinders) + len(env.spheres) + len(env.radars) + len(env.prisms)


def _route_points(problem: PlanningProblem, settings: PlannerSettings) -> int:
    """Waypoints (start and goal included) of the longest route the search scores: the roadmap's guide may grow
    the swarm's route to planner.roadmap.max_guide_points."""
    interior = settings.pso.n_waypoints
    if uses_roadmap(settings):
        interior = max(interior, settings.roadmap.max_guide_points)
    return interior + 2


def memory_parts(problem: PlanningProblem, settings: PlannerSettings) -> list[tuple[Part, float]]:
    """(part, limit) for every memory-bound quantity of a plan."""
    parts: list[tuple[Part, float]] = []
    spacing = settings.sample_spacing
    route_m = ROUTE_STRETCH * problem.direct_distance
    samples = route_m / spacing
    parts.append((Part(samples, f"planner.sample_spacing={spacing:g} m on a {problem.direct_distance:.0f} m route "
                       f"gives about {_n(samples)} trajectory samples",
                       f"raise planner.sample_spacing to at least {math.ceil(route_m / MAX_SAMPLES * 10) / 10:g} m"),
                  MAX_SAMPLES))
    points = _route_points(problem, settings)
    if settings.algorithm in ("fusion", "aco"):
        aco = settings.aco
        m = (2 * aco.cross_half + 1) * (2 * aco.vert_half + 1)
        edges = (points - 1) * m * m
        parts.append((Part(edges, f"planner.aco.cross_half={aco.cross_half} and vert_half={aco.vert_half} make a "
                           f"corridor lattice of {m} nodes a layer and {_n(edges)} edges over {points - 1} legs",
                           "lower planner.aco.cross_half or planner.aco.vert_half (or the waypoints)"),
                      MAX_LATTICE_EDGES))
    if uses_roadmap(settings):
        nodes = roadmap.grid_nodes(problem, settings.roadmap)
        h = roadmap.auto_spacing(problem, settings.roadmap)
        parts.append((Part(nodes, f"planner.roadmap at {h:.3g} m spacing and up to {settings.roadmap.max_levels} "
                           f"levels lays {_n(nodes)} lattice nodes",
                           "raise planner.roadmap.spacing or lower planner.roadmap.max_levels"),
                      MAX_ROADMAP_NODES))
    if kernel.chosen() == "numpy":
        pri = problem.env.prisms  # a prism holds six breakpoints per (padded) edge
        batch = max(settings.pso.n_pop, settings.aco.n_ants) * (points - 1) * (obstacles(problem) - len(pri)
                                                                              + 6 * pri.padded[0].size + 1)
        parts.append((Part(batch, f"the numpy kernel (FUSEPLAN_KERNEL=numpy) holds {_n(batch)} "
                           "particle-segment-obstacle distances at once",
                           "lower planner.pso.n_pop (or use the compiled kernel)"),
                      MAX_NUMPY_BATCH))
    return parts


def time_parts(problem: PlanningProblem, settings: PlannerSettings, budgeted: bool = False) -> list[Part]:
    """Upper estimates, in seconds on the reference machine, of what a plan computes; ``budgeted``: the search
    stops at a time budget, so its iterations are left out."""
    which = kernel.chosen()
    k = obstacles(problem)
    timed = len(problem.env.threats) * THREAT_SAMPLES if problem.timed_threats else 0
    segments = _route_points(problem, settings) - 1
    per_path = segments * (SEGMENT_S[which] + PAIR_S[which] * (k + timed))
    what = f"{segments} segments × {k} obstacles" + (f" and {len(problem.env.threats)} threats" if timed else "")
    parts: list[Part] = []
    pso, aco, rm = settings.pso, settings.aco, settings.roadmap
    road = uses_roadmap(settings)
    if not budgeted and settings.algorithm != "aco":
        swarms = 2 if road and settings.algorithm == "fusion" else 1  # the roadmap fusion may run a second swarm
        paths = swarms * pso.n_pop * (pso.max_iter + 1)
        parts.append(Part(paths * per_path, f"planner.pso.n_pop={pso.n_pop} × max_iter={pso.max_iter}"
                          + (" × 2 swarms" if swarms > 1 else "") + f" × {what}",
                          "lower planner.pso.n_pop or planner.pso.max_iter"))
    if not budgeted and settings.algorithm in ("fusion", "aco"):
        iterations = aco.max_iter + (rm.colony_iter if road else 0)
        parts.append(Part(aco.n_ants * iterations * per_path,
                          f"planner.aco.n_ants={aco.n_ants} × {iterations} iterations × {what}",
                          "lower planner.aco.n_ants or planner.aco.max_iter"))
    if settings.algorithm in ("fusion", "aco"):
        points = _route_points(problem, settings)
        parts.append(Part(lattice_setup_s(problem, aco, points), f"the corridor lattice over {points - 1} legs "
                          f"(cross_half={aco.cross_half}, vert_half={aco.vert_half}) against {k} obstacles",
                          "lower planner.aco.cross_half or planner.aco.vert_half"))
    if road:
        nodes = roadmap.grid_nodes(problem, rm)
        parts.append(Part(nodes * (k + 1) * ROADMAP_PAIR_S, f"a roadmap of {_n(nodes)} lattice nodes × {k} obstacles",
                          "raise planner.roadmap.spacing or lower planner.roadmap.max_levels"))
    parts.append(Part(post_reserve_s(problem, settings), f"checking the trajectory every "
                      f"planner.sample_spacing={settings.sample_spacing:g} m against {k} obstacles",
                      "raise planner.sample_spacing"))
    return parts


def _duration(seconds: float) -> str:
    if seconds >= 3600:
        return f"{seconds / 3600:.3g} h"
    return f"{seconds / 60:.3g} min" if seconds >= 60 else f"{seconds:.2g} s"


def check_workload(problem: PlanningProblem, settings: PlannerSettings, budgeted: bool = False,
                   source: str | None = None) -> None:
    """Raise :class:`JobTooLarge` (one line: what, how much, the limit, which setting to change; after
    ``source``, the scenario file, when given) when ``settings`` on ``problem`` would take more memory or time than
    :data:`MAX_SAMPLES` … :data:`MAX_PLAN_S` allow. ``budgeted``: the plan has a time budget (which bounds its
    search)."""
    where = f"{source}: " if source else ""
    for part, limit in memory_parts(problem, settings):
        if part.amount > limit:
            raise JobTooLarge(f"{where}{part.detail} (limit {_n(limit)}): {part.advice}")
    parts = time_parts(problem, settings, budgeted)
    total = sum(p.amount for p in parts)
    if total > MAX_PLAN_S:
        worst = max(parts, key=lambda p: p.amount)
        raise JobTooLarge(f"{where}the plan would take up to {_duration(total)} on a 2-core machine (limit "
                          f"{_duration(MAX_PLAN_S)}), {_duration(worst.amount)} of it for {worst.detail}: "
                          f"{worst.advice}")


def estimate_s(problem: PlanningProblem, settings: PlannerSettings, budgeted: bool = False) -> float:
    """The upper time estimate :func:`check_workload` holds to :data:`MAX_PLAN_S`, in seconds."""
    return sum(p.amount for p in time_parts(problem, settings, budgeted))
