"""The planner's subcommands of ``fuseplan``: plan, compare, bench (the paper's experiments).

:mod:`companion.cli` assembles them with the companion's (export, fly, sim, demo) into the one command line, so
this layer never imports the companion. User mistakes raise :class:`FuseplanError` (one line, exit 2); an
infeasible plan exits 3; success exits 0.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import typing
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from planner import console
from planner.errors import FuseplanError
from planner.world.config import ALGORITHM_NAMES, PAPER_MODE, ACOConfig

EXIT_OK, EXIT_BAD_INPUT, EXIT_INFEASIBLE = 0, 2, 3
ACO_INITS: tuple[str, ...] = typing.get_args(typing.get_type_hints(ACOConfig)["init"])
T = typing.TypeVar("T")


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Every option's default in its help, unless the help already says it or there is nothing to show (a flag,
    no value, an empty list)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        none = action.default is None or isinstance(action.default, bool) or action.default in ([], argparse.SUPPRESS)
        if none or "default" in text.lower() or not action.option_strings:
            return text
        return super()._get_help_string(action)


def verbosity_options(top: bool = False) -> argparse.ArgumentParser:
    """``-v`` and ``-q`` as a parent parser: on the top parser (defaults False) and on every subcommand (no
    default, so that ``fuseplan -v fly ...`` is not undone by the subcommand's own parse)."""
    p = argparse.ArgumentParser(add_help=False)
    default = False if top else argparse.SUPPRESS
    p.add_argument("-v", "--verbose", action="store_true", default=default, help="debug logging on stderr")
    p.add_argument("-q", "--quiet", action="store_true", default=default,
                   help="no progress output: results, warnings and errors only")
    return p


def add_command(sub: argparse._SubParsersAction, name: str, help: str, run: Callable[[argparse.Namespace], int],
                ) -> argparse.ArgumentParser:
    """A subcommand with ``-v``/``-q`` and defaults shown in its help; ``main`` calls ``run(parsed args)``."""
    p = sub.add_parser(name, help=help, description=help, parents=[verbosity_options()],
                       formatter_class=HelpFormatter)
    p.set_defaults(func=run)
    return p


def options_from(cls: type[T], ns: argparse.Namespace, **given: typing.Any) -> T:
    """A command's options dataclass from the parsed ``ns``: each field from the attribute of its name (a field
    the parser lacks fails here, loudly), except those ``given``."""
    fields = [f.name for f in dataclasses.fields(cls) if f.name not in given]  # type: ignore[arg-type]  # cls is a dataclass type; a TypeVar bound cannot say so
    return cls(**{name: getattr(ns, name) for name in fields}, **given)


def command(cls: type[T], cmd: Callable[[T], int]) -> Callable[[argparse.Namespace], int]:
    """``cmd`` run on its options object, built from the parsed arguments (the one place they are read)."""
    return lambda ns: cmd(cls.from_args(ns))  # type: ignore[attr-defined]  # every options class has from_args; no Protocol for classmethods


def make_output_dir(path: Path) -> None:
    """Create an output directory (and parents); a user's error message, not a traceback, if it cannot be."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise FuseplanError(f"{path}: cannot create the output directory: {e.strerror or e}") from e


def add_paper_option(parser: argparse.ArgumentParser) -> None:
    """``--paper``: plan in paper mode, the paper's planners as published (no roadmap pipeline)."""
    parser.add_argument("--paper", action="store_true",
                        help="paper mode: the paper's planners as published, without the roadmap pipeline "
                             f"(--set {PAPER_MODE}; fly: the live replans too; export: when it plans); the default "
                             "is the roadmap pipeline")


def mode_overrides(paper: bool) -> list[str]:
    """The overrides that ``--paper`` stands for (none without it)."""
    return [PAPER_MODE] if paper else []


def add_source_options(parser: argparse.ArgumentParser) -> None:
    """``--zones``, ``--base``, ``--fence``, ``--rally``: what a mission or a scenario is planned with besides
    itself (docs/scenario_format.md, "Missions and zones from ground stations")."""
    parser.add_argument("--zones", action="append", default=[], type=Path, metavar="FILE",
                        help="add the no-fly zones of a zones file: our GeoJSON (Polygon, MultiPolygon, or Point "
                             "with radius_m; floor and ceiling with their reference), OpenAIP airspace or ED-269 UAS "
                             "geographical zones, told apart by their structure (docs/imports.md); repeatable")
    parser.add_argument("--base", type=Path, metavar="SCENARIO.toml",
                        help="a mission's vehicle, altitude band, clearances and planner settings from this "
                             "scenario (default: the band around the mission's heights)")
    parser.add_argument("--fence", type=Path, metavar="FILE",
                        help="a Mission Planner fence file for a .waypoints mission")
    parser.add_argument("--rally", type=Path, metavar="FILE",
                        help="a Mission Planner rally file for a .waypoints mission")


@dataclass(frozen=True)
class SourceArgs:
    """``--zones``, ``--base``, ``--fence``, ``--rally`` (:func:`add_source_options`)."""

    zones: tuple[Path, ...] = ()
    base: Path | None = None
    fence: Path | None = None
    rally: Path | None = None

    @classmethod
    def from_args(cls, ns: argparse.Namespace) -> SourceArgs:
        return cls(tuple(ns.zones), ns.base, ns.fence, ns.rally)

    def given(self) -> bool:
        return bool(self.zones) or any(v is not None for v in (self.base, self.fence, self.rally))

    def scenario(self, source: Path, beside: Path | None) -> Path:
        """The scenario file to load for ``source`` with these options (planner.world.sources); a PLAN.json is its
        own source and takes none."""
        from planner.world.sources import derived_scenario

        if source.suffix.lower() == ".json":
            if self.given():
                raise FuseplanError(f"{source}: a PLAN.json was planned with its zones: --zones, --base, --fence and "
                                    "--rally are for scenarios and missions")
            return source
        return derived_scenario(source, self.zones, self.base, self.fence, self.rally, beside)


@dataclass(frozen=True)
class PlanArgs:
    """``fuseplan plan``."""

    scenario: Path
    algorithm: str | None = None
    paper: bool = False
    aco_init: str | None = None
    seed: int | None = None
    overrides: tuple[str, ...] = ()
    output: Path | None = None
    plot: Path | None = None
    quiet: bool = False
    sources: SourceArgs = SourceArgs()

    @classmethod
    def from_args(cls, ns: argparse.Namespace) -> PlanArgs:
        return options_from(cls, ns, overrides=tuple(ns.overrides), sources=SourceArgs.from_args(ns))


@dataclass(frozen=True)
class ExecutorArgs:
    """``--workers``, ``--executor``, ``--scheduler`` (compare and bench)."""

    workers: int | None = None
    executor: str = "local"
    scheduler: str | None = None

    @classmethod
    def from_args(cls, ns: argparse.Namespace) -> ExecutorArgs:
        return options_from(cls, ns)


@dataclass(frozen=True)
class CompareArgs:
    """``fuseplan compare``."""

    scenario: Path
    runs: int
    seed: int
    algorithms: str
    overrides: tuple[str, ...]
    output: Path
    quiet: bool
    executor: ExecutorArgs

    @classmethod
    def from_args(cls, ns: argparse.Namespace) -> CompareArgs:
        return options_from(cls, ns, overrides=tuple(ns.overrides), executor=ExecutorArgs.from_args(ns))


@dataclass(frozen=True)
class BenchArgs:
    """``fuseplan bench NAME`` (the companion's benches extend it)."""

    name: str
    runs: int | None
    seed_base: int
    overrides: tuple[str, ...]
    output: Path
    quiet: bool
    quick: bool
    parts: str | None
    latency_seeds: int | None
    executor: ExecutorArgs

    @classmethod
    def from_args(cls, ns: argparse.Namespace) -> BenchArgs:
        return options_from(cls, ns, overrides=tuple(ns.overrides), executor=ExecutorArgs.from_args(ns))


def add_commands(sub: argparse._SubParsersAction) -> dict[str, argparse.ArgumentParser]:
    """Register plan, compare and bench on ``sub``; returns their parsers by name (the companion adds options and
    may run them its own way: ``set_defaults(func=...)`` again)."""
    pl = add_command(sub, "plan", "plan a route for a scenario and write PLAN.json", command(PlanArgs, cmd_plan))
    pl.add_argument("scenario", type=Path, help="scenario TOML file (see docs/scenario_format.md), or a ground "
                    "station's mission: QGroundControl .plan, Mission Planner .waypoints")
    pl.add_argument("--algorithm", choices=ALGORITHM_NAMES, default=None,
                    help="optimiser (default: the scenario's planner.algorithm, else fusion)")
    add_paper_option(pl)
    pl.add_argument("--aco-init", choices=ACO_INITS, default=None,
                    help="fusion: ACO pheromone initialisation (default: the scenario's, else gkdm)")
    pl.add_argument("--seed", type=int, default=None, help="random seed (default: the scenario's)")
    add_set_option(pl, "override a scenario value, e.g. --set planner.pso.n_pop=100 (repeatable)")
    pl.add_argument("-o", "--output", type=Path, help="write the plan here: PLAN.json, or, named *.plan, a "
                    "QGroundControl plan of the safe route keeping a mission's fence and rally points")
    add_source_options(pl)
    pl.add_argument("--plot", type=Path, help="write a PNG of the route and the convergence curve")
    cp = add_command(sub, "compare", "run every algorithm N times on a scenario and tabulate the results",
                     command(CompareArgs, cmd_compare))
    cp.add_argument("scenario", type=Path, help="scenario TOML file")
    cp.add_argument("--runs", type=int, default=10, help="runs per algorithm")
    cp.add_argument("--seed", type=int, default=1, help="run r uses seed SEED + r")
    cp.add_argument("--algorithms", default=",".join(ALGORITHM_NAMES), help="comma-separated subset")
    cp.add_argument("--workers", type=int, default=None,
                    help="local processes or dask-local workers (default: CPU count, at most 8)")
    add_executor_options(cp)
    add_set_option(cp, "override a scenario value for every run (repeatable)")
    cp.add_argument("-o", "--output", type=Path, default=Path("compare"),
                    help="directory for compare.jsonl (records, resumable), compare.md, compare.csv, "
                    "compare_runs.csv, compare.png")
    bn = add_command(sub, "bench", "reproduce one of the paper's experiments (e.g. ablation) and report it",
                     command(BenchArgs, cmd_bench))
    bn.add_argument("name", help="which bench (e.g. ablation)")
    bn.add_argument("--runs", type=int, default=None,
                    help="runs per variant (default: the bench's, 30; speed: repeats of each headline row, 5)")
    bn.add_argument("--workers", type=int, default=None,
                    help="local processes or dask-local workers (default: CPU count, at most 8; speed: 1, one "
                    "plan at a time)")
    add_executor_options(bn)
    bn.add_argument("--seed-base", type=int, default=2000, help="run r uses seed SEED_BASE + r")
    add_set_option(bn, "override a scenario value for every variant (repeatable)")
    bn.add_argument("-o", "--output", type=Path, default=Path("bench-results"),
                    help="directory for NAME.jsonl (records, resumable), NAME.md, NAME.csv, PNGs")
    bn.add_argument("--quick", action="store_true",
                    help="bench speed only: reduced budgets, levels and seeds (a smoke test, about a minute)")
    bn.add_argument("--parts", default=None, metavar="LIST",
                    help="bench speed only: comma-separated subset of headline,reference,scaling,latency,polygons "
                    "(default: all)")
    bn.add_argument("--latency-seeds", type=int, default=None, metavar="N",
                    help="bench speed only: seeds per scenario and load in the latency part (default 20)")
    return {"plan": pl, "compare": cp, "bench": bn}


def add_set_option(parser: argparse.ArgumentParser, help: str) -> None:
    """``--set SECTION.KEY=VALUE`` (repeatable), collected in ``overrides``."""
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help=help)


def add_executor_options(parser: argparse.ArgumentParser) -> None:
    from planner.bench.executor import EXECUTORS

    parser.add_argument("--executor", choices=EXECUTORS, default="local",
                        help="where the runs execute: local (a process pool, the default), dask (an existing "
                        "dask.distributed cluster, with --scheduler) or dask-local (a dask LocalCluster here); dask "
                        "needs the [cluster] extra")
    parser.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                        help="--executor dask: the scheduler's address (as `dask scheduler` prints it)")


def executor_from(opts: ExecutorArgs) -> typing.Any:
    """The executor the options choose (planner.bench.executor.ExecutorSpec), checked: a mistake is one line."""
    from planner.bench.executor import ExecutorSpec

    spec = ExecutorSpec(opts.executor, opts.workers, opts.scheduler)
    spec.check()
    return spec


def cmd_plan(args: PlanArgs, announce_output: bool = True) -> int:
    """``fuseplan plan`` (``announce_output`` False: the caller says what it wrote)."""
    from planner.legs import check_legs_workload, plan_scenario
    from planner.plan import plan_to_json, problem_from_scenario
    from planner.world.scenario import load_scenario

    overrides = list(args.overrides) + mode_overrides(args.paper)
    if args.algorithm:
        overrides.append(f'planner.algorithm="{args.algorithm}"')
    if args.seed is not None:
        overrides.append(f"planner.seed={args.seed}")
    if args.aco_init:
        overrides.append(f'planner.aco.init="{args.aco_init}"')
    scenario = load_scenario(args.scenario, overrides)
    if args.plot is not None and args.plot.suffix.lower() != ".png":
        raise FuseplanError(f"{args.plot}: --plot writes a PNG; name the file *.png")
    for out in (args.output, args.plot):  # fail before a long search, not after it
        check_writable(out)
    settings = scenario.planner
    problem = problem_from_scenario(scenario)
    # before the "planning" line: one line
    check_legs_workload(problem, scenario.vias, settings, source=str(args.scenario))
    if not args.quiet:
        print(f"planning {scenario.name} with {settings.algorithm}, seed {settings.seed}, "
              f"{settings.pso.n_pop} particles × {settings.pso.max_iter} iterations", file=sys.stderr)
    with console.iteration_progress(args.quiet) as show:
        result = plan_scenario(scenario, settings, np.random.default_rng(settings.seed), seed=settings.seed,
                               progress=show)
    doc = plan_to_json(result, scenario)
    m = doc["metrics"]
    through = np.vstack([scenario.start, scenario.vias, scenario.goal])
    direct = float(np.linalg.norm(np.diff(through, axis=0), axis=1).sum())
    viol = ", ".join(f"{k} {v}" for k, v in doc["violations"].items())
    extra = {k: v for k, v in doc["cost_violations"].items() if v}
    if extra:
        viol += " (cost terms on the waypoint path: " + ", ".join(f"{k} {v}" for k, v in extra.items()) + ")"
    print(f"{scenario.name}: {result.algorithm} seed {result.seed} -> {result.status.value}")
    clearance = m["min_clearance_m"]
    print(f"  cost      {result.cost:.1f}  (penalty {doc['cost_terms']['penalty']:.1f})")
    print(f"  length    {m['length_m']:.1f} m  ({m['length_m'] / direct:.3f} x direct {direct:.1f} m"
          + (f" through {len(scenario.vias)} vias" if len(scenario.vias) else "") + "), "
          f"smoothness {m['smoothness']:.2f} rad, min clearance "
          + ("n/a (no obstacles)" if clearance is None else f"{clearance:.1f} m"))
    print(f"  violations {viol}")
    print(f"  time      {m['plan_time_s']:.2f} s, {m['iterations']} iterations "
          f"({result.optimiser.stop_reason}), converged at iteration {m['convergence_iteration']}")
    if result.legs:
        print("  legs      " + ", ".join(f"{r.status.value} {r.cost:.1f} ({r.iterations} it, {r.time_s:.2f} s)"
                                        for r in result.legs) + " (the whole route checked as one)")
    if "phases" in doc:
        ph = dict(doc["phases"])
        winner = ph.pop("winner")
        road = ph.pop("roadmap", None)
        if road is not None:
            no_route = road["stop_reason"].startswith("no route")
            print(f"  roadmap   {'infeasible: ' if no_route and not result.feasible else ''}{road['stop_reason']} "
                  f"({road['time_s']:.2f} s{', then the paper fusion' if no_route else ''})")
        names = {"pso": "SPSO", "colony": "roadmap colony", "pso2": "SPSO (colony's corridor)", "aco": "ACO",
                 "paper": "then the paper fusion"}
        print("  phases    " + " -> ".join(
            f"{names.get(k, k)} " + ("n/a" if v["best_cost"] is None else f"{v['best_cost']:.1f}")
            + f" ({v['iterations']} it, {v['time_s']:.2f} s)" for k, v in ph.items() if "/" not in k)
              + f"; winner {winner}")
    if args.output:
        write_text(args.output, json.dumps(doc, indent=1, allow_nan=False) + "\n")
        if announce_output:  # plan -o SAFE.plan: the caller says what it wrote
            print(f"  wrote {args.output}")
    if args.plot:
        from planner.plot import plot_plan

        try:
            plot_plan(args.plot, scenario.environment, result.waypoints, result.trajectory.points,
                      result.optimiser.history, f"{scenario.name}: {result.algorithm} ({result.status.value})")
        except OSError as e:
            raise FuseplanError(f"{args.plot}: cannot write plot: {e.strerror or e}") from e
        print(f"  wrote {args.plot}")
    return EXIT_OK if result.feasible else EXIT_INFEASIBLE


def cmd_compare(args: CompareArgs) -> int:
    import dataclasses

    from planner.bench import compare
    from planner.bench.runner import set_options
    from planner.plan import problem_from_scenario
    from planner.workload import check_workload
    from planner.world.scenario import load_scenario

    if args.runs < 1:
        raise FuseplanError("--runs must be >= 1")
    executor = executor_from(args.executor)
    if args.seed < 0:
        raise FuseplanError("--seed must be >= 0")
    try:
        algorithms = compare.check_algorithms([a.strip() for a in args.algorithms.split(",") if a.strip()])
    except ValueError as e:
        raise FuseplanError(str(e)) from e
    scenario = load_scenario(args.scenario, list(args.overrides))  # bad input fails here, once, not in every worker
    for name in algorithms:  # and so does a job too large for the machine
        check_workload(problem_from_scenario(scenario), dataclasses.replace(scenario.planner, algorithm=name),
                       source=str(args.scenario))
    make_output_dir(args.output)  # and an unusable output directory before the runs, not after them
    if not args.quiet:
        print(f"comparing {', '.join(algorithms)} on {args.scenario.name}: {args.runs} runs each, "
              f"seeds {args.seed}..{args.seed + args.runs - 1}, on {executor.describe()}", file=sys.stderr)
    specs = compare.specs_for(str(args.scenario), list(args.overrides), algorithms, args.runs, args.seed)
    jsonl = args.output / "compare.jsonl"
    try:
        with console.run_progress("runs", args.quiet) as progress:
            records, outcome = compare.run_all(specs, jsonl, executor, progress)
    except KeyboardInterrupt:
        return _interrupted(jsonl, "runs")
    if not args.quiet:  # stdout is the table's, for a pipe
        print(f"{outcome.computed} runs computed, {outcome.reused} reused from {jsonl}"
              + (f"; on {outcome.ran_on}" if outcome.ran_on else ""), file=sys.stderr)
    rows = compare.summarise(records, algorithms)
    console.show_markdown(compare.format_table(rows))
    header = (f"`fuseplan compare {args.scenario} --runs {args.runs} --seed {args.seed} --algorithms "
              f"{','.join(algorithms)}{set_options(args.overrides)}`"
              + (f" (ran on {outcome.ran_on})" if outcome.ran_on else ""))
    try:
        files = compare.write_outputs(args.output, "compare", records, rows, header)
    except OSError as e:
        raise FuseplanError(f"{args.output}: cannot write results: {e.strerror or e}") from e
    print("wrote " + ", ".join(str(f) for f in files))
    return EXIT_OK


def cmd_bench(args: BenchArgs, other_benches: tuple[str, ...] = ()) -> int:
    """Run one of the planner's benches (``other_benches``: names the caller handles itself, for the message)."""
    import dataclasses
    import time

    from planner.bench import BENCHES
    from planner.bench.runner import BenchSettings, run_bench

    if args.name == "speed":
        return cmd_bench_speed(args)
    bench = BENCHES.get(args.name)
    if bench is None:
        raise FuseplanError(f"unknown bench {args.name!r}; choose from "
                            f"{', '.join(sorted([*BENCHES, 'speed', *other_benches]))}")
    runs = bench.default_runs if args.runs is None else args.runs
    workers = args.executor.workers
    if runs < 1 or (workers is not None and workers < 1) or args.seed_base < 0:
        raise FuseplanError("--runs and --workers must be >= 1 and --seed-base >= 0")
    executor = executor_from(args.executor)
    settings = BenchSettings(bench, runs, args.seed_base, tuple(args.overrides))
    for v in bench.variants:  # bad input fails here, once, not in every worker
        settings.check(v)
    make_output_dir(args.output)
    if not args.quiet:
        print(f"bench {bench.name}: {bench.description}; {len(bench.variants)} variants × {runs} runs, seeds "
              f"{args.seed_base}..{args.seed_base + runs - 1}, on {executor.describe()}", file=sys.stderr)
    t0 = time.perf_counter()
    try:
        with console.run_progress("runs", args.quiet) as progress:
            outcome = run_bench(settings, args.output, executor, progress)
    except KeyboardInterrupt:
        return _interrupted(args.output / f"{bench.name}.jsonl", "runs")
    wall = time.perf_counter() - t0
    print(f"{outcome.computed} runs computed, {outcome.reused} reused from {outcome.jsonl}; {wall:.1f} s"
          + (f" on {outcome.ran_on}" if outcome.ran_on else ""))
    settings = dataclasses.replace(settings, ran_on=outcome.ran_on)
    return _report(args.output, bench.name, lambda: bench.report(args.output, outcome.records, settings))


def local_only(executor: ExecutorArgs, what: str) -> None:
    """``what`` (a timing bench) runs on this machine: any other executor is a user's mistake."""
    if executor.executor != "local" or executor.scheduler:
        raise FuseplanError(f"{what} times plans on this machine and runs on --executor local only")


def cmd_bench_speed(args: BenchArgs) -> int:
    """``fuseplan bench speed``: both cost kernels, the plain-numpy reference, scaling, replan latency under load
    (:mod:`planner.bench.speed`). --runs: repeats of each headline row (default 5); --workers: plans at a time
    (default 1, the times of one core)."""
    import time

    from planner.bench import speed

    local_only(args.executor, "bench speed")
    s = speed.settings_from(args.quick, args.runs, args.seed_base, args.executor.workers, list(args.overrides),
                            args.parts, args.latency_seeds)
    speed.check(s)  # bad input fails here, once, not in every worker
    make_output_dir(args.output)
    if not args.quiet:
        print(f"bench speed: {', '.join(s.parts)}; {speed.n_jobs(s)} plans, headline × {s.runs} (median), "
              f"{s.workers} at a time{' (quick)' if s.quick else ''}", file=sys.stderr)
    t0 = time.perf_counter()
    try:
        with console.run_progress("plans", args.quiet) as progress:
            records, reused = speed.run(s, args.output, progress)
    except KeyboardInterrupt:
        return _interrupted(args.output / "speed.jsonl", "plans")
    print(f"{len(records) - reused} plans computed, {reused} reused from {args.output / 'speed.jsonl'}; "
          f"{time.perf_counter() - t0:.1f} s")
    return _report(args.output, "speed", lambda: speed.report(args.output, records, s))


def _interrupted(jsonl: Path, what: str) -> int:
    """Ctrl-C during a bench: say where the finished work is and that the same command resumes it."""
    print(f"fuseplan: interrupted; finished {what} are in {jsonl}; run the same command again to resume",
          file=sys.stderr)
    return 130


def _report(output: Path, name: str, write: typing.Callable[[], list[Path]]) -> int:
    """Write a bench's report files, show ``NAME.md`` and list what was written."""
    try:
        files = write()
    except OSError as e:
        raise FuseplanError(f"{output}: cannot write results: {e.strerror or e}") from e
    console.show_markdown((output / f"{name}.md").read_text())
    print("wrote " + ", ".join(str(f) for f in files))
    return EXIT_OK


def check_writable(path: Path | None) -> None:
    if path is None:
        return
    parent = path.resolve().parent
    if not parent.is_dir():
        raise FuseplanError(f"{path}: directory {parent} does not exist")
    if path.is_dir():
        raise FuseplanError(f"{path}: is a directory")


def write_text(path: Path, text: str) -> None:
    try:
        path.write_text(text)
    except OSError as e:
        raise FuseplanError(f"{path}: cannot write: {e.strerror or e}") from e
