"""``fuseplan bench replan``: replan latency on the built-in simulated autopilot (issue 6's benchmark).

Each run plans a scenario, flies it on the simulator (real UDP on 127.0.0.1) at the given speed-up (1× is the
target condition: wall time is vehicle time) until the first replan has made its new mission current, and
records the time from the conflict being seen to that moment, split into planning (wall, worker process
included) and upload + readback + set-current. Targets: planning ≤ 150 ms, end to end ≤ 1 s. ``cpu_hog`` busy
processes (:func:`planner.bench.load.cpu_hog`) can run beside the flights, and the report gives every replan's
planning-time overrun of its budget (issue 16: a deadline that holds only on an idle machine is not one).
"""

from __future__ import annotations

import asyncio
import json
from collections import Counter
from collections.abc import Callable, Coroutine, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from companion.flight.supervisor import FlightSupervisor
from companion.mavlink.link import Link
from companion.mavlink.protocol import MissionClient
from companion.mission.builder import mission_from_plan_json, spec_from_plan_json
from companion.mission.events import EventLog
from companion.replanning.replan import ReplanConfig
from companion.replanning.replanner import LiveReplanner
from companion.sim import SimAutopilot
from planner import kernel
from planner.bench.load import cpu_hog
from planner.bench.runner import write_csv
from planner.world.scenario import Scenario

PLAN_TARGET_S = 0.150
END_TO_END_TARGET_S = 1.0
NOT_LIVE = "no replan live"  # a conflict was seen but no new mission went live (held until the threat passed)
NO_CONFLICT = "no conflict"


@dataclass(frozen=True)
class LatencyRun:
    scenario: str
    run: int
    speedup: float
    status: str  # plan status of the replan made live, NOT_LIVE (conflict seen, held until clear) or NO_CONFLICT
    held: bool
    latency_s: float  # conflict seen → new mission current (wall)
    plan_s: float
    swap_s: float  # upload + readback + set-current (+ hold/resume when held)
    sep_after_m: float
    cpu_hog: int = 0  # busy processes that ran beside the flight
    plans_s: str = ""  # planning wall time of every replan planned in the flight, in order (space-separated)


async def fly_on_sim(plan_doc: dict, scenario: Scenario, *, speedup: float, cfg: ReplanConfig, seed: int,
                     flight_timeout: float, before: Callable[[SimAutopilot], None] | None = None,
                     during: Callable[[SimAutopilot, LiveReplanner], Coroutine[Any, Any, None]] | None = None,
                     stop: Callable[[LiveReplanner], bool] | None = None) -> tuple:
    """Fly ``plan_doc`` with live replanning on a simulator over UDP on 127.0.0.1. ``before(sim)`` runs
    before the flight (fault injection), ``during(sim, replanner)`` beside it; ``stop(replanner)`` ends the
    flight early once true. Returns (outcome or None if stopped, event records, replanner, simulator)."""
    async with SimAutopilot(scenario, "udpin:127.0.0.1:0", speedup=speedup, seed=seed) as sim:
        if before is not None:
            before(sim)
        async with Link(f"udpout:127.0.0.1:{sim.port}", open_timeout=5.0) as link:
            await link.wait_heartbeat(10.0)
            items = mission_from_plan_json(plan_doc, scenario, "ardupilot")
            spec = spec_from_plan_json(plan_doc, scenario, "ardupilot")
            client = MissionClient(link)
            events = EventLog()
            sup = FlightSupervisor(link, client, events, arm=True)
            async with LiveReplanner(link, client, events, scenario, spec, items, cfg, rate=speedup,
                                     seed=seed) as rp:
                flight = asyncio.create_task(sup.fly(items, (), ready_timeout=30.0,
                                                     flight_timeout=flight_timeout, replanner=rp))
                side = asyncio.create_task(during(sim, rp)) if during is not None else None
                while not flight.done() and not (stop is not None and stop(rp)):
                    await asyncio.wait({flight}, timeout=0.05)
                for task in (flight, side):
                    if task is not None and not task.done():
                        task.cancel()
                out = (await asyncio.gather(flight, return_exceptions=True))[0]
                if side is not None:
                    await asyncio.gather(side, return_exceptions=True)
                if isinstance(out, BaseException) and not isinstance(out, asyncio.CancelledError):
                    raise out
            return (None if isinstance(out, BaseException) else out), events.records, rp, sim


async def _one(plan_doc: dict, scenario: Scenario, run: int, speedup: float, cfg: ReplanConfig,
               timeout_s: float) -> LatencyRun:
    _out, _records, rp, _sim = await fly_on_sim(
        plan_doc, scenario, speedup=speedup, cfg=cfg, seed=run, flight_timeout=timeout_s,
        stop=lambda r: any(x.latency_s is not None for x in r.records))
    done = [r for r in rp.records if r.latency_s is not None]
    plans = " ".join(f"{r.plan_s:.3f}" for r in rp.records if r.plan_status)
    if not done:
        nan = float("nan")
        status = NOT_LIVE if rp.records else NO_CONFLICT
        return LatencyRun(scenario.name, run, speedup, status, any(r.held for r in rp.records), nan, nan, nan, nan,
                          plans_s=plans)
    r = done[0]
    return LatencyRun(scenario.name, run, speedup, r.plan_status, r.held, r.latency_s, r.plan_s, r.upload_s,
                      float(r.sep_after_m), plans_s=plans)


def run_latency_bench(plans: Sequence[tuple[dict, Scenario]], runs: int, speedup: float, output: Path,
                      cfg: ReplanConfig | None = None, progress: Callable[[str], None] | None = None,
                      hog: int = 0) -> list[LatencyRun]:
    """``runs`` flights per (PLAN.json document, scenario), with ``hog`` busy processes beside them; writes
    replan.md, replan.csv, replan.json."""
    cfg = cfg or ReplanConfig()

    def said(res: LatencyRun) -> str:
        return (f"{res.status}, latency {res.latency_s:.3f} s (plan {res.plan_s:.3f} s, swap {res.swap_s:.3f} s"
                f"{', held' if res.held else ''})")

    with cpu_hog(hog) as running:
        results = [replace(r, cpu_hog=running)
                   for r in _each_flight(plans, runs, speedup, cfg, _one, 2.0, "run", said, progress)]
    write_report(results, cfg, output)
    return results


def _each_flight(plans: Sequence[tuple[dict, Scenario]], runs: int, speedup: float, cfg: ReplanConfig,
                 fly: Callable[..., Coroutine[Any, Any, Any]], routes_long: float, word: str,
                 said: Callable[[Any], str], progress: Callable[[str], None] | None) -> list[Any]:
    """``runs`` flights of each plan, ``fly(doc, scenario, run, speedup, cfg, timeout_s)`` each, the timeout
    60 s + ``routes_long`` × the route's flying time; progress says "SCENARIO WORD r/runs: said(result)"."""
    results = []
    for doc, sc in plans:
        timeout = 60.0 + routes_long * float(doc["metrics"]["length_m"]) / sc.vehicle.cruise_speed / speedup
        for run in range(1, runs + 1):
            res = asyncio.run(fly(doc, sc, run, speedup, cfg, timeout))
            results.append(res)
            if progress is not None:
                progress(f"{sc.name} {word} {run}/{runs}: {said(res)}")
    return results


def _pct(values: np.ndarray, q: float) -> float:
    return float(np.percentile(values, q)) if values.size else float("nan")


def _pipeline(cfg: ReplanConfig) -> str:
    """What the report says of the replans' planner beyond the budget and swarm."""
    return (("; replans by the roadmap pipeline" if cfg.roadmap
             else "; replans by the scenario's planner (--replan-paper)") + f"; cost kernel: {kernel.chosen()}")


def write_report(results: list[LatencyRun], cfg: ReplanConfig, output: Path) -> list[Path]:
    output.mkdir(parents=True, exist_ok=True)
    csv_path = output / "replan.csv"
    write_csv(csv_path, [asdict(r) for r in results], list(LatencyRun.__dataclass_fields__))
    (output / "replan.json").write_text(json.dumps([asdict(r) for r in results], indent=1) + "\n")
    lines = [
        "# Replan latency on the built-in simulated autopilot",
        "",
        "Conflict seen → new mission current (verified by readback, MAV_CMD_DO_SET_MISSION_CURRENT confirmed by "
        f"MISSION_CURRENT), first replan of each flight. Replan budget {cfg.budget_s:g} s, swarm "
        f"{cfg.population}{_pipeline(cfg)}. Targets: planning ≤ {PLAN_TARGET_S * 1000:.0f} ms, end to end ≤ "
        f"{END_TO_END_TARGET_S:g} s.",
        "",
        "| scenario | speed-up | runs | replanned | planning median / max (s) | swap median / max (s) "
        "| end to end median / p90 / max (s) | held | verdict |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name in dict.fromkeys(r.scenario for r in results):
        rs = [r for r in results if r.scenario == name]
        ok = [r for r in rs if r.status not in (NOT_LIVE, NO_CONFLICT)]
        lat = np.array([r.latency_s for r in ok])
        pl = np.array([r.plan_s for r in ok])
        sw = np.array([r.swap_s for r in ok])
        meets = bool(ok) and len(ok) == len(rs) and pl.max() <= PLAN_TARGET_S + 1e-9 \
            and lat.max() <= END_TO_END_TARGET_S
        lines.append(
            f"| {name} | {rs[0].speedup:g}× | {len(rs)} | {len(ok)} | {_pct(pl, 50):.3f} / {_pct(pl, 100):.3f} "
            f"| {_pct(sw, 50):.3f} / {_pct(sw, 100):.3f} | {_pct(lat, 50):.3f} / {_pct(lat, 90):.3f} / "
            f"{_pct(lat, 100):.3f} | {sum(r.held for r in rs)} | {'meets both targets' if meets else 'MISSES'} |")
    hog = results[0].cpu_hog if results else 0
    lines += ["", f"Load: {hog} busy process{'es' if hog != 1 else ''} (planner.bench.load.cpu_hog) beside the "
              "flights. Planning overrun of the budget, every replan planned (not only the first made live), and "
              "conflict seen → new mission current:", "",
              "| scenario | replans planned | overrun median / p99 / max (ms) | within budget + 10 ms "
              "| conflict → current median (s) |", "|---|---|---|---|---|"]
    for name in dict.fromkeys(r.scenario for r in results):
        rs = [r for r in results if r.scenario == name]
        over = 1000.0 * (np.array([float(v) for r in rs for v in r.plans_s.split()]) - cfg.budget_s)
        lat = np.array([r.latency_s for r in rs if r.status not in (NOT_LIVE, NO_CONFLICT)])
        lines.append(f"| {name} | {over.size} | {_pct(over, 50):.1f} / {_pct(over, 99):.1f} / {_pct(over, 100):.1f} "
                     f"| {int((over <= 10.0).sum())} of {over.size} | {_pct(lat, 50):.3f} |")
    lines += ["", "Planning is wall time around the worker process (search, smoothing, checks and the hand-over); "
              "swap is upload + readback + set-current, plus a LOITER/AUTO round trip when the guard held the "
              "vehicle. Runs in replan.csv."]
    md = output / "replan.md"
    md.write_text("\n".join(lines) + "\n")
    return [md, csv_path, output / "replan.json"]


# --- whole flights: how many replans a conflict takes (issue 15) ----------------------------------------------------
LIVE_OK = ("exact", "approximate")
ONE_REPLAN_TARGET = 0.90  # share of conflicts resolved by one replan
GOOD_REPLAN_TARGET = 0.95  # share of replans exact/approximate with the predicted separation kept


@dataclass(frozen=True)
class FlightRun:
    scenario: str
    run: int
    speedup: float
    completed: bool
    conflicts: int  # distinct threats that caused a replan or a hold
    replans: int  # replans attempted (planned)
    live: int  # replans whose mission went live
    good: int  # replans exact/approximate whose predicted separation ≥ d_coll + margin
    one_replan: int  # conflicts resolved by exactly one live replan
    statuses: str  # plan status of each replan, in order


async def _whole(plan_doc: dict, scenario: Scenario, run: int, speedup: float, cfg: ReplanConfig,
                 timeout_s: float) -> FlightRun:
    out, _records, rp, _sim = await fly_on_sim(plan_doc, scenario, speedup=speedup, cfg=cfg, seed=run,
                                               flight_timeout=timeout_s)
    need = scenario.hazard.d_coll + cfg.margin_m
    recs = rp.records
    planned = [r for r in recs if r.plan_status]
    good = [r for r in planned if r.plan_status in LIVE_OK and r.sep_after_m is not None and r.sep_after_m >= need]
    threats = {r.threat for r in recs}
    live = Counter(r.threat for r in recs if r.latency_s is not None)
    return FlightRun(scenario.name, run, speedup, out is not None and out.completed, len(threats), len(planned),
                     sum(live.values()), len(good), sum(live[t] == 1 for t in threats),
                     " ".join(r.plan_status or "-" for r in recs))


def run_flight_bench(plans: Sequence[tuple[dict, Scenario]], runs: int, speedup: float, output: Path,
                     cfg: ReplanConfig | None = None, progress: Callable[[str], None] | None = None,
                     hog: int = 0) -> list[FlightRun]:
    """``runs`` whole flights per plan, with ``hog`` busy processes beside them; writes replan_flights.md and
    replan_flights.csv."""
    cfg = cfg or ReplanConfig()

    def said(res: FlightRun) -> str:
        return f"{res.conflicts} conflicts, {res.replans} replans ({res.statuses}), {res.live} live"

    with cpu_hog(hog):
        results = _each_flight(plans, runs, speedup, cfg, _whole, 3.0, "flight", said, progress)
    output.mkdir(parents=True, exist_ok=True)
    write_csv(output / "replan_flights.csv", [asdict(r) for r in results], list(FlightRun.__dataclass_fields__))
    lines = ["# Replans per conflict over whole flights on the built-in simulated autopilot", "",
             f"Every flight flown to its end at {speedup:g}× with live replanning (budget {cfg.budget_s:g} s, swarm "
             f"{cfg.population}, the scenario's planner settings{_pipeline(cfg)}). A replan is *good* when "
             "it ends exact or approximate with a predicted separation of at least d_coll + margin "
             f"({cfg.margin_m:g} m); a conflict (one threat) is resolved by one replan when exactly one new mission "
             f"went live for it. Targets (issue 15): good ≥ {100 * GOOD_REPLAN_TARGET:.0f} %, one replan per "
             f"conflict ≥ {100 * ONE_REPLAN_TARGET:.0f} %. Load: {hog} busy processes beside the flights.", "",
             "| scenario | flights | completed | conflicts | replans | good | one replan per conflict | verdict |",
             "|---|---|---|---|---|---|---|---|"]
    for name in dict.fromkeys(r.scenario for r in results):
        rs = [r for r in results if r.scenario == name]
        conflicts, replans = sum(r.conflicts for r in rs), sum(r.replans for r in rs)
        good, one = sum(r.good for r in rs), sum(r.one_replan for r in rs)
        g = good / replans if replans else float("nan")
        o = one / conflicts if conflicts else float("nan")
        meets = replans > 0 and g >= GOOD_REPLAN_TARGET and o >= ONE_REPLAN_TARGET
        lines.append(f"| {name} | {len(rs)} | {sum(r.completed for r in rs)} | {conflicts} | {replans} | "
                     f"{good} ({100 * g:.0f} %) | {one} ({100 * o:.0f} %) | {'meets' if meets else 'MISSES'} |")
    lines += ["", "Per flight (statuses of each replan in order, '-' a hold without a plan): replan_flights.csv."]
    (output / "replan_flights.md").write_text("\n".join(lines) + "\n")
    return results
