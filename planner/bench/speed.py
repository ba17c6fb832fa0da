"""``fuseplan bench speed``: how fast the planner is, in one run (issues 5, 16 and 35). Five parts:

- **headline**: the same plans on both cost kernels (``FUSEPLAN_KERNEL=compiled`` and ``=numpy``, set in the worker
  process before it plans; :func:`planner.kernel.chosen` reads it at each evaluation): a Table-6 SPSO run on
  ``rescue_static.toml`` (nPop 500 × 200 iterations, stagnation stop off: 100 500 evaluations) and the default plan
  (the paper's fusion, scenario as shipped) on ``large_obstacle_field.toml``; each repeated ``runs`` times (default
  5) with the same seed, one plan at a time by default (times of one core), median reported;
- **reference**: :mod:`planner.bench.reference_spso`, a plain vectorised numpy port of the original SPSO with the
  same swarm and iterations on the same cylinders, the naive speed reference ("a plain numpy port takes X s");
- **scaling**: one factor at a time around a base of nPop 250, MaxIt 100, 16 waypoints, 100 obstacles on
  ``large_obstacle_field.toml`` (nPop, MaxIt, waypoints, obstacle count), on the compiled kernel with its obstacle
  broad phase on and off (``FUSEPLAN_BROAD_PHASE``, set in the worker like the kernel) and on the numpy kernel;
  log–log slope per factor;
- **latency**: plans at the live replanner's budget (100 particles, 0.15 s, roadmap pipeline, the roadmap built
  before the clock) on ``rescue_dynamic`` and ``crossing_traffic`` with their threat picture, ``latency_seeds``
  seeds, with and without :func:`planner.bench.load.cpu_hog` (one busy process), reporting how far plan time runs
  over the budget (median, p99, max);
- **polygons**: the compiled cost of one swarm on a field of polygon prisms and on a field of cylinders of the same
  centres, radii and tops (:func:`obstacle_field`), unlimited and roofed: microseconds per path and their ratio.

Every plan is a record in ``DIR/speed.jsonl`` (appended as it finishes, so an interrupted run resumes) that names
the kernel it ran on (as :func:`planner.kernel.chosen` saw it in the worker) and the broad-phase setting. Writes
``speed.md`` (headline table first), ``speed.csv`` (summary rows), ``speed_runs.csv`` (every plan), ``speed.png``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from planner import kernel
from planner.bench import runner
from planner.bench.load import cpu_hog
from planner.bench.runner import PAPER_MODE, ROADMAP_MODE, SCENARIO_DIR, appending, load_records, write_csv
from planner.errors import FuseplanError
from planner.replan import BUDGET_S as REPLAN_BUDGET_S
from planner.replan import POPULATION as REPLAN_POP
from planner.replan import THREAT_MARGIN_M, replan_problem, scripted_picture
from planner.world.environment import Cylinders, Environment, Prisms

log = logging.getLogger(__name__)

KERNEL_ENV = kernel.ENV_VAR  # FUSEPLAN_KERNEL: compiled | numpy
BROAD_ENV = kernel.BROAD_ENV_VAR  # FUSEPLAN_BROAD_PHASE: on | off (default on), the compiled kernel's broad phase
PARTS = ("headline", "reference", "scaling", "latency", "polygons")
TABLE6 = (PAPER_MODE, 'planner.algorithm="spso"', "planner.pso.stagnation_iters=100000")  # n_pop/max_iter: defaults


@dataclass(frozen=True)
class Row:
    """A headline row: one plan, timed on both kernels."""

    key: str
    label: str
    scenario: str  # file in sitl_scenarios/
    overrides: tuple[str, ...] = ()


HEADLINE = (
    Row("spso_table6", "SPSO, Table 6 (nPop {n_pop} × {max_iter} iterations), rescue_static", "rescue_static.toml",
        TABLE6),
    Row("fusion_default", "default plan (fusion, as shipped), large_obstacle_field", "large_obstacle_field.toml"),
)
REFERENCE_ROW = HEADLINE[0]  # the reference runs on this row's scenario, with its swarm size and iterations
SCALING_SCENARIO = "large_obstacle_field.toml"
SCALING_SET = {"n_pop": "planner.pso.n_pop", "max_iter": "planner.pso.max_iter",
               "n_waypoints": "planner.pso.n_waypoints", "obstacles": "random_obstacles.count"}
LATENCY_SCENARIOS = ("rescue_dynamic.toml", "crossing_traffic.toml")
# the polygons part: a field of cylinders and one of polygon prisms on the same centres and radii, unlimited or
# roofed (tops / ceilings in the band), each scored by the compiled cost on one swarm many times
FIELD_KEYS = ("cylinders/unlimited", "prisms/unlimited", "cylinders/roofed", "prisms/roofed")


@dataclass(frozen=True)
class FieldSettings:
    """The polygons part's map and swarm: ``count`` obstacles of radius ``radius`` on a ``size`` m square map (the
    band 50–300 m, roofs 150–250 m), ``paths`` paths of ``waypoints`` interior points scored ``repeats`` times."""

    size: float = 3000.0
    count: int = 100
    radius: tuple[float, float] = (40.0, 120.0)
    vertices: tuple[int, int] = (5, 10)
    paths: int = 100
    waypoints: int = 16
    repeats: int = 200
    d_safe: float = 60.0
    d_coll: float = 15.0


@dataclass(frozen=True)
class SpeedSettings:
    """Everything a speed run depends on; :data:`FULL` is the default, :data:`QUICK` the ``--quick`` one."""

    runs: int = 5  # repeats of each headline row and of the reference (same seed; median reported)
    scaling_runs: int = 3  # seeds per scaling level and arm
    latency_seeds: int = 20  # seeds per latency scenario and load
    seed_base: int = 2000
    workers: int = 1  # plans at a time in the headline, reference and scaling parts (latency: always one)
    user_overrides: tuple[str, ...] = ()  # --set, after the bench's own, before a scaling level's
    parts: tuple[str, ...] = PARTS
    quick: bool = False
    budget_overrides: tuple[str, ...] = ()  # added to every headline row (--quick: smaller budgets)
    scaling_base: dict[str, int] = field(default_factory=lambda: {"n_pop": 250, "max_iter": 100, "n_waypoints": 16,
                                                                  "obstacles": 100})
    scaling_levels: dict[str, tuple[int, ...]] = field(default_factory=lambda: {
        "n_pop": (100, 250, 500, 1000), "max_iter": (50, 100, 200), "n_waypoints": (4, 8, 16),
        "obstacles": (25, 50, 100)})
    scaling_arms: tuple[tuple[str, str], ...] = (("compiled", "on"), ("compiled", "off"), ("numpy", "on"))
    budget_s: float = REPLAN_BUDGET_S  # the companion's live replan budget (ReplanConfig.budget_s)
    hog: int = 1  # busy processes beside the measured plan in the loaded half of the latency part
    polygon_field: FieldSettings = FieldSettings()

    def command(self) -> str:
        """The command line that reproduces this run."""
        parts = ["fuseplan bench speed", "--quick" if self.quick else "", f"--runs {self.runs}",
                 f"--seed-base {self.seed_base}", f"--workers {self.workers}",
                 f"--latency-seeds {self.latency_seeds}",
                 f"--parts {','.join(self.parts)}" if self.parts != PARTS else ""]
        parts += [f"--set '{o}'" for o in self.user_overrides]
        return " ".join(p for p in parts if p)


FULL = SpeedSettings()
QUICK = SpeedSettings(
    runs=2, scaling_runs=1, latency_seeds=3, quick=True,
    budget_overrides=("planner.pso.n_pop=60", "planner.pso.max_iter=20", "planner.aco.max_iter=5"),
    scaling_base={"n_pop": 40, "max_iter": 10, "n_waypoints": 8, "obstacles": 50},
    scaling_levels={"n_pop": (20, 40), "max_iter": (5, 10), "n_waypoints": (4, 8), "obstacles": (25, 50)},
    polygon_field=FieldSettings(repeats=20))


@dataclass(frozen=True)
class Job:
    """One timed plan (or one reference run) and the environment its worker plans in."""

    part: str
    key: str  # headline row, scaling level "factor=level", latency scenario stem, "reference"
    scenario: str
    overrides: tuple[str, ...]
    seed: int
    repeat: int
    kernel: str  # compiled | numpy | reference
    broad_phase: str  # on | off
    load: int = 0  # busy processes beside it
    budget_s: float | None = None
    polygon_field: FieldSettings | None = None  # the polygons part's map and swarm

    @property
    def id(self) -> str:
        return f"{self.part}/{self.key}/{self.kernel}/broad-{self.broad_phase}/load{self.load}/r{self.repeat}"

    @property
    def fingerprint(self) -> str:
        """What decides the result: a resumed record must match it."""
        d = dataclasses.asdict(self)
        d["scenario"] = Path(self.scenario).name
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


# --- what runs -----------------------------------------------------------------------------------------------------
def jobs(s: SpeedSettings) -> list[tuple[str, int, list[Job]]]:
    """(part, load, jobs) in the order they run; a part's jobs are interleaved (repeat, row, kernel) so a slow
    spell of the machine falls on every row and kernel alike."""
    out: list[tuple[str, int, list[Job]]] = []
    if "headline" in s.parts:
        out.append(("headline", 0, [
            Job("headline", row.key, str(SCENARIO_DIR / row.scenario),
                (*row.overrides, *s.budget_overrides, *s.user_overrides), s.seed_base, r, k, "on")
            for r in range(s.runs) for row in HEADLINE for k in kernel.KERNELS]))
    if "reference" in s.parts:
        row = REFERENCE_ROW
        out.append(("reference", 0, [
            Job("reference", "reference", str(SCENARIO_DIR / row.scenario),
                (*row.overrides, *s.budget_overrides, *s.user_overrides), s.seed_base, r, "reference", "on")
            for r in range(s.runs)]))
    if "scaling" in s.parts:
        base = (PAPER_MODE, 'planner.algorithm="spso"', "planner.pso.stagnation_iters=100000",
                *(f"{SCALING_SET[k]}={v}" for k, v in s.scaling_base.items()), *s.user_overrides)
        out.append(("scaling", 0, [
            Job("scaling", f"{f}={x}", str(SCENARIO_DIR / SCALING_SCENARIO), (*base, f"{SCALING_SET[f]}={x}"),
                s.seed_base + r, r, k, bp)
            for r in range(s.scaling_runs) for f, levels in s.scaling_levels.items() for x in levels
            for k, bp in s.scaling_arms]))
    if "polygons" in s.parts:
        out.append(("polygons", 0, [
            Job("polygons", key, "", (), s.seed_base, r, "compiled", "on", polygon_field=s.polygon_field)
            for r in range(s.runs) for key in FIELD_KEYS]))
    if "latency" in s.parts:
        sets = (ROADMAP_MODE, f"planner.pso.n_pop={REPLAN_POP}", *s.user_overrides)
        for load in (0, s.hog):
            out.append(("latency", load, [
                Job("latency", Path(name).stem, str(SCENARIO_DIR / name), sets, s.seed_base + i, i, "compiled", "on",
                    load, s.budget_s)
                for i in range(s.latency_seeds) for name in LATENCY_SCENARIOS]))
    return out


PLANNER_DIR = Path(__file__).resolve().parent.parent


def source_hash() -> str:
    """A hash of the planner's Python sources as they are on disk now (``planner/**/*.py``): records made while
    someone edits the planner say so by differing."""
    h = hashlib.sha256()
    for f in sorted(PLANNER_DIR.rglob("*.py")):
        h.update(f.relative_to(PLANNER_DIR).as_posix().encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:12]


def revision() -> str:
    """``git`` HEAD of the checkout and whether planner/ has uncommitted changes (or "unknown")."""
    import subprocess

    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=PLANNER_DIR, capture_output=True,
                              text=True, timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "."], cwd=PLANNER_DIR, capture_output=True,
                               text=True, timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return f"{head}" + (" with uncommitted changes in planner/" if dirty else "")




def _set_environment(job: Job) -> None:
    if job.kernel in kernel.KERNELS:
        os.environ[KERNEL_ENV] = job.kernel
    os.environ[BROAD_ENV] = job.broad_phase


def run_job(job: Job) -> dict[str, Any]:
    """Plan once in this worker with the job's kernel and broad phase; a flat, JSON-ready record."""
    from planner.deadline import Deadline
    from planner.plan import json_safe, plan, problem_from_scenario, uses_roadmap
    from planner.world.scenario import load_scenario

    _set_environment(job)
    if job.part == "polygons":
        return json_safe(_run_field(job, job.polygon_field or FieldSettings()))
    sc = load_scenario(job.scenario, job.overrides)
    env = sc.environment
    common = {
        "id": job.id, "part": job.part, "key": job.key, "repeat": job.repeat, "seed": job.seed, "load": job.load,
        "fingerprint": job.fingerprint, "scenario": Path(job.scenario).name, "broad_phase": os.environ[BROAD_ENV],
        "source": source_hash(), "loadavg_1m": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
        "n_pop": sc.planner.pso.n_pop, "max_iter": sc.planner.pso.max_iter,
        "obstacles": len(env.cylinders) + len(env.spheres) + len(env.radars),
    }
    if job.kernel == "reference":
        return json_safe({**common, **_run_reference(sc, job.seed)})
    # a latency job plans against the picture a live replan sees: the scripted threats and every intruder as an
    # ADS-B track, all grown by the replanner's margin (planner.replan, as the companion builds it)
    problem = (replan_problem(sc, sc.start, sc.goal, scripted_picture(sc), 0.0, threat_margin=THREAT_MARGIN_M)
               if job.part == "latency" else problem_from_scenario(sc))
    settings = sc.planner
    if uses_roadmap(settings):  # built once per map before the clock, as the companion's worker does at warm-up
        from planner.search import roadmap

        roadmap.routes(problem, settings.roadmap)
    # the first plan in a process loads the compiled code and the modules: not what is measured
    runner.warm_once((job.scenario, job.overrides, job.kernel, job.broad_phase), problem, settings)
    res = plan(problem, settings, np.random.default_rng(job.seed), seed=job.seed,
               deadline=Deadline.after(job.budget_s))
    return json_safe({
        **common, "kernel": kernel.chosen(), "n_waypoints": settings.pso.n_waypoints,
        "algorithm": settings.algorithm, "status": res.status.value, "feasible": res.feasible, "cost": res.cost,
        "time_s": res.plan_time_s, "search_s": res.optimiser.time_s, "iterations": res.optimiser.iterations,
        "evaluations": res.optimiser.evaluations, "stop_reason": res.optimiser.stop_reason,
        "budget_s": job.budget_s, "overrun_s": None if job.budget_s is None else res.plan_time_s - job.budget_s,
    })


def obstacle_field(kind: str, roofed: bool, seed: int, f: FieldSettings) -> Environment:
    """``f.count`` cylinders, or polygon prisms on the same centres, radii and tops: each polygon's vertices at
    0.6–1 × the radius from the centre, at jittered even angles (star-shaped, mostly concave), its disc the
    cylinder's or smaller. Roofed: tops / ceilings 150–250 m above home; else unlimited."""
    rng = np.random.default_rng(seed)
    c = rng.uniform(200.0, f.size - 200.0, (f.count, 2))
    r = rng.uniform(*f.radius, f.count)
    top = rng.uniform(150.0, 250.0, f.count) if roofed else np.full(f.count, np.inf)
    if kind == "cylinders":
        return Environment(f.size, f.size, 50.0, 300.0, cylinders=Cylinders(c[:, 0], c[:, 1], r, top,
                                                                            np.zeros(f.count)))
    polygons = []
    for k in range(f.count):  # set-up, once per field
        n = int(rng.integers(f.vertices[0], f.vertices[1] + 1))
        ang = (np.arange(n) + rng.uniform(-0.3, 0.3, n)) * 2.0 * np.pi / n
        rad = r[k] * rng.uniform(0.6, 1.0, n)
        polygons.append(c[k] + rad[:, None] * np.column_stack([np.cos(ang), np.sin(ang)]))
    return Environment(f.size, f.size, 50.0, 300.0,
                       prisms=Prisms.from_polygons(polygons, np.full(f.count, -np.inf), top))


def _run_field(job: Job, f: FieldSettings) -> dict[str, Any]:
    """Score one swarm ``f.repeats`` times on the job's field with the compiled cost: microseconds per path."""
    import time

    from planner.problem import PlanningProblem
    from planner.world.config import HazardConfig, VehicleLimits

    kind, tops = job.key.split("/")
    env = obstacle_field(kind, tops == "roofed", job.seed, f)
    start, goal = np.array([100.0, 100.0, 150.0]), np.array([f.size - 100.0, f.size - 100.0, 150.0])
    problem = PlanningProblem(env, start, goal, VehicleLimits(), HazardConfig(d_safe=f.d_safe, d_coll=f.d_coll))
    rng = np.random.default_rng(job.seed + 1)  # the same swarm on every field
    line = np.linspace(start, goal, f.waypoints + 2)
    paths = line[None] + rng.normal(0.0, 0.05 * problem.direct_distance, (f.paths, f.waypoints + 2, 3)) \
        * np.array([1.0, 1.0, 0.3])
    paths[:, 0], paths[:, -1] = start, goal
    ev = problem.evaluate(paths)  # compiles or loads the kernel: not what is measured
    t0 = time.perf_counter()
    for _ in range(f.repeats):  # the timed loop: one swarm, scored again and again
        problem.evaluate(paths)
    elapsed = time.perf_counter() - t0
    return {"id": job.id, "part": job.part, "key": job.key, "repeat": job.repeat, "seed": job.seed, "load": 0,
            "fingerprint": job.fingerprint, "scenario": "", "broad_phase": os.environ[BROAD_ENV],
            "source": source_hash(), "loadavg_1m": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
            "kernel": kernel.chosen(), "obstacles": f.count, "paths": f.paths, "waypoints": f.waypoints,
            "evaluations": f.repeats * f.paths, "time_s": elapsed, "us_per_path": 1e6 * elapsed / (f.repeats * f.paths),
            "collisions": int(ev.violations["collision"].sum()), "hazard": float(ev.terms["J2"].sum()),
            "cost": float(ev.total.sum())}


def _run_reference(sc: Any, seed: int) -> dict[str, Any]:
    from planner.bench import reference_spso as ref

    cfg = ref.ReferenceConfig(n_pop=sc.planner.pso.n_pop, max_iter=sc.planner.pso.max_iter)
    world = ref.ReferenceWorld.of(sc)
    ref.solve(world, dataclasses.replace(cfg, n_pop=10, max_iter=2), np.random.default_rng(0))  # warm, as above
    r = ref.solve(world, cfg, np.random.default_rng(seed))
    return {"kernel": "reference", "n_waypoints": cfg.n_waypoints, "algorithm": "reference SPSO",
            "status": "exact" if r.violations == 0 else "infeasible", "feasible": r.violations == 0,
            "cost": r.cost, "time_s": r.time_s, "search_s": r.time_s, "iterations": cfg.max_iter,
            "evaluations": r.evaluations, "stop_reason": "max_iterations", "budget_s": None, "overrun_s": None}


def run(s: SpeedSettings, out_dir: Path, progress: Callable[[int, int], None] | None = None,
        ) -> tuple[list[dict[str, Any]], int]:
    """Run what ``DIR/speed.jsonl`` does not hold yet; returns (records in job order, how many were reused)."""
    groups = jobs(s)
    jsonl = out_dir / "speed.jsonl"
    have = load_records(jsonl, key=lambda rec: str(rec["id"]))
    every = [j for _, _, js in groups for j in js]
    for j in every:
        if j.id in have and have[j.id].get("fingerprint") != j.fingerprint:
            raise FuseplanError(f"{jsonl}: {j.id} was made with other settings (--quick, --set, --seed-base); "
                                "delete the file or choose another -o to start afresh")
    total = sum(j.id not in have for j in every)
    done = 0
    new: dict[str, dict[str, Any]] = {}
    with appending(jsonl) as f, ProcessPoolExecutor(max_workers=max(1, s.workers)) as pool:
        for part, load, js in groups:
            todo = [j for j in js if j.id not in have]
            if not todo:
                continue
            width = 1 if part == "latency" else max(1, s.workers)
            with cpu_hog(load) if load else nullcontext():
                for rec in _execute(pool, todo, width):
                    f.write(json.dumps(rec, allow_nan=False) + "\n")
                    f.flush()
                    new[rec["id"]] = rec
                    done += 1
                    if progress is not None:
                        progress(done, total)
    return [have.get(j.id) or new[j.id] for j in every], len(every) - total



def _execute(pool: ProcessPoolExecutor, todo: Sequence[Job], width: int) -> Iterator[dict[str, Any]]:
    """Run ``todo`` on ``pool`` with at most ``width`` in flight, yielding records as they finish."""
    queue = list(todo)
    pending: dict[Future, Job] = {}
    while queue or pending:
        while queue and len(pending) < width:
            j = queue.pop(0)
            pending[pool.submit(run_job, j)] = j
        finished, _ = wait(pending, return_when=FIRST_COMPLETED)
        for fut in finished:
            j = pending.pop(fut)
            try:
                yield fut.result()
            except FuseplanError:
                raise
            except Exception as e:  # a failed plan stops the bench, saying which and why
                raise FuseplanError(f"{j.id} (seed {j.seed}) failed: {type(e).__name__}: {e}") from e


# --- summaries -----------------------------------------------------------------------------------------------------
def _times(recs: Sequence[dict[str, Any]], col: str = "time_s") -> np.ndarray:
    return np.array([r[col] for r in recs], dtype=float)


def _pick(records: Sequence[dict[str, Any]], **want: Any) -> list[dict[str, Any]]:
    return [r for r in records if all(r.get(k) == v for k, v in want.items())]


def _stats(recs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    t = _times(recs)
    costs = {r["cost"] for r in recs}
    return {"runs": len(recs), "time_median_s": float(np.median(t)), "time_min_s": float(t.min()),
            "time_max_s": float(t.max()), "evaluations": recs[0]["evaluations"],
            "cost": float(np.median([r["cost"] for r in recs])),
            "feasible_share": float(np.mean([bool(r["feasible"]) for r in recs])),
            "costs_equal": len(costs) == 1}


def headline_rows(records: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per headline row and kernel: median time of the repeats, and numpy ÷ compiled; then the reference."""
    out = []
    for row in HEADLINE:
        by = {k: _pick(records, part="headline", key=row.key, kernel=k) for k in kernel.KERNELS}
        if not all(by.values()):
            continue
        st = {k: _stats(v) for k, v in by.items()}
        out.append({"part": "headline", "key": row.key, "label": row.label.format(**by["compiled"][0]),
                    **{f"{k}_{c}": v for k in kernel.KERNELS for c, v in st[k].items()},
                    "ratio": st["numpy"]["time_median_s"] / st["compiled"]["time_median_s"],
                    "same_cost_both_kernels": len({r["cost"] for v in by.values() for r in v}) == 1})
    ref = _pick(records, part="reference")
    if ref:
        st = _stats(ref)
        out.append({"part": "reference", "key": "reference", "label": "plain-numpy SPSO reference "
                    f"(planner/bench/reference_spso.py, nPop {ref[0]['n_pop']} × {ref[0]['max_iter']}, "
                    f"{ref[0]['n_waypoints']} waypoints), {ref[0]['scenario'].removesuffix('.toml')}",
                    **{f"reference_{c}": v for c, v in st.items()}})
    return out


def _split(key: str) -> tuple[str, int]:
    factor, level = key.split("=")
    return factor, int(level)


def _arm(kernel_name: str, broad: str) -> str:
    return f"{kernel_name}, broad phase {broad}" if kernel_name == "compiled" else kernel_name


def scaling_rows(records: Sequence[dict[str, Any]], s: SpeedSettings) -> list[dict[str, Any]]:
    """Per factor, level and arm: median time over the seeds."""
    out = []
    for factor, levels in s.scaling_levels.items():
        for x in levels:
            for k, bp in s.scaling_arms:
                rec = _pick(records, part="scaling", key=f"{factor}={x}", kernel=k, broad_phase=bp)
                if rec:
                    out.append({"part": "scaling", "key": f"{factor}={x}", "factor": factor, "level": x,
                                "kernel": k, "broad_phase": bp, "arm": _arm(k, bp), **_stats(rec),
                                "us_per_eval": 1e6 * float(np.median(_times(rec))) / rec[0]["evaluations"]})
    return out


def slopes(rows: Sequence[dict[str, Any]], s: SpeedSettings) -> dict[tuple[str, str], float]:
    """Per (arm, factor): least-squares slope of log(median time) against log(level)."""
    out = {}
    for k, bp in s.scaling_arms:
        for factor in s.scaling_levels:
            rr = [r for r in rows if r["factor"] == factor and r["kernel"] == k and r["broad_phase"] == bp]
            if len(rr) >= 2:
                out[(_arm(k, bp), factor)] = float(np.polyfit(np.log([r["level"] for r in rr]),
                                                              np.log([r["time_median_s"] for r in rr]), 1)[0])
    return out


def latency_rows(records: Sequence[dict[str, Any]], s: SpeedSettings) -> list[dict[str, Any]]:
    """Per scenario and load: plan time and its overrun over the budget (time − budget), median / p99 / max."""
    out = []
    for name in LATENCY_SCENARIOS:
        for load in sorted({0, s.hog}):
            rec = _pick(records, part="latency", key=Path(name).stem, load=load)
            if not rec:
                continue
            t, over = _times(rec), _times(rec, "overrun_s")
            out.append({"part": "latency", "key": Path(name).stem, "load": load, "runs": len(rec),
                        "budget_s": rec[0]["budget_s"], "time_median_s": float(np.median(t)),
                        "time_min_s": float(t.min()),
                        "time_p99_s": float(np.percentile(t, 99)), "time_max_s": float(t.max()),
                        "overrun_median_s": float(np.median(over)), "overrun_p99_s": float(np.percentile(over, 99)),
                        "overrun_max_s": float(over.max()), "over_budget": int((over > 0).sum()),
                        "feasible_share": float(np.mean([bool(r["feasible"]) for r in rec])),
                        "statuses": ", ".join(f"{k} {v}" for k, v in sorted(Counter(r["status"] for r in rec).items())),
                        })
    return out


def polygon_rows(records: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per field (unlimited, roofed): median microseconds per path of the cylinders and of the prisms, and their
    ratio (prisms ÷ cylinders)."""
    out = []
    for tops in ("unlimited", "roofed"):
        cyl = _pick(records, part="polygons", key=f"cylinders/{tops}")
        pri = _pick(records, part="polygons", key=f"prisms/{tops}")
        if cyl and pri:
            c, p = (float(np.median(_times(r, "us_per_path"))) for r in (cyl, pri))
            out.append({"part": "polygons", "key": tops, "runs": len(cyl), "obstacles": cyl[0]["obstacles"],
                        "paths": cyl[0]["paths"], "waypoints": cyl[0]["waypoints"],
                        "evaluations": cyl[0]["evaluations"], "cylinders_us": c, "prisms_us": p, "ratio": p / c,
                        "cylinder_collisions": cyl[0]["collisions"], "prism_collisions": pri[0]["collisions"]})
    return out


def _polygons_md(rows: Sequence[dict[str, Any]], s: SpeedSettings) -> list[str]:
    f = s.polygon_field
    lines = ["## Polygon prisms against cylinders", "",
             f"The compiled cost of one swarm ({f.paths} paths of {f.waypoints} interior waypoints, the straight line "
             f"bent by noise) scored {f.repeats} times on a {f.size:g} m field of {f.count} obstacles: cylinders of "
             f"radius {f.radius[0]:g}–{f.radius[1]:g} m, or polygon prisms on the same centres with "
             f"{f.vertices[0]}–{f.vertices[1]} vertices at 0.6–1 × that radius (star-shaped, mostly concave); "
             "unlimited, or roofed at 150–250 m (tops, ceilings). Median of "
             f"{s.runs} runs, microseconds per path evaluation; ratio = prisms ÷ cylinders.", "",
             "| field | cylinders (µs/path) | prisms (µs/path) | ratio | collisions in the swarm (cyl / prism) |",
             "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['key']} | {r['cylinders_us']:.2f} | {r['prisms_us']:.2f} | {r['ratio']:.2f}× "
                     f"| {r['cylinder_collisions']} / {r['prism_collisions']} |")
    return [*lines, ""]


def reproducible(records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Same seed and settings → the same cost. ``same_kernel``: bit for bit across repeats and broad-phase settings
    of one kernel (headline, scaling, reference); ``across_kernels``: the largest relative difference of one seed's
    final cost between the compiled and the numpy kernel (their costs of one path agree to 1e-9, not bit for bit,
    and a whole search can amplify the last bits)."""
    same: dict[tuple[Any, ...], set[float]] = {}
    seed_costs: dict[tuple[Any, ...], list[float]] = {}
    for r in records:
        if r["part"] in ("headline", "scaling", "reference"):
            same.setdefault((r["part"], r["key"], r["seed"], r["kernel"]), set()).add(r["cost"])
            seed_costs.setdefault((r["part"], r["key"], r["seed"]), []).append(r["cost"])
    rel = [(max(c) - min(c)) / max(abs(min(c)), 1e-300) for c in seed_costs.values()]
    return {"same_kernel": all(len(v) == 1 for v in same.values()), "groups": len(same),
            "across_kernels": max(rel, default=0.0)}



# --- report --------------------------------------------------------------------------------------------------------
def report(out_dir: Path, records: list[dict[str, Any]], s: SpeedSettings) -> list[Path]:
    head, scal, lat = headline_rows(records), scaling_rows(records, s), latency_rows(records, s)
    paths = [out_dir / "speed.md", out_dir / "speed.csv", out_dir / "speed_runs.csv", out_dir / "speed.png"]
    paths[0].write_text(markdown(records, s))
    write_csv(paths[1], csv_rows(head, scal, lat, polygon_rows(records)), CSV_COLUMNS)
    run_fields: list[str] = []
    for r in records:
        run_fields += [k for k in r if k not in run_fields]
    write_csv(paths[2], records, run_fields)
    plot(paths[3], scal, lat, s)
    return paths


CSV_COLUMNS = ("part", "key", "label", "kernel", "broad_phase", "load", "runs", "evaluations", "time_median_s",
               "time_min_s", "time_p99_s", "time_max_s", "ratio", "budget_s", "overrun_median_s", "overrun_p99_s",
               "overrun_max_s", "over_budget", "cost", "feasible_share")


def csv_rows(head: Sequence[dict[str, Any]], scal: Sequence[dict[str, Any]], lat: Sequence[dict[str, Any]],
             poly: Sequence[dict[str, Any]] = ()) -> list[dict[str, Any]]:
    """One row per (part, row, kernel / arm, load): the headline's ``ratio`` is numpy ÷ compiled (on both of its
    rows), the reference's its time ÷ the compiled SPSO row's, a polygon field's prisms ÷ cylinders (its time: the
    prisms' per path)."""
    out: list[dict[str, Any]] = []
    spso = next((r for r in head if r["key"] == REFERENCE_ROW.key), None)
    for r in head:
        for k in (kernel.KERNELS if r["part"] == "headline" else ("reference",)):
            row = {c.removeprefix(f"{k}_"): v for c, v in r.items() if c.startswith(f"{k}_")}
            ratio = r.get("ratio") if r["part"] == "headline" else (
                None if spso is None else row["time_median_s"] / spso["compiled_time_median_s"])
            out.append({**row, "part": r["part"], "key": r["key"], "label": r["label"], "kernel": k,
                        "broad_phase": "on", "load": 0, "ratio": ratio})
    out += [{**r, "label": f"{r['factor']} {r['level']}, {r['arm']}", "load": 0} for r in scal]
    out += [{**r, "label": f"{r['key']}, {'cpu_hog(' + str(r['load']) + ')' if r['load'] else 'idle'}",
             "kernel": "compiled", "broad_phase": "on"} for r in lat]
    out += [{"part": "polygons", "key": r["key"], "label": f"{r['key']} field, prisms ÷ cylinders",
             "kernel": "compiled", "broad_phase": "on", "load": 0, "runs": r["runs"], "evaluations": r["evaluations"],
             "time_median_s": 1e-6 * r["prisms_us"], "ratio": r["ratio"]} for r in poly]
    return out


def _s(x: float) -> str:
    return f"{x:.3f} s" if x < 10 else f"{x:.1f} s"


def _spread(row: dict[str, Any], prefix: str) -> str:
    """Median time and, in brackets, the fastest and slowest run."""
    return (f"{_s(row[prefix + 'time_median_s'])} ({row[prefix + 'time_min_s']:.3f}–"
            f"{row[prefix + 'time_max_s']:.3f})")


def _machine(records: Sequence[dict[str, Any]], s: SpeedSettings) -> str:
    cores = os.cpu_count() or 1
    loads = [r["loadavg_1m"] for r in records if r.get("loadavg_1m") is not None]
    shared = (f" The machine is shared: its 1-minute load average, read before each plan, was {min(loads):.1f}–"
              f"{max(loads):.1f} (median {float(np.median(loads)):.1f}; this run alone adds about 1, 2 with the hog)."
              if loads else "")
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else cores
    how = ("serially, one plan at a time (`--workers 1`): the times are those of one core" if s.workers == 1
           else f"{s.workers} plans at a time (`--workers {s.workers}`): they share the cores")
    return (f"Machine: {cores} cores ({usable} usable by this process). Headline, reference and scaling plans ran "
            f"{how}; the latency plans ran one at a time, beside {s.hog} busy process(es) in the loaded half." + shared)


def markdown(records: Sequence[dict[str, Any]], s: SpeedSettings) -> str:
    head, scal, lat = headline_rows(records), scaling_rows(records, s), latency_rows(records, s)
    kernels_seen = sorted({r["kernel"] for r in records})
    sources = sorted({r["source"] for r in records if r.get("source")})
    code = f"Code: {revision()}, planner source hash {', '.join(sources) or 'unknown'}."
    if len(sources) > 1:
        code += (f" **The planner's source changed during this run ({len(sources)} versions): the numbers mix "
                 "versions.**")
    lines = ["# Planning speed: both cost kernels, a plain-numpy SPSO, scaling, replan latency under load", "",
             f"`{s.command()}` (records name their kernel: {', '.join(kernels_seen)})", "", _machine(records, s),
             code, ""]
    if s.quick:
        lines += ["**Quick run** (`--quick`): reduced budgets and levels, for a smoke test; not the numbers to quote.",
                  ""]
    if head:
        lines += _headline_md(head, s)
    if scal:
        lines += _scaling_md(scal, s)
    if lat:
        lines += _latency_md(lat, s)
    poly = polygon_rows(records)
    if poly:
        lines += _polygons_md(poly, s)
    rep = reproducible(records)
    lines += ["## Reproducibility", "",
              "Only the times vary between runs. Same seed, settings and kernel → the same cost, bit for bit, across "
              "repeats and broad-phase settings: " + ("yes" if rep["same_kernel"] else "**NO**")
              + f" ({rep['groups']} groups of one seed and kernel). Between the two kernels one seed's final cost "
              f"differs by at most {rep['across_kernels']:.1e} relative: the kernels score one path alike to 1e-9 but "
              "not bit for bit (the compiled one adds in other orders and takes its arctangents, sines and cosines "
              "from polynomials within a rounding of libm's), and a search is chaotic: a difference in the last bits "
              "can send one seed's swarm elsewhere. The tests compare the kernels over 20 seeds statistically.", ""]
    return "\n".join(lines)


def _headline_md(head: Sequence[dict[str, Any]], s: SpeedSettings) -> list[str]:
    lines = ["## Headline", "",
             f"Median wall time of {s.runs} runs of the same plan (same seed {s.seed_base}), each kernel chosen in the "
             "worker with `FUSEPLAN_KERNEL`; the plan time is the whole `plan()` call (search, smoothing, checks). "
             "In brackets: the fastest and the slowest run. Ratio: numpy ÷ compiled (medians).", "",
             "| row | compiled | numpy | ratio | evaluations | cost (same on both kernels) |",
             "|---|---|---|---|---|---|"]
    ours = None
    for r in head:
        if r["part"] == "headline":
            lines.append(f"| {r['label']} | {_spread(r, 'compiled_')} | {_spread(r, 'numpy_')} "
                         f"| {r['ratio']:.1f}× | {r['compiled_evaluations']} | {r['compiled_cost']:.1f} "
                         f"({'yes' if r['same_cost_both_kernels'] else 'no'}) |")
            if r["key"] == REFERENCE_ROW.key:
                ours = r
        else:
            t = r["reference_time_median_s"]
            rat = "" if ours is None else (f"{t / ours['compiled_time_median_s']:.1f}× ours compiled, "
                                           f"{t / ours['numpy_time_median_s']:.1f}× ours numpy")
            ok = "clear of the cylinders" if r["reference_feasible_share"] == 1 else "NOT always clear"
            lines.append(f"| {r['label']} | — | {_spread(r, 'reference_')} | {rat} | {r['reference_evaluations']} "
                         f"| {r['reference_cost']:.1f} (its own cost; {ok}) |")
    ref = [r for r in head if r["part"] == "reference"]
    if ref and ours is not None:
        t = ref[0]["reference_time_median_s"]
        lines += ["", f"A plain numpy port of SPSO (planner/bench/reference_spso.py: the original's cost — length, "
                  "cylinder threat with safe/collision distances, altitude band, turn and climb angles — with a flat "
                  f"penalty) takes {_s(t)} for the same swarm and iterations on the same cylinders; ours takes "
                  f"{_s(ours['compiled_time_median_s'])} on the compiled kernel and {_s(ours['numpy_time_median_s'])} "
                  "on the numpy one, evaluating a cost that also checks the flown Bézier curve (its deviation, "
                  "curvature and climb), the map bounds and the destination term, with depth-scaled penalties. The "
                  "costs are not comparable numbers (different terms and weights); the work per evaluation is "
                  "larger in ours."]
    return [*lines, ""]


def _scaling_md(scal: Sequence[dict[str, Any]], s: SpeedSettings) -> list[str]:
    arms = [_arm(k, bp) for k, bp in s.scaling_arms]
    base = ", ".join(f"{k} {v}" for k, v in s.scaling_base.items())
    lines = ["## Scaling with particles, iterations, waypoints and obstacles", "",
             f"SPSO on `{SCALING_SCENARIO}`, stagnation stop off (evaluations = nPop × (MaxIt + 1)), one factor at a "
             f"time around {base}; median of {s.scaling_runs} seeds ({s.seed_base}…). Broad phase: "
             f"`{BROAD_ENV}=on|off`, set in the worker; it only concerns the compiled kernel (the numpy arm ran "
             "with it on); the two give the same costs bit for bit.", "",
             "| factor | level | evaluations | " + " | ".join(f"{a} (s)" for a in arms)
             + " | broad off ÷ on | numpy ÷ compiled (on) |", "|---|---|---|" + "---|" * (len(arms) + 2)]
    by = {(r["key"], r["arm"]): r for r in scal}
    for factor, levels in s.scaling_levels.items():
        for x in levels:
            key = f"{factor}={x}"
            cells = [by.get((key, a)) for a in arms]
            first = next(c for c in cells if c is not None)
            on, off, npy = (by.get((key, a)) for a in (_arm("compiled", "on"), _arm("compiled", "off"), "numpy"))
            cols = ["—" if c is None else f"{c['time_median_s']:.3f}" for c in cells]
            cols.append(f"{off['time_median_s'] / on['time_median_s']:.2f}" if on and off else "—")
            cols.append(f"{npy['time_median_s'] / on['time_median_s']:.1f}×" if on and npy else "—")
            base = " (base)" if x == s.scaling_base[factor] else ""
            lines.append(f"| {factor} | {x}{base} | {first['evaluations']} | " + " | ".join(cols) + " |")
    sl = slopes(scal, s)
    lines += ["", "Log–log slope of median time against each factor (1 = proportional):", "",
              "| arm | " + " | ".join(s.scaling_levels) + " |", "|---|" + "---|" * len(s.scaling_levels)]
    for a in arms:
        lines.append(f"| {a} | " + " | ".join(f"{sl[(a, f)]:.2f}" if (a, f) in sl else "—"
                                               for f in s.scaling_levels) + " |")
    return [*lines, ""]


def _latency_md(lat: Sequence[dict[str, Any]], s: SpeedSettings) -> list[str]:
    lines = ["## Replan latency under load", "",
             f"Plans at the live replanner's budget: {REPLAN_POP} particles, `budget_s` {s.budget_s:g} s (the "
             "companion's ReplanConfig defaults), the roadmap pipeline with the roadmap built before the clock, "
             "start → goal at mission time 0 against the scenario's threat picture (scripted threats, and each "
             f"intruder as an ADS-B track, all grown by {THREAT_MARGIN_M:g} m), no warm start; "
             f"{s.latency_seeds} seeds each, one plan at a time, without and with `cpu_hog({s.hog})` (busy "
             "process(es) beside the planner). Plan time is the whole `plan()` call; overrun = plan time − budget "
             f"(negative: within it). p99 of {s.latency_seeds} values is interpolated near the maximum.", "",
             "| scenario | load | plans | plan time median / p99 / max (s) | overrun median / p99 / max (s) "
             "| over budget | feasible | statuses |", "|---|---|---|---|---|---|---|---|"]
    for r in lat:
        lines.append(f"| {r['key']} | {'cpu_hog(' + str(r['load']) + ')' if r['load'] else 'idle'} | {r['runs']} "
                     f"| {r['time_median_s']:.3f} / {r['time_p99_s']:.3f} / {r['time_max_s']:.3f} "
                     f"| {r['overrun_median_s']:+.3f} / {r['overrun_p99_s']:+.3f} / {r['overrun_max_s']:+.3f} "
                     f"| {r['over_budget']} of {r['runs']} | {100 * r['feasible_share']:.0f} % | {r['statuses']} |")
    return [*lines, ""]


def plot(path: Path, scal: Sequence[dict[str, Any]], lat: Sequence[dict[str, Any]], s: SpeedSettings) -> None:
    """Median time against each factor on log–log axes, one line per arm (kernel, broad phase); plan times of the
    latency part against the budget."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    factors = list(s.scaling_levels)
    fig, axes = plt.subplots(1, len(factors) + 1, figsize=(4.2 * (len(factors) + 1), 4))
    styles = {("compiled", "on"): ("C0", "-", "o"), ("compiled", "off"): ("C1", "--", "s"),
              ("numpy", "on"): ("C3", "-", "^"), ("numpy", "off"): ("C2", "--", "v")}
    for ax, factor in zip(axes, factors):
        for k, bp in s.scaling_arms:
            rr = [r for r in scal if r["factor"] == factor and r["kernel"] == k and r["broad_phase"] == bp]
            if not rr:
                continue
            c, ls, m = styles.get((k, bp), ("C7", ":", "x"))
            ax.plot([r["level"] for r in rr], [r["time_median_s"] for r in rr], color=c, ls=ls, marker=m,
                    label=_arm(k, bp))
        ax.set_xlabel(factor)
        if not ax.get_lines():
            ax.text(0.5, 0.5, "scaling not run", ha="center", va="center", transform=ax.transAxes)
            continue
        ax.set_xscale("log")
        ax.set_yscale("log")
        levels = s.scaling_levels[factor]
        ax.set_xticks(levels, [str(x) for x in levels])
        ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
        ax.set_ylabel("planning time (s), median")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    ax = axes[-1]
    if lat:
        labels = [f"{r['key'].replace('_', chr(10))}\n{'cpu_hog' if r['load'] else 'idle'}" for r in lat]
        vals = [[r["time_median_s"], r["time_p99_s"], r["time_max_s"]] for r in lat]
        x = np.arange(len(lat))
        for i, (name, c) in enumerate((("median", "C0"), ("p99", "C1"), ("max", "C3"))):
            ax.bar(x + (i - 1) * 0.27, [v[i] for v in vals], width=0.27, color=c, label=name)
        ax.axhline(s.budget_s, color="k", ls="--", lw=1, label=f"budget {s.budget_s:g} s")
        ax.set_xticks(x, labels, fontsize=7)
        ax.set_ylabel("replan plan time (s)")
        ax.legend(fontsize=8)
    else:
        ax.text(0.5, 0.5, "latency not run", ha="center", va="center", transform=ax.transAxes)
    ax.set_title("replan latency")
    fig.suptitle("fuseplan bench speed: scaling by kernel and broad phase; replan latency")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def settings_from(quick: bool, runs: int | None, seed_base: int, workers: int | None, overrides: Sequence[str],
                  parts: str | None, latency_seeds: int | None) -> SpeedSettings:
    """The run's settings from the command line; bad values raise FuseplanError."""
    s = QUICK if quick else FULL
    chosen = tuple(p.strip() for p in (parts or ",".join(PARTS)).split(",") if p.strip())
    bad = [p for p in chosen if p not in PARTS]
    if bad or not chosen:
        raise FuseplanError(f"--parts: expected a comma-separated subset of {','.join(PARTS)}, got {parts!r}")
    s = dataclasses.replace(s, runs=s.runs if runs is None else runs, seed_base=seed_base,
                            workers=1 if workers is None else workers, user_overrides=tuple(overrides),
                            parts=tuple(p for p in PARTS if p in chosen),
                            latency_seeds=s.latency_seeds if latency_seeds is None else latency_seeds)
    if s.runs < 1 or s.workers < 1 or s.seed_base < 0 or s.latency_seeds < 1:
        raise FuseplanError("--runs, --workers and --latency-seeds must be >= 1 and --seed-base >= 0")
    return s


def check(s: SpeedSettings) -> None:
    """Load every scenario with the overrides its jobs use and check the jobs' size, so bad input fails once, up
    front."""
    from planner.plan import problem_from_scenario
    from planner.workload import check_workload
    from planner.world.scenario import load_scenario

    seen = set()
    for _, _, js in jobs(s):
        for j in js:
            if j.part != "polygons" and (j.scenario, j.overrides, j.budget_s) not in seen:
                seen.add((j.scenario, j.overrides, j.budget_s))
                sc = load_scenario(j.scenario, j.overrides)
                check_workload(problem_from_scenario(sc), sc.planner, budgeted=j.budget_s is not None,
                               source=str(j.scenario))


def n_jobs(s: SpeedSettings) -> int:
    return sum(len(js) for _, _, js in jobs(s))


BENCHES: tuple = ()  # ``fuseplan bench speed`` is wired in planner.cli (its parts are not one Bench's variants)
