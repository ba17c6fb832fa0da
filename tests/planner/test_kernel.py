"""The compiled cost kernel (planner/kernel.py) against the numpy reference (PlanningProblem.evaluate_reference):
the same terms, penalties and totals to 1e-9 relative and the same violation counts, on random swarms over every
shipped scenario and over a map with every obstacle family, threat law, terrain and a start heading."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planner import kernel
from planner.plan import problem_from_scenario
from planner.problem import CATEGORIES, TERMS, PlanningProblem
from planner.world.config import HazardConfig, VehicleLimits
from planner.world.environment import Cylinders, Environment, Radars, Spheres, Threat, Threats
from planner.world.scenario import load_scenario
from planner.world.terrain import Terrain

SCENARIOS = sorted((Path(__file__).resolve().parents[2] / "sitl_scenarios").glob("*.toml"))
RTOL = 1e-9

pytestmark = pytest.mark.skipif(kernel.njit is None, reason="numba is not installed: only the reference runs")


def swarm(problem: PlanningProblem, rng: np.random.Generator, n_pop: int = 64, n_wp: int = 8,
          spread: float = 0.25) -> np.ndarray:
    """Random paths start → goal: the straight line bent by noise of ``spread`` × the direct distance, so a
    swarm has every kind of particle, from clean to colliding, out of the band and out of bounds."""
    line = np.linspace(problem.start, problem.goal, n_wp + 2)
    scale = spread * max(problem.direct_distance, 100.0)
    paths = line[None] + rng.normal(0.0, scale, (n_pop, n_wp + 2, 3)) * np.array([1.0, 1.0, 0.3])
    paths[:, 0], paths[:, -1] = problem.start, problem.goal
    paths[:3, 1:-1] = line[1:-1]  # straight and near-straight particles too
    paths[1, 1] = paths[1, 0]  # a zero-length segment
    return paths


def assert_same(problem: PlanningProblem, paths: np.ndarray) -> None:
    got = problem.evaluate(paths)
    ref = problem.evaluate_reference(paths)
    for name in TERMS:
        np.testing.assert_allclose(got.terms[name], ref.terms[name], rtol=RTOL, atol=1e-12, err_msg=name)
    np.testing.assert_allclose(got.penalty, ref.penalty, rtol=RTOL, atol=1e-9)
    np.testing.assert_allclose(got.total, ref.total, rtol=RTOL, atol=1e-9)
    for c in CATEGORIES:
        np.testing.assert_array_equal(got.violations[c], ref.violations[c], err_msg=c)


@pytest.fixture(autouse=True)
def compiled(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(kernel.ENV_VAR, raising=False)
    assert kernel.chosen() == "compiled"


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


@pytest.mark.parametrize("terrain", [True, False], ids=["terrain", "flat"])
@pytest.mark.parametrize("heading", [None, (0.6, -0.8, 0.0), (-1.0, 0.2, 0.1)], ids=["none", "h1", "h2"])
def test_kernel_matches_the_reference_with_every_family(terrain: bool, heading) -> None:  # noqa: ANN001
    env = every_family()
    if not terrain:
        env = Environment(env.size_x, env.size_y, env.z_min, env.z_max, env.cylinders, env.spheres, env.radars,
                          None, env.threats)
    problem = PlanningProblem(env, np.array([100.0, 100.0, 120.0]), np.array([1900.0, 1850.0, 200.0]),
                              VehicleLimits(), HazardConfig(d_safe=120.0, d_coll=20.0), start_time=3.0,
                              start_heading=heading)
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
