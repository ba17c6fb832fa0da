"""``fuseplan bench flights``: whole flights of the shipped scenarios with moving threats, on the built-in simulator
or on a real autopilot (ArduPilot SITL plane or copter, PX4 SITL), with live replanning and, on request, without;
what the vehicle flew, flight by flight, and per backend × scenario × replanning.

Each flight is ``fuseplan fly`` as a person would run it (in this process, through the command line's own entry
point, so its exit code is the command's): ``--sim --speedup 20`` on the simulator; on a real autopilot
(:mod:`companion.flight.autopilots`, a fresh one per flight) ``--connect`` its companion port ``--arm --traffic``
its spare port, as tests/sitl/campaign.py and tests/px4 fly them; copters with ``--set vehicle.type="copter"``.
Every flight's report directory is kept under ``DIR/flights/``; its record (exit code, flight.json's clearance,
separations and replans, the track errors measured here, the hold count) is appended to ``DIR/flights.jsonl`` as it
finishes, so an interrupted bench resumes where it stopped. Then ``flights.md``, ``flights.csv`` (per backend ×
scenario × replanning) and ``flights_runs.csv`` (per flight).

Track errors (:func:`track_errors`) come from the report's ``events.jsonl``: the ``position`` records (the
autopilot's GLOBAL_POSITION_INT, at most 10 per wall second) against the mission live at each record's time (the
last ``mission`` record before it, i.e. the last verified upload), or PLAN.json's planned trajectory when the log
has no mission record.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import platform
import shutil
import time
import tomllib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from companion.flight import autopilots
from companion.flight.safety import AIRBORNE_M
from planner.bench.runner import appending, load_records, set_options, write_csv
from planner.errors import FuseplanError
from planner.plan import json_safe

BACKENDS = ("sim", "sitl-plane", "sitl-copter", "px4", "px4-vtol")
SPEEDUP = {"sim": 20.0, "sitl-plane": 10.0, "sitl-copter": 10.0, "px4": 10.0,  # px4: 2 cores keep up with 10x
           "px4-vtol": 10.0}
PX4_MODELS = {"px4": autopilots.PX4_MODEL, "px4-vtol": autopilots.PX4_VTOL_MODEL}  # the PX4 backends' SIH models
COPTER = ('vehicle.type="copter"',)
# PX4's SIH standard VTOL: it flies its route as a fixed-wing at its trim airspeed (FW_AIRSPD_TRIM 10 m/s; 18 would
# be capped at its 12 m/s maximum), and PX4 rejects a VTOL mission without a landing (MIS_TKO_LAND_REQ)
VTOL = ('vehicle.cruise_speed=10', 'vehicle.end_action="land"')
OVERRIDES = {"sitl-copter": COPTER, "px4": COPTER, "px4-vtol": VTOL}  # what each backend's flights are flown with
DEFAULT_RUNS = 5
EXIT_BAD_INPUT, EXIT_INTERRUPTED = 2, 130  # fly's exit codes that are not a flight's result


# --- what is flown ------------------------------------------------------------------------------------------------
def moving_threat_scenarios(folder: Path) -> dict[str, Path]:
    """The scenarios in ``folder`` with ``[[threats]]`` or ``[[intruders]]``, by name (file stem)."""
    found = {}
    for path in sorted(folder.glob("*.toml")):
        try:
            doc = tomllib.loads(path.read_text())
        except (OSError, tomllib.TOMLDecodeError):
            continue
        if doc.get("threats") or doc.get("intruders"):
            found[path.stem] = path
    return found


@dataclass(frozen=True)
class FlightsSettings:
    """One ``fuseplan bench flights`` invocation."""

    backend: str  # one of BACKENDS
    runs: int
    scenarios: tuple[Path, ...]
    replan_off_too: bool  # --no-replan-too
    output: Path
    overrides: tuple[str, ...] = ()  # --set, for every flight
    folder: Path | None = None  # the autopilot's folder (--sitl-dir or the environment)
    hog: int = 0  # --cpu-hog: busy processes beside the flights
    replan_budget: float | None = None  # --replan-budget: fly's, for every flight (None: its default)

    @property
    def fly_overrides(self) -> tuple[str, ...]:
        return (*self.overrides, *OVERRIDES.get(self.backend, ()))

    @property
    def fingerprint(self) -> str:
        """What decides a flight besides its key: a resumed record must match it."""
        return json.dumps([self.backend, SPEEDUP[self.backend], list(self.fly_overrides)]
                          + ([{"cpu_hog": self.hog}] if self.hog else [])
                          + ([{"replan_budget": self.replan_budget}] if self.replan_budget is not None else []))

    def command(self) -> str:
        names = ",".join(p.stem for p in self.scenarios)
        return (f"fuseplan bench flights --backend {self.backend} --runs {self.runs} --scenarios {names}"
                + (" --no-replan-too" if self.replan_off_too else "") + (f" --cpu-hog {self.hog}" if self.hog else "")
                + (f" --replan-budget {self.replan_budget:g}" if self.replan_budget is not None else "")
                + f" -o {self.output}"
                + set_options(self.overrides))

    def flights(self) -> list[tuple[Path, bool, int]]:
        """(scenario, replanning, run) in the order they are flown."""
        return [(sc, replan, run) for sc in self.scenarios for replan in ((True, False) if self.replan_off_too
                                                                           else (True,))
                for run in range(1, self.runs + 1)]


def missing(backend: str, folder: Path | None) -> str | None:
    """Why ``backend`` cannot fly here (one line), or None."""
    if backend == "sim":
        return None
    if backend in PX4_MODELS:
        return autopilots.px4_missing(folder)
    return autopilots.ardupilot_missing(backend.removeprefix("sitl-"), folder)


def autopilot_folder(backend: str, folder: Path | None) -> Path | None:
    """``--sitl-dir``, else the backend's environment variable (FUSEPLAN_SITL_DIR, FUSEPLAN_PX4_DIR)."""
    if backend == "sim":
        return None
    return autopilots.folder_of(autopilots.PX4_ENV if backend in PX4_MODELS else autopilots.ARDUPILOT_ENV, folder)


@contextlib.contextmanager
def _autopilot(s: FlightsSettings, home: tuple[float, float, float]) -> Iterator[autopilots.Endpoints | None]:
    """A fresh autopilot for one flight (None on the simulator, which ``fly --sim`` runs itself)."""
    if s.backend == "sim":
        yield None
    elif s.backend in PX4_MODELS:
        with autopilots.px4_sitl(home, s.folder or Path(), SPEEDUP[s.backend], PX4_MODELS[s.backend]) as ep:
            yield ep
    else:
        with autopilots.ardupilot_sitl(s.backend.removeprefix("sitl-"), home, s.folder or Path(),
                                       SPEEDUP[s.backend]) as ep:
            yield ep


def _key(rec: dict[str, Any]) -> tuple[str, str, bool, int]:
    return str(rec["backend"]), str(rec["scenario"]), bool(rec["replanning"]), int(rec["run"])


# --- one flight ---------------------------------------------------------------------------------------------------
FlyCommand = Callable[[list[str]], int]  # ``fuseplan ARGV`` in this process (companion.cli.main): its exit code


def fly_one(s: FlightsSettings, scenario: Path, replan: bool, run: int, fly: FlyCommand) -> dict[str, Any]:
    """Fly once and return the flight's record (raises when no flight result came: the autopilot would not start,
    fly refused its input (exit 2) or was interrupted (KeyboardInterrupt))."""
    from planner.world.scenario import load_scenario

    report = s.output / "flights" / s.backend / f"{scenario.stem}-{'replan' if replan else 'no-replan'}-{run}"
    if report.exists():  # an earlier try that left no record
        shutil.rmtree(report)
    home = load_scenario(scenario, list(s.fly_overrides)).home
    argv = ["fly", str(scenario), "-q", "--report", str(report),
            *(a for o in s.fly_overrides for a in ("--set", o)), *(() if replan else ("--no-replan",)),
            *(("--replan-budget", f"{s.replan_budget:g}") if replan and s.replan_budget is not None else ())]
    t0 = time.monotonic()
    with _autopilot(s, (home.lat, home.lon, home.alt)) as ep:
        if ep is None:
            argv += ["--sim", "--speedup", f"{SPEEDUP['sim']:g}"]
            where = f"built-in simulator at {SPEEDUP['sim']:g}x"
        else:
            argv += ["--connect", ep.connect, "--arm", "--traffic", ep.traffic]
            where = ep.describe
        code = fly(argv)
    wall = time.monotonic() - t0
    if code == EXIT_INTERRUPTED:
        raise KeyboardInterrupt
    if code == EXIT_BAD_INPUT:
        raise FuseplanError(f"fuseplan {' '.join(argv)} refused its input (exit 2)")
    return flight_record(s, scenario.stem, replan, run, code, wall, report, where)


def flight_record(s: FlightsSettings, scenario: str, replan: bool, run: int, code: int, wall_s: float,
                  report: Path, where: str) -> dict[str, Any]:
    """The record of a flown report directory: flight.json's numbers as they are, the track errors and holds."""
    flight = _read_json(report / "flight.json")
    events = _read_events(report / "events.jsonl")
    plan = _read_json(report / "PLAN.json")
    d_coll = flight.get("d_coll_m")
    static, traffic = flight.get("min_static_clearance_m"), flight.get("min_traffic_separation_m")
    err = track_errors(events, plan)
    live = [r for r in flight.get("replan_log") or [] if isinstance(r, dict) and r.get("latency_s") is not None]
    return json_safe({
        "version": RECORD_VERSION,
        "backend": s.backend, "scenario": scenario, "replanning": replan, "run": run, "fingerprint": s.fingerprint,
        "exit": code, "completed": bool(flight.get("completed")), "reason": flight.get("reason"),
        "flown_safe": flight.get("flown_safe"), "d_coll_m": d_coll,
        "min_static_clearance_m": static, "nearest_obstacle": flight.get("nearest_obstacle"),
        "min_traffic_separation_m": traffic, "nearest_traffic": flight.get("nearest_traffic"),
        "min_separation_m": flight.get("min_separation_m") or {},
        "static_kept": _kept(static, d_coll), "traffic_kept": _kept(traffic, d_coll),
        "xtrack_p50_m": err.xtrack_p50, "xtrack_p95_m": err.xtrack_p95,
        "climb_error_p50_m": err.climb_p50, "climb_error_p95_m": err.climb_p95,
        "route_samples": err.samples, "reference": err.reference,
        "replans": flight.get("replans"), "replan_attempts": flight.get("replan_attempts"),
        "holds": sum(e.get("event") == "hold" for e in events),
        # each replan made live: conflict seen → new mission current, its planning and its swap (wall s), and
        # whether only the changed items were written
        "replan_latency_s": [r["latency_s"] for r in live], "replan_plan_s": [r.get("plan_s") for r in live],
        "replan_swap_s": [r.get("upload_s") for r in live],
        "partial_writes": sum(str(r.get("upload_path", "")).startswith("partial") for r in live),
        "track_source": flight.get("track_source"), "wall_s": round(wall_s, 1), "autopilot": where,
        "host": host(), "report": str(report.relative_to(s.output)),
    })


RECORD_VERSION = 2  # a reused record of another version is read again from its report directory


def _kept(value: Any, d_coll: Any) -> bool:
    """Whether a measured clearance kept d_coll (a flight with nothing measured did not)."""
    return isinstance(value, (int, float)) and isinstance(d_coll, (int, float)) and value >= d_coll


def _read_json(path: Path) -> dict[str, Any]:
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return doc if isinstance(doc, dict) else {}


def _read_events(path: Path) -> list[dict[str, Any]]:
    out = []
    with contextlib.suppress(OSError):
        for line in path.read_text().splitlines():
            with contextlib.suppress(ValueError):
                out.append(json.loads(line))
    return out


def host() -> str:
    """This machine, for the report: name, cores, CPU model, system, Python."""
    cpu = platform.processor() or "unknown CPU"
    with contextlib.suppress(OSError):
        cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                    if line.startswith("model name")), cpu)
    return (f"{platform.node()}: {os.cpu_count()} cores ({cpu}), {platform.system()} {platform.release()}, "
            f"Python {platform.python_version()}")


# --- track errors -------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TrackErrors:
    """Cross-track and climb error of a flight's route part (metres; None when nothing was flown on it)."""

    xtrack_p50: float | None
    xtrack_p95: float | None
    climb_p50: float | None
    climb_p95: float | None
    samples: int  # track points measured
    reference: str  # "live mission" or "planned trajectory"


def project(points: np.ndarray, route: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each of ``points`` (N, 3) ENU m projected in plan view onto the polyline ``route`` (M, 3): the horizontal
    distance to it (N,) and the route's altitude at the nearest point (N,), interpolated along its leg (the
    altitude the route asks for at that along-track distance)."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    route = np.asarray(route, dtype=float).reshape(-1, 3)
    if len(route) == 1:
        return np.linalg.norm(points[:, :2] - route[0, :2], axis=1), np.full(len(points), route[0, 2])
    a, b = route[:-1], route[1:]  # (S, 3) legs
    d = b[:, :2] - a[:, :2]
    len2 = np.einsum("sk,sk->s", d, d)
    rel = points[:, None, :2] - a[None, :, :2]  # (N, S, 2)
    u = np.clip(np.einsum("nsk,sk->ns", rel, d) / np.where(len2 > 0, len2, 1.0), 0.0, 1.0)  # (N, S)
    dist = np.linalg.norm(rel - u[..., None] * d[None], axis=2)
    leg = np.argmin(dist, axis=1)
    n = np.arange(len(points))
    z = a[leg, 2] + u[n, leg] * (b[leg, 2] - a[leg, 2])
    return dist[n, leg], z


def route_errors(track: np.ndarray, routes: Sequence[tuple[float, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Cross-track distance (N,) and climb error, flown minus asked altitude (N,), of ``track`` (N, 4: t, x, y, z)
    against the route live at each point's time: the last of ``routes`` ((t, (M, 3)), in time order) from at or
    before it (the first for points before them all)."""
    track = np.asarray(track, dtype=float).reshape(-1, 4)
    xtrack, climb = np.empty(len(track)), np.empty(len(track))
    live = np.clip(np.searchsorted([t for t, _ in routes], track[:, 0], side="right") - 1, 0, None)
    for k in np.unique(live):
        on = live == k
        dist, z = project(track[on, 1:], routes[k][1])
        xtrack[on], climb[on] = dist, track[on, 3] - z
    return xtrack, climb


def track_errors(events: Sequence[dict[str, Any]], plan_doc: dict[str, Any]) -> TrackErrors:
    """The flight's cross-track and climb errors (p50, p95 of their absolute values) over its route part: from
    the first item reached at or after the route's start to the end of the flight (``finished``), airborne
    ``position`` records only. The take-off and the climb to the route's start, whose path the mission leaves to
    the autopilot, are not counted. The reference is the mission live at each record's time, from the route's
    start (the ``mission`` records: each verified upload), else PLAN.json's planned trajectory."""
    missions = [(float(e["t"]), np.asarray(e["items"], dtype=float).reshape(-1, 4))
                for e in events if e.get("event") == "mission" and e.get("items")]
    if missions:  # items are [seq, x, y, z]; the first is the take-off (at the start), the second the start
        first = missions[0][1]
        start_seq = first[1, 0] if len(first) > 1 else first[0, 0]
        routes = [(t, rows[1:, 1:] if len(rows) > 1 else rows[:, 1:]) for t, rows in missions]
        reference = "live mission"
    else:
        start_seq = -math.inf
        traj = np.asarray((plan_doc.get("trajectory") or {}).get("points") or plan_doc.get("waypoints") or [],
                          dtype=float).reshape(-1, 3)
        routes = [(-math.inf, traj)] if len(traj) else []
        reference = "planned trajectory"
    on_route = min((float(e["t"]) for e in events if e.get("event") == "reached" and e.get("seq", -1) >= start_seq),
                   default=None)
    end = next((float(e["t"]) for e in events if e.get("event") == "finished"), math.inf)
    track = np.array([(e["t"], e["x"], e["y"], e["z"]) for e in events if e.get("event") == "position"
                      and on_route is not None and on_route <= e["t"] <= end and e["z"] > AIRBORNE_M],
                     dtype=float).reshape(-1, 4)
    if not len(track) or not routes:
        return TrackErrors(None, None, None, None, 0, reference)
    xtrack, climb = route_errors(track, routes)

    def pct(v: np.ndarray, q: float) -> float:
        return round(float(np.percentile(np.abs(v), q)), 2)

    return TrackErrors(pct(xtrack, 50), pct(xtrack, 95), pct(climb, 50), pct(climb, 95), len(track), reference)


# --- the bench ----------------------------------------------------------------------------------------------------
def run_flights_bench(s: FlightsSettings, fly: FlyCommand,
                      progress: Callable[[str], None] | None = None) -> tuple[list[dict[str, Any]], int]:
    """Fly what ``DIR/flights.jsonl`` does not hold yet, appending each flight's record as it finishes; write the
    report files. Returns (records in flight order, flights reused). A flight that gave no result (the autopilot
    would not start, say) does not stop the others; the bench then ends with the first one's reason, and the same
    command flies only those again."""
    say = progress or (lambda _text: None)
    s.output.mkdir(parents=True, exist_ok=True)
    jsonl = s.output / "flights.jsonl"
    have = load_records(jsonl, _key)
    plan = s.flights()
    keys = [(s.backend, sc.stem, replan, run) for sc, replan, run in plan]
    for k in keys:
        if k in have and have[k].get("fingerprint") != s.fingerprint:
            raise FuseplanError(f"{jsonl}: {k[1]} run {k[3]} on {k[0]} was flown with other settings (--set); "
                                "delete the file or choose another -o to start afresh")
    for k in keys:  # records of an older version: the report directory says what this version measures
        rec = have.get(k)
        if rec is not None and rec.get("version") != RECORD_VERSION and (s.output / rec["report"]).is_dir():
            have[k] = flight_record(s, rec["scenario"], rec["replanning"], rec["run"], rec["exit"], rec["wall_s"],
                                    s.output / rec["report"], rec["autopilot"])
    todo = [(f, k) for f, k in zip(plan, keys) if k not in have]
    say(f"bench flights: {s.backend}, {', '.join(p.stem for p in s.scenarios)}, {s.runs} flight(s) each, "
        f"replanning {'on and off' if s.replan_off_too else 'on'}: {len(todo)} to fly, "
        f"{len(keys) - len(todo)} reused from {jsonl}")
    failed: list[str] = []
    with appending(jsonl) as f:
        for i, ((scenario, replan, run), k) in enumerate(todo, 1):
            label = f"[{i}/{len(todo)}] {s.backend} {scenario.stem} replanning {'on' if replan else 'off'} run {run}"
            try:
                rec = fly_one(s, scenario, replan, run, fly)
            except (RuntimeError, FuseplanError, OSError) as e:  # no result; an interrupt still ends the bench
                failed.append(f"{label}: {str(e).splitlines()[0]}")
                say(f"{label}: FAILED, no result: {e}")
                continue
            f.write(json.dumps(rec, allow_nan=False) + "\n")
            f.flush()
            have[k] = rec
            say(f"{label}: {said(rec)}")
    records = [have[k] for k in keys if k in have]
    write_report(s, records)
    if failed:
        raise FuseplanError(f"{len(failed)} of {len(todo)} flights gave no result, the first {failed[0]}; the "
                            f"finished ones are in {jsonl}: run the same command again to fly the others")
    return records, len(keys) - len(todo)


def said(rec: dict[str, Any]) -> str:
    """One progress line's worth of a flight record."""
    seps = ", ".join(f"{k} {v:.1f}" for k, v in sorted(rec["min_separation_m"].items()) if v is not None)
    return (f"exit {rec['exit']}, {'completed' if rec['completed'] else 'NOT completed'}, static "
            f"{_m(rec['min_static_clearance_m'])} ({rec['nearest_obstacle']}), traffic {seps or '-'} m, "
            f"cross-track p95 {_m(rec['xtrack_p95_m'])}, climb error p95 {_m(rec['climb_error_p95_m'])}, replans "
            f"{rec['replans']} ({rec['replan_attempts']}), holds {rec['holds']}, {rec['wall_s']:.0f} s")


def _m(v: Any) -> str:
    return f"{v:.1f} m" if isinstance(v, (int, float)) else "-"


# --- the report ---------------------------------------------------------------------------------------------------
SUMMARISED = ("min_static_clearance_m", "min_traffic_separation_m", "xtrack_p50_m", "xtrack_p95_m",
              "climb_error_p50_m", "climb_error_p95_m", "replans", "replan_attempts", "holds", "wall_s")
RUN_FIELDS = ("backend", "scenario", "replanning", "run", "exit", "completed", "flown_safe", "d_coll_m",
              "min_static_clearance_m", "nearest_obstacle", "static_kept", "min_traffic_separation_m",
              "nearest_traffic", "traffic_kept", "separations", "xtrack_p50_m", "xtrack_p95_m", "climb_error_p50_m",
              "climb_error_p95_m", "route_samples", "reference", "replans", "replan_attempts", "holds",
              "replan_latency_s", "partial_writes", "track_source", "reason", "wall_s", "autopilot", "host", "report")


def summarise(records: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per backend × scenario × replanning (first-flown order): flights, completed, kept d_coll (static, traffic)
    and the min / median / max of every :data:`SUMMARISED` number over the flights that measured it."""
    rows = []
    for key in dict.fromkeys((r["backend"], r["scenario"], r["replanning"]) for r in records):
        rs = [r for r in records if (r["backend"], r["scenario"], r["replanning"]) == key]
        row: dict[str, Any] = {"backend": key[0], "scenario": key[1], "replanning": key[2], "flights": len(rs),
                               "completed": sum(r["completed"] for r in rs),
                               "static_kept": sum(r["static_kept"] for r in rs),
                               "traffic_kept": sum(r["traffic_kept"] for r in rs)}
        for col in SUMMARISED:
            v = np.array([r[col] for r in rs if isinstance(r.get(col), (int, float))], dtype=float)
            for name, fn in (("min", np.min), ("median", np.median), ("max", np.max)):
                row[f"{col}_{name}"] = round(float(fn(v)), 2) if v.size else None
        rows.append(row)
    return rows


def write_report(s: FlightsSettings, records: Sequence[dict[str, Any]]) -> list[Path]:
    """flights.md, flights.csv (per backend × scenario × replanning), flights_runs.csv (per flight)."""
    rows = summarise(records)
    out = s.output
    write_csv(out / "flights.csv", rows, list(rows[0]) if rows else ["backend"])
    write_csv(out / "flights_runs.csv",
              [{**r, "separations": "; ".join(f"{k} {v}" for k, v in sorted(r["min_separation_m"].items())),
                "replan_latency_s": " ".join(f"{v:g}" for v in r.get("replan_latency_s") or [])}
               for r in records], RUN_FIELDS)

    def two(row: dict[str, Any], col: str, a: str, b: str, fmt: str = ".1f") -> str:
        x, y = row[f"{col}_{a}"], row[f"{col}_{b}"]
        return "-" if x is None else f"{x:{fmt}} / {y:{fmt}}"

    lines = [f"# Flights with moving threats: {s.backend}", "", f"`{s.command()}`", "",
             "Hosts: " + "; ".join(dict.fromkeys(r["host"] for r in records)) + ". Autopilots: "
             + "; ".join(dict.fromkeys(r["autopilot"] for r in records)) + "."
             + (f" Load: {s.hog} busy process{'es' if s.hog != 1 else ''} (planner.bench.load.cpu_hog) beside "
                "the flights." if s.hog else ""), "",
             ("| backend | scenario | replanning | flights | completed | kept d_coll: static | kept d_coll: traffic "
             "| static clearance min / median (m) | traffic separation min / median (m) "
             "| cross-track p50 / p95, median (m) | cross-track p95 max (m) | climb error p50 / p95, median (m) "
             "| climb error p95 max (m) | replans median / max | attempts median / max | holds median / max |"),
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        n = row["flights"]

        def med(col: str, row: dict[str, Any] = row) -> str:
            v = row[f"{col}_median"]
            return "-" if v is None else f"{v:.1f}"

        lines.append(
            f"| {row['backend']} | {row['scenario']} | {'on' if row['replanning'] else 'off'} | {n} "
            f"| {row['completed']} | {row['static_kept']} of {n} | {row['traffic_kept']} of {n} "
            f"| {two(row, 'min_static_clearance_m', 'min', 'median')} "
            f"| {two(row, 'min_traffic_separation_m', 'min', 'median')} "
            f"| {med('xtrack_p50_m')} / {med('xtrack_p95_m')} | {_num(row['xtrack_p95_m_max'])} "
            f"| {med('climb_error_p50_m')} / {med('climb_error_p95_m')} | {_num(row['climb_error_p95_m_max'])} "
            f"| {two(row, 'replans', 'median', 'max', 'g')} | {two(row, 'replan_attempts', 'median', 'max', 'g')} "
            f"| {two(row, 'holds', 'median', 'max', 'g')} |")
    latency = latency_rows(records)
    if latency:
        lines += ["", "Replans made live: conflict seen → new mission current (wall seconds, pooled over the flights), "
                  "its planning and its swap (upload with readback, set-current and, when held, the resume), and "
                  "how many wrote only the changed items (MISSION_WRITE_PARTIAL_LIST):", "",
                  "| backend | scenario | replans live | conflict → live median / p90 / max (s) | planning median (s) "
                  "| swap median (s) | partial writes |", "|---|---|---|---|---|---|---|"]
        lines += [f"| {r['backend']} | {r['scenario']} | {r['n']} | {r['median']:.3f} / {r['p90']:.3f} / "
                  f"{r['max']:.3f} | {r['plan']:.3f} | {r['swap']:.3f} | {r['partial']} of {r['n']} |"
                  for r in latency]
    lines += ["", "Per flight (flights_runs.csv; each flight's report directory is under flights/):", "",
              ("| scenario | replanning | run | exit | completed | static clearance (m, nearest) "
              "| separation per threat (m) | cross-track p50 / p95 (m) | climb error p50 / p95 (m) "
              "| replans (attempts) | holds | wall (s) |"), "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in records:
        seps = ", ".join(f"{k} {v:.1f}" for k, v in sorted(r["min_separation_m"].items()) if v is not None)
        lines.append(
            f"| {r['scenario']} | {'on' if r['replanning'] else 'off'} | {r['run']} | {r['exit']} | {r['completed']} "
            f"| {_num(r['min_static_clearance_m'])} ({r['nearest_obstacle']}) | {seps or '-'} "
            f"| {_num(r['xtrack_p50_m'])} / {_num(r['xtrack_p95_m'])} "
            f"| {_num(r['climb_error_p50_m'])} / {_num(r['climb_error_p95_m'])} "
            f"| {r['replans']} ({r['replan_attempts']}) | {r['holds']} | {r['wall_s']:.0f} |")
    refs = sorted({r["reference"] for r in records})
    lines += ["", ("How each number is measured. Exit: `fuseplan fly`'s exit code (0 completed, 4 link/upload or "
              "departure refused, 5 not completed, 6 unsafe). Static clearance, traffic separation (per threat: "
              "centre distance − protected radius) and replans (made live; attempts: conflicts replanned) are "
              "flight.json's, from its own track (`track_source`: the simulator's truth, or the autopilot's "
              "GLOBAL_POSITION_INT against the scripted intruders); *kept* means ≥ d_coll (a flight that measured "
              "nothing did not keep it). Holds: `hold` events in events.jsonl. Cross-track: horizontal distance "
              "of each airborne `position` record of events.jsonl (the autopilot's GLOBAL_POSITION_INT, at most "
              "10 per wall second) to the route live at that time; climb error: its altitude minus the route's "
              "altitude at the nearest point (the same along-track distance), p50 / p95 of the absolute value. "
              f"Route live at a time: {_reference_text(refs)}. Measured from the first item reached at or after the "
              "route's start to the end of the flight: the take-off and the climb to the start, whose path the "
              "mission leaves to the autopilot, are not counted; holds (a loiter circle off the route) are.")]
    md = out / "flights.md"
    md.write_text("\n".join(lines) + "\n")
    return [md, out / "flights.csv", out / "flights_runs.csv", out / "flights.jsonl"]


def latency_rows(records: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per backend × scenario (replanning on), the replans made live pooled over the flights: their number, the
    median / p90 / max of conflict → live, the medians of planning and swap, and the partial writes."""
    rows = []
    for key in dict.fromkeys((r["backend"], r["scenario"]) for r in records if r["replanning"]):
        rs = [r for r in records if r["replanning"] and (r["backend"], r["scenario"]) == key]
        lat = np.array([v for r in rs for v in r.get("replan_latency_s") or []], dtype=float)
        if not lat.size:
            continue
        plan = np.array([v for r in rs for v in r.get("replan_plan_s") or [] if v is not None], dtype=float)
        swap = np.array([v for r in rs for v in r.get("replan_swap_s") or [] if v is not None], dtype=float)
        rows.append({"backend": key[0], "scenario": key[1], "n": int(lat.size), "median": float(np.median(lat)),
                     "p90": float(np.percentile(lat, 90)), "max": float(lat.max()),
                     "plan": float(np.median(plan)) if plan.size else math.nan,
                     "swap": float(np.median(swap)) if swap.size else math.nan,
                     "partial": sum(int(r.get("partial_writes") or 0) for r in rs)})
    return rows


def _reference_text(refs: Sequence[str]) -> str:
    text = {"live mission": "the last mission verified before it (events.jsonl `mission` records: the first upload "
                            "and each replan's), from the route's start",
            "planned trajectory": "PLAN.json's planned trajectory (the log had no `mission` record)"}
    return "; ".join(f"{text.get(r, r)}" for r in refs) or "none (nothing flown)"


def _num(v: Any) -> str:
    return f"{v:.1f}" if isinstance(v, (int, float)) else "-"
