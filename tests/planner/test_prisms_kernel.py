"""Polygon prisms in every planner consumer (issue 35): the compiled kernel against the numpy reference on random
swarms with concave prisms, finite floors and ceilings and a keep-in polygon; the broad phase's skip stays exact;
segment_blocked; the checker counts a prism collision and names ``prisms[k]``; a map without prisms costs what it
did before prisms existed (the families it has, only)."""

from __future__ import annotations

from dataclasses import replace

import kernel_reference
import numpy as np
import pytest
from kernel_reference import assert_broad_phase_exact, assert_same

from planner import kernel
from planner.problem import PlanningProblem
from planner.trajectory.checks import check_trajectory, nearest_obstacle, obstacle_clearance, smooth
from planner.world.config import HazardConfig, VehicleLimits
from planner.world.environment import Cylinders, Environment, Prisms, Spheres
from planner.world.terrain import Terrain

pytestmark = [pytest.mark.skipif(kernel.njit is None, reason="numba is not installed: only the reference runs"),
              pytest.mark.usefixtures("compiled")]


def star(cx: float, cy: float, r_out: float, r_in: float, n: int = 5) -> np.ndarray:
    """A concave star polygon (2n vertices) around (cx, cy)."""
    ang = np.arange(2 * n) * np.pi / n
    r = np.where(np.arange(2 * n) % 2 == 0, r_out, r_in)
    return np.column_stack([cx + r * np.cos(ang), cy + r * np.sin(ang)])


def prism_world(terrain: bool = False, keep_in: bool = True) -> Environment:
    """Concave and convex prisms, unlimited and roofed and floored, a keep-in fence round most of the map, a
    cylinder and a sphere beside them."""
    polys = [star(600.0, 700.0, 220.0, 90.0), np.array([[1100.0, 300.0], [1500.0, 350.0], [1300.0, 650.0]]),
             np.array([[1300.0, 1000.0], [1700.0, 1000.0], [1700.0, 1400.0], [1500.0, 1400.0], [1500.0, 1150.0],
                       [1300.0, 1150.0]]),  # an L
             star(900.0, 1500.0, 160.0, 110.0, 7)]
    floors, ceilings, keep = [-np.inf, -np.inf, 60.0, -np.inf], [np.inf, 170.0, 220.0, 140.0], [False] * 4
    if keep_in:
        polys.append(np.array([[20.0, 20.0], [1980.0, 40.0], [1950.0, 1980.0], [1000.0, 1700.0], [30.0, 1960.0]]))
        floors, ceilings, keep = floors + [-np.inf], ceilings + [np.inf], keep + [True]
    xs = np.linspace(0.0, 2000.0, 41)
    hills = 30.0 * np.sin(xs[None] / 300.0) * np.cos(xs[:, None] / 250.0) + 30.0
    return Environment(2000.0, 2000.0, 50.0, 300.0,
                       cylinders=Cylinders([300.0], [1300.0], [70.0], [np.inf], [0.0]),
                       spheres=Spheres([[1600.0, 700.0, 150.0]], [90.0]),
                       prisms=Prisms.from_polygons(polys, floors, ceilings, keep),
                       terrain=Terrain(0.0, 0.0, 50.0, 50.0, hills) if terrain else None)


def problem_on(env: Environment, **kw) -> PlanningProblem:
    return PlanningProblem(env, np.array([100.0, 100.0, 120.0]), np.array([1850.0, 1800.0, 200.0]), VehicleLimits(),
                           HazardConfig(d_safe=80.0, d_coll=20.0), **kw)


def swarm(problem: PlanningProblem, rng: np.random.Generator, **kw: float) -> np.ndarray:
    """kernel_reference.swarm as these tests draw it: two straight particles, no zero-length segment."""
    return kernel_reference.swarm(problem, rng, straight=2, zero_length=False, **kw)


@pytest.mark.parametrize("terrain", [False, True], ids=["flat", "terrain"])
def test_kernel_matches_the_reference_with_prisms(terrain: bool) -> None:
    problem = problem_on(prism_world(terrain), start_heading=(1.0, 0.2, 0.0))
    rng = np.random.default_rng(17)
    for n_wp, spread in ((1, 0.1), (6, 0.05), (8, 0.2), (16, 0.4)):
        assert_same(problem, swarm(problem, rng, n_wp=n_wp, spread=spread))
    # the prisms count: the same swarm without them costs less hazard and collides less
    paths = swarm(problem, np.random.default_rng(2), n_pop=128, spread=0.3)
    bare = problem_on(replace(problem.env, prisms=Prisms.empty()))
    with_p, without = problem.evaluate(paths), bare.evaluate(paths)
    assert (with_p.terms["J2"] >= without.terms["J2"]).all() and (with_p.terms["J2"] > without.terms["J2"]).any()
    assert with_p.violations["collision"].sum() > without.violations["collision"].sum()


def test_the_broad_phase_skips_prisms_exactly(monkeypatch: pytest.MonkeyPatch) -> None:
    """Broad phase on and off agree to the last bit with prisms (a keep-in one never skipped), in swarms from
    spread out to converged."""
    problem = problem_on(prism_world())
    rng = np.random.default_rng(9)
    for n_wp, spread in ((2, 0.3), (12, 0.002), (12, 0.03), (24, 0.1)):
        paths = swarm(problem, rng, n_pop=96, n_wp=n_wp, spread=spread)
        assert_broad_phase_exact(problem, paths, monkeypatch)
        assert_same(problem, paths)


@pytest.mark.parametrize("broad", ["on", "off"])
def test_blocked_edges_with_prisms_match_the_reference(monkeypatch: pytest.MonkeyPatch, broad: str) -> None:
    monkeypatch.setenv(kernel.BROAD_ENV_VAR, broad)
    problem = problem_on(prism_world())
    rng = np.random.default_rng(12)
    a = rng.uniform([-50, -50, 0], [2050, 2050, 320], (40, 30, 3))
    b = a + rng.normal(0.0, 1.0, a.shape) * rng.choice([5.0, 80.0, 600.0], a.shape[:-1])[..., None]
    got, ref = problem.segment_blocked(a, b), problem.segment_blocked_reference(a, b)
    assert got.shape == (40, 30) and np.array_equal(got, ref)
    assert 0.05 < got.mean() < 0.95
    bare = problem_on(replace(problem.env, prisms=Prisms.empty()))
    assert (got & ~bare.segment_blocked(a, b)).any()  # some edges are blocked by prisms alone


def test_the_checker_counts_prism_collisions_and_names_the_prism() -> None:
    env = prism_world(keep_in=False)
    hazard = HazardConfig(d_safe=80.0, d_coll=20.0)
    through = np.array([[100.0, 700.0, 150.0], [600.0, 700.0, 150.0], [1000.0, 700.0, 150.0]])  # the star
    traj = smooth(through, 5.0, 20.0)
    res = check_trajectory(traj, through, env, hazard, VehicleLimits())
    assert res.counts["collision"] == 1 and res.min_clearance < 0.0
    clearance, name = nearest_obstacle(traj.points, env)
    assert name == "prisms[0]" and clearance == pytest.approx(res.min_clearance)
    over = through + [0.0, 0.0, 0.0]
    over[:, :2] = [[1000.0, 200.0], [1300.0, 450.0], [1700.0, 400.0]]  # across the triangle, 30 m over its ceiling
    over[:, 2] = 200.0
    traj = smooth(over, 5.0, 20.0)
    res = check_trajectory(traj, over, env, hazard, VehicleLimits())
    assert nearest_obstacle(traj.points, env)[1] == "prisms[1]"
    assert obstacle_clearance(traj.points, None, env).min() == pytest.approx(30.0, abs=1e-6)
    assert res.counts["collision"] == 0


def test_a_map_without_prisms_is_scored_as_before() -> None:
    """No prisms: the kernel's inputs hold none, and a world of only the other families scores exactly what the
    same world scores (the prism terms add nothing, not even a rounding)."""
    env = prism_world()
    bare = replace(env, prisms=Prisms.empty())
    problem = problem_on(bare)
    assert problem.kernel_inputs.pri_rows.shape == (0, 6) and len(problem.kernel_inputs.ob_x) == 2
    paths = swarm(problem, np.random.default_rng(4))
    assert_same(problem, paths)


def test_the_lane_pass_gives_seg_prism_bit_for_bit() -> None:
    """prism_lanes (the cost's SIMD pass over the segments near one prism) against seg_prism, one segment at a time:
    the same value exactly, for segments outside, crossing once, twice or more, wholly inside, above a ceiling or
    below a floor, against concave and keep-in polygons."""
    from planner.kernel.segments import prism_lanes, seg_prism

    prisms = prism_world().prisms
    rng = np.random.default_rng(35)
    m = 200
    cases = {"crossings>2": 0, "inside": 0, "outside": 0, "non-level": 0}
    for k in range(len(prisms)):
        i0, i1 = int(prisms.start[k]), int(prisms.start[k + 1])
        cx, cy, r = prisms.cx[k], prisms.cy[k], prisms.r[k]
        f, h, keep = float(prisms.floor[k]), float(prisms.ceiling[k]), bool(prisms.keep_in[k])
        for _ in range(5):
            a = np.column_stack([rng.uniform(cx - 1.5 * r, cx + 1.5 * r, m), rng.uniform(cy - 1.5 * r, cy + 1.5 * r, m),
                                 rng.uniform(0.0, 300.0, m)])
            b = a + rng.normal(0.0, [0.8 * r, 0.8 * r, 40.0], (m, 3))
            la = np.vstack([a.T, b.T, rng.uniform(20.0, 120.0, m)])
            clr = np.empty(m)
            prism_lanes(la, prisms.vertices, i0, i1, f, h, keep, m, np.empty((12, 2 * m + i1 - i0 + 6)), clr)
            cross, knots = np.empty(i1 - i0), np.empty(6)
            want = np.array([seg_prism(*a[i], *b[i], prisms.vertices, i0, i1, f, h, keep, la[6, i], cross, knots)
                             for i in range(m)])
            assert np.array_equal(clr, want), (k, np.flatnonzero(clr != want)[:5])
            zlo, zhi = np.minimum(a[:, 2], b[:, 2]), np.maximum(a[:, 2], b[:, 2])
            cases["non-level"] += int(np.sum((zlo < f) | (zhi > h)))
            cases["inside"] += int(np.sum(want < 0.0))
            cases["outside"] += int(np.sum(want > 0.0))
    assert min(cases["inside"], cases["outside"], cases["non-level"]) > 50, cases
