"""The ``fuseplan`` command line: plan, compare, bench (:mod:`planner.cli`) with export, fly, sim, demo, report.

The top layer: it assembles the planner's subcommands and the companion's. User mistakes print one line and exit 2
(``fly``: also a fence larger than the autopilot stores, refused before anything is sent);
an infeasible plan exits 3; success exits 0; ``fly`` adds 4 (link or upload failure, or a vehicle the scenario
cannot be flown from), 5 (started but not completed) and 6 (the flown track broke d_coll).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from companion.flight import HEARTBEAT_WAIT_S
from companion.mavlink.link import DEFAULT_BAUD
from companion.mission.events import BY_NAME, ENDINGS, Event, Tone
from planner import cli as planner_cli
from planner import console
from planner.cli import (
    EXIT_BAD_INPUT,
    EXIT_INFEASIBLE,
    EXIT_OK,
    BenchArgs,
    PlanArgs,
    SourceArgs,
    add_command,
    add_paper_option,
    add_set_option,
    check_writable,
    command,
    mode_overrides,
    options_from,
    write_text,
)
from planner.distribution import fuseplan_version, shipped_scenarios
from planner.errors import FuseplanError, PlanRefused
from planner.world.config import ALGORITHM_NAMES

if TYPE_CHECKING:
    from companion.mavlink.signing import SigningKey
    from companion.mission.builder import Autopilot
    from companion.mission.exports import ExportFormat
    from companion.replanning.replan import ReplanConfig
    from companion.status import Bind
    from planner.world.geo_inputs import OperatorMission
    from planner.world.scenario import Scenario

SCENARIOS = shipped_scenarios()


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="fuseplan", description="Plan safe 3-D UAV routes and fly them over MAVLink.",
                                parents=[planner_cli.verbosity_options(top=True)],
                                formatter_class=planner_cli.HelpFormatter)
    p.add_argument("--version", action="version", version=f"%(prog)s {fuseplan_version()}",
                   help="print fuseplan's version and exit")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND",
                           help="what to do (`fuseplan COMMAND --help`: its options)")
    planner_parsers = planner_cli.add_commands(sub)
    planner_parsers["plan"].set_defaults(func=command(PlanArgs, cmd_plan))
    planner_parsers["bench"].set_defaults(func=command(CompanionBenchArgs, cmd_bench))
    ex = add_command(sub, "export", "write a mission file (.waypoints, QGroundControl .plan, GeoJSON)",
                     command(ExportArgs, cmd_export))
    ex.add_argument("source", type=Path, help="a scenario TOML or a ground station's mission (planned first), "
                    "or a PLAN.json")
    ex.add_argument("--format", required=True, choices=("waypoints", "plan", "geojson"),
                    help="the file written: Mission Planner .waypoints, QGroundControl .plan or GeoJSON")
    ex.add_argument("-o", "--output", type=Path, required=True, help="the mission file to write")
    ex.add_argument("--autopilot", choices=("ardupilot", "px4", "px4-vtol"), default="ardupilot",
                    help="the mission layout: ArduPilot, PX4, or a PX4 VTOL (VTOL take-off and landing)")
    ex.add_argument("--scenario", type=Path, help="the scenario of a PLAN.json (default: the one it names)")
    ex.add_argument("--densify", action="store_true", help="add points of the smoothed trajectory")
    add_set_option(ex, "override a scenario value when planning (repeatable)")
    ex.add_argument("--seed", type=int, default=None, help="random seed when planning (default: the scenario's)")
    add_paper_option(ex)
    ex.add_argument("--force", action="store_true",
                    help="write a PLAN.json that fails its check against the scenario anyway, marked UNCHECKED in "
                         "the file (never for flying)")
    planner_cli.add_source_options(ex)
    fl = add_command(sub, "fly", "plan, upload, start and monitor a mission over MAVLink", command(FlyArgs, cmd_fly))
    fl.add_argument("scenario", type=Path, help="scenario TOML or a ground station's mission (planned now), or a "
                    "PLAN.json")
    where = fl.add_mutually_exclusive_group(required=True)
    where.add_argument("--connect", metavar="URL", help="autopilot link, e.g. tcp:127.0.0.1:5760 (ArduPilot SITL), "
                       "udpin:0.0.0.0:14550, /dev/ttyACM0 (with --baud, or /dev/ttyACM0,BAUD)")
    where.add_argument("--sim", action="store_true", help="fly on the built-in simulated autopilot (arming implied)")
    _baud_option(fl)
    fl.add_argument("--speedup", type=float, default=1.0, help="simulator speed-up (with --sim)")
    fl.add_argument("--sim-loss", type=float, default=0.0, help="simulator packet loss probability (with --sim)")
    fl.add_argument("--arm", action="store_true", help="let the companion arm the vehicle (never without this)")
    fl.add_argument("--no-fence", action="store_true", help="do not upload the no-fly cylinders as a fence")
    fl.add_argument("--densify", action="store_true", help="add points of the smoothed trajectory as waypoints")
    _signing_options(fl)
    fl.add_argument("--no-replan", action="store_true",
                    help="fly the first plan whatever the threats do (no live replanning)")
    fl.add_argument("--replan-budget", type=float, default=None, metavar="S",
                    help="wall seconds the planner may use for one live replan (default 0.15)")
    fl.add_argument("--traffic", metavar="URL",
                    help="fly the scenario's [[intruders]] against a real autopilot: report them as an ADS-B "
                    "receiver (component 156) on this spare MAVLink port of it, e.g. tcp:127.0.0.1:5763 (SITL "
                    "SERIAL2), and measure separation from its positions")
    fl.add_argument("--backend", choices=("pymavlink", "mavsdk"), default="pymavlink",
                    help="how the companion talks to the autopilot: its own pymavlink link, or MAVSDK "
                    "(mission_raw, action, mavlink_direct); planning, replanning and the report stay the same")
    fl.add_argument("--flight-timeout", type=float, default=None, metavar="S",
                    help="wall seconds to supervise the flight before reporting it incomplete (exit 5; the vehicle "
                         "flies on with its verified mission); default 120 s + 4 x the route's flying time")
    fl.add_argument("--heartbeat-timeout", type=float, default=None, metavar="S",
                    help=f"seconds to wait for the autopilot's first HEARTBEAT (default {HEARTBEAT_WAIT_S:g})")
    fl.add_argument("--target-system", type=int, default=None, metavar="N",
                    help="the autopilot's MAVLink system id (1-255); without it the one that answers is used, and "
                         "HEARTBEATs from a second autopilot refuse the flight before any upload")
    fl.add_argument("--report", type=Path, default=Path("fuseplan-report"), help="report directory")
    fl.add_argument("--scenario-file", type=Path, help="the scenario of a PLAN.json (default: the one it names)")
    add_set_option(fl, "override a scenario value when planning (repeatable)")
    fl.add_argument("--seed", type=int, default=None, help="random seed when planning (default: the scenario's)")
    fl.add_argument("--algorithm", choices=ALGORITHM_NAMES, default=None,
                    help="optimiser of the first plan (default: the scenario's planner.algorithm, else fusion)")
    add_paper_option(fl)
    planner_cli.add_source_options(fl)
    fl.add_argument("--fence-from-vehicle", action="store_true",
                    help="download the fence (and rally points) the operator uploaded with a ground station and plan "
                         "around it; it stays on the vehicle as it is (with --connect)")
    fl.add_argument("--goal-from-vehicle", action="store_true",
                    help="the goal is the last navigation item of the mission on the vehicle (with --connect)")
    _status_options(fl)
    sv = add_command(sub, "serve", "run as the companion's service: plan every mission the operator uploads round the "
                     "vehicle's fence, replace it with the verified safe route while disarmed, supervise the flight "
                     "(docs/serve.md); with -q only errors, the status page's address and the one-line start and "
                     "stop banners are printed (they say where the service is and that it stopped cleanly)",
                     command(ServeArgs, cmd_serve))
    sv.add_argument("config", type=Path, help="the service's configuration file (TOML; docs/serve.example.toml)")
    sv.add_argument("--check", action="store_true", help="check the configuration file and exit")
    sm = add_command(sub, "sim", "run the built-in simulated autopilot alone", command(SimArgs, cmd_sim))
    sm.add_argument("scenario", type=Path, help="the scenario TOML whose vehicle, home and intruders are simulated")
    sm.add_argument("--listen", default="udpin:127.0.0.1:14550", help="udpin:HOST:PORT or tcp:HOST:PORT "
                    "(loopback unless you name another address)")
    sm.add_argument("--speedup", type=float, default=1.0, help="simulated seconds per wall second")
    sm.add_argument("--loss", type=float, default=0.0, help="packet loss probability")
    sm.add_argument("--latency", type=float, default=0.0, help="extra outgoing latency, s")
    _signing_options(sm)
    bn = planner_parsers["bench"]
    bn.add_argument("--speedup", type=float, default=1.0,
                    help="bench replan only: simulator speed-up (1 = the latency target's condition)")
    bn.add_argument("--whole", action="store_true",
                    help="bench replan only: fly every flight to its end and count replans per conflict")
    bn.add_argument("--replan-paper", action="store_true",
                    help="bench replan only: the first routes and the replans by the paper's fusion (paper mode) "
                         "instead of the roadmap pipeline, for comparison")
    bn.add_argument("--cpu-hog", type=int, default=0, metavar="N",
                    help="bench replan and bench flights: N busy processes beside the flights (deadlines under "
                         "load, issue 16)")
    bn.add_argument("--backend", choices=("sim", "sitl-plane", "sitl-copter", "px4", "px4-vtol"), default="sim",
                    help="bench flights only: what flies: the built-in simulator (20x), ArduPilot SITL plane or "
                         "copter (10x), PX4 SITL quadrotor or standard VTOL (10x)")
    bn.add_argument("--scenarios", default=None, metavar="A,B",
                    help="bench flights only: comma-separated subset of the shipped scenarios with moving threats "
                         "(default: all of them)")
    bn.add_argument("--no-replan-too", action="store_true",
                    help="bench flights only: fly every flight again without replanning")
    bn.add_argument("--replan-budget", type=float, default=None, metavar="S",
                    help="bench flights only: fly's --replan-budget for every flight with replanning (default: "
                         "fly's)")
    bn.add_argument("--sitl-dir", type=Path, default=None, metavar="DIR",
                    help="bench flights only: the autopilot's folder (default $FUSEPLAN_SITL_DIR for ArduPilot, "
                         "$FUSEPLAN_PX4_DIR for PX4)")
    dm = add_command(sub, "demo", "plan the dynamic rescue scenario and fly it on the built-in simulated autopilot "
                     "at 20x, replanning around an intruder", command(DemoArgs, cmd_demo))
    _status_options(dm)
    dm.add_argument("--insecure-key-file", action="store_true",
                    help="use a --status-token file that other users can read (with a warning)")
    rp = add_command(sub, "report", "summarise a `fuseplan fly` report directory, or serve its status page",
                     command(ReportArgs, cmd_report))
    rp.add_argument("directory", type=Path, help="the report directory (holds events.jsonl, flight.json)")
    rp.add_argument("--serve", nargs="?", const=STATUS_DEFAULT, metavar="[HOST:]PORT",
                    help=f"serve the flight's status page until Ctrl-C (default {STATUS_DEFAULT})")
    rp.add_argument("--status-token", type=Path, metavar="FILE",
                    help="a file holding the page's token (required to serve beyond loopback)")
    rp.add_argument("--status-host", action="append", metavar="NAME",
                    help="another name the page may be reached by (as for fly; repeatable)")
    rp.add_argument("--insecure-key-file", action="store_true",
                    help="use a --status-token file that other users can read (with a warning) instead of refusing it")
    return p


STATUS_DEFAULT = "127.0.0.1:8765"


def _baud_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--baud", type=int, default=DEFAULT_BAUD, metavar="N",
                   help="serial links: the port's baud rate (a URL's own ,BAUD wins); ignored on network links")


def _signing_options(p: argparse.ArgumentParser) -> None:
    """MAVLink 2 signing on ``fly`` and ``sim``: a raw key or a passphrase, never guessed from the file."""
    signing = p.add_mutually_exclusive_group()
    signing.add_argument("--signing-key", type=Path, metavar="FILE",
                         help="MAVLink 2 signing with the key in FILE: exactly 32 raw bytes, or 64 hex digits; sign "
                         "everything, ignore unsigned input")
    signing.add_argument("--signing-passphrase", type=Path, metavar="FILE",
                         help="MAVLink 2 signing with the key MAVProxy's `signing setup PASSPHRASE` makes (SHA-256) "
                         "from the passphrase on FILE's first line (one word, 8+ characters)")
    p.add_argument("--insecure-key-file", action="store_true",
                   help="use a key, passphrase or --status-token file that other users can read (with a warning) "
                   "instead of refusing it")


def _status_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--status-page", metavar="[HOST:]PORT",
                   help="serve a live, read-only status page of the flight (default host 127.0.0.1; port 0: any "
                        "free port); any address but loopback needs --status-token")
    p.add_argument("--status-token", type=Path, metavar="FILE",
                   help="a file holding the status page's token (16+ characters); every request must carry it")
    p.add_argument("--status-host", action="append", metavar="NAME",
                   help="another name browsers may reach the page by (a reverse proxy's, this machine's DNS name; "
                        "repeatable); a Host that names neither it, loopback, the address reached nor this machine "
                        "gets 421")


# -- the commands' options: one dataclass each, built from the parsed arguments in its from_args -----------------


@dataclass(frozen=True)
class StatusArgs:
    """The status page's options (fly, demo: ``--status-page``; report: ``--serve``)."""

    where: str | None = None
    token_file: Path | None = None
    hosts: tuple[str, ...] = ()
    insecure_key_file: bool = False
    option: str = "--status-page"  # what the page is asked for with, for messages

    @classmethod
    def from_args(cls, ns: argparse.Namespace, option: str = "--status-page") -> StatusArgs:
        where = ns.serve if option == "--serve" else ns.status_page
        return cls(where, ns.status_token, tuple(ns.status_host or ()), ns.insecure_key_file, option)

    def bind(self) -> tuple[Bind, str | None] | None:
        """(Bind, token), checked before any work; None when no page was asked for."""
        from companion.status import Bind, read_token

        if self.where is None:
            for given, name in ((self.token_file, "--status-token"), (self.hosts, "--status-host")):
                if given:
                    raise FuseplanError(f"{name} goes with {self.option}")
            return None
        bind = Bind.parse(self.where, list(self.hosts))
        token = read_token(self.token_file, bind, self.insecure_key_file)
        bind.check_free()
        return bind, token


@dataclass(frozen=True)
class SigningArgs:
    """``--signing-key`` / ``--signing-passphrase`` (fly, sim)."""

    key_file: Path | None = None
    passphrase_file: Path | None = None
    insecure_key_file: bool = False

    @classmethod
    def from_args(cls, ns: argparse.Namespace) -> SigningArgs:
        return cls(ns.signing_key, ns.signing_passphrase, ns.insecure_key_file)

    @property
    def given(self) -> bool:
        return self.key_file is not None or self.passphrase_file is not None

    def key(self) -> SigningKey | None:
        from companion.mavlink.signing import key_from_files

        return key_from_files(self.key_file, self.passphrase_file, self.insecure_key_file)


@dataclass(frozen=True)
class FlyArgs:
    """``fuseplan fly``; the defaults are the parser's (``demo`` builds one directly)."""

    scenario: Path
    connect: str | None = None
    sim: bool = False
    baud: int = DEFAULT_BAUD
    speedup: float = 1.0
    sim_loss: float = 0.0
    arm: bool = False
    no_fence: bool = False
    densify: bool = False
    signing: SigningArgs = SigningArgs()
    no_replan: bool = False
    replan_budget: float | None = None
    traffic: str | None = None
    backend: str = "pymavlink"
    flight_timeout: float | None = None
    heartbeat_timeout: float | None = None
    target_system: int | None = None
    report: Path = Path("fuseplan-report")
    scenario_file: Path | None = None
    overrides: tuple[str, ...] = ()
    seed: int | None = None
    algorithm: str | None = None
    paper: bool = False
    quiet: bool = False
    sources: SourceArgs = SourceArgs()
    fence_from_vehicle: bool = False
    goal_from_vehicle: bool = False
    status: StatusArgs = StatusArgs()

    @classmethod
    def from_args(cls, ns: argparse.Namespace) -> FlyArgs:
        return options_from(cls, ns, overrides=tuple(ns.overrides), signing=SigningArgs.from_args(ns),
                            sources=SourceArgs.from_args(ns), status=StatusArgs.from_args(ns))


@dataclass(frozen=True)
class DemoArgs:
    """``fuseplan demo``."""

    quiet: bool
    status: StatusArgs

    @classmethod
    def from_args(cls, ns: argparse.Namespace) -> DemoArgs:
        return cls(ns.quiet, StatusArgs.from_args(ns))


@dataclass(frozen=True)
class SimArgs:
    """``fuseplan sim``."""

    scenario: Path
    listen: str
    speedup: float
    loss: float
    latency: float
    quiet: bool
    signing: SigningArgs

    @classmethod
    def from_args(cls, ns: argparse.Namespace) -> SimArgs:
        return options_from(cls, ns, signing=SigningArgs.from_args(ns))


@dataclass(frozen=True)
class ServeArgs:
    """``fuseplan serve``."""

    config: Path
    check: bool
    quiet: bool

    @classmethod
    def from_args(cls, ns: argparse.Namespace) -> ServeArgs:
        return options_from(cls, ns)


@dataclass(frozen=True)
class ExportArgs:
    """``fuseplan export``."""

    source: Path
    format: ExportFormat
    output: Path
    autopilot: Autopilot
    scenario: Path | None
    densify: bool
    overrides: tuple[str, ...]
    seed: int | None
    paper: bool
    force: bool
    quiet: bool
    sources: SourceArgs

    @classmethod
    def from_args(cls, ns: argparse.Namespace) -> ExportArgs:
        return options_from(cls, ns, overrides=tuple(ns.overrides), sources=SourceArgs.from_args(ns))


@dataclass(frozen=True)
class ReportArgs:
    """``fuseplan report``."""

    directory: Path
    quiet: bool
    status: StatusArgs

    @classmethod
    def from_args(cls, ns: argparse.Namespace) -> ReportArgs:
        return cls(ns.directory, ns.quiet, StatusArgs.from_args(ns, "--serve"))


@dataclass(frozen=True)
class CompanionBenchArgs:
    """``fuseplan bench NAME``: the planner's options and the companion benches' (replan, flights)."""

    planner: BenchArgs
    speedup: float
    whole: bool
    replan_paper: bool
    cpu_hog: int
    backend: str
    scenarios: str | None
    no_replan_too: bool
    replan_budget: float | None
    sitl_dir: Path | None

    @classmethod
    def from_args(cls, ns: argparse.Namespace) -> CompanionBenchArgs:
        return options_from(cls, ns, planner=BenchArgs.from_args(ns))


def _announce(url: str, token: str | None) -> None:
    print(f"status page: {url}" + ("?token=<the token in --status-token FILE>" if token else ""), flush=True)


REPLAN_BENCH_SCENARIOS = ("rescue_dynamic.toml", "crossing_traffic.toml")


def cmd_bench(args: CompanionBenchArgs) -> int:
    """``fuseplan bench NAME``: the companion's benches by name, else the planner's."""
    own = {"replan": cmd_bench_replan, "flights": cmd_bench_flights}
    run = own.get(args.planner.name)
    return run(args) if run is not None else planner_cli.cmd_bench(args.planner, other_benches=tuple(own))


def cmd_bench_replan(args: CompanionBenchArgs) -> int:
    """Replan latency on the simulated autopilot (companion.flight.latency_bench)."""
    from companion.flight.latency_bench import run_flight_bench, run_latency_bench
    from companion.replanning.replan import ReplanConfig

    bench = args.planner
    planner_cli.local_only(bench.executor, "bench replan")
    runs = 5 if bench.runs is None else bench.runs
    hog = args.cpu_hog
    if runs < 1 or not (math.isfinite(args.speedup) and args.speedup > 0) or hog < 0:
        raise FuseplanError("--runs must be >= 1, --speedup a finite number > 0 and --cpu-hog >= 0")
    paper = args.replan_paper  # the first routes and the replans by the paper's planners
    plans = [_plan_doc_for(SCENARIOS / name, None, list(bench.overrides) + mode_overrides(paper), None,
                           for_flight=True)
             for name in REPLAN_BENCH_SCENARIOS]
    say = (lambda _t: None) if bench.quiet else (lambda t: print(t, file=sys.stderr, flush=True))
    whole = args.whole
    say(f"bench replan: {len(plans)} scenarios × {runs} flights at {args.speedup:g}× "
        + ("to the end" if whole else "until the first replan") + (f", {hog} busy processes beside" if hog else ""))
    try:
        cfg = ReplanConfig(roadmap=not paper)
        if whole:
            run_flight_bench(plans, runs, args.speedup, bench.output, cfg, progress=say, hog=hog)
        else:
            run_latency_bench(plans, runs, args.speedup, bench.output, cfg, progress=say, hog=hog)
    except OSError as e:
        raise FuseplanError(f"{bench.output}: cannot write results: {e.strerror or e}") from e
    console.show_markdown((bench.output / ("replan_flights.md" if whole else "replan.md")).read_text())
    return EXIT_OK


def cmd_bench_flights(args: CompanionBenchArgs) -> int:
    """Whole flights of the scenarios with moving threats on one backend (companion.flight.flights_bench)."""
    from companion.flight import flights_bench as fb
    from planner.bench.load import cpu_hog
    from planner.world.scenario import load_scenario

    bench = args.planner
    planner_cli.local_only(bench.executor, "bench flights")
    runs = fb.DEFAULT_RUNS if bench.runs is None else bench.runs
    if runs < 1:
        raise FuseplanError("--runs must be >= 1")
    folder = fb.autopilot_folder(args.backend, args.sitl_dir)
    why = fb.missing(args.backend, folder)
    if why:
        raise FuseplanError(f"bench flights --backend {args.backend}: {why}")
    shipped = fb.moving_threat_scenarios(SCENARIOS)
    names = [n.strip().removesuffix(".toml") for n in (args.scenarios or ",".join(shipped)).split(",") if n.strip()]
    unknown = [n for n in names if n not in shipped]
    if unknown or not names:
        raise FuseplanError(f"--scenarios: {', '.join(unknown) or 'none named'}: choose from the scenarios with "
                            f"moving threats: {', '.join(shipped)}")
    hog = args.cpu_hog
    if hog < 0:
        raise FuseplanError("--cpu-hog must be >= 0")
    settings = fb.FlightsSettings(args.backend, runs, tuple(shipped[n] for n in dict.fromkeys(names)),
                                  args.no_replan_too, bench.output, bench.overrides, folder, hog,
                                  _seconds(args.replan_budget, "--replan-budget"))
    for path in settings.scenarios:  # bad --set fails here, once, not in every flight
        load_scenario(path, list(settings.fly_overrides))
    planner_cli.make_output_dir(bench.output)
    say = (lambda _t: None) if bench.quiet else (lambda t: print(t, file=sys.stderr, flush=True))
    try:
        with cpu_hog(hog):
            _records, reused = fb.run_flights_bench(settings, main, progress=say)
    except KeyboardInterrupt:
        return planner_cli._interrupted(bench.output / "flights.jsonl", "flights")
    except OSError as e:
        raise FuseplanError(f"{bench.output}: cannot write results: {e.strerror or e}") from e
    console.show_markdown((bench.output / "flights.md").read_text())
    print(f"wrote {bench.output / 'flights.md'}, flights.csv, flights_runs.csv, flights.jsonl ({reused} flights "
          "reused)")
    return EXIT_OK


def _plan_doc_for(source: Path, scenario_path: Path | None, overrides: list[str], seed: int | None,
                  feasible_only: bool = True, for_flight: bool = False, force: bool = False,
                  ) -> tuple[dict[str, Any], Scenario]:
    """(PLAN.json document, scenario) from a PLAN.json or by planning a scenario TOML now. ``for_flight``:
    dynamic threats are timed from the mission start (the vehicle reaches the route's start only after its
    takeoff), as the companion sees them in flight. A PLAN.json is checked again against its scenario and its
    derived parts rebuilt (:mod:`planner.plan_file`); one that fails is refused (exit 3) unless ``force``, when
    the document carries the fault under ``unchecked``."""
    from planner.legs import plan_scenario
    from planner.plan import plan_to_json
    from planner.world.scenario import load_scenario

    if source.suffix.lower() == ".json":
        from planner.plan_file import read_plan_document, recheck, refuse_unless_passed

        doc = read_plan_document(source)
        named = scenario_path or (Path(doc["scenario_file"]) if doc.get("scenario_file") else None)
        if named is None:
            raise FuseplanError(f"{source}: names no scenario file; pass --scenario")
        sc = load_scenario(named, overrides)
        _check_plan_matches(source, doc, sc)
        checked = recheck(doc, sc, _plan_start_time(source, doc, sc, for_flight))
        if not force:
            refuse_unless_passed(checked, source, sc)
        elif not checked.passed:
            checked.document["unchecked"] = checked.fault
        return checked.document, sc
    sc = load_scenario(source, with_flight_margins(source, overrides)
                       + ([f"planner.seed={seed}"] if seed is not None else []))
    start_time = None
    if len(sc.environment.threats):
        from companion.mission.builder import time_to_start

        start_time = time_to_start(sc) if for_flight else 0.0
    res = plan_scenario(sc, sc.planner, np.random.default_rng(sc.planner.seed), start_time, seed=sc.planner.seed)
    if feasible_only and not res.feasible:
        raise PlanRefused(f"{source}: no feasible plan ({res.status.value}); nothing exported")
    return plan_to_json(res, sc, start_time), sc


def _plan_start_time(source: Path, doc: dict, sc: Scenario, for_flight: bool) -> float | None:
    """The mission time at the route's start a PLAN.json is checked at: for a flight, the scenario's time to the
    start (as fly plans); otherwise the file's, which must be what `plan` (0) or `fly` (that time) wrote."""
    if not len(sc.environment.threats):
        return doc.get("start_time_s")  # nothing moves: the time does not matter
    from companion.mission.builder import time_to_start

    flight = time_to_start(sc)
    given = doc.get("start_time_s")
    if for_flight or given is None or given == 0 or abs(given - flight) < 1e-3:
        return flight if for_flight else given
    raise FuseplanError(f"{source}: start_time_s: {given:g} s is neither 0 (as `plan` writes) nor this scenario's "
                        f"time to the route's start, {flight:.3f} s (as `fly` writes)")


def with_flight_margins(source: Path, overrides: list[str]) -> list[str]:
    """``overrides`` and what a plan to be flown needs beyond the scenario's vehicle (a plane's swing past each new
    leg, vehicle_limits.flight_overrides): plan, fly and export plan with them; the paper's benches do not."""
    from companion.mavlink.vehicle_limits import flight_overrides
    from planner.world.scenario import load_scenario

    return list(overrides) + flight_overrides(load_scenario(source, overrides).vehicle)


def _check_plan_matches(source: Path, doc: dict, sc: Scenario) -> None:
    """A PLAN.json is only flown or exported with its own scenario: same name, home, start and goal, and every via
    of the scenario a waypoint of the route, in order."""
    home = doc["home"]  # shape checked: finite numbers
    same = (doc["scenario"] == sc.name
            and all(abs(float(home[k]) - getattr(sc.home, k)) < 1e-9 for k in ("lat", "lon", "alt"))
            and np.allclose(doc["waypoints"][0], sc.start) and np.allclose(doc["waypoints"][-1], sc.goal))
    if not same:
        raise FuseplanError(f"{source}: planned for scenario {doc.get('scenario')!r}, not {sc.name!r} "
                            f"({sc.source}): home, start or goal differ; plan again for this scenario")
    waypoints, at = np.asarray(doc["waypoints"], dtype=float), 0
    for i, via in enumerate(sc.vias):
        hits = np.flatnonzero(np.all(np.isclose(waypoints[at:], via), axis=1))
        if not len(hits):
            raise FuseplanError(f"{source}: the route does not pass through route.vias[{i}] of {sc.source} "
                                f"({', '.join(f'{v:g}' for v in via)}); plan again for this scenario")
        at += int(hits[0]) + 1


def cmd_plan(args: PlanArgs) -> int:
    """``fuseplan plan``: a scenario or a ground station's mission (with any zones) planned, written as PLAN.json
    or, with ``-o SAFE.plan``, as a QGroundControl plan of the safe route that keeps the mission's own fence,
    rally points and settings (written whole or not at all)."""
    import os
    import tempfile

    from planner.world.sources import is_mission, read_mission

    out, source = args.output, args.scenario
    as_qgc = out is not None and out.suffix.lower() == ".plan"
    if as_qgc:
        check_writable(out)
        if not is_mission(source):
            raise FuseplanError(f"{out}: -o *.plan keeps a ground station's mission: plan a .plan or .waypoints "
                                "mission (for a scenario, `fuseplan export --format plan`)")
    scenario = args.sources.scenario(source, out)
    args = replace(args, scenario=scenario, overrides=tuple(with_flight_margins(scenario, list(args.overrides))))
    if out is None or not as_qgc:  # as_qgc implies an out; testing it narrows out for mypy
        return planner_cli.cmd_plan(args)
    from companion.mission.builder import mission_from_plan_json, spec_from_plan_json
    from companion.mission.exports import write_operator_plan
    from planner.world.scenario import load_scenario

    mission = read_mission(source, args.sources.fence, args.sources.rally)
    autopilot: Autopilot = "px4" if mission.extras.get("firmware_type") == PX4_FIRMWARE else "ardupilot"
    with tempfile.TemporaryDirectory(prefix="fuseplan-") as tmp:
        plan_json = Path(tmp) / "PLAN.json"
        code = planner_cli.cmd_plan(replace(args, output=plan_json), announce_output=False)
        if code != EXIT_OK:
            print(f"fuseplan: {out} not written: the route is not safe", file=sys.stderr)
            return code
        doc = json.loads(plan_json.read_text())
    sc = load_scenario(scenario, list(args.overrides))
    part = out.with_name(out.name + ".part")
    try:
        write_operator_plan(part, mission_from_plan_json(doc, sc, autopilot), spec_from_plan_json(doc, sc, autopilot),
                            mission)
        os.replace(part, out)
    except ValueError as e:
        raise FuseplanError(f"{out}: cannot write: {e}") from e
    except OSError as e:
        raise FuseplanError(f"{out}: cannot write: {e.strerror or e}") from e
    finally:
        part.unlink(missing_ok=True)
    print(f"  wrote {out} ({autopilot}; its scenario: {scenario})")
    return EXIT_OK


def cmd_export(args: ExportArgs) -> int:
    """Write a mission file from a scenario (planned now) or a PLAN.json (checked again first; ``--force`` writes
    one that fails, marked unchecked in the file). Written to a temporary name and renamed: never half a file."""
    import os

    from companion.mission.exports import export_from_plan_json
    from companion.mission.fence_fit import export_fence_warning

    check_writable(args.output)
    source = args.sources.scenario(args.source, args.output)
    doc, sc = _plan_doc_for(source, args.scenario, list(args.overrides) + mode_overrides(args.paper), args.seed,
                            force=args.force)
    part = args.output.with_name(args.output.name + ".part")
    try:
        export_from_plan_json(doc, sc, args.format, part, args.autopilot, densify=args.densify)
        os.replace(part, args.output)
    except (KeyError, ValueError) as e:
        raise FuseplanError(f"{source}: cannot export: {e}") from e
    except OSError as e:
        raise FuseplanError(f"{args.output}: cannot write: {e.strerror or e}") from e
    finally:
        part.unlink(missing_ok=True)
    if doc.get("unchecked"):
        print(f"fuseplan: warning: {args.output} was written UNCHECKED (--force), and says so inside: "
              f"{doc['unchecked']}", file=sys.stderr)
    if args.format == "plan" and (too_big := export_fence_warning(doc, sc, args.autopilot)):
        print(f"fuseplan: warning: {args.output}: {too_big}", file=sys.stderr)
    if not args.quiet:
        print(f"wrote {args.output} ({args.format}, {args.autopilot})")
    return EXIT_OK


EXIT_LINK, EXIT_ABORTED, EXIT_UNSAFE = 4, 5, 6
PX4_FIRMWARE = 12  # MAV_AUTOPILOT_PX4, a .plan's firmwareType


def _seconds(value: float | None, option: str) -> float | None:
    """``option``'s value (None when not given): a finite number of seconds > 0."""
    if value is not None and not (math.isfinite(value) and value > 0):
        raise FuseplanError(f"{option} must be a finite number of seconds > 0")
    return value


def _check_report_dir(report: Path) -> None:
    """A report directory that can be made: refused before planning, so that nothing is half-written."""
    if report.exists() and not report.is_dir():
        raise FuseplanError(f"{report}: the report directory is a file")
    parent = next((a for a in report.resolve().parents if a.exists()), None)
    if parent is None or not parent.is_dir():
        raise FuseplanError(f"{report}: cannot create the report directory under {parent}")


def _vehicle_world(args: FlyArgs, scenario: Path, key: SigningKey | None) -> tuple[Any, Path]:
    """``--fence-from-vehicle`` / ``--goal-from-vehicle``: the fence, rally points and mission the operator left on
    the vehicle, downloaded over a link of its own before planning (read back by each autopilot's rules), written
    to the report as ``vehicle_world.json``; returns it and the scenario to plan: ``scenario`` with them."""
    import asyncio
    import dataclasses

    from companion.mavlink.errors import CompanionError
    from companion.mavlink.link import Link
    from companion.mavlink.protocol import MissionClient
    from companion.mission.vehicle_world import download_world
    from planner.world.sources import vehicle_scenario

    if args.sim or args.connect is None:
        raise FuseplanError("--fence-from-vehicle and --goal-from-vehicle read a real autopilot (--connect)")
    if scenario.suffix.lower() != ".toml":
        raise FuseplanError(f"{scenario}: --fence-from-vehicle and --goal-from-vehicle plan a scenario TOML (its "
                            "vehicle, band and start) with what the vehicle holds")
    wait = _seconds(args.heartbeat_timeout, "--heartbeat-timeout") or HEARTBEAT_WAIT_S
    url = args.connect

    async def read() -> OperatorMission:
        async with Link(url, open_timeout=10.0, signing_key=key, target_system=args.target_system,
                        baud=args.baud) as link:
            await link.wait_heartbeat(wait)
            return await download_world(MissionClient(link), url)

    try:
        world = asyncio.run(read())
    except (CompanionError, TimeoutError, OSError) as e:
        raise FuseplanError(f"{url}: cannot read the vehicle's fence and mission: {e}") from e
    args.report.mkdir(parents=True, exist_ok=True)
    write_text(args.report / "vehicle_world.json", json.dumps(dataclasses.asdict(world), indent=1, default=str) + "\n")
    return world, vehicle_scenario(scenario, world, args.fence_from_vehicle, args.goal_from_vehicle,
                                   args.report / scenario.name)


def _replan_config(budget: float | None, paper: bool) -> ReplanConfig | None:
    """The live replanner's settings for ``fly``: its defaults (None) unless ``--replan-budget``
    or ``--paper`` (then the replans too are the paper's planners, the scenario's settings in paper mode)."""
    from companion.replanning.replan import ReplanConfig

    if budget is None and not paper:
        return None
    if budget is None:
        return ReplanConfig(roadmap=not paper)
    return ReplanConfig(budget_s=budget, roadmap=not paper)


def cmd_fly(args: FlyArgs) -> int:
    import asyncio

    from companion.flight.fly import FlyOptions, fly
    from companion.mavlink.errors import CompanionError, FenceTooLarge
    from companion.mission.events import EventLog

    if not (math.isfinite(args.speedup) and args.speedup > 0) or not 0 <= args.sim_loss < 1:
        raise FuseplanError("--speedup must be a finite number > 0 and --sim-loss in [0, 1)")
    if not args.sim and (args.speedup != 1.0 or args.sim_loss):
        raise FuseplanError("--speedup and --sim-loss apply to the built-in simulator (--sim) only")
    if args.traffic and args.sim:
        raise FuseplanError("--traffic is for a real autopilot (--connect): the simulator flies the intruders itself")
    if not 0 < args.baud <= 10_000_000:
        raise FuseplanError(f"--baud {args.baud}: a baud rate is a positive number")
    if args.backend == "mavsdk":
        from companion.mavlink.mavsdk_backend import unsupported_options

        why = unsupported_options(signing=args.signing.given, target_system=args.target_system is not None)
        if why:
            raise FuseplanError(why)
    key = args.signing.key()
    budget = _seconds(args.replan_budget, "--replan-budget")  # every option is checked before any planning or writing
    heartbeat = _seconds(args.heartbeat_timeout, "--heartbeat-timeout")
    flight_timeout = _seconds(args.flight_timeout, "--flight-timeout")
    from companion.mavlink.link import check_url

    for option, url in (("--connect", args.connect), ("--traffic", args.traffic)):
        if url is not None:
            check_url(url, option)
    _check_report_dir(args.report)
    from planner.world.sources import is_mission

    scenario = args.scenario
    if args.sources.given() or is_mission(scenario):
        args.report.mkdir(parents=True, exist_ok=True)
        scenario = args.sources.scenario(scenario, args.report / scenario.name)
    world = None
    if args.fence_from_vehicle or args.goal_from_vehicle:
        world, scenario = _vehicle_world(args, scenario, key)
    target = args.target_system
    if target is not None and not 1 <= target <= 255:
        raise FuseplanError(f"--target-system {target}: a MAVLink system id is 1-255")
    if target is not None and args.sim:
        raise FuseplanError("--target-system is for a real autopilot (--connect): the simulator is system 1")
    status = args.status.bind()
    overrides = (list(args.overrides) + mode_overrides(args.paper)
                 + ([f'planner.algorithm="{args.algorithm}"'] if args.algorithm else []))
    say = (lambda *_: None) if args.quiet else (lambda text: print(text, flush=True))
    say(f"{'checking' if scenario.suffix.lower() == '.json' else 'planning'} {scenario.name} ...")
    doc, sc = _plan_doc_for(scenario, args.scenario_file, overrides, args.seed, feasible_only=False,
                            for_flight=True)
    try:
        args.report.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise FuseplanError(f"{args.report}: cannot create the report directory: {e.strerror or e}") from e
    write_text(args.report / "PLAN.json", json.dumps(doc, indent=1, allow_nan=False) + "\n")
    say(f"  {doc['status']}: cost {doc['cost']:.1f}, {doc['metrics']['length_m']:.0f} m, "
        f"{doc['metrics']['plan_time_s']:.2f} s")
    if doc["status"] not in ("exact", "approximate"):
        print(f"fuseplan: no feasible plan ({doc['status']}); not flying. See {args.report / 'PLAN.json'}",
              file=sys.stderr)
        return EXIT_INFEASIBLE
    opts = FlyOptions(connect=args.connect, sim=args.sim, baud=args.baud, speedup=args.speedup,
                      sim_loss=args.sim_loss, arm=args.arm, fence=not (args.no_fence or args.fence_from_vehicle),
                      densify=args.densify, report=args.report, replan=not args.no_replan,
                      replan_config=_replan_config(budget, args.paper),
                      signing_key=key, traffic=args.traffic, backend=args.backend,
                      heartbeat_timeout=HEARTBEAT_WAIT_S if heartbeat is None else heartbeat, target_system=target,
                      flight_timeout=flight_timeout,
                      plan_again=None if scenario.suffix.lower() == ".json" else (
                          lambda extra: _plan_doc_for(scenario, args.scenario_file, overrides + extra, args.seed,
                                                      feasible_only=False, for_flight=True)))
    events = EventLog(args.report / "events.jsonl", echo=None if args.quiet else _echo_event)
    if world is not None:
        events.log(Event.VEHICLE_WORLD, source=str(world.source), zones=[z.name for z in world.zones],
                   rally=len(world.rally), goal=None if world.goal is None else [world.goal.lat, world.goal.lon],
                   scenario=str(scenario))
    try:
        if status is None:
            flight = asyncio.run(fly(doc, sc, opts, events))
        else:
            from companion.status import serve_flight

            bind, token = status
            flight = asyncio.run(serve_flight(lambda: fly(doc, sc, opts, events), events, bind, token,
                                              lambda url: _announce(url, token)))
    except CompanionError as e:  # before the vehicle was armed (after it, fly reports the flight as it went)
        events.log(Event.FAILED, error=str(e))
        _unflown(args.report, str(e))
        print(f"fuseplan: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT if isinstance(e, FenceTooLarge) else EXIT_LINK  # the user's zones, not the link
    except KeyboardInterrupt:
        events.log(Event.ABORTED, reason="interrupted by the user")
        _unflown(args.report, "interrupted")
        print("fuseplan: interrupted; the vehicle keeps its current mode and mission", file=sys.stderr)
        return 130
    finally:
        events.close()
    near = f" ({flight['nearest_obstacle']})" if flight.get("nearest_obstacle") else ""
    say(f"{'completed' if flight['completed'] else 'NOT completed'}"
        f"{'' if flight['flown_safe'] else ' but UNSAFE'}: {flight['reason']}; "
        f"{len(flight['items_reached'])} items reached, upload {flight['upload_s']:.2f} s, "
        f"flown clearance {flight['min_static_clearance_m']:.1f} m{near}; report in {args.report}/")
    if flight.get("min_separation_m"):
        seps = ", ".join(f"{k} {v:.1f} m" for k, v in flight["min_separation_m"].items())
        lat = flight.get("replan_latency_s") or {}
        say(f"replans {flight['replans']}" + (f" (latency median {lat['median']:.2f} s, max {lat['max']:.2f} s)"
                                               if lat else "")
            + f"; min separation (truth): {seps}; d_coll {flight['d_coll_m']:g} m")
    if not flight["flown_safe"]:  # never a plain success, whatever the mission's own outcome
        print(f"fuseplan: UNSAFE flight ({'completed' if flight['completed'] else 'not completed'}): "
              + "; ".join(flight["breaches"]) + (" (replanning was off)" if not flight["replanning"] else ""),
              file=sys.stderr)
        return EXIT_UNSAFE
    if not flight["completed"]:
        print(f"fuseplan: flight NOT completed: {flight['reason']}", file=sys.stderr)
        return EXIT_ABORTED
    return EXIT_OK


_STYLES = {Tone.BAD: "red", Tone.WARN: "yellow", Tone.GOOD: "green"}  # rich styles, on a terminal only


def _unflown(report: Path, reason: str) -> None:
    """flight.json of a flight that ended before the vehicle was armed (after it, fly writes the whole report)."""
    doc = {"completed": False, "reason": reason, "fuseplan_version": fuseplan_version()}
    write_text(report / "flight.json", json.dumps(doc, indent=1) + "\n")


def _echo_event(rec: dict) -> None:
    """Progress lines for the events a person watching the flight cares about; replans spelled out."""
    e = BY_NAME[rec["event"]]
    if not e.echoed:
        return
    detail = {k: v for k, v in rec.items() if k not in ("t", "event")}
    if e == Event.CONFLICT:
        text = (f"CONFLICT with {rec['threat']} in {rec['in_s']:.1f} s: predicted separation "
                f"{rec['separation_m']:.1f} m (d_coll {rec['d_coll_m']:g} m) -> replan {rec['n']}")
    elif e == Event.REPLAN_PLANNED:
        text = (f"replan {rec['n']}: {rec['status']} in {rec['plan_s']:.3f} s from {rec['commit']}, "
                f"{rec['waypoints']} waypoints, predicted separation {rec['separation_after_m']:.1f} m")
    elif e == Event.REPLANNED:
        text = (f"replan {rec['n']}: new mission current {rec['latency_s']:.3f} s after the conflict was seen "
                f"(plan {rec['plan_s']:.3f} s, upload+verify+set-current {rec['upload_s']:.3f} s"
                f"{', vehicle held meanwhile' if rec['held'] else ''})")
    else:
        text = f"{e} " + " ".join(f"{k}={v}" for k, v in detail.items())
    console.say(f"  [{rec['t']:6.1f} s] {text}".rstrip(), _STYLES.get(e.tone))


def cmd_serve(args: ServeArgs) -> int:
    """``fuseplan serve CONFIG``: until SIGINT or SIGTERM (exit 0); a bad configuration is one line, exit 2."""
    from companion.service.cli import run_service

    return run_service(args.config, check_only=args.check, echo=None if args.quiet else _echo_event,
                       quiet=args.quiet)


def cmd_sim(args: SimArgs) -> int:
    import asyncio

    from companion.sim import serve
    from planner.world.scenario import load_scenario

    sc = load_scenario(args.scenario)
    if not (math.isfinite(args.speedup) and args.speedup > 0) or not 0 <= args.loss < 1 or not (
            math.isfinite(args.latency) and args.latency >= 0):
        raise FuseplanError("--speedup must be a finite number > 0, --loss in [0, 1), --latency >= 0")
    key = args.signing.key()
    if not args.quiet:
        print(f"simulated {sc.vehicle.type} for {sc.name} on {args.listen} (speed-up {args.speedup:g}); Ctrl-C stops",
              flush=True)
    try:
        asyncio.run(serve(sc, args.listen, args.speedup, args.loss, args.latency, signing_key=key))
    except KeyboardInterrupt:
        pass
    except OSError as e:
        raise FuseplanError(f"{args.listen}: cannot listen: {e.strerror or e}") from e
    return EXIT_OK


def demo_flight(args: DemoArgs) -> FlyArgs:
    """What ``demo`` flies: ``fly sitl_scenarios/rescue_dynamic.toml --sim --speedup 20 --report fuseplan-demo``,
    with demo's own -q and status page."""
    return FlyArgs(scenario=SCENARIOS / "rescue_dynamic.toml", sim=True, speedup=20.0, report=Path("fuseplan-demo"),
                   quiet=args.quiet, status=args.status)


def cmd_demo(args: DemoArgs) -> int:
    if not args.quiet:
        print("fuseplan demo: planning the dynamic rescue scenario and flying it on the built-in simulated autopilot "
              "(20x); an intruder reported over ADS-B will cross the route, and the companion holds and replans "
              "around it, or waits until it has passed when no clear route comes in time")
    return cmd_fly(demo_flight(args))


def cmd_report(args: ReportArgs) -> int:
    """A report directory's summary (flight.json), or its status page served until Ctrl-C (``--serve``)."""
    import asyncio

    from companion.status import load_events, serve_report

    status = args.status.bind()
    if status is None:
        return _summarise_report(args.directory, load_events(args.directory))
    bind, token = status
    if not args.quiet:
        print(f"serving the status page of {args.directory}; Ctrl-C stops", flush=True)
    try:
        asyncio.run(serve_report(args.directory, bind, token, lambda url: _announce(url, token)))
    except KeyboardInterrupt:
        pass
    return EXIT_OK


def _summarise_report(directory: Path, records: list[dict]) -> int:
    try:
        flight = json.loads((directory / "flight.json").read_text())
    except (OSError, ValueError):
        flight = {}
    scene = next((r for r in records if r["event"] == Event.SCENE), {})
    done = next((r for r in reversed(records) if r["event"] in ENDINGS), None)
    print(f"{directory}: {scene.get('name', 'unknown scenario')}, {len(records)} events over "
          f"{records[-1]['t'] if records else 0:.1f} s")
    if done is not None:
        print(f"  {done['event']}: {done.get('reason') or done.get('error') or ''}".rstrip())
    if flight.get("replans") is not None:
        lat = flight.get("replan_latency_s") or {}
        print(f"  replans {flight['replans']}" + (f", latency median {lat['median']:.2f} s, max {lat['max']:.2f} s"
                                                  if lat else "")
              + (f"; min clearance {clear:.1f} m" if isinstance(clear := flight.get("min_clearance_m"), (int, float))
                 else ""))
    print(f"  `fuseplan report {directory} --serve` shows the flight in a browser")
    return EXIT_OK


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args))
    except PlanRefused as e:
        print(f"fuseplan: {e}", file=sys.stderr)
        return EXIT_INFEASIBLE
    except FuseplanError as e:
        print(f"fuseplan: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except MemoryError:
        print("fuseplan: error: out of memory: lower planner.pso.n_pop, the obstacles or the map, or raise "
              "planner.sample_spacing",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    except BrokenPipeError:  # `fuseplan compare | head`: the reader left; files are already written
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
