"""A plan request as ``fly --fence-from-vehicle --goal-from-vehicle`` plans it: the base scenario of the
configuration with its zones files, the vehicle's fence as zones, the last place of the operator's mission as the
goal (the places before it as vias), and the vehicle's own position as the start; planned as ``fly`` plans a
scenario (dynamic threats timed from the mission start, a plane's flight margins)."""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from companion.mavlink.vehicle_limits import flight_overrides
from companion.mission.geo import geodetic_to_enu
from companion.service.config import ServeConfig
from planner.errors import FuseplanError, ScenarioError
from planner.world.geo_inputs import OperatorMission
from planner.world.scenario import Scenario, load_scenario
from planner.world.sources import derived_scenario, vehicle_scenario

log = logging.getLogger(__name__)
FEASIBLE = ("exact", "approximate")
EDGE_SLACK_M = 5.0  # m outside the region a vehicle's position is taken as on its edge


class PlanRefusal(FuseplanError):
    """The request cannot be planned or has no safe route; ``str()`` is the reason told to the operator."""

    @classmethod
    def of(cls, e: FuseplanError) -> PlanRefusal:
        """A scenario's error without its file (the request's own, in the report): ``FIELD: REASON``."""
        if isinstance(e, ScenarioError):
            return cls(f"{e.field}: {e.reason}" if e.field else e.reason)
        return cls(str(e))


def request_scenario(cfg: ServeConfig, world: OperatorMission, position: tuple[float, float],
                     report: Path) -> tuple[Path, list[str]]:
    """The scenario file of this request (written in ``report``) and the overrides that put its start at the
    vehicle's ``position`` (latitude, longitude in degrees) at the base scenario's start height."""
    report.mkdir(parents=True, exist_ok=True)
    try:
        base = derived_scenario(cfg.scenario, cfg.zones, beside=report / "base.toml") if cfg.zones else cfg.scenario
        path = vehicle_scenario(base, world, True, True, report / "request.toml")
        sc = load_scenario(path, list(cfg.overrides))
    except FuseplanError as e:
        raise PlanRefusal.of(e) from e
    east, north, _ = geodetic_to_enu(position[0], position[1], sc.home.alt, sc.home)
    env = sc.environment  # a vehicle on the region's edge (its home at the corner) within GPS noise is inside
    east = _onto_edge(float(east), env.size_x)
    north = _onto_edge(float(north), env.size_y)
    start = f"route.start=[{east:.1f}, {north:.1f}, {float(sc.start[2]):g}]"
    return path, [*cfg.overrides, start]


def _onto_edge(v: float, size: float) -> float:
    """``v`` moved onto [0, size] when it is within EDGE_SLACK_M outside (else left for the scenario to refuse)."""
    if -EDGE_SLACK_M <= v < 0.0:
        return 0.0
    if size < v <= size + EDGE_SLACK_M:
        return size
    return v


def plan_request(path: Path, overrides: list[str], seed: int | None, budget_s: float | None = None,
                 stop: threading.Event | None = None) -> tuple[dict[str, Any], Scenario]:
    """(PLAN.json document, scenario) of the request scenario ``path``, the search stopped after ``budget_s`` wall
    seconds (the best route found by then, checked as every plan is; None: the planner's own stop criteria); raises
    :class:`PlanRefusal` for a scenario that cannot be built (the goal or the start outside the region, in a
    zone…) or with no feasible route. ``stop`` set (the service stopping) ends a budgeted search at its next
    iteration: its deadline's clock jumps past the budget (the thread cannot be cancelled, and the process waits
    for it before it exits)."""
    from companion.mission.builder import time_to_start
    from planner.deadline import Deadline
    from planner.legs import plan_scenario
    from planner.plan import plan_to_json

    try:
        sc = load_scenario(path, overrides)
        sc = load_scenario(path, [*overrides, *flight_overrides(sc.vehicle)]
                           + ([f"planner.seed={seed}"] if seed is not None else []))
    except FuseplanError as e:
        raise PlanRefusal.of(e) from e
    start_time = time_to_start(sc) if len(sc.environment.threats) else None
    res = plan_scenario(sc, sc.planner, np.random.default_rng(sc.planner.seed), start_time,
                        Deadline.after(budget_s, _stoppable(stop)), seed=sc.planner.seed)
    doc = plan_to_json(res, sc, start_time)
    if doc["status"] == "timeout":
        raise PlanRefusal(f"no safe route found within plan.budget_s = {budget_s:g} s")
    if doc["status"] not in FEASIBLE:
        raise PlanRefusal(f"no safe route ({doc['status']}): the goal or a via may be walled off by zones")
    return doc, sc


def _stoppable(stop: threading.Event | None) -> Callable[[], float]:
    """time.perf_counter, or infinity once ``stop`` is set (every budget overrun)."""
    if stop is None:
        return time.perf_counter
    return lambda: math.inf if stop.is_set() else time.perf_counter()


__all__ = ["PlanRefusal", "plan_request", "request_scenario"]
