"""Live replanning, the pure part (docs/design.md, "Live replanning"): the flown mission as a route, commit point,
the replanning problem with its warm start, the splice of a new route into the mission, and the record of a replan.

The MAVLink choreography (upload while flying, guard, hold, set-current) is in :mod:`companion.replanning.replanner`.
Times here are *mission time*: vehicle seconds since the mission started, the clock the scenario's scripted
threats run on; ADS-B tracks are put on it too.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from companion.mavlink.items import FRAME_REL_ALT, MissionItem, normalise_frame
from companion.mission.builder import CMD_LOITER_UNLIM, CMD_WAYPOINT, MissionSpec, waypoint_items
from companion.mission.geo import geodetic_to_enu
from companion.replanning.threats import route_distances, route_points
from planner import replan as planner_replan
from planner.world.config import PlannerSettings
from planner.world.home import Home


@dataclass(frozen=True)
class ReplanConfig:
    """Replanning settings; each default lives here only. ``*_s`` in vehicle seconds unless ``wall``."""

    enabled: bool = True
    budget_s: float = planner_replan.BUDGET_S  # wall seconds the planner may use for one replan
    # after a plan that was not safe, the next one for the same conflict gets twice the budget, up to this, when the
    # conflict is far enough off for the longer commit lead (a loaded machine gives the planner less of a core);
    # never less than budget_s. A plan made while the vehicle holds on a checked pattern gets it at once: nothing
    # is flown into while it plans, and its route keeps a wider margin (replan_problem's static_margin)
    max_budget_s: float = 0.6
    population: int = planner_replan.POPULATION  # swarm size for a replan
    settle_iters: int = planner_replan.SETTLE_ITERS  # stop this many iterations after feasible (planner.replan)
    guide_routes: int = planner_replan.GUIDE_ROUTES  # roadmap guide routes per replan (planner.replan)
    # replans run the roadmap pipeline (docs/method.md §15) whatever [planner.roadmap] says of the first route;
    # the worker builds the roadmap once, at its warm-up. False: the scenario's own planner settings
    roadmap: bool = True
    detour_offsets_m: tuple[float, ...] = (-400.0, -250.0, -120.0, 120.0, 250.0, 400.0)  # warm-start bulges
    horizon_s: float = 90.0  # how far ahead conflicts are predicted
    margin_m: float = planner_replan.THREAT_MARGIN_M  # a conflict is a predicted separation below d_coll + margin
    sample_dt_s: float = 0.5  # route sampling for the prediction (18 m/s + 15 m/s → 8 m between samples)
    track_radius_m: float = 40.0  # protected radius assumed for an ADS-B contact (ADS-B carries none)
    track_growth_m_s: float = planner_replan.TRACK_GROWTH_M_S  # per second of track age and prediction
    track_max_age_s: float = 10.0  # drop a contact not heard from for this long
    lead_margin_s: float = 2.0  # added to the commit lead beyond planning and upload time
    min_interval_s: float = 5.0  # rate limit: vehicle seconds between two replans
    guard_s: float = 1.5  # hold if the vehicle could finish its active item this soon, new mission unverified
    upload_attempts: int = 3  # verified uploads tried (holding after the first failure) before giving up
    hold_retry_s: float = 3.0  # while holding: retry planning this often (vehicle s)
    check_interval_wall_s: float = 0.05  # conflict checks at most this often (wall)
    # a plane held in LOITER circles its hold point: when it resumes it may be back on its route up to one circle
    # later (2π r / v); resuming needs the route clear for every such delay (SITL's plane.parm: WP_LOITER_RAD 80)
    plane_loiter_radius_m: float = 80.0
    rejoin_step_s: float = 2.0  # delays between 0 and one circle checked this far apart
    # room for longer routes: on an autopilot that takes partial writes, a mission that ends in a loiter at the goal
    # is flown with this many copies of that item behind it (never reached: NAV_LOITER_UNLIM never ends), so that a
    # replan whose route has up to this many more points keeps the length and writes only what changed (with_room)
    spare_items: int = 16

    def __post_init__(self) -> None:
        if not (self.budget_s > 0 and self.population >= 2 and self.upload_attempts >= 1 and self.horizon_s > 0
                and self.sample_dt_s > 0 and self.guard_s >= 0 and self.spare_items >= 0 and self.settle_iters >= 0
                and self.guide_routes >= 1):
            raise ValueError(f"invalid replanning settings: {self}")


@dataclass
class ReplanRecord:
    """One replan, as written to flight.json and drawn on the report."""

    n: int
    reason: str
    threat: str
    t_mission: float
    conflict_in_s: float
    sep_before_m: float
    sep_after_m: float | None = None
    plan_status: str = ""
    budget_s: float = 0.0  # the planner's time budget for this plan (it doubles after a failed plan)
    plan_s: float = 0.0
    upload_s: float = 0.0
    latency_s: float | None = None  # conflict detected → new mission current (wall)
    held: bool = False
    upload_path: str = ""  # "partial FIRST-LAST", "whole" or "unchanged" (MissionClient.upload_changed_verified)
    outcome: str = ""
    commit: list[float] = field(default_factory=list)
    old_route: list[list[float]] = field(default_factory=list)
    new_route: list[list[float]] = field(default_factory=list)

    def summary(self) -> dict[str, Any]:
        """The event-log view (routes left out)."""
        d = {k: v for k, v in self.__dict__.items() if k not in ("old_route", "new_route")}
        return {k: round(v, 3) if isinstance(v, float) else v for k, v in d.items()}


@dataclass(frozen=True)
class MissionRoute:
    """The mission as flown: ENU points of its route waypoints (NAV_WAYPOINT in the relative frame, after
    the takeoff) keyed by seq, and the goal's seq (the last such waypoint)."""

    items: tuple[MissionItem, ...]
    seqs: np.ndarray  # (K,) seq of each route waypoint, increasing
    points: np.ndarray  # (K, 3) ENU m

    @classmethod
    def of(cls, items: Sequence[MissionItem], home: Home) -> MissionRoute:
        wps = [it for it in items if it.command == CMD_WAYPOINT and normalise_frame(it.frame) == FRAME_REL_ALT]
        if not wps:
            raise ValueError("the mission has no waypoints in the relative frame")
        pts = np.array([geodetic_to_enu(it.lat, it.lon, home.alt + it.z, home) for it in wps], dtype=float)
        pts[:, 2] = [it.z for it in wps]  # relative altitude is z above home, not a geodetic height
        return cls(tuple(items), np.array([it.seq for it in wps]), pts)

    @property
    def goal_seq(self) -> int:
        return int(self.seqs[-1])

    @property
    def goal(self) -> np.ndarray:
        return self.points[-1]

    def remaining(self, position: np.ndarray, current_seq: int) -> tuple[np.ndarray, np.ndarray]:
        """(route (M, 3) from ``position`` through every waypoint from ``current_seq`` on, the seq of each
        route vertex, −1 for the position). Past the goal: just the position."""
        ahead = self.seqs >= current_seq
        route = np.vstack([np.asarray(position, dtype=float)[None], self.points[ahead]])
        return route, np.concatenate([[-1], self.seqs[ahead]])


@dataclass(frozen=True)
class CommitPoint:
    """Where the new route starts: ``point`` on the current route, ``lead_m`` ahead of the vehicle, reached
    at mission time ``t``. Items with seq < ``first_new_seq`` stay as they are; the new route's first item
    (``point`` itself) gets ``first_new_seq``."""

    point: np.ndarray
    lead_m: float
    t: float
    first_new_seq: int
    old_tail: np.ndarray  # (J, 3) the old route from the commit point to the goal (the warm start)
    heading: np.ndarray | None = None  # (3,) the direction the vehicle flies through the point (None: climbing out)


def commit_point(route: np.ndarray, route_seqs: np.ndarray, current_seq: int, lead_m: float, speed: float,
                 t_now: float) -> CommitPoint:
    """The point ``lead_m`` ahead along ``route`` (from :meth:`MissionRoute.remaining`), kept short of the
    goal so a route remains to plan. The vehicle flies every unchanged waypoint up to it, so the first new
    item is the one after the last route vertex passed before it (the current item when it lies on the leg
    being flown)."""
    cum = route_distances(route)
    lead = float(np.clip(lead_m, 0.0, max(cum[-1] - 1.0, 0.0)))
    p, seg = route_points(route, np.array([lead]))
    k = int(seg[0])  # on leg route[k] → route[k+1]
    first_new = current_seq if k == 0 else int(route_seqs[k]) + 1
    tail = np.vstack([p, route[k + 1:]])
    return CommitPoint(p[0], lead, t_now + lead / max(speed, 1e-6), first_new, tail, route[k + 1] - route[k])


VIA_MATCH_M = 1.0  # a route waypoint this close to one of the scenario's vias is that via (a plan puts it exactly)


def via_items(route: MissionRoute, vias: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """(item seq, via) for each of the scenario's ``vias`` (k, 3) found, in order, among the route's waypoints
    before the goal; a via not on the route (never flown through) is left out."""
    out, at = [], 0
    for via in np.asarray(vias, dtype=float).reshape(-1, 3):
        near = np.flatnonzero(np.linalg.norm(route.points[at:] - via, axis=1) < VIA_MATCH_M)
        if not len(near):
            continue
        at += int(near[0])
        if int(route.seqs[at]) < route.goal_seq:
            out.append((int(route.seqs[at]), via))
        at += 1
    return out


def vias_ahead(route: MissionRoute, vias: np.ndarray, first_new_seq: int, start: np.ndarray,
               min_leg_m: float) -> np.ndarray:
    """The scenario's ``vias`` (k, 3) a replan from ``start`` must still pass through (:func:`via_items`): those at
    item ``first_new_seq`` or later (the items before it stay as they are: the vehicle has passed them, or flies
    them unchanged); one closer than ``min_leg_m`` to ``start`` is where the new route begins. (m, 3), m ≤ k."""
    out = [via for seq, via in via_items(route, vias)
           if seq >= first_new_seq and float(np.linalg.norm(via - start)) >= min_leg_m]
    return np.array(out, dtype=float).reshape(-1, 3)


def tail_to(tail: np.ndarray, point: np.ndarray) -> np.ndarray:
    """The old route ``tail`` (J, 3) up to ``point`` on it (a via), for the warm start of the leg that ends there;
    the straight line to it when it is not on the tail."""
    near = np.flatnonzero(np.linalg.norm(tail - point, axis=1) < VIA_MATCH_M)
    return tail[:int(near[0]) + 1] if len(near) and near[0] > 0 else np.vstack([tail[0], point])


def warm_starts(tail: np.ndarray, offsets_m: Sequence[float], n_points: int = 10) -> np.ndarray:
    """Seeds for the replanning swarm (k, n_points, 3): the old route from the commit point, resampled
    evenly along its length, and copies bent sideways by each offset (a half-sine bulge perpendicular to
    the commit→goal line, zero at both ends).

    A crossing threat can only be dodged by passing ahead of or behind it; the old route alone leaves the
    swarm to discover that in a fraction of a second, the bent copies hand it both sides at once (with
    them the budgeted replans of the shipped scenarios went from mostly infeasible to feasible).
    """
    tail = np.asarray(tail, dtype=float)
    cum = route_distances(tail)
    u = np.linspace(0.0, cum[-1], n_points)
    base = np.stack([np.interp(u, cum, tail[:, k]) for k in range(3)], axis=1)
    d = tail[-1, :2] - tail[0, :2]
    norm = float(np.linalg.norm(d))
    if norm == 0.0 or cum[-1] == 0.0:
        return base[None]
    perp = np.array([-d[1] / norm, d[0] / norm, 0.0])
    bulge = np.sin(np.pi * u / cum[-1])[:, None] * perp
    return np.stack([base] + [base + o * bulge for o in offsets_m])


def replan_settings(settings: PlannerSettings, cfg: ReplanConfig) -> PlannerSettings:
    """:func:`planner.replan.replan_settings` with ``cfg``'s swarm size, early stop, roadmap and guide routes."""
    return planner_replan.replan_settings(settings, cfg.population, cfg.settle_iters, cfg.roadmap, cfg.guide_routes)


def padded(route: np.ndarray, n: int, min_leg_m: float) -> np.ndarray:
    """``route`` (K, 3) with points added, each at the middle of the then longest leg, until it has ``n`` points
    (fewer when no leg is longer than ``min_leg_m``): the same path, flown the same way (a point on a straight leg
    is no turn), so that a replanned mission can keep the flying one's length and be written in part."""
    pts = [np.asarray(p, dtype=float) for p in np.asarray(route, dtype=float)]
    while len(pts) < n:
        legs = [float(np.linalg.norm(b - a)) for a, b in itertools.pairwise(pts)]
        k = int(np.argmax(legs))
        if legs[k] <= min_leg_m:
            break
        pts.insert(k + 1, 0.5 * (pts[k] + pts[k + 1]))
    return np.array(pts)


def _ends_in_loiter(tail: Sequence[MissionItem]) -> bool:
    """The items after the goal are a loiter that never ends (and copies of it: :func:`with_room`)."""
    return bool(tail) and all(it.command == CMD_LOITER_UNLIM for it in tail)


def with_room(items: Sequence[MissionItem], spare: int) -> list[MissionItem]:
    """``items`` with ``spare`` copies of their end item behind it when that is a loiter that never ends
    (NAV_LOITER_UNLIM: the vehicle never gets past it, so it never flies them), else as they are. A replan's
    longer route then fits in the same length, and only its changed items are written (:func:`splice`,
    MISSION_WRITE_PARTIAL_LIST, docs/autopilots.md §8.5)."""
    if spare <= 0 or not items or items[-1].command != CMD_LOITER_UNLIM:
        return list(items)
    return list(items) + [items[-1].with_seq(len(items) + k) for k in range(spare)]


def splice(items: Sequence[MissionItem], first_new_seq: int, new_route: np.ndarray, goal_seq: int,
           spec: MissionSpec, length: int | None = None) -> list[MissionItem]:
    """``items[:first_new_seq]`` unchanged, then a waypoint per point of ``new_route`` (commit point first,
    goal last), then the old items after the goal (the end action), renumbered. With ``length`` (the flying
    mission's, on an autopilot that takes partial writes) a shorter result is made that long, so that only its
    changed part needs writing (MISSION_WRITE_PARTIAL_LIST, docs/autopilots.md §8.5): after a loiter end, with
    copies of it (:func:`with_room`: the slots that already held copies are then left as they were); else with
    points on the route's longest legs (:func:`padded`).

    Keeping the prefix identical means an upload in flight rewrites those slots with what they already hold,
    so the vehicle, still on one of them, never reads a half-written item before the new part is verified.
    """
    if not 0 < first_new_seq <= goal_seq:
        raise ValueError(f"first new item {first_new_seq} must be in 1..{goal_seq}")
    tail = list(items[goal_seq + 1:])
    room = _ends_in_loiter(tail)
    if room:
        tail = tail[:1]  # the copies behind the loiter are room, made again below
    if length is not None and not room:
        want = length - first_new_seq - len(tail)
        new_route = padded(new_route, want, 3.0 * spec.vehicle.acceptance_radius)
    new = list(items[:first_new_seq]) + waypoint_items(new_route, spec) + tail
    if length is not None and room:
        new += tail[-1:] * max(length - len(new), 0)
    return [it.with_seq(seq) for seq, it in enumerate(new)]
