"""A PLAN.json read back: its shape checked, then its route checked again against its scenario (issue 33).

A PLAN.json is a file anyone can edit. Before ``fly`` or ``export`` uses one, its waypoints go through the same
cost and trajectory check as a fresh plan (:func:`planner.plan.plan`): obstacles, bounds, altitude band and
vehicle limits of the scenario it names. Everything derived from the route (trajectory, violations, metrics,
cost) is recomputed from the waypoints, so nothing the file claims about them is trusted.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeGuard

import numpy as np

from planner.errors import FuseplanError, PlanRefused
from planner.files import read_regular_file
from planner.plan import PlanResult, PlanStatus, assess, json_safe, plan_to_json, problem_from_scenario
from planner.search.swarm import OptimiserResult
from planner.trajectory.checks import CATEGORIES, nearest_obstacle
from planner.workload import MAX_SAMPLES
from planner.world.config import MAX_COORD
from planner.world.scenario import Scenario

MAX_PLAN_BYTES = 64 * 2**20  # a PLAN.json holds a few thousand trajectory samples: well under 1 MB in practice
MAX_WAYPOINTS = 1000  # far beyond any plan's handful of waypoints; ArduPilot SITL stores ~700 plane items
FEASIBLE = (PlanStatus.EXACT.value, PlanStatus.APPROXIMATE.value)


def read_plan_document(path: Path) -> dict[str, Any]:
    """The PLAN.json at ``path`` with its shape checked (:func:`check_shape`); one line (exit 2) if it is not one."""
    data = read_regular_file(path, MAX_PLAN_BYTES, "plan")
    try:
        doc = json.loads(data.decode("utf-8"))
    except UnicodeDecodeError:
        raise FuseplanError(f"{path}: not a PLAN.json: not UTF-8 text") from None
    except RecursionError:
        raise FuseplanError(f"{path}: not a PLAN.json: values nested too deeply") from None
    except ValueError as e:
        raise FuseplanError(f"{path}: not a PLAN.json: {e}") from None
    check_shape(doc, path)
    return doc


def _number(value: Any) -> TypeGuard[int | float]:
    """A finite JSON number (an integer too large for a float is not: JSON allows 10**400)."""
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


def check_shape(doc: Any, path: Path) -> None:
    """Refuse (one line naming the key) a document that is not a PLAN.json this version can fly: the route, home,
    scenario and status must be there with the right types and finite numbers."""
    def bad(key: str, why: str) -> FuseplanError:
        return FuseplanError(f"{path}: {key}: {why}")

    if not isinstance(doc, dict):
        raise FuseplanError(f"{path}: not a PLAN.json: a JSON object is expected, found {type(doc).__name__}")
    wps = doc.get("waypoints")
    if not isinstance(wps, list) or not 2 <= len(wps) <= MAX_WAYPOINTS:
        raise bad("waypoints", f"a list of 2 to {MAX_WAYPOINTS} [x, y, z] points is expected"
                  + ("" if isinstance(wps, list) else f", found {type(wps).__name__}")
                  + (f", found {len(wps)}" if isinstance(wps, list) else ""))
    for i, p in enumerate(wps):
        if not (isinstance(p, list) and len(p) == 3 and all(_number(v) for v in p)):
            raise bad(f"waypoints[{i}]", f"three finite numbers [x, y, z] expected, found {_short(p)}")
        if max(abs(v) for v in p) > MAX_COORD:
            raise bad(f"waypoints[{i}]", f"{_short(p)} is beyond ±{MAX_COORD:g} m of home: no map is that large")
    home = doc.get("home")
    if not isinstance(home, dict):
        raise bad("home", f"an object with lat, lon, alt is expected, found {_short(home)}")
    for k in ("lat", "lon", "alt"):
        if not _number(home.get(k)):
            raise bad(f"home.{k}", f"a finite number is expected, found {_short(home.get(k))}")
    if not isinstance(doc.get("scenario"), str):
        raise bad("scenario", "the scenario's name is expected")
    if doc.get("scenario_file") is not None and not isinstance(doc["scenario_file"], str):
        raise bad("scenario_file", "a path is expected")
    if not isinstance(doc.get("status"), str) or doc["status"] not in {s.value for s in PlanStatus}:
        raise bad("status", f"one of {', '.join(s.value for s in PlanStatus)} is expected, "
                  f"found {_short(doc.get('status'))}")
    start = doc.get("start_time_s")
    if start is not None and not (_number(start) and start >= 0):
        raise bad("start_time_s", f"null or a finite number of seconds >= 0 is expected, found {_short(start)}")
    seed = doc.get("seed")
    if seed is not None and not (isinstance(seed, int) and not isinstance(seed, bool) and 0 <= seed < 2**63):
        raise bad("seed", f"null or a non-negative integer is expected, found {_short(seed)}")


def _short(value: Any) -> str:
    text = json.dumps(value, allow_nan=True) if not isinstance(value, (dict, list)) else type(value).__name__
    return text if len(text) <= 40 else text[:37] + "..."


@dataclass(frozen=True)
class Recheck:
    """A PLAN.json's route checked against its scenario: the recomputed document and, if it fails, why."""

    document: dict[str, Any]
    fault: str | None  # one line: the first fault found; None when the route passes

    @property
    def passed(self) -> bool:
        return self.fault is None


def recheck(doc: Mapping[str, Any], scenario: Scenario, start_time: float | None = None) -> Recheck:
    """Check ``doc``'s waypoints exactly as :func:`planner.plan.plan` checks a fresh route (the cost's own
    violation terms and the smoothed trajectory's check, timed threats from ``start_time``: the mission time at
    the route's start, chosen by the caller, never taken from the file on trust) and rebuild the document from
    them. The fault names the first failing category, where, and by how much."""
    waypoints = np.asarray(doc["waypoints"], dtype=float)
    scenario = as_planned(doc, scenario)
    problem = problem_from_scenario(scenario, start_time)
    settings = scenario.planner
    length = float(np.linalg.norm(np.diff(waypoints, axis=0), axis=1).sum())
    if length / settings.sample_spacing > MAX_SAMPLES:  # before smoothing it: that many samples do not fit
        return Recheck(dict(doc), _waypoint_fault(waypoints, scenario) or (
            f"length: the route is {length:.0f} m long, more than {MAX_SAMPLES:g} samples at "
            f"planner.sample_spacing {settings.sample_spacing:g} m; no plan of this map is"))
    evaluation = problem.evaluate(waypoints[None])
    traj, check, feasible = assess(problem, settings, waypoints, evaluation)
    claimed = doc["status"]
    status = PlanStatus(claimed) if feasible and claimed in FEASIBLE else (
        PlanStatus.EXACT if feasible else PlanStatus.INFEASIBLE)
    metrics = found if isinstance(found := doc.get("metrics"), dict) else {}
    history = found if isinstance(found := doc.get("history"), list) else []
    opt = OptimiserResult(waypoints, float(evaluation.total[0]), evaluation,
                          [float(h) for h in history if _number(h)] or [float(evaluation.total[0])],
                          _count(metrics.get("iterations")), "read from a PLAN.json", 0.0,
                          _count(metrics.get("evaluations")))
    plan_s = metrics.get("plan_time_s")
    result = PlanResult(status, str(doc.get("algorithm") or settings.algorithm), doc.get("seed"), waypoints,
                        evaluation, traj, check, opt, float(plan_s) if _number(plan_s) else 0.0)
    fresh = plan_to_json(result, scenario, start_time)
    if isinstance(doc.get("phases"), dict):
        fresh["phases"] = json_safe(doc["phases"])  # as read, made strict JSON again
    if claimed not in FEASIBLE:
        return Recheck(fresh, f"its status is {claimed!r}: the planner found no feasible route; plan again")
    if not feasible:
        return Recheck(fresh, _first_fault(result, scenario))
    return Recheck(fresh, None)


def as_planned(doc: Mapping[str, Any], scenario: Scenario) -> Scenario:
    """``scenario`` with the turn allowance the plan was made with, when the plan allowed more than the scenario
    says (``plan``, ``fly`` and ``export`` add a plane's swing past each new leg; a wider one is only stricter)."""
    vehicle = doc.get("vehicle")
    swing = vehicle.get("turn_overshoot") if isinstance(vehicle, dict) else None
    if not _number(swing) or swing <= scenario.vehicle.turn_overshoot:
        return scenario
    return dataclasses.replace(scenario, vehicle=dataclasses.replace(scenario.vehicle, turn_overshoot=float(swing)))


def _waypoint_fault(waypoints: np.ndarray, scenario: Scenario) -> str | None:
    """The first waypoint outside the region or the altitude band, in words (a route too long to sample is
    named by what makes it so, when a waypoint does)."""
    env = scenario.environment
    x, y, z = waypoints.T
    outside = (x < 0) | (x > env.size_x) | (y < 0) | (y > env.size_y)
    height = z - env.ground(np.clip(x, 0, env.size_x), np.clip(y, 0, env.size_y))
    off_band = (height < env.z_min) | (height > env.z_max)
    wrong = np.flatnonzero(outside | off_band)
    if not len(wrong):
        return None
    i = int(wrong[0])
    if outside[i]:
        return (f"bounds: waypoint {i} at {_at(waypoints[i].tolist())} is outside the region "
                f"(0–{env.size_x:g} m east, 0–{env.size_y:g} m north)")
    return (f"altitude: waypoint {i} is {height[i]:.1f} m above the ground at {_at(waypoints[i].tolist())}, "
            f"outside the band {env.z_min:g}–{env.z_max:g} m")


def _count(value: Any) -> int:
    return int(value) if _number(value) and value >= 0 else 0


def _at(point: list[float]) -> str:
    return "(" + ", ".join(f"{v:.1f}" for v in point) + ") m"


def _first_fault(result: PlanResult, scenario: Scenario) -> str:
    """One line: the first category that fails, in the order a pilot cares about, where and by how much, and
    which other categories fail too."""
    failing = [c for c in CATEGORIES if result.check.counts.get(c)]
    also = f" (also failing: {', '.join(failing[1:])})" if len(failing) > 1 else ""
    return _describe(result, scenario) + also


def _describe(result: PlanResult, scenario: Scenario) -> str:
    check, env, hazard, vehicle = result.check, scenario.environment, scenario.hazard, scenario.vehicle
    where = check.locations
    for category in CATEGORIES:
        if not check.counts.get(category):
            continue
        first = where.get(category, [[math.nan] * 3])[0]
        if category == "collision":
            clearance, name = nearest_obstacle(result.trajectory.points, env)
            what = (f"comes {clearance:.1f} m from {name} (d_coll {hazard.d_coll:g} m)" if name is not None
                    else "enters a threat's or radar's zone")
            return f"collision: the route {what}, first at {_at(first)}"
        if category == "altitude":
            ground = float(env.ground(np.array([first[0]]), np.array([first[1]]))[0])
            return (f"altitude: the route is {first[2] - ground:.1f} m above the ground at {_at(first)}, outside "
                    f"the band {env.z_min:g}–{env.z_max:g} m")
        if category == "bounds":
            return (f"bounds: the route leaves the region (0–{env.size_x:g} m east, 0–{env.size_y:g} m north) "
                    f"at {_at(first)}")
        if category == "turn":
            return (f"turn: the route turns tighter than the vehicle can (radius {vehicle.min_turn_radius:g} m, "
                    f"at most {math.degrees(vehicle.max_turn):.0f}° per waypoint) at {_at(first)}")
        return (f"{category}: the route climbs or sinks steeper than {math.degrees(vehicle.max_climb):.0f}° "
                f"at {_at(first)}")
    counted = {k: v for k, v in result.cost_violations.items() if v}
    return "the cost counts violations on the waypoint path: " + ", ".join(f"{k} {v}" for k, v in counted.items())


def refuse_unless_passed(check: Recheck, source: Path, scenario: Scenario) -> None:
    """Raise :class:`PlanRefused` (exit 3, one line) when the re-check failed."""
    if not check.passed:
        raise PlanRefused(f"{source}: refused: checked against scenario {scenario.name!r} ({scenario.source}), "
                          f"{check.fault}")
