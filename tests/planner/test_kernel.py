"""The compiled cost kernel (planner/kernel/) against the numpy reference (PlanningProblem.evaluate_reference):
the same terms, penalties and totals to 1e-9 relative and the same violation counts, on random swarms over every
shipped scenario and over a map with every obstacle family, threat law, terrain and a start heading."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from kernel_reference import assert_broad_phase_exact, assert_same, swarm

from planner import kernel
from planner.kernel import fastmath
from planner.plan import problem_from_scenario
from planner.problem import CATEGORIES, TERMS, PlanningProblem
from planner.search import spso
from planner.world.config import HazardConfig, SPSOConfig, VehicleLimits
from planner.world.environment import (
    Cylinders,
    Environment,
    Radars,
    Spheres,
    Threat,
    Threats,
)
from planner.world.geometry import spherical_to_cartesian
from planner.world.scenario import load_scenario
from planner.world.terrain import Terrain

SCENARIOS = sorted((Path(__file__).resolve().parents[2] / "sitl_scenarios").glob("*.toml"))
SCENARIOS_BY_NAME = {p.stem: p for p in SCENARIOS}

pytestmark = [pytest.mark.skipif(kernel.njit is None, reason="numba is not installed: only the reference runs"),
              pytest.mark.usefixtures("compiled")]


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.stem)
def test_kernel_matches_the_reference_on_every_shipped_scenario(path: Path) -> None:
    problem = problem_from_scenario(load_scenario(path))
    rng = np.random.default_rng(7)
    for spread in (0.02, 0.1, 0.3):
        assert_same(problem, swarm(problem, rng, spread=spread))
    violations = problem.evaluate(swarm(problem, rng, spread=0.3)).n_violations
    assert violations.min() == 0 or violations.max() > 0  # the swarm is not all one thing
    assert violations.max() > 0


def every_family() -> Environment:
    """Finite and unlimited cylinders, spheres, a hemisphere, radars, hilly terrain, and a threat of each law."""
    xs = np.linspace(0.0, 2000.0, 41)
    hills = 40.0 * np.sin(xs[None] / 300.0) * np.cos(xs[:, None] / 250.0) + 40.0
    threats = Threats((
        Threat("l", "loiter", 40.0, (900.0, 1100.0, 150.0), speed=20.0, circle_radius=200.0, phase=0.3,
               direction=-1.0),
        Threat("p", "patrol", 30.0, (300.0, 1500.0, 180.0), (1700.0, 600.0, 120.0), speed=25.0),
        Threat("p0", "patrol", 30.0, (500.0, 500.0, 180.0), (500.0, 500.0, 180.0), speed=5.0),  # a zero-length leg
        Threat("t", "track", 35.0, (1500.0, 200.0, 160.0), (-12.0, 14.0, 0.5), t_ref=4.0, radius_growth=0.5),
    ))
    return Environment(
        2000.0, 2000.0, 50.0, 300.0,
        cylinders=Cylinders([600.0, 1200.0, 1500.0], [800.0, 900.0, 1400.0], [80.0, 60.0, 100.0],
                            [np.inf, 160.0, 220.0], [0.0, 0.0, 0.0]),
        spheres=Spheres([[1000.0, 400.0, 150.0], [400.0, 1300.0, 0.0]], [90.0, 150.0]),
        radars=Radars([[1700.0, 1700.0, 0.0]], [250.0], [0.8]),
        terrain=Terrain(0.0, 0.0, 50.0, 50.0, hills),
        threats=threats,
    )


@pytest.mark.parametrize("overshoot", [0.0, 22.0], ids=["curve", "overshoot"])
@pytest.mark.parametrize("terrain", [True, False], ids=["terrain", "flat"])
@pytest.mark.parametrize("heading", [None, (0.6, -0.8, 0.0), (-1.0, 0.2, 0.1)], ids=["none", "h1", "h2"])
def test_kernel_matches_the_reference_with_every_family(terrain: bool, heading, overshoot: float) -> None:
    env = every_family()
    if not terrain:
        env = dataclasses.replace(env, terrain=None)  # by name: Environment's fields gained prisms before terrain
    problem = PlanningProblem(env, np.array([100.0, 100.0, 120.0]), np.array([1900.0, 1850.0, 200.0]),
                              VehicleLimits(turn_overshoot=overshoot), HazardConfig(d_safe=120.0, d_coll=20.0),
                              start_time=3.0, start_heading=heading)
    rng = np.random.default_rng(11)
    for n_wp, spread in ((1, 0.1), (6, 0.05), (8, 0.2), (20, 0.1)):
        assert_same(problem, swarm(problem, rng, n_wp=n_wp, spread=spread))
    # every category occurs somewhere in these swarms, so each is compared where it counts
    ev = problem.evaluate(swarm(problem, np.random.default_rng(3), n_pop=256, spread=0.3))
    assert all(ev.violations[c].sum() > 0 for c in CATEGORIES), {c: int(v.sum()) for c, v in ev.violations.items()}


def test_a_path_costs_the_same_alone_or_in_a_swarm() -> None:
    problem = PlanningProblem(every_family(), np.array([100.0, 100.0, 120.0]), np.array([1900.0, 1850.0, 200.0]),
                              VehicleLimits(), start_time=0.0)
    paths = swarm(problem, np.random.default_rng(5))
    whole = problem.evaluate(paths)
    for i in (0, 17, 63):
        alone = problem.evaluate(paths[i])
        assert alone.total[0] == whole.total[i]
        assert all(alone.violations[c][0] == whole.violations[c][i] for c in CATEGORIES)


def test_the_environment_variable_picks_the_reference(monkeypatch: pytest.MonkeyPatch) -> None:
    problem = problem_from_scenario(load_scenario(SCENARIOS[0]))
    paths = swarm(problem, np.random.default_rng(2))
    monkeypatch.setenv(kernel.ENV_VAR, "numpy")
    assert kernel.chosen() == "numpy"
    ref = problem.evaluate_reference(paths)
    got = problem.evaluate(paths)
    assert np.array_equal(got.total, ref.total)  # the reference itself, bit for bit
    monkeypatch.setenv(kernel.ENV_VAR, "fortran")
    with pytest.raises(ValueError, match="FUSEPLAN_KERNEL='fortran'"):
        problem.evaluate(paths)


def field(rng: np.random.Generator, count: int = 120) -> Environment:
    """A dense field for the broad phase: cylinders (unlimited and finite) and spheres of mixed sizes, some
    reaching past the map's edges, on a 3000 × 2000 m map (a grid of many cells)."""
    n_c = count // 2
    return Environment(
        3000.0, 2000.0, 50.0, 300.0,
        cylinders=Cylinders(rng.uniform(-100, 3100, n_c), rng.uniform(-100, 2100, n_c), rng.uniform(5, 150, n_c),
                            np.where(rng.random(n_c) < 0.5, np.inf, rng.uniform(80, 250, n_c)), np.zeros(n_c)),
        spheres=Spheres(np.column_stack([rng.uniform(0, 3000, count - n_c), rng.uniform(0, 2000, count - n_c),
                                         rng.uniform(0, 250, count - n_c)]), rng.uniform(10, 200, count - n_c)),
    )


def test_the_broad_phase_gives_the_same_costs_bit_for_bit(monkeypatch: pytest.MonkeyPatch) -> None:
    """Skipping obstacles out of reach of the swarm's segment only skips exact zeros, and the rest are summed in
    the same order: on and off (every obstacle) agree to the last bit, and both match the reference; segments of
    every length, off the map too, over a dense field, in swarms from spread out to tight (where most are skipped).
    The grid is segment_blocked's (tested below)."""
    problem = PlanningProblem(field(np.random.default_rng(4)), np.array([50.0, 60.0, 120.0]),
                              np.array([2950.0, 1900.0, 200.0]), VehicleLimits(),
                              HazardConfig(d_safe=60.0, d_coll=15.0))
    grid = problem.kernel_inputs.grid
    assert grid.nx * grid.ny > 16  # the grid really has cells
    rng = np.random.default_rng(9)
    for n_wp, spread in ((2, 0.3), (16, 0.002), (16, 0.02), (16, 0.1), (40, 0.05)):
        paths = swarm(problem, rng, n_pop=128, n_wp=n_wp, spread=spread)
        on = assert_broad_phase_exact(problem, paths, monkeypatch)
        assert_same(problem, paths)
    assert on.violations["collision"].max() > 0 and on.terms[TERMS[1]].max() > 0
    monkeypatch.setenv(kernel.BROAD_ENV_VAR, "sometimes")
    with pytest.raises(ValueError, match="FUSEPLAN_BROAD_PHASE='sometimes'"):
        problem.evaluate(paths)


@pytest.mark.parametrize("reflection", [True, False])
@pytest.mark.parametrize("per_particle_w", [False, True])
def test_the_compiled_swarm_step_equals_numpys_bit_for_bit_and_decoding_to_a_rounding(
    monkeypatch: pytest.MonkeyPatch, reflection: bool, per_particle_w: bool
) -> None:
    rng = np.random.default_rng(6)
    p, n = 300, 8
    lo, hi = np.tile([0.0, -0.3, -1.0], (n, 1)), np.tile([200.0, 0.3, 1.0], (n, 1))
    vmax = 0.2 * (hi - lo)
    x, pbest = (lo + rng.random((2, p, n, 3)) * (hi - lo))
    v = rng.normal(0.0, 1.0, (p, n, 3)) * vmax  # fast enough that many particles leave the box
    r1, r2 = rng.random((2, p, n, 3))
    w = rng.random((p, 1, 1)) if per_particle_w else 0.7
    got = spso.pso_step(x, v, pbest, pbest[3], w, 1.5, 1.5, lo, hi, vmax, reflection, r1, r2)
    monkeypatch.setenv(kernel.ENV_VAR, "numpy")
    ref = spso.pso_step(x, v, pbest, pbest[3], w, 1.5, 1.5, lo, hi, vmax, reflection, r1, r2)
    assert np.array_equal(got[0], ref[0]) and np.array_equal(got[1], ref[1])
    start, goal = np.array([200.0, 200.0, 50.0]), np.array([800.0, 800.0, 50.0])
    paths = kernel.decode_spherical(x, start, goal)  # its sines and cosines are fastmath.fast_sincos's, not libm's
    ref_paths = spherical_to_cartesian(start, x[..., 0], x[..., 1], x[..., 2])
    assert np.allclose(paths[:, 1:-1], ref_paths, rtol=1e-14, atol=1e-12)
    assert not np.allclose(paths[:, 1:-1], ref_paths + 1e-9, rtol=1e-14, atol=1e-12)  # the check can fail
    assert np.array_equal(paths[:, 0], np.broadcast_to(start, (p, 3)))
    assert np.array_equal(paths[:, -1], np.broadcast_to(goal, (p, 3)))


def _spso_runs(problem: PlanningProblem, cfg: SPSOConfig, seeds: range) -> list:
    return [spso.SphericalPSO(cfg).run(problem, np.random.default_rng(s)) for s in seeds]


def test_whole_searches_agree_statistically_and_each_kernel_is_deterministic(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A search is chaotic, so whole plans are compared over 20 seeds: the same number of feasible results and
    mean costs within one standard error; and each kernel gives the same plan for the same seed, bit for bit."""
    problem = problem_from_scenario(load_scenario(SCENARIOS_BY_NAME["rescue_static"]))
    # the kernels' sines, cosines and arctangents differ by a rounding, so a seed's search can part ways (a few of
    # 20 do): the swarm is big enough that the success rate is high and its count is not a coin toss
    cfg = SPSOConfig(n_waypoints=8, n_pop=150, max_iter=60)
    seeds = range(20)
    runs = {}
    for name in kernel.KERNELS:
        monkeypatch.setenv(kernel.ENV_VAR, name)
        runs[name] = _spso_runs(problem, cfg, seeds)
        again = _spso_runs(problem, cfg, range(3))
        for a, b in zip(runs[name], again):
            assert np.array_equal(a.path, b.path) and a.cost == b.cost and a.history == b.history
    feasible = {k: sum(r.evaluation.penalty[0] == 0.0 for r in rr) for k, rr in runs.items()}
    assert feasible["compiled"] == feasible["numpy"] and feasible["compiled"] > 0
    costs = {k: np.array([r.cost for r in rr]) for k, rr in runs.items()}
    se = max(costs[k].std(ddof=1) / np.sqrt(len(seeds)) for k in costs)
    assert abs(costs["compiled"].mean() - costs["numpy"].mean()) <= se


@pytest.mark.parametrize("broad", ["on", "off"])
def test_blocked_edges_match_the_reference(monkeypatch: pytest.MonkeyPatch, broad: str) -> None:
    """The ant colonies' hopeless-edge test, compiled, against numpy: a dense field (the grid) and every family
    (finite tops, radars); edges of every length, in a lattice-like (…, 3) shape."""
    monkeypatch.setenv(kernel.BROAD_ENV_VAR, broad)
    rng = np.random.default_rng(12)
    for env in (field(np.random.default_rng(5)), every_family()):
        problem = PlanningProblem(env, np.array([50.0, 60.0, 120.0]), np.array([1950.0, 1900.0, 200.0]),
                                  VehicleLimits(), HazardConfig(d_safe=60.0, d_coll=15.0))
        a = rng.uniform([-100, -100, 0], [env.size_x + 100, env.size_y + 100, 320], (40, 30, 3))
        b = a + rng.normal(0.0, 1.0, a.shape) * rng.choice([5.0, 80.0, 600.0], a.shape[:-1])[..., None]
        got = problem.segment_blocked(a, b)
        ref = problem.segment_blocked_reference(a, b)
        assert got.shape == (40, 30) and np.array_equal(got, ref)
        assert 0.05 < got.mean() < 0.95  # both kinds of edge occur


def test_warm_up_readies_every_compiled_function() -> None:
    """After warm_up a replan finds every kernel compiled (or loaded from the disk cache): no JIT pause mid-flight."""
    problem = problem_from_scenario(load_scenario(SCENARIOS_BY_NAME["rescue_static"]))
    kernel.warm_up(problem)
    for fn in (kernel.cost._cost, kernel.segments._blocked, kernel.swarm._decode_spherical, kernel.swarm._pso_step):
        assert fn.signatures, fn.__name__


def test_the_disk_caches_go_stale_with_any_file_of_the_kernel() -> None:
    """The compiled functions inline helpers from the kernel's other files, so each one's disk cache is stamped
    with every file of planner/kernel/ (planner.kernel.jit), not only its own: an edit anywhere recompiles them."""
    assert kernel.jit.PACKAGE_STAMPED
    for fn in (kernel.cost._cost, kernel.segments._blocked, kernel.swarm._pso_step):
        assert fn._cache._impl.locator.get_source_stamp()[1] == kernel.jit.package_stamp(), fn.__name__


def test_the_branch_free_arctangent_and_sine_cosine_match_libm_to_a_rounding_or_two() -> None:
    """The kernel's SIMD-friendly fast_atan2 and fast_sincos (polynomials, not libm calls) against math's, over every
    octant and quadrant, the reduction thresholds, axes, zeros and huge ratios."""
    rng = np.random.default_rng(11)
    atan2, sincos = (getattr(fn, "py_func", fn) for fn in (fastmath.fast_atan2, fastmath.fast_sincos))
    t8 = math.tan(math.pi / 8)
    pts = [*rng.normal(0.0, 1.0, (20000, 2)), *(rng.normal(0.0, 1.0, (2000, 2)) * [1e-200, 1.0]),
           (0.0, 0.0), (0.0, 1.0), (0.0, -1.0), (1.0, 0.0), (-1.0, 0.0), (1.0, 1.0), (-1.0, -1.0), (1e300, 1.0),
           (1.0, 1e300), (t8, 1.0), (math.nextafter(t8, 1.0), 1.0), (math.nextafter(t8, 0.0), 1.0), (1.0, -t8)]
    for y, x in pts:
        want = math.atan2(y, x)
        assert abs(atan2(y, x) - want) <= 4.5e-16 * abs(want) + 1e-300, (y, x)
    for a in [*rng.uniform(-4 * math.pi, 4 * math.pi, 20000), *(k * math.pi / 4 for k in range(-16, 17)), 0.0,
              1e-300, -1e-300]:
        s, c = sincos(a)
        assert abs(s - math.sin(a)) <= 4.5e-16 and abs(c - math.cos(a)) <= 4.5e-16, a


def test_a_converged_swarm_skips_only_obstacles_that_add_nothing() -> None:
    """A swarm that has converged shares one small box per segment, and the kernel skips the obstacles beyond
    every particle's reach from it. Swarms of ±0.5 m around a route whose corner passes a cylinder (and a sphere)
    at clearances from inside d_coll to beyond d_safe + the corner's cut still match the reference: a reach that
    forgot the cut, or the slack for rounding, would zero the soft term of the near ones."""
    env = Environment(
        1000.0, 1000.0, 50.0, 300.0,
        cylinders=Cylinders([500.0, 150.0], [500.0, 850.0], [60.0, 40.0], [np.inf, np.inf], [0.0, 0.0]),
        spheres=Spheres([[500.0, 500.0, 400.0]], [90.0]))  # above the cylinder: its plan view is the nearer
    problem = PlanningProblem(env, np.array([100.0, 300.0, 120.0]), np.array([900.0, 300.0, 120.0]),
                              VehicleLimits(), HazardConfig(d_safe=40.0, d_coll=10.0))
    rng = np.random.default_rng(21)
    soft = []
    for clearance in np.arange(0.0, 70.0, 2.5):  # of the corner from the cylinder's surface
        corner = np.array([500.0, 500.0 - 60.0 - clearance, 120.0])
        base = np.stack([problem.start, corner, problem.goal])
        paths = base[None] + rng.uniform(-0.5, 0.5, (48, 3, 3))
        paths[:, 0], paths[:, -1] = problem.start, problem.goal
        assert_same(problem, paths)
        soft.append(problem.evaluate(paths).terms[TERMS[1]].max())
    assert soft[0] > 0.0 and soft[-1] == 0.0  # near and far corners both occur
