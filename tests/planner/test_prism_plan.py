"""A plan on a map of polygon prisms (issue 35): a concave star across the straight line, a triangle roofed low
enough for the band to let the route over it, a tall L, all inside a keep-in fence. plan() with the default
settings finds a feasible route whose flown curve, sampled every half metre and measured independently
(polygons.signed_distance plus the vertical part), keeps d_coll from every polygon; the same seed gives the same
route, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from planner.plan import plan
from planner.problem import PlanningProblem
from planner.trajectory.checks import smooth
from planner.world import polygons
from planner.world.config import HazardConfig, PlannerSettings, VehicleLimits
from planner.world.environment import Environment, Prisms

STAR = np.array([[700.0, 180.0], [740.0, 380.0], [900.0, 430.0], [740.0, 480.0], [700.0, 820.0],
                 [660.0, 480.0], [500.0, 430.0], [660.0, 380.0]])  # concave, across the straight line
TRIANGLE = np.array([[1050.0, 330.0], [1250.0, 420.0], [1080.0, 560.0]])  # roofed at 140 m: over it in the band
TALL_L = np.array([[300.0, 550.0], [450.0, 550.0], [450.0, 620.0], [360.0, 620.0], [360.0, 850.0],
                   [300.0, 850.0]])
FENCE = np.array([[20.0, 60.0], [1480.0, 20.0], [1470.0, 960.0], [760.0, 900.0], [30.0, 980.0]])


def world() -> Environment:
    prisms = Prisms.from_polygons([STAR, TRIANGLE, TALL_L, FENCE], [-np.inf, -np.inf, 40.0, -np.inf],
                                  [np.inf, 140.0, np.inf, np.inf], [False, False, False, True])
    return Environment(1500.0, 1000.0, 50.0, 300.0, prisms=prisms)


def independent_clearance(env: Environment, pts: np.ndarray) -> np.ndarray:
    """Least signed distance (M,) of points to any prism, one polygon at a time with planner.world.polygons."""
    p = env.prisms
    out = np.full(len(pts), np.inf)
    for k in range(len(p)):
        u = polygons.signed_distance(p.polygon(k), pts[:, :2]) * (-1.0 if p.keep_in[k] else 1.0)
        with np.errstate(invalid="ignore"):
            w = np.maximum(p.floor[k] - pts[:, 2], pts[:, 2] - p.ceiling[k])
        d = np.hypot(np.maximum(u, 0.0), np.maximum(w, 0.0)) + np.minimum(np.maximum(u, w), 0.0)
        out = np.minimum(out, d)
    return out


@pytest.fixture(scope="module")
def problem() -> PlanningProblem:
    return PlanningProblem(world(), np.array([100.0, 480.0, 120.0]), np.array([1400.0, 480.0, 120.0]),
                           VehicleLimits(), HazardConfig(d_safe=60.0, d_coll=15.0))


def test_the_straight_line_is_blocked(problem: PlanningProblem) -> None:
    line = np.linspace(problem.start, problem.goal, 50)
    assert independent_clearance(problem.env, line).min() < 0.0  # the star stands across it


def test_plan_keeps_clear_of_every_polygon_and_repeats_bit_for_bit(problem: PlanningProblem) -> None:
    settings = PlannerSettings()
    res = plan(problem, settings, np.random.default_rng(3), seed=3)
    assert res.feasible, (res.status, res.violations, res.cost_violations)
    dense = smooth(res.waypoints, 0.5, problem.vehicle.cruise_speed).points
    clear = independent_clearance(problem.env, dense)
    assert clear.min() >= problem.hazard.d_coll - 1e-6, clear.min()
    assert res.check.min_clearance == pytest.approx(clear.min(), abs=0.5)  # the checker saw the same
    again = plan(problem, settings, np.random.default_rng(3), seed=3)
    assert np.array_equal(again.waypoints, res.waypoints)
