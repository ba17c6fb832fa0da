"""A live replan's problem and settings (docs/design.md, "Live replanning"), defined once for the companion's
replanner; the benches that time plans at its budget (speed's latency part, robustness's 0.15 s variants) take its
budget, swarm size and threat picture from here. The planner may not import the companion, so the facts live here."""

from __future__ import annotations

import dataclasses

import numpy as np

from planner.problem import PlanningProblem
from planner.world.config import PlannerSettings
from planner.world.environment import Threat, Threats
from planner.world.scenario import Scenario

BUDGET_S = 0.15  # wall seconds the planner may use for one live replan
POPULATION = 100  # swarm size for a replan (the scenario's other planner settings are kept)
# a replan stops searching this many swarm iterations after its route first became feasible (colonies skipped): the
# vehicle needs a safe route now more than the shortest one (planner.pso.feasible_iters); 0: search the whole budget
SETTLE_ITERS = 10
# guide routes from the roadmap for a replan (planner.roadmap.n_routes): each costs a shortest-path search over the
# whole roadmap, about a third of a replan's time, and the old route and its bent copies already seed other
# corridors (replaying 18 SITL replans, 4 seeds each, 1 route found the same 44 of 72 feasible as 3, in a median
# 0.033 s instead of 0.052 s)
GUIDE_ROUTES = 1
THREAT_MARGIN_M = 15.0  # a conflict is a predicted separation below d_coll + this; a replan keeps it from threats
TRACK_GROWTH_M_S = 0.5  # an ADS-B track's uncertainty growth per second of age and prediction (NACv ~1 m/s)


def replan_problem(scenario: Scenario, start: np.ndarray, goal: np.ndarray, threats: Threats,
                   start_time: float, speed: float | None = None,
                   heading: np.ndarray | None = None, threat_margin: float = 0.0,
                   static_margin: float = 0.0) -> PlanningProblem:
    """The scenario's static world with the current threat picture, from ``start`` to ``goal``, flown from
    mission time ``start_time`` (time-aware threats, docs/method.md §4.6) at ``speed`` (default: the scenario's cruise
    speed; the replanner passes the vehicle's measured pace), arriving at ``start`` flying along ``heading`` (the
    turn onto the new route is held to the vehicle's limits: an autopilot overshoots a sharper one). Each threat's
    radius grows by ``threat_margin`` m: the replanner calls a route clear at d_coll + its margin, so a replan
    that kept only d_coll would be a new conflict at once. ``static_margin`` m more are kept from everything: a
    route planned from a hold is flown from the circle once its resume is checked, at d_coll + that margin."""
    hazard = scenario.hazard
    if static_margin:
        d_coll = hazard.d_coll + static_margin
        hazard = dataclasses.replace(hazard, d_coll=d_coll, d_safe=max(hazard.d_safe, d_coll))
    if threat_margin:
        threats = threats.grown(threat_margin)
    env = dataclasses.replace(scenario.environment, threats=threats)
    s = scenario.planner
    vehicle = scenario.vehicle if speed is None else dataclasses.replace(scenario.vehicle, cruise_speed=speed)
    return PlanningProblem(env, np.asarray(start, dtype=float), np.asarray(goal, dtype=float), vehicle,
                           hazard, s.weights, s.penalty, start_time, heading)


def replan_settings(settings: PlannerSettings, population: int = POPULATION, settle_iters: int = SETTLE_ITERS,
                    roadmap: bool = True, guide_routes: int = GUIDE_ROUTES) -> PlannerSettings:
    """The scenario's planner settings with the replanning swarm size and its early stop once feasible, and the
    roadmap on with the replans' guide routes if ``roadmap`` (else as the scenario says)."""
    out = dataclasses.replace(settings, pso=dataclasses.replace(settings.pso, n_pop=population,
                                                                feasible_iters=settle_iters))
    if roadmap:
        out = dataclasses.replace(out, roadmap=dataclasses.replace(out.roadmap, enabled=True, n_routes=guide_routes))
    return out


def scripted_picture(scenario: Scenario, growth_m_s: float = TRACK_GROWTH_M_S) -> Threats:
    """The threat picture at mission time 0 as the companion would see it: the scripted threats, and each
    ``[[intruders]]`` aircraft as an ADS-B track seen at its first waypoint, flying its first leg at its speed,
    its radius growing with prediction time."""
    items = list(scenario.environment.threats.items)
    for intr in scenario.intruders:
        p0, p1 = np.array(intr.waypoints[0], dtype=float), np.array(intr.waypoints[1], dtype=float)
        vel = intr.speed * (p1 - p0) / max(float(np.linalg.norm(p1 - p0)), 1e-9)
        items.append(Threat(intr.id, "track", intr.radius, tuple(p0), tuple(vel), radius_growth=growth_m_s))
    return Threats(tuple(items))
