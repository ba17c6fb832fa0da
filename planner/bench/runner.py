"""The bench runner: every (variant, run) of a bench on an executor (a local process pool or a dask cluster,
:mod:`planner.bench.executor`), each finished run appended at once as one JSON line to ``DIR/NAME.jsonl``, so an
interrupted bench resumes where it stopped, on any executor.

Run r of every variant plans with ``numpy.random.default_rng(seed_base + r)``; a run carries its scenario's text,
so it loads the same map wherever it runs; records are put back in (variant, run) order before anything is
summarised, so every number except the wall-clock times is the same, bit for bit, whatever the executor, the
number of workers or the order in which runs finished.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import functools
import hashlib
import json
import logging
import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from planner import kernel
from planner.bench.executor import ExecutorSpec, Failed, open_pool
from planner.distribution import shipped_scenarios
from planner.errors import FuseplanError
from planner.files import read_regular_file
from planner.world.config import PAPER_MODE  # noqa: F401 - the paper benches' first override, imported from here
from planner.world.scenario_text import ScenarioText, materialise

log = logging.getLogger(__name__)

SCENARIO_DIR = shipped_scenarios()
ROADMAP_MODE = "planner.roadmap.enabled=true"  # fuseplan's roadmap pipeline, the default (docs/method.md §15)
MAX_RECORDS_BYTES = 2**30  # a records file to resume from: 1e5 runs of a few kB each (a bench runs hundreds)


@dataclass(frozen=True)
class Variant:
    key: str  # "V1" …: the table's row id and the records' "variant"
    label: str  # what it is, e.g. "w/o spherical"
    overrides: tuple[str, ...] = ()  # scenario ``--set`` strings that make this variant
    scenario: Path | None = None  # this variant's scenario file, when it is not the bench's
    family: str | None = None  # a generated hard-map family instead: run r flies map seed seed_base + r
    budget_s: float | None = None  # wall-clock budget of each plan (None: the iteration budget alone)
    peer: str | None = None  # an OMPL peer planner instead of ours (planner.bench.peers), for budget_s


@dataclass(frozen=True)
class Bench:
    name: str
    description: str
    scenario: Path
    base_overrides: tuple[str, ...]  # the bench's budget; the user's --set come after, the variant's last
    variants: tuple[Variant, ...]
    default_runs: int
    # (output dir, records in (variant, run) order, the run settings) -> files written
    report: Callable[[Path, list[dict[str, Any]], BenchSettings], list[Path]]


@dataclass(frozen=True)
class BenchSettings:
    bench: Bench
    runs: int
    seed_base: int
    user_overrides: tuple[str, ...] = ()
    ran_on: str = ""  # the executor and its worker count, for the report ("" before the runs)

    def overrides_for(self, variant: Variant) -> tuple[str, ...]:
        return (*self.bench.base_overrides, *self.user_overrides, *variant.overrides)

    def scenario_for(self, variant: Variant) -> Path:
        return variant.scenario if variant.scenario is not None else self.bench.scenario

    def check(self, variant: Variant) -> None:
        """Load what the variant's runs load (its first generated map) and check the job's size, so bad input fails
        once, up front."""
        from planner.plan import problem_from_scenario
        from planner.workload import check_workload
        from planner.world.scenario import load_scenario

        path = generated_map(variant.family, self.seed_base) if variant.family else self.scenario_for(variant)
        sc = load_scenario(path, self.overrides_for(variant))
        if variant.peer is None:
            check_workload(problem_from_scenario(sc), sc.planner, budgeted=variant.budget_s is not None,
                           source=str(path))


@dataclass(frozen=True)
class RunSpec:
    scenario: str
    overrides: tuple[str, ...]
    variant: str
    run: int
    seed: int
    family: str | None = None
    budget_s: float | None = None
    peer: str | None = None
    source: ScenarioText | None = None  # the scenario's text, loaded in place of the file wherever the run is

    @property
    def fingerprint(self) -> str:
        """What decides the result (scenario file name, overrides, seed; map family, budget, peer): a resumed
        record must match it."""
        parts: list[Any] = [Path(self.scenario).name, list(self.overrides), self.seed]
        if self.family or self.budget_s is not None or self.peer:
            parts += [self.family, self.budget_s, self.peer]
        text = json.dumps(parts)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass
class BenchOutcome:
    records: list[dict[str, Any]]  # (variant, run) order
    reused: int  # runs found in the JSON-lines file
    computed: int  # runs planned now
    jsonl: Path = field(default_factory=Path)
    ran_on: str = ""  # the executor and its worker count ("" when every run was reused)


def specs_for(settings: BenchSettings) -> list[RunSpec]:
    b = settings.bench
    text = functools.cache(ScenarioText.read)
    return [RunSpec(str(settings.scenario_for(v)), settings.overrides_for(v), v.key, r, settings.seed_base + r,
                    v.family, v.budget_s, v.peer,
                    None if v.family else text(settings.scenario_for(v), settings.overrides_for(v)))
            for v in b.variants for r in range(settings.runs)]


_MAP_DIR: list[Path] = []  # this process's folder of generated maps


@functools.lru_cache(maxsize=64)
def hard_map(family: str, seed: int) -> Any:
    """Hard map ``family``/``seed`` (planner.bench.hardmaps.HardMap), generated once per process."""
    from planner.bench import hardmaps

    return hardmaps.generate(family, seed)


def generated_map(family: str, seed: int) -> Path:
    """The scenario file of hard map ``family``/``seed``, written once per process (with its DEM beside it, for
    the terrain families)."""
    import tempfile

    if not _MAP_DIR:
        _MAP_DIR.append(Path(tempfile.mkdtemp(prefix="fuseplan-maps-")))
    path = _MAP_DIR[0] / f"hardmap_{family}_{seed}.toml"
    if not path.exists():
        hard_map(family, seed).write(_MAP_DIR[0])
    return path


def _planted_length(spec: RunSpec) -> dict[str, Any]:
    """The planted route's length of a generated map's run, for the records."""
    if not spec.family:
        return {}
    route = hard_map(spec.family, spec.seed).planted
    return {"family": spec.family, "planted_length_m": float(np.linalg.norm(np.diff(route, axis=0), axis=1).sum())}


_WARM: set[Any] = set()  # what this process has warmed up


def warm_once(key: Any, problem: Any, settings: Any) -> None:
    """Before a process's first timed plan of ``key`` (scenario, overrides, kernel …): load (or compile) the
    kernels and import the planner's modules with a tiny search of the same settings on ``problem``, so that no
    run's time includes them. The tiny search leaves no state behind that a later plan reads."""
    from planner.plan import plan

    if key in _WARM:
        return
    kernel.warm_up(problem)
    small = dataclasses.replace(settings, pso=dataclasses.replace(settings.pso, n_pop=10, max_iter=2),
                                aco=dataclasses.replace(settings.aco, max_iter=2))
    plan(problem, small, np.random.default_rng(0))
    _WARM.add(key)


def run_one(spec: RunSpec) -> dict[str, Any]:
    """Plan once (in a worker process) and return a flat, JSON-ready record."""
    from planner.deadline import Deadline
    from planner.plan import json_safe, plan, problem_from_scenario, uses_roadmap
    from planner.world.scenario import load_scenario

    path: str | Path = spec.scenario
    extra: tuple[str, ...] = ()
    if spec.family:
        path = generated_map(spec.family, spec.seed)
    elif spec.source is not None:
        path, extra = materialise(spec.source)
    sc = load_scenario(path, (*spec.overrides, *extra))
    problem = problem_from_scenario(sc)
    if spec.peer:
        return json_safe(_run_peer(spec, problem))
    build_s = None
    if uses_roadmap(sc.planner):  # built once per map, before the clock
        from planner.search import roadmap

        build_s = roadmap.routes(problem, sc.planner.roadmap)[0].build_s  # builds (and caches) what plan uses
    warm_once((spec.scenario, spec.overrides), problem, sc.planner)
    res = plan(problem, sc.planner, np.random.default_rng(spec.seed), seed=spec.seed,
               deadline=Deadline.after(spec.budget_s))
    m = res.metrics(sc.hazard.d_safe)
    return json_safe({
        **_planted_length(spec), "roadmap_build_s": build_s,
        "variant": spec.variant, "run": spec.run, "seed": spec.seed, "fingerprint": spec.fingerprint,
        "status": res.status.value, "feasible": res.feasible, "cost": res.cost,
        "penalty": float(res.evaluation.penalty[0]), "length_m": m["length_m"], "smoothness": m["smoothness"],
        "time_s": m["plan_time_s"], "convergence_iteration": m["convergence_iteration"],
        "iterations": m["iterations"], "evaluations": m["evaluations"],
        "violations": sum(res.violations.values()) + sum(res.cost_violations.values()),
        "violations_by_category": {k: res.violations[k] + res.cost_violations.get(k, 0) for k in res.violations},
        "robustness": m["robustness"],
        "history": [float(h) for h in res.optimiser.history],
        "phases": {name: {"best_cost": ph.best_cost, "iterations": ph.iterations, "time_s": ph.time_s,
                          "evaluations": ph.evaluations}
                   for name, ph in (getattr(res.optimiser, "phases", None) or {}).items()},
    })


def _run_peer(spec: RunSpec, problem: Any) -> dict[str, Any]:
    """One OMPL peer run (planner.bench.peers): found, flyable by our checker, length, time."""
    from planner.bench import peers

    r = peers.solve(problem, spec.peer or "", spec.budget_s or 1.0, spec.seed)
    return {**_planted_length(spec), "variant": spec.variant, "run": spec.run, "seed": spec.seed,
            "fingerprint": spec.fingerprint, "status": r.status, "found": r.found, "feasible": r.flyable,
            "length_m": r.length_m if r.found else None, "time_s": r.time_s,
            "violations": sum(r.violations.values()) if r.violations else None}


def _variant_run(rec: dict[str, Any]) -> tuple[str, int]:
    return str(rec["variant"]), int(rec["run"])


def load_records(path: Path, key: Callable[[dict[str, Any]], Any] = _variant_run) -> dict[Any, dict[str, Any]]:
    """Records already in ``path`` by ``key`` (default (variant, run)); a line cut short by an interruption is
    skipped. A path that is not a regular file of at most MAX_RECORDS_BYTES is refused in one line."""
    if not path.exists():
        return {}
    out: dict[Any, dict[str, Any]] = {}
    text = read_regular_file(path, MAX_RECORDS_BYTES, "records").decode("utf-8", errors="replace")
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
            k = key(rec)
        except (ValueError, KeyError, TypeError):
            log.warning("%s:%d: not a bench record, skipped (an interrupted write?)", path, n)
            continue
        out[k] = rec
    return out


@contextlib.contextmanager
def appending(jsonl: Path) -> Iterator[TextIO]:
    """``jsonl`` open for appending records, a line cut short by an interruption first ended (so it does not
    swallow the next record)."""
    with jsonl.open("a+") as f:
        f.seek(0, 2)
        if f.tell() > 0:
            f.seek(f.tell() - 1)
            if f.read(1) != "\n":
                f.write("\n")
        yield f


Progress = Callable[[int, int, int], None]  # (runs finished, runs to do, of them failed)


def run_bench(settings: BenchSettings, out_dir: Path, executor: ExecutorSpec,
              progress: Progress | None = None) -> BenchOutcome:
    """Run what ``DIR/NAME.jsonl`` does not hold yet on ``executor``, appending each record as its run finishes."""
    return run_specs(specs_for(settings), out_dir / f"{settings.bench.name}.jsonl", executor, progress)


def run_specs(specs: Sequence[RunSpec], jsonl: Path, executor: ExecutorSpec,
              progress: Progress | None = None) -> BenchOutcome:
    """Run the specs ``jsonl`` does not hold yet (by (variant, run), made with the same settings), appending each
    record as its run finishes; a failed run is retried by the next invocation, after the others have finished."""
    have = load_records(jsonl)
    for s in specs:
        rec = have.get((s.variant, s.run))
        if rec is not None and rec.get("fingerprint") != s.fingerprint:
            raise FuseplanError(f"{jsonl}: {s.variant} run {s.run} was made with other settings (scenario, --set "
                                f"or seeds); delete the file or choose another -o to start afresh")
    todo = [s for s in specs if (s.variant, s.run) not in have]
    new: dict[tuple[str, int], dict[str, Any]] = {}
    ran_on = ""
    if todo:
        ran_on = _run_tasks(todo, jsonl, executor, new, progress)
    records = [have.get((s.variant, s.run)) or new[(s.variant, s.run)] for s in specs]
    return BenchOutcome(records, len(specs) - len(todo), len(todo), jsonl, ran_on)


def _run_tasks(todo: Sequence[RunSpec], jsonl: Path, executor: ExecutorSpec,
               new: dict[tuple[str, int], dict[str, Any]], progress: Progress | None) -> str:
    """Run ``todo`` on the executor; this process alone writes the file, one flushed line per finished run.
    Returns what ran them (executor, workers)."""
    failed: list[tuple[RunSpec, str]] = []
    with appending(jsonl) as f, open_pool(executor, len(todo)) as pool:
        for i, rec in pool.run(run_one, todo):
            spec = todo[i]
            if isinstance(rec, Failed):
                failed.append((spec, rec.error))
                log.warning("%s run %d (seed %d) failed: %s", spec.variant, spec.run, spec.seed, rec.error)
            else:
                f.write(json.dumps(rec, allow_nan=False) + "\n")
                f.flush()
                new[(spec.variant, spec.run)] = rec
            if progress is not None:
                progress(len(new) + len(failed), len(todo), len(failed))
    if failed:
        spec, error = failed[0]
        raise FuseplanError(f"{len(failed)} of {len(todo)} runs failed, the first {spec.variant} run {spec.run} "
                            f"(seed {spec.seed}): {error}; the {len(new)} finished are in {jsonl}: run the same "
                            f"command again to retry the failed ones")
    return pool.ran_on


def summarise(records: Sequence[dict[str, Any]], variants: Sequence[Variant], columns: Sequence[str],
              ) -> list[dict[str, Any]]:
    """Per variant: runs, mean and sample std of every column, success (feasible) rate."""
    rows = []
    for v in variants:
        rec = [r for r in records if r["variant"] == v.key]
        row: dict[str, Any] = {"variant": v.key, "label": v.label, "runs": len(rec)}
        for col in columns:
            x = np.array([r[col] for r in rec], dtype=float)
            row[f"{col}_mean"] = float(x.mean())
            row[f"{col}_std"] = float(x.std(ddof=1)) if len(x) > 1 else 0.0
        row["success_rate"] = float(np.mean([bool(r["feasible"]) for r in rec]))
        rows.append(row)
    return rows


# --- report pieces every bench uses ----------------------------------------------------------------------
def set_options(overrides: Sequence[str]) -> str:
    """The ``--set`` options that reproduce ``overrides``, each quoted for a shell, with a leading space each."""
    return "".join(f" --set '{o}'" for o in overrides)


def command_line(settings: BenchSettings) -> str:
    """The command that reproduces these results, in Markdown code quotes, the cost kernel they ran on (the
    numpy one when numba is missing or FUSEPLAN_KERNEL=numpy; times differ, docs/design.md) and the executor."""
    sets = set_options(settings.user_overrides)
    ran_on = f"; ran on {settings.ran_on}" if settings.ran_on else ""
    return (f"`fuseplan bench {settings.bench.name} --runs {settings.runs} --seed-base {settings.seed_base}{sets}` "
            f"(cost kernel: {kernel.chosen()}{ran_on})")


def settings_list(settings: BenchSettings) -> str:
    """The bench's own and the user's overrides, in the order they apply (later ones win)."""
    return ", ".join(f"`{o}`" for o in (*settings.bench.base_overrides, *settings.user_overrides))


def claims_table(verdicts: Sequence[tuple[str, str, str, str, bool | str]]) -> list[str]:
    """Markdown rows for (claim, paper, ours, rule, verdict); a bool verdict reads reproduced / not."""
    lines = ["| claim | paper | ours | rule | verdict |", "|---|---|---|---|---|"]
    for claim, paper, ours, rule, ok in verdicts:
        verdict = ok if isinstance(ok, str) else ("reproduced" if ok else "not reproduced")
        lines.append(f"| {claim} | {paper} | {ours} | {rule} | {verdict} |")
    return lines


def add_cost_comparison(rows: list[dict[str, Any]], records: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Add ``delta_cost_pct`` (mean cost vs the first row's) and ``p_ranksums`` (Wilcoxon rank-sum of the
    row's costs against the first row's; NaN for the first) to summarise() rows."""
    from scipy.stats import ranksums

    base = rows[0]

    def costs(variant: str) -> np.ndarray:
        return np.array([r["cost"] for r in records if r["variant"] == variant], dtype=float)

    ref = costs(base["variant"])
    for row in rows:
        row["delta_cost_pct"] = 100.0 * (row["cost_mean"] - base["cost_mean"]) / base["cost_mean"]
        row["p_ranksums"] = math.nan if row is base else float(ranksums(costs(row["variant"]), ref).pvalue)
    return rows


def write_csv(path: Path, rows: Sequence[dict[str, Any]], fields: Sequence[str]) -> None:
    """One CSV table with the given columns (extra keys in a row are left out)."""
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(fields), extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
