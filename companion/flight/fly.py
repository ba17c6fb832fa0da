"""`fuseplan fly`: plan → connect → build items for the autopilot found → upload, verify → start →
monitor → report directory. With ``sim=True`` the built-in simulated autopilot runs in this process."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from companion.flight import HEARTBEAT_WAIT_S
from companion.flight.announce import Announcer
from companion.flight.departure import VehicleFix, check_departure
from companion.flight.report import plot_track, write_json
from companion.flight.safety import flown_safety
from companion.flight.supervisor import (
    DepartureRefused,
    FlightOutcome,
    FlightSupervisor,
    check_one_autopilot,
)
from companion.mavlink.errors import CompanionError, FenceTooLarge
from companion.mavlink.fence_capacity import capacity_params, fence_capacity
from companion.mavlink.link import DEFAULT_BAUD, Link
from companion.mavlink.mavsdk_backend import MavsdkLink, MavsdkMissionClient
from companion.mavlink.params import read_params
from companion.mavlink.protocol import MissionClient
from companion.mavlink.signing import SigningKey
from companion.mavlink.telemetry import TelemetryRates
from companion.mavlink.vehicle_limits import (
    AutopilotLimits,
    limits_from,
    overshoot_override,
    parameter_names,
)
from companion.mission import picture
from companion.mission.builder import (
    build_fence,
    fenced_circles,
    mission_from_plan_json,
    prisms_left_out,
    spec_from_plan_json,
)
from companion.mission.events import EventLog
from companion.mission.exports import (
    write_geojson,
    write_qgc_plan,
    write_waypoints,
    zones_from_prisms,
    zones_of,
)
from companion.mission.fence_fit import fence_refusal, fenced_zones
from companion.mission.geo import geodetic_to_enu, lonlatalt
from companion.replanning.replan import MissionRoute, ReplanConfig, with_room
from companion.replanning.replanner import LiveReplanner
from companion.replanning.separation import min_separations
from companion.replanning.swap import LiveMission
from companion.replanning.worker import PlanWorker, expects_traffic
from planner.distribution import fuseplan_version
from planner.plan_file import as_planned
from planner.world.scenario import Scenario

if TYPE_CHECKING:
    from companion.sim.traffic import TrafficFeed

log = logging.getLogger(__name__)
RATES_WAIT_S = 15.0  # wall seconds the first round of telemetry rate requests may delay the upload
IDENTITY_WINDOW_S = 1.2  # wall seconds after the first HEARTBEAT: autopilots send theirs at 1 Hz
TLOG = "flight.tlog"  # the report's telemetry log: every message of the companion's link (pymavlink backend)
MISSIONS = "missions"  # the report's folder of every mission stored on the vehicle, in order


async def _rates_answered(rates: TelemetryRates) -> None:
    with contextlib.suppress(TimeoutError):
        await asyncio.wait_for(asyncio.shield(rates.wait()), RATES_WAIT_S)


@dataclass
class FlyOptions:
    connect: str | None = None  # pymavlink URL of a real autopilot / SITL
    baud: int = DEFAULT_BAUD  # a serial --connect's baud rate (a URL's own ,BAUD wins)
    sim: bool = False
    speedup: float = 1.0
    sim_loss: float = 0.0
    arm: bool = False
    fence: bool = True
    densify: bool = False
    report: Path = Path("fuseplan-report")
    source_system: int = 1
    replan: bool = True  # live replanning around dynamic threats (when the scenario has any)
    replan_config: ReplanConfig | None = None  # None: ReplanConfig() defaults
    signing_key: SigningKey | None = None  # MAVLink 2 signing (our simulator uses the same key)
    traffic: str | None = None  # a real autopilot's spare port: fly the scenario's intruders there (TrafficFeed)
    backend: str = "pymavlink"  # or "mavsdk": the vehicle through MAVSDK (companion.mavlink.mavsdk_backend)
    heartbeat_timeout: float = HEARTBEAT_WAIT_S  # s to wait for the autopilot's first HEARTBEAT
    flight_timeout: float | None = None  # wall s the flight is supervised; None: 120 s + 4 × its flying time
    target_system: int | None = None  # the autopilot's system id; None: the one heard, refused if several are
    # plans the scenario again with these extra --set overrides (the vehicle's own limits), or None: a PLAN.json
    # given by the user is flown as it is or refused
    plan_again: Callable[[list[str]], tuple[dict[str, Any], Scenario]] | None = None


DEFAULT_LOITER_RADIUS_M = 60.0  # ArduPlane's WP_LOITER_RAD default, when the autopilot does not say


async def fly(plan_doc: dict[str, Any], scenario: Scenario, opts: FlyOptions, events: EventLog) -> dict[str, Any]:
    """Fly ``plan_doc`` (a PLAN.json document) and write the report; returns the flight.json document."""
    from companion.sim import SimAutopilot
    from companion.sim.traffic import TrafficFeed

    events.log("scene", **picture.scene(scenario, plan_doc))
    sim = None
    if opts.sim:
        sim = SimAutopilot(scenario, listen="udpin:127.0.0.1:0", speedup=opts.speedup, loss=opts.sim_loss,
                           seed=int(plan_doc.get("seed") or 0), signing_key=opts.signing_key)
        await sim.start()
        url = f"udpout:127.0.0.1:{sim.port}"
        events.log("sim_started", port=sim.port, speedup=opts.speedup, loss=opts.sim_loss)
    else:
        url = opts.connect or ""
    try:
        if opts.signing_key is not None:
            events.log("signing", key=opts.signing_key.fingerprint)
        async with _link(url, opts) as link, contextlib.AsyncExitStack() as early:
            early.enter_context(Announcer(link, events))  # the decisions to the ground station (STATUSTEXT)
            # the planner process starts now: its start and imports (seconds on a busy companion) overlap the boot
            # wait, the parameter reads and the upload; the replanner warms it on the route and closes it
            clock_rate = opts.speedup if sim is not None else None  # vehicle s per wall s where known (our simulator)
            worker = None
            if opts.replan and expects_traffic(scenario, clock_rate):
                worker = PlanWorker()
                early.push_async_callback(asyncio.to_thread, worker.close)  # if no replanner ever takes it
            rates = TelemetryRates(link, on_results=lambda answers: events.log("telemetry_rates", **answers)).start()
            await link.wait_heartbeat(timeout=opts.heartbeat_timeout)
            # the streams we do not read turned off before the first transfer (PX4 floods a companion link with
            # ~500 messages/s times its speed-up: an upload in that flood timed out three times on a busy machine)
            # meanwhile, long enough to hear every autopilot on the link once: never follow merely the first
            await asyncio.gather(_rates_answered(rates), asyncio.sleep(IDENTITY_WINDOW_S))
            check_one_autopilot(link, events)
            autopilot = link.profile.layout  # the builder's layout key ("ardupilot", "px4")
            params = await read_params(link, [*parameter_names(autopilot, scenario.vehicle.type),
                                              *capacity_params(link.autopilot)])
            limits = limits_from(params, autopilot, scenario.vehicle, DEFAULT_LOITER_RADIUS_M)
            events.log("vehicle_limits", **limits.summary())
            plan_doc, scenario = await _plan_within(plan_doc, scenario, limits, opts, events)
            items = mission_from_plan_json(plan_doc, scenario, autopilot, densify=opts.densify)
            spec = spec_from_plan_json(plan_doc, scenario, autopilot, densify=opts.densify)
            top = float(np.max(np.asarray(plan_doc["trajectory"]["points"])[:, 2]))
            env = scenario.environment
            # min_route_alt 0: the climb-out from home counts, so a prism with a floor is never fenced
            fence = build_fence(env.cylinders, scenario.home, max_route_alt=top, prisms=env.prisms,
                                min_route_alt=0.0) if opts.fence and (len(env.cylinders) or len(env.prisms)) else []
            _write_mission_files(opts.report, plan_doc, scenario, items, spec, fence)
            _check_fence_fits(fence, link, params, scenario, top, events)
            client = MavsdkMissionClient(link) if isinstance(link, MavsdkLink) else MissionClient(link)  # the link's
            planned = len(items)  # as in the mission files
            if opts.replan and client.writes_in_part:  # room for a replan's longer route (never flown)
                items = with_room(items, (opts.replan_config or ReplanConfig()).spare_items)
                events.log("mission_room", items=len(items), spare=len(items) - planned)
            sup = FlightSupervisor(link, client, events, arm=opts.arm or opts.sim, home=scenario.home)
            length = float(plan_doc["metrics"]["length_m"])
            timeout = opts.flight_timeout or 120.0 + 4.0 * length / scenario.vehicle.cruise_speed / max(
                opts.speedup, 1e-3)
            replanner = feed = None
            async with contextlib.AsyncExitStack() as stack:
                if opts.traffic and scenario.intruders:
                    feed = await stack.enter_async_context(
                        TrafficFeed(opts.traffic, scenario, plan_doc["waypoints"], system=link.target_system or 1))
                    events.log("traffic", url=opts.traffic, intruders=[i.id for i in scenario.intruders])
                if opts.replan:  # moving threats, ADS-B, and the flown-safety guard on every flight
                    replanner = await stack.enter_async_context(LiveReplanner(
                        link, client, events, scenario, spec, items, opts.replan_config,
                        rate=clock_rate, seed=int(plan_doc.get("seed") or 0),
                        limits=limits, worker=worker))
                try:
                    outcome = await sup.fly(items, fence, ready_timeout=60.0 if sim is None else 30.0,
                                            flight_timeout=timeout, replanner=replanner,
                                            departure=_departure_check(plan_doc, scenario, limits, events))
                except CompanionError as e:
                    if not sup.started or sup.outcome is None:
                        raise
                    # armed or started: a flight, reported whole (its track, its flown safety), not a refusal
                    outcome = sup.outcome
                    outcome.completed = False
                    outcome.reason = f"{e} (after the start: the vehicle keeps its current mode and mission)"
                    events.log("failed", error=str(e), started=True)
    finally:
        if sim is not None:
            await sim.stop()
    _, index = record_flown_missions(opts.report, plan_doc, scenario, spec, fence, sup, replanner, events)
    return _write_flight_report(opts, plan_doc, scenario, outcome, sim, autopilot, (planned, len(items)), replanner,
                                feed, limits, index)


async def _plan_within(plan_doc: dict[str, Any], scenario: Scenario, limits: AutopilotLimits, opts: FlyOptions,
                 events: EventLog) -> tuple[dict[str, Any], Scenario]:
    """The plan, made again within the vehicle's own limits when it asks for more than the autopilot will fly: a
    bank beyond its roll limit, (a plane) a climb steeper than its climb-rate limit allows at the plan's speed, or
    less room after turns than its path-follower swings past a new leg (``turn_overshoot``). A PLAN.json that does
    so is refused (nothing uploaded)."""
    scenario = as_planned(plan_doc, scenario)
    v = scenario.vehicle
    stricter: list[str] = []
    if limits.read and v.max_bank_deg > limits.max_bank_deg + 1e-6:
        stricter.append(f"vehicle.max_bank_deg={limits.max_bank_deg:g}")
    if limits.read and v.type == "plane":
        climb = math.degrees(math.asin(min(min(limits.climb_rate, limits.sink_rate) / v.cruise_speed, 1.0)))
        if v.max_climb_deg > climb + 0.05:
            stricter.append(f"vehicle.max_climb_deg={math.floor(climb * 10) / 10:g}")
    swing = limits.turn_overshoot(v.cruise_speed)  # at the speed the mission sets (DO_CHANGE_SPEED)
    if v.turn_overshoot < swing - 0.05:  # its path-follower swings wider than the plan allows
        stricter.append(overshoot_override(swing))
    if not stricter:
        return plan_doc, scenario
    events.log("plan_beyond_vehicle", overrides=stricter, plan_again=opts.plan_again is not None)
    if opts.plan_again is None:
        raise DepartureRefused(f"the plan asks for more than the vehicle's parameters allow ({', '.join(stricter)}): "
                               "plan the scenario again with those values; nothing was uploaded")
    doc, sc = await asyncio.to_thread(opts.plan_again, stricter)  # the link's tasks keep running meanwhile
    events.log("planned_again", status=doc["status"], length_m=round(float(doc["metrics"]["length_m"]), 1),
               overrides=stricter)
    if doc["status"] not in ("exact", "approximate"):
        raise DepartureRefused(f"no feasible plan within the vehicle's limits ({', '.join(stricter)}: "
                               f"{doc['status']}); nothing was uploaded")
    write_json(opts.report / "PLAN.json", doc)
    events.log("scene", **picture.scene(sc, doc))
    return doc, sc


def _departure_check(plan_doc: dict[str, Any], scenario: Scenario, limits: AutopilotLimits,
                     events: EventLog) -> Callable[[VehicleFix, bool], None]:
    """The supervisor's check of the departure from where the vehicle is (before anything is uploaded)."""
    def check(fix: VehicleFix, on_ground: bool) -> None:
        route = np.asarray(plan_doc["waypoints"], dtype=float)
        verdict = check_departure(fix, route[0], scenario.vehicle.takeoff_alt, limits, scenario.environment,
                                  scenario.hazard.d_coll, on_ground, onto=route[1] if len(route) > 1 else None)
        events.log("departure", on_ground=on_ground, **verdict.summary())
        if verdict.refusal is not None:
            raise DepartureRefused(verdict.refusal)
        metrics = plan_doc["metrics"]
        events.log("plan_accepted", length_m=round(float(metrics["length_m"]), 1),
                   min_clearance_m=round(float(metrics["min_clearance_m"]), 1), waypoints=len(route))
    return check


def _check_fence_fits(fence: list, link: Link, params: dict[str, float], scenario: Scenario, top: float,
                      events: EventLog) -> None:
    """Refuse, before anything is sent, a fence larger than the autopilot stores (its HEARTBEAT says which
    autopilot; ArduPilot's storage may be widened by a parameter): the vehicle's mission and fence stay as they are."""
    capacity = fence_capacity(link.autopilot, link.vehicle_type, params)
    if not fence or capacity is None:
        return
    fits = capacity.fits(fence)
    events.log("fence_capacity", items=len(fence), max_items=capacity.max_items,
               storage_bytes=capacity.storage_bytes, source=capacity.source, fits=fits)
    if not fits:  # which zones: each built alone, with the route heights build_fence was given
        zones = fenced_zones(scenario.environment, scenario.home, top, 0.0)
        raise FenceTooLarge(fence_refusal(fence, zones, capacity) or "the fence does not fit the autopilot")


def _link(url: str, opts: FlyOptions) -> Link:
    """Our pymavlink link, recording the report's telemetry log, or MAVSDK's (``opts.backend``), which records none:
    MAVSDK hands us decoded messages, not the bytes on the wire, and does the mission transfers out of our sight."""
    if opts.backend == "mavsdk":
        (opts.report / TLOG).unlink(missing_ok=True)  # not an earlier flight's log beside this flight's report
        return MavsdkLink(url, source_system=opts.source_system, open_timeout=10.0)
    return Link(url, source_system=opts.source_system, open_timeout=10.0, signing_key=opts.signing_key,
                target_system=opts.target_system, baud=opts.baud, tlog=opts.report / TLOG)


def record_flown_missions(report: Path, plan_doc: dict[str, Any], scenario: Scenario, spec: Any, fence: list,
                          sup: FlightSupervisor, replanner: LiveReplanner | None,
                          events: EventLog) -> tuple[list[LiveMission], list[dict[str, Any]]]:
    """After a flight (``fly``'s, ``serve``'s): the report's record of the missions stored on the vehicle, the last
    one as mission.* and every one in missions/; returns them and their index for flight.json's ``missions``."""
    missions = _flown_missions(sup, replanner, events)
    if missions:  # the report's mission files: what was stored on the vehicle, the last one as mission.*
        _write_mission_files(report, plan_doc, scenario, list(missions[-1].items), spec, fence,
                             replanned=len(missions) > 1)
    return missions, _write_missions(report, missions, spec, replanner)


def _flown_missions(sup: FlightSupervisor, replanner: LiveReplanner | None, events: EventLog) -> list[LiveMission]:
    """Every mission stored on the vehicle and verified there during the flight, in order: the supervisor's upload,
    then each replan's (and each restore's); empty if the first upload was never verified."""
    if not sup.verified:
        return []
    t = next((r["t"] for r in reversed(events.records) if r["event"] == "upload_verified"), 0.0)
    return [LiveMission(t, "initial", tuple(sup.verified)), *(replanner.history if replanner is not None else ())]


def _write_missions(report: Path, missions: list[LiveMission], spec: Any,
                    replanner: LiveReplanner | None) -> list[dict[str, Any]]:
    """``missions/NN-REASON.waypoints`` for each mission stored on the vehicle; their index for flight.json (``t``:
    the event log's time its readback matched, ``reason``, ``items``, ``file``; a replan's ``outcome``)."""
    folder = report / MISSIONS
    folder.mkdir(exist_ok=True)
    for old in folder.glob("[0-9][0-9]-*.waypoints"):  # an earlier flight's, in a report directory used again
        old.unlink()
    outcomes = {r.n: r.outcome for r in replanner.records} if replanner is not None else {}
    index = []
    for k, mission in enumerate(missions, start=1):
        name = f"{k:02d}-{mission.reason.replace(' ', '-')}.waypoints"
        write_waypoints(folder / name, mission.items, spec.home)
        entry = {"t": mission.t, "reason": mission.reason, "items": len(mission.items), "file": f"{MISSIONS}/{name}"}
        if mission.replan is not None:
            entry["outcome"] = outcomes.get(mission.replan)
        index.append(entry)
    return index


def _write_mission_files(report: Path, plan_doc: dict[str, Any], scenario: Scenario, items: list, spec: Any,
                         fence: list, replanned: bool = False) -> None:
    """mission.waypoints, mission.plan (with the fence uploaded) and mission.geojson of ``items``: the planned
    mission before the flight, the last one stored on the vehicle after it. ``replanned``: ``items`` are a replan's,
    so the geojson's route is theirs, without the first plan's smoothed trajectory."""
    write_waypoints(report / "mission.waypoints", items, spec.home)
    polygons = zones_from_prisms(scenario.environment.prisms, spec.home)
    top = float(np.max(np.asarray(plan_doc["trajectory"]["points"], dtype=float)[:, 2]))
    left_out = prisms_left_out(scenario.environment.prisms, 0.0, top)
    write_qgc_plan(report / "mission.plan", items, spec,  # the fence's zones, by the rule the upload used
                   fenced_circles(scenario.environment.cylinders, spec.home, top) if fence else (),
                   zones=[z for k, z in enumerate(polygons) if k not in left_out] if fence else ())
    traj = lonlatalt(np.asarray(plan_doc["trajectory"]["points"], dtype=float), spec.home)
    route = MissionRoute.of(items, spec.home).points if replanned else np.asarray(plan_doc["waypoints"])
    write_geojson(report / "mission.geojson", lonlatalt(route, spec.home), zones_of(scenario, spec.home),
                  None if replanned else traj, {"scenario": scenario.name, "replanned": replanned},
                  geo_zones=polygons)


def _write_flight_report(opts: FlyOptions, plan_doc: dict[str, Any], scenario: Scenario, out: FlightOutcome,
                         sim: Any, autopilot: str, n_items: tuple[int, int],
                         replanner: LiveReplanner | None = None,
                         feed: TrafficFeed | None = None, limits: AutopilotLimits | None = None,
                         missions: list[dict[str, Any]] | None = None, tlog: Path | None = None) -> dict[str, Any]:
    """flight.json and track.png; the flown track is the simulator's truth when we ran it, else telemetry.
    ``tlog``: the link's telemetry log when it is not the report's own flight.tlog (``serve``'s, one per start of
    the service, named by its absolute path).
    Separations: the simulator's truth tracks, or a traffic feed's (the autopilot's positions against the
    intruders' scripted tracks)."""
    until = truth_until(sim, out)
    if sim is not None and sim.truth:
        flown = np.array([(x, y, z) for t, _lat, _lon, _alt, x, y, z in sim.truth if t <= until])
        source = "simulator truth"
    elif out.track:
        tr = np.array(out.track)
        flown = geodetic_to_enu(tr[:, 1], tr[:, 2], scenario.home.alt + tr[:, 3], scenario.home)
        source = "GLOBAL_POSITION_INT"
    else:
        flown, source = np.zeros((0, 3)), "none"
    seps = truth_separations(sim, scenario, until) if feed is None else feed.separations()
    safety = flown_safety(flown, scenario.environment, scenario.hazard.d_coll,
                          {k: v.separation for k, v in seps.items()})
    records = replanner.records if replanner is not None else []
    pace = replanner.prediction.pace if replanner is not None else None
    latencies = [r.latency_s for r in records if r.latency_s is not None]  # one per replan done
    doc = {
        "fuseplan_version": fuseplan_version(),
        "completed": out.completed,
        "reason": out.reason,
        "holding": out.holding,
        "items_reached": sorted(out.items_reached),
        "mission_items": n_items[0],  # the planned mission
        "room_items": n_items[1] - n_items[0],  # copies of its loiter end uploaded behind it (replan.with_room)
        "missions": missions or [],  # every mission stored on the vehicle (missions/), the last one as mission.*
        "tlog": str(tlog) if tlog is not None else TLOG if (opts.report / TLOG).exists() else None,
        "fence_items": out.fence_count,
        "min_clearance_m": safety.static_clearance_m,  # static obstacles (kept under its old name)
        "min_static_clearance_m": safety.static_clearance_m,
        "nearest_obstacle": safety.nearest_obstacle,
        "min_traffic_separation_m": safety.traffic_separation_m,
        "nearest_traffic": safety.nearest_traffic,
        "flown_safe": safety.safe,
        "breaches": safety.breaches,
        "d_coll_m": scenario.hazard.d_coll,
        "replanning": bool(opts.replan),
        "replans": len(latencies),
        "replan_attempts": len(records),
        "min_separation_m": {k: round(v.separation, 2) for k, v in seps.items()},
        "min_separation_t_s": {k: round(v.t, 2) for k, v in seps.items()},
        "separation_source": "simulator truth" if sim is not None else (
            "GLOBAL_POSITION_INT against the scripted intruders (traffic feed)" if feed is not None else None),
        "pace_m_s": None if pace is None else round(pace, 2),
        "replan_latency_s": _stats(latencies),
        "replan_plan_s": _stats([r.plan_s for r in records]),
        "replan_log": [r.summary() for r in records],
        "upload_s": round(out.upload_s, 3),
        "flight_wall_s": round(out.flight_s, 3),
        "autopilot": autopilot,
        "link": "built-in simulator" if sim is not None else opts.connect,
        "backend": opts.backend,
        "speedup": opts.speedup if sim is not None else None,
        "track_source": source,
        "track_points": len(flown),
        "statustexts": out.statustexts[-20:],
        "vehicle_limits": None if limits is None else limits.summary(),
    }
    write_json(opts.report / "flight.json", doc)
    truth = sim.intruder_truth if sim is not None else (feed.intruders if feed is not None else {})
    intr = {k: np.array([(x, y, z) for _t, x, y, z in v]).reshape(-1, 3) for k, v in truth.items()}
    replans = [(np.array(r.old_route), np.array(r.new_route)) for r in records if r.new_route]
    plot_track(opts.report / "track.png", scenario.environment, np.asarray(plan_doc["trajectory"]["points"]),
               flown, f"{scenario.name}: planned vs flown ({'completed' if out.completed else 'not completed'}"
               f", {len(latencies)} replans)", intr, replans)
    return doc


def truth_until(sim: Any, out: FlightOutcome) -> float:
    """Sim time up to which the simulator's truth track is the flight's: when the goal was reached, if the mission
    completed. The companion lets go there (a telemetry track ends there too); what follows is the autopilot's end
    action (ArduPlane's RTL home, straight over whatever lies between), flown for as long as the process takes to
    stop the simulator, which under load was long enough to cross a cylinder."""
    if sim is None or not out.completed or not out.items_reached:
        return math.inf
    return sim.reached_at.get(max(out.items_reached), math.inf)


def truth_separations(sim: Any, scenario: Scenario, until: float = math.inf) -> dict:
    """Truth-track minimum separation to every intruder and scripted threat up to sim time ``until`` (simulator
    runs only)."""
    if sim is None or not sim.truth:
        return {}
    vehicle = np.array([(t, x, y, z) for t, _lat, _lon, _alt, x, y, z in sim.truth if t <= until])
    radius = {i.id: i.radius for i in scenario.intruders}
    tracks = {k: (np.array(v).reshape(-1, 4), radius[k]) for k, v in sim.intruder_truth.items()}
    return min_separations(vehicle, tracks, scenario.environment.threats, sim.mission_start_time)


def _stats(values: list[float]) -> dict[str, float] | None:
    if not values:
        return None
    v = np.asarray(values, dtype=float)
    return {"n": int(v.size), "min": round(float(v.min()), 3), "median": round(float(np.median(v)), 3),
            "max": round(float(v.max()), 3)}
