"""The ``fuseplan`` command line: subcommands plan and demo (fly, sim, export, bench arrive with their issues).

User mistakes print one line and exit 2; an infeasible plan exits 3; success exits 0.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import typing
from pathlib import Path

import numpy as np

from planner.config import ALGORITHM_NAMES, ACOConfig
from planner.errors import FuseplanError

EXIT_OK, EXIT_BAD_INPUT, EXIT_INFEASIBLE = 0, 2, 3
ACO_INITS: tuple[str, ...] = typing.get_args(typing.get_type_hints(ACOConfig)["init"])


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="fuseplan", description="Plan safe 3-D UAV routes and fly them over MAVLink.")
    p.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = p.add_subparsers(dest="command", required=True)
    pl = sub.add_parser("plan", help="plan a route for a scenario and write PLAN.json")
    pl.add_argument("scenario", type=Path, help="scenario TOML file (see docs/scenario_format.md)")
    pl.add_argument("--algorithm", choices=ALGORITHM_NAMES, default=None,
                    help="optimiser (default: the scenario's planner.algorithm, else fusion)")
    pl.add_argument("--aco-init", choices=ACO_INITS, default=None,
                    help="fusion: ACO pheromone initialisation (default gkdm)")
    pl.add_argument("--seed", type=int, default=None, help="random seed (default: the scenario's)")
    pl.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="override a scenario value, e.g. --set planner.pso.n_pop=100 (repeatable)")
    pl.add_argument("-o", "--output", type=Path, help="write the plan as JSON here")
    pl.add_argument("--plot", type=Path, help="write a PNG of the route and the convergence curve")
    pl.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    cp = sub.add_parser("compare", help="run every algorithm N times on a scenario and tabulate the results")
    cp.add_argument("scenario", type=Path)
    cp.add_argument("--runs", type=int, default=10, help="runs per algorithm (default 10)")
    cp.add_argument("--seed", type=int, default=1, help="run r uses seed SEED + r (default 1)")
    cp.add_argument("--algorithms", default=",".join(ALGORITHM_NAMES),
                    help=f"comma-separated subset (default: {','.join(ALGORITHM_NAMES)})")
    cp.add_argument("--workers", type=int, default=None, help="worker processes (default: CPU count)")
    cp.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE")
    cp.add_argument("-o", "--output", type=Path, default=Path("compare"),
                    help="directory for compare.csv, compare_runs.csv, compare.png (default ./compare)")
    cp.add_argument("-q", "--quiet", action="store_true")
    sub.add_parser("demo", help="plan the rescue scenario and draw it (flies once the companion lands)")
    return p


def _progress(quiet: bool):  # noqa: ANN202
    """A progress line for long searches on an interactive stderr (every 10 % of the iteration budget)."""
    if quiet or not sys.stderr.isatty():
        return None

    def show(it: int, total: int, cost: float) -> None:
        if it == total or it % max(total // 10, 1) == 0:
            print(f"\r  iteration {it:4d}/{total}  best cost {cost:12.1f}", end="", file=sys.stderr, flush=True)
    return show


def cmd_plan(args: argparse.Namespace) -> int:
    from planner.plan import plan, plan_to_json, problem_from_scenario
    from planner.scenario import load_scenario

    overrides = list(args.overrides)
    if args.algorithm:
        overrides.append(f'planner.algorithm="{args.algorithm}"')
    if args.seed is not None:
        overrides.append(f"planner.seed={args.seed}")
    if getattr(args, "aco_init", None):
        overrides.append(f'planner.aco.init="{args.aco_init}"')
    scenario = load_scenario(args.scenario, overrides)
    if args.plot is not None and args.plot.suffix.lower() != ".png":
        raise FuseplanError(f"{args.plot}: --plot writes a PNG; name the file *.png")
    for out in (args.output, args.plot):  # fail before a long search, not after it
        _check_writable(out)
    settings = scenario.planner
    problem = problem_from_scenario(scenario)
    if not args.quiet:
        print(f"planning {scenario.name} with {settings.algorithm}, seed {settings.seed}, "
              f"{settings.pso.n_pop} particles × {settings.pso.max_iter} iterations", file=sys.stderr)
    show = _progress(args.quiet)
    result = plan(problem, settings, np.random.default_rng(settings.seed), seed=settings.seed, progress=show)
    if show is not None:
        print(file=sys.stderr)
    doc = plan_to_json(result, scenario)
    m = doc["metrics"]
    direct = problem.direct_distance
    viol = ", ".join(f"{k} {v}" for k, v in doc["violations"].items())
    extra = {k: v for k, v in doc["cost_violations"].items() if v}
    if extra:
        viol += " (cost terms on the waypoint path: " + ", ".join(f"{k} {v}" for k, v in extra.items()) + ")"
    print(f"{scenario.name}: {result.algorithm} seed {result.seed} -> {result.status.value}")
    clearance = m["min_clearance_m"]
    print(f"  cost      {result.cost:.1f}  (penalty {doc['cost_terms']['penalty']:.1f})")
    print(f"  length    {m['length_m']:.1f} m  ({m['length_m'] / direct:.3f} x direct {direct:.1f} m), "
          f"smoothness {m['smoothness']:.2f} rad, min clearance "
          + ("n/a (no obstacles)" if clearance is None else f"{clearance:.1f} m"))
    print(f"  violations {viol}")
    print(f"  time      {m['plan_time_s']:.2f} s, {m['iterations']} iterations "
          f"({result.optimiser.stop_reason}), converged at iteration {m['convergence_iteration']}")
    if "phases" in doc:
        ph = doc["phases"]
        print(f"  phases    SPSO {ph['pso']['best_cost']:.1f} ({ph['pso']['iterations']} it, "
              f"{ph['pso']['time_s']:.2f} s, {ph['pso']['stop_reason']}) -> ACO {ph['aco']['best_cost']:.1f} "
              f"({ph['aco']['iterations']} it, {ph['aco']['time_s']:.2f} s); winner {ph['winner']}")
    if args.output:
        _write(args.output, json.dumps(doc, indent=1, allow_nan=False) + "\n")
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


def cmd_compare(args: argparse.Namespace) -> int:
    from planner import compare
    from planner.scenario import load_scenario

    if args.runs < 1:
        raise FuseplanError("--runs must be >= 1")
    if args.workers is not None and args.workers < 1:
        raise FuseplanError("--workers must be >= 1")
    if args.seed < 0:
        raise FuseplanError("--seed must be >= 0")
    try:
        algorithms = compare.check_algorithms([a.strip() for a in args.algorithms.split(",") if a.strip()])
    except ValueError as e:
        raise FuseplanError(str(e)) from e
    load_scenario(args.scenario, args.overrides)  # bad input fails here, once, not in every worker
    try:  # and an unusable output directory before the runs, not after them
        args.output.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise FuseplanError(f"{args.output}: cannot create the output directory: {e.strerror or e}") from e
    workers = args.workers or compare.default_workers()
    if not args.quiet:
        print(f"comparing {', '.join(algorithms)} on {args.scenario.name}: {args.runs} runs each, "
              f"seeds {args.seed}..{args.seed + args.runs - 1}, {workers} workers", file=sys.stderr)
    specs = compare.specs_for(str(args.scenario), args.overrides, algorithms, args.runs, args.seed)
    records = compare.run_all(specs, workers, show_progress=not args.quiet)
    rows = compare.summarise(records, algorithms)
    print(compare.format_table(rows))
    try:
        files = compare.write_outputs(args.output, "compare", records, rows)
    except OSError as e:
        raise FuseplanError(f"{args.output}: cannot write results: {e.strerror or e}") from e
    print("wrote " + ", ".join(str(f) for f in files))
    return EXIT_OK


def cmd_demo(args: argparse.Namespace) -> int:
    here = Path(__file__).resolve().parent.parent / "sitl_scenarios" / "rescue_static.toml"
    out = Path("fuseplan-demo")
    try:
        out.mkdir(exist_ok=True)
    except OSError as e:
        raise FuseplanError(f"{out}: cannot create the report directory: {e.strerror or e}") from e
    print("fuseplan demo: flying on the built-in simulated autopilot is not available yet "
          "(companion issue); planning the rescue scenario instead.")
    ns = argparse.Namespace(scenario=here, algorithm=None, seed=None, overrides=[], quiet=False,
                            output=out / "PLAN.json", plot=out / "plan.png")
    return cmd_plan(ns)


def _check_writable(path: Path | None) -> None:
    if path is None:
        return
    parent = path.resolve().parent
    if not parent.is_dir():
        raise FuseplanError(f"{path}: directory {parent} does not exist")
    if path.is_dir():
        raise FuseplanError(f"{path}: is a directory")


def _write(path: Path, text: str) -> None:
    try:
        path.write_text(text)
    except OSError as e:
        raise FuseplanError(f"{path}: cannot write: {e.strerror or e}") from e


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        if args.command == "plan":
            return cmd_plan(args)
        if args.command == "compare":
            return cmd_compare(args)
        return cmd_demo(args)
    except FuseplanError as e:
        print(f"fuseplan: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except MemoryError:
        print("fuseplan: error: out of memory: reduce planner.pso.n_pop, n_waypoints or the map size",
              file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
