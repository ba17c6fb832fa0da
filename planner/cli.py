"""The ``fuseplan`` command line: plan, compare, export, fly, sim, bench, demo.

User mistakes print one line and exit 2; an infeasible plan exits 3; success exits 0; ``fly`` adds 4 (link or
upload failure) and 5 (started but not completed).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
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
    ex = sub.add_parser("export", help="write a mission file (.waypoints, QGroundControl .plan, GeoJSON)")
    ex.add_argument("source", type=Path, help="a scenario TOML (planned first) or a PLAN.json")
    ex.add_argument("--format", required=True, choices=("waypoints", "plan", "geojson"))
    ex.add_argument("-o", "--output", type=Path, required=True)
    ex.add_argument("--autopilot", choices=("ardupilot", "px4"), default="ardupilot")
    ex.add_argument("--scenario", type=Path, help="the scenario of a PLAN.json (default: the one it names)")
    ex.add_argument("--densify", action="store_true", help="add points of the smoothed trajectory")
    ex.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE")
    ex.add_argument("--seed", type=int, default=None)
    fl = sub.add_parser("fly", help="plan, upload, start and monitor a mission over MAVLink")
    fl.add_argument("scenario", type=Path, help="scenario TOML (planned now) or a PLAN.json")
    where = fl.add_mutually_exclusive_group(required=True)
    where.add_argument("--connect", metavar="URL", help="autopilot link, e.g. tcp:127.0.0.1:5760 (ArduPilot SITL), "
                       "udpin:0.0.0.0:14550, /dev/ttyACM0")
    where.add_argument("--sim", action="store_true", help="fly on the built-in simulated autopilot (arming implied)")
    fl.add_argument("--speedup", type=float, default=1.0, help="simulator speed-up (with --sim)")
    fl.add_argument("--sim-loss", type=float, default=0.0, help="simulator packet loss probability (with --sim)")
    fl.add_argument("--arm", action="store_true", help="let the companion arm the vehicle (never without this)")
    fl.add_argument("--no-fence", action="store_true", help="do not upload the no-fly cylinders as a fence")
    fl.add_argument("--densify", action="store_true", help="add points of the smoothed trajectory as waypoints")
    fl.add_argument("--signing-key", type=Path, metavar="FILE",
                    help="MAVLink 2 signing: a 32-byte key file or a passphrase file (SHA-256, as MAVProxy); "
                    "sign everything, ignore unsigned input")
    fl.add_argument("--no-replan", action="store_true",
                    help="fly the first plan whatever the threats do (no live replanning)")
    fl.add_argument("--replan-budget", type=float, default=None, metavar="S",
                    help="wall seconds the planner may use for one live replan (default 0.15)")
    fl.add_argument("--traffic", metavar="URL",
                    help="fly the scenario's [[intruders]] against a real autopilot: report them as an ADS-B "
                    "receiver (component 156) on this spare MAVLink port of it, e.g. tcp:127.0.0.1:5763 (SITL "
                    "SERIAL2), and measure separation from its positions")
    fl.add_argument("--backend", choices=("pymavlink", "mavsdk"), default="pymavlink",
                    help="how the companion talks to the autopilot: its own pymavlink link (default), or MAVSDK "
                    "(mission_raw, action, mavlink_direct); planning, replanning and the report stay the same")
    fl.add_argument("--report", type=Path, default=Path("fuseplan-report"), help="report directory")
    fl.add_argument("--scenario-file", type=Path, help="the scenario of a PLAN.json (default: the one it names)")
    fl.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE")
    fl.add_argument("--seed", type=int, default=None)
    fl.add_argument("--algorithm", choices=ALGORITHM_NAMES, default=None)
    fl.add_argument("-q", "--quiet", action="store_true")
    sm = sub.add_parser("sim", help="run the built-in simulated autopilot alone")
    sm.add_argument("scenario", type=Path)
    sm.add_argument("--listen", default="udpin:127.0.0.1:14550", help="udpin:HOST:PORT or tcp:HOST:PORT "
                    "(loopback unless you name another address)")
    sm.add_argument("--speedup", type=float, default=1.0)
    sm.add_argument("--loss", type=float, default=0.0, help="packet loss probability")
    sm.add_argument("--latency", type=float, default=0.0, help="extra outgoing latency, s")
    sm.add_argument("--signing-key", type=Path, metavar="FILE", help="MAVLink 2 signing key (as for fly)")
    bn = sub.add_parser("bench", help="reproduce one of the paper's experiments (e.g. ablation) and report it")
    bn.add_argument("name", help="which bench (e.g. ablation)")
    bn.add_argument("--runs", type=int, default=None, help="runs per variant (default: the bench's, 30)")
    bn.add_argument("--workers", type=int, default=None, help="worker processes (default: CPU count)")
    bn.add_argument("--seed-base", type=int, default=2000, help="run r uses seed SEED_BASE + r (default 2000)")
    bn.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="override a scenario value for every variant (repeatable)")
    bn.add_argument("-o", "--output", type=Path, default=Path("bench-results"),
                    help="directory for NAME.jsonl (records, resumable), NAME.md, NAME.csv, PNGs "
                    "(default ./bench-results)")
    bn.add_argument("--speedup", type=float, default=1.0,
                    help="bench replan only: simulator speed-up (1 = the latency target's condition)")
    bn.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    sub.add_parser("demo", help="plan the dynamic rescue scenario and fly it on the built-in simulated autopilot "
                   "at 20x, replanning around an intruder")
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


def cmd_bench(args: argparse.Namespace) -> int:
    import time

    from planner.bench import BENCHES
    from planner.bench.runner import BenchSettings, progress_bar, run_bench
    from planner.compare import default_workers
    from planner.scenario import load_scenario

    if args.name == "replan":
        return cmd_bench_replan(args)
    bench = BENCHES.get(args.name)
    if bench is None:
        raise FuseplanError(f"unknown bench {args.name!r}; choose from "
                            f"{', '.join(sorted([*BENCHES, 'replan']))}")
    runs = bench.default_runs if args.runs is None else args.runs
    if runs < 1 or (args.workers is not None and args.workers < 1) or args.seed_base < 0:
        raise FuseplanError("--runs and --workers must be >= 1 and --seed-base >= 0")
    settings = BenchSettings(bench, runs, args.seed_base, tuple(args.overrides))
    for v in bench.variants:  # bad input fails here, once, not in every worker
        load_scenario(settings.scenario_for(v), settings.overrides_for(v))
    try:
        args.output.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise FuseplanError(f"{args.output}: cannot create the output directory: {e.strerror or e}") from e
    workers = args.workers or default_workers()
    if not args.quiet:
        print(f"bench {bench.name}: {bench.description}; {len(bench.variants)} variants × {runs} runs, seeds "
              f"{args.seed_base}..{args.seed_base + runs - 1}, {workers} workers", file=sys.stderr)
    t0 = time.perf_counter()
    try:
        outcome = run_bench(settings, args.output, workers, None if args.quiet else progress_bar)
    except KeyboardInterrupt:
        print(f"fuseplan: interrupted; finished runs are in {args.output / (bench.name + '.jsonl')}; "
              "run the same command again to resume", file=sys.stderr)
        return 130
    wall = time.perf_counter() - t0
    print(f"{outcome.computed} runs computed, {outcome.reused} reused from {outcome.jsonl}; {wall:.1f} s")
    try:
        files = bench.report(args.output, outcome.records, settings)
    except OSError as e:
        raise FuseplanError(f"{args.output}: cannot write results: {e.strerror or e}") from e
    print((args.output / f"{bench.name}.md").read_text())
    print("wrote " + ", ".join(str(f) for f in files))
    return EXIT_OK


REPLAN_BENCH_SCENARIOS = ("rescue_dynamic.toml", "crossing_traffic.toml")


def cmd_bench_replan(args: argparse.Namespace) -> int:
    """Replan latency on the simulated autopilot (companion.latency_bench)."""
    from companion.latency_bench import run_latency_bench

    runs = 5 if args.runs is None else args.runs
    if runs < 1 or not (math.isfinite(args.speedup) and args.speedup > 0):
        raise FuseplanError("--runs must be >= 1 and --speedup a finite number > 0")
    here = Path(__file__).resolve().parent.parent / "sitl_scenarios"
    plans = [_plan_doc_for(here / name, None, list(args.overrides), None, for_flight=True)
             for name in REPLAN_BENCH_SCENARIOS]
    say = (lambda _t: None) if args.quiet else (lambda t: print(t, file=sys.stderr, flush=True))
    say(f"bench replan: {len(plans)} scenarios × {runs} flights at {args.speedup:g}× until the first replan")
    try:
        run_latency_bench(plans, runs, args.speedup, args.output, progress=say)
    except OSError as e:
        raise FuseplanError(f"{args.output}: cannot write results: {e.strerror or e}") from e
    print((args.output / "replan.md").read_text())
    return EXIT_OK


def _plan_doc_for(source: Path, scenario_path: Path | None, overrides: list[str], seed: int | None,
                  feasible_only: bool = True, for_flight: bool = False) -> tuple[dict, object]:
    """(PLAN.json document, scenario) from a PLAN.json or by planning a scenario TOML now. ``for_flight``:
    dynamic threats are timed from the mission start (the vehicle reaches the route's start only after its
    takeoff), as the companion sees them in flight."""
    from planner.plan import plan, plan_to_json, problem_from_scenario
    from planner.scenario import load_scenario

    if source.suffix.lower() == ".json":
        try:
            doc = json.loads(source.read_text())
        except (OSError, ValueError) as e:
            raise FuseplanError(f"{source}: cannot read the plan: {e}") from e
        if not isinstance(doc, dict) or "waypoints" not in doc:
            raise FuseplanError(f"{source}: not a fuseplan PLAN.json (no waypoints)")
        named = scenario_path or (Path(doc["scenario_file"]) if doc.get("scenario_file") else None)
        if named is None:
            raise FuseplanError(f"{source}: names no scenario file; pass --scenario")
        sc = load_scenario(named, overrides)
        _check_plan_matches(source, doc, sc)
        return doc, sc
    sc = load_scenario(source, overrides + ([f"planner.seed={seed}"] if seed is not None else []))
    start_time = None
    if len(sc.environment.threats):
        from companion.builder import time_to_start

        start_time = time_to_start(sc) if for_flight else 0.0
    res = plan(problem_from_scenario(sc, start_time), sc.planner, np.random.default_rng(sc.planner.seed),
               seed=sc.planner.seed)
    if feasible_only and not res.feasible:
        raise FuseplanError(f"{source}: no feasible plan ({res.status.value}); nothing exported")
    return plan_to_json(res, sc, start_time), sc


def _check_plan_matches(source: Path, doc: dict, sc: object) -> None:
    """A PLAN.json is only flown or exported with its own scenario: same name, home, start and goal."""
    home = doc.get("home") or {}
    same = (doc.get("scenario") == sc.name
            and all(abs(float(home.get(k, math.nan)) - getattr(sc.home, k)) < 1e-9 for k in ("lat", "lon", "alt"))
            and np.allclose(doc["waypoints"][0], sc.start) and np.allclose(doc["waypoints"][-1], sc.goal))
    if not same:
        raise FuseplanError(f"{source}: planned for scenario {doc.get('scenario')!r}, not {sc.name!r} "
                            f"({sc.source}): home, start or goal differ; plan again for this scenario")


def cmd_export(args: argparse.Namespace) -> int:
    from companion.exports import export_from_plan_json

    _check_writable(args.output)
    doc, sc = _plan_doc_for(args.source, args.scenario, args.overrides, args.seed)
    try:
        path = export_from_plan_json(doc, sc, args.format, args.output, args.autopilot, densify=args.densify)
    except (KeyError, ValueError) as e:
        raise FuseplanError(f"{args.source}: cannot export: {e}") from e
    except OSError as e:
        raise FuseplanError(f"{args.output}: cannot write: {e.strerror or e}") from e
    print(f"wrote {path} ({args.format}, {args.autopilot})")
    return EXIT_OK


EXIT_LINK, EXIT_ABORTED = 4, 5


def cmd_fly(args: argparse.Namespace) -> int:
    import asyncio

    from companion.errors import CompanionError
    from companion.events import EventLog
    from companion.fly import FlyOptions, fly
    from companion.replan import ReplanConfig
    from companion.signing import SigningKey

    if not (math.isfinite(args.speedup) and args.speedup > 0) or not 0 <= args.sim_loss < 1:
        raise FuseplanError("--speedup must be a finite number > 0 and --sim-loss in [0, 1)")
    if not args.sim and (args.speedup != 1.0 or args.sim_loss):
        raise FuseplanError("--speedup and --sim-loss apply to the built-in simulator (--sim) only")
    if getattr(args, "traffic", None) and args.sim:
        raise FuseplanError("--traffic is for a real autopilot (--connect): the simulator flies the intruders itself")
    backend = getattr(args, "backend", "pymavlink")
    if backend == "mavsdk":
        from companion.mavsdk_backend import unsupported_options

        why = unsupported_options(signing=getattr(args, "signing_key", None) is not None)
        if why:
            raise FuseplanError(why)
    key = SigningKey.load(args.signing_key) if getattr(args, "signing_key", None) else None
    overrides = list(args.overrides) + ([f'planner.algorithm="{args.algorithm}"'] if args.algorithm else [])
    try:
        args.report.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise FuseplanError(f"{args.report}: cannot create the report directory: {e.strerror or e}") from e
    say = (lambda *_: None) if args.quiet else (lambda text: print(text, flush=True))
    say(f"planning {args.scenario.name} ...")
    doc, sc = _plan_doc_for(args.scenario, args.scenario_file, overrides, args.seed, feasible_only=False,
                            for_flight=True)
    _write(args.report / "PLAN.json", json.dumps(doc, indent=1, allow_nan=False) + "\n")
    say(f"  {doc['status']}: cost {doc['cost']:.1f}, {doc['metrics']['length_m']:.0f} m, "
        f"{doc['metrics']['plan_time_s']:.2f} s")
    if doc["status"] not in ("exact", "approximate"):
        print(f"fuseplan: no feasible plan ({doc['status']}); not flying. See {args.report / 'PLAN.json'}",
              file=sys.stderr)
        return EXIT_INFEASIBLE
    replan_cfg = None
    if getattr(args, "replan_budget", None) is not None:
        if not (math.isfinite(args.replan_budget) and args.replan_budget > 0):
            raise FuseplanError("--replan-budget must be a finite number of seconds > 0")
        replan_cfg = ReplanConfig(budget_s=args.replan_budget)
    opts = FlyOptions(connect=args.connect, sim=args.sim, speedup=args.speedup, sim_loss=args.sim_loss,
                      arm=args.arm, fence=not args.no_fence, densify=args.densify, report=args.report,
                      replan=not getattr(args, "no_replan", False), replan_config=replan_cfg,
                      signing_key=key, traffic=getattr(args, "traffic", None), backend=backend)
    events = EventLog(args.report / "events.jsonl", echo=None if args.quiet else _echo_event)
    try:
        flight = asyncio.run(fly(doc, sc, opts, events))
    except CompanionError as e:
        events.log("failed", error=str(e))
        _write(args.report / "flight.json", json.dumps({"completed": False, "reason": str(e)}, indent=1) + "\n")
        print(f"fuseplan: error: {e}", file=sys.stderr)
        return EXIT_LINK
    except KeyboardInterrupt:
        events.log("aborted", reason="interrupted by the user")
        _write(args.report / "flight.json", json.dumps({"completed": False, "reason": "interrupted"}) + "\n")
        print("fuseplan: interrupted; the vehicle keeps its current mode and mission", file=sys.stderr)
        return 130
    finally:
        events.close()
    say(f"{'completed' if flight['completed'] else 'NOT completed'}: {flight['reason']}; "
        f"{len(flight['items_reached'])} items reached, upload {flight['upload_s']:.2f} s, "
        f"min clearance {flight['min_clearance_m']:.1f} m; report in {args.report}/")
    if flight.get("min_separation_m"):
        seps = ", ".join(f"{k} {v:.1f} m" for k, v in flight["min_separation_m"].items())
        lat = flight.get("replan_latency_s") or {}
        say(f"replans {flight['replans']}" + (f" (latency median {lat['median']:.2f} s, max {lat['max']:.2f} s)"
                                               if lat else "")
            + f"; min separation (truth): {seps}; d_coll {flight['d_coll_m']:g} m")
        lost = [k for k, v in flight["min_separation_m"].items() if v < flight["d_coll_m"]]
        if lost:
            print(f"fuseplan: warning: separation below d_coll with {', '.join(lost)}"
                  + (" (replanning was off)" if not flight["replanning"] else ""), file=sys.stderr)
    return EXIT_OK if flight["completed"] else EXIT_ABORTED


_ECHOED = ("reached", "statustext", "mode", "armed", "upload_verified", "mission_start", "ready", "connected",
           "finished", "timeout", "arm_refused", "waiting_for_pilot_arm", "failed", "track",
           "track_expired", "conflict_predicted", "hold", "resume", "threat_cleared", "replan_upload_failed",
           "set_current", "replanner_failed", "upload_failed", "backup_failed", "mission_restored",
           "mission_restore_failed", "link_lost", "link_restored", "resync", "resync_mismatch", "booting", "booted")


def _echo_event(rec: dict) -> None:
    """Progress lines for the events a person watching the flight cares about; replans spelled out."""
    e = rec["event"]
    detail = {k: v for k, v in rec.items() if k not in ("t", "event")}
    if e == "conflict":
        text = (f"CONFLICT with {rec['threat']} in {rec['in_s']:.1f} s: predicted separation "
                f"{rec['separation_m']:.1f} m (d_coll {rec['d_coll_m']:g} m) -> replan {rec['n']}")
    elif e == "replan_planned":
        text = (f"replan {rec['n']}: {rec['status']} in {rec['plan_s']:.3f} s from {rec['commit']}, "
                f"{rec['waypoints']} waypoints, predicted separation {rec['separation_after_m']:.1f} m")
    elif e == "replanned":
        text = (f"replan {rec['n']}: new mission current {rec['latency_s']:.3f} s after the conflict was seen "
                f"(plan {rec['plan_s']:.3f} s, upload+verify+set-current {rec['upload_s']:.3f} s"
                f"{', vehicle held meanwhile' if rec['held'] else ''})")
    elif e in _ECHOED:
        text = f"{e} " + " ".join(f"{k}={v}" for k, v in detail.items())
    else:
        return
    print(f"  [{rec['t']:6.1f} s] {text}".rstrip(), flush=True)


def cmd_sim(args: argparse.Namespace) -> int:
    import asyncio

    from companion.signing import SigningKey
    from companion.sim import serve
    from planner.scenario import load_scenario

    sc = load_scenario(args.scenario)
    if not (math.isfinite(args.speedup) and args.speedup > 0) or not 0 <= args.loss < 1 or not (
            math.isfinite(args.latency) and args.latency >= 0):
        raise FuseplanError("--speedup must be a finite number > 0, --loss in [0, 1), --latency >= 0")
    print(f"simulated {sc.vehicle.type} for {sc.name} on {args.listen} (speed-up {args.speedup:g}); Ctrl-C stops",
          flush=True)
    try:
        key = SigningKey.load(args.signing_key) if args.signing_key else None
        asyncio.run(serve(sc, args.listen, args.speedup, args.loss, args.latency, signing_key=key))
    except KeyboardInterrupt:
        pass
    except OSError as e:
        raise FuseplanError(f"{args.listen}: cannot listen: {e.strerror or e}") from e
    return EXIT_OK


def cmd_demo(args: argparse.Namespace) -> int:
    """fly sitl_scenarios/rescue_dynamic.toml --sim --speedup 20 --report fuseplan-demo/"""
    here = Path(__file__).resolve().parent.parent / "sitl_scenarios" / "rescue_dynamic.toml"
    print("fuseplan demo: planning the dynamic rescue scenario and flying it on the built-in simulated autopilot "
          "(20x); an intruder reported over ADS-B will cross the route and the companion replans around it")
    ns = argparse.Namespace(scenario=here, connect=None, sim=True, speedup=20.0, sim_loss=0.0, arm=False,
                            no_fence=False, densify=False, report=Path("fuseplan-demo"), scenario_file=None,
                            overrides=[], seed=None, algorithm=None, quiet=False, no_replan=False,
                            replan_budget=None)
    return cmd_fly(ns)


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
        if args.command == "export":
            return cmd_export(args)
        if args.command == "fly":
            return cmd_fly(args)
        if args.command == "sim":
            return cmd_sim(args)
        if args.command == "bench":
            return cmd_bench(args)
        return cmd_demo(args)
    except FuseplanError as e:
        print(f"fuseplan: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except MemoryError:
        print("fuseplan: error: out of memory: reduce planner.pso.n_pop, n_waypoints or the map size",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    except BrokenPipeError:  # `fuseplan compare | head`: the reader left; files are already written
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
