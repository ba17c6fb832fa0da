"""The command line's habits (issue 36): -v/-q on every subcommand wherever they are written, help text and
defaults on every option, --version, each subcommand dispatched on its own options object (demo's is fly's), and
fly's --baud reaching the serial port it opens."""

from __future__ import annotations

import argparse
import dataclasses
import importlib.metadata
import os
import termios
from pathlib import Path

import pytest

from companion.cli import (
    SCENARIOS,
    DemoArgs,
    FlyArgs,
    SigningArgs,
    StatusArgs,
    _parser,
    demo_flight,
    main,
)
from planner.cli import HelpFormatter, SourceArgs

STATIC = SCENARIOS / "rescue_static.toml"
QUICK_PLAN = ["--set", "planner.pso.n_pop=200", "--set", "planner.pso.max_iter=80"]
# the fewest arguments each subcommand parses with
MINIMAL = {"plan": ["s.toml"], "compare": ["s.toml"], "bench": ["ablation"],
           "export": ["s.toml", "--format", "plan", "-o", "x.plan"], "fly": ["s.toml", "--sim"], "sim": ["s.toml"],
           "demo": [], "report": ["dir"], "serve": ["serve.toml"]}


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def test_every_subcommand_is_covered_here() -> None:
    assert set(_subparsers(_parser())) == set(MINIMAL)


@pytest.mark.parametrize("name", sorted(MINIMAL))
@pytest.mark.parametrize("flag,dest", [("-v", "verbose"), ("--verbose", "verbose"), ("-q", "quiet"),
                                       ("--quiet", "quiet")])
def test_v_and_q_work_before_and_after_every_subcommand(name: str, flag: str, dest: str) -> None:
    other = {"verbose": "quiet", "quiet": "verbose"}[dest]
    parser = _parser()
    plain = parser.parse_args([name, *MINIMAL[name]])
    assert getattr(plain, dest) is False and getattr(plain, other) is False
    for argv in ([flag, name, *MINIMAL[name]], [name, flag, *MINIMAL[name]], [name, *MINIMAL[name], flag]):
        args = parser.parse_args(argv)
        assert getattr(args, dest) is True, argv  # not undone by the subcommand's own defaults
        assert getattr(args, other) is False, argv
    both = parser.parse_args(["-v", name, *MINIMAL[name], "-q"])
    assert both.verbose is True and both.quiet is True


def _options(parser: argparse.ArgumentParser) -> list[tuple[str, argparse.Action]]:
    found = [(parser.prog, a) for a in parser._actions if not isinstance(a, argparse._HelpAction)]
    for sub in _subparsers(parser).values():
        found += [(sub.prog, a) for a in sub._actions if not isinstance(a, argparse._HelpAction)]
    return found


def test_every_option_and_argument_has_help_text() -> None:
    options = _options(_parser())
    assert len(options) > 90  # the walk reached the subcommands
    missing = [f"{prog} {'/'.join(a.option_strings) or a.dest}" for prog, a in options
               if not (a.help and a.help.strip() and a.help != argparse.SUPPRESS)]
    assert missing == []


def test_help_shows_every_default_worth_showing_and_no_none() -> None:
    parser = _parser()
    for sub in [parser, *_subparsers(parser).values()]:
        formatter = HelpFormatter(sub.prog)
        for action in sub._actions:
            if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)) or not action.option_strings:
                continue
            text = formatter._expand_help(action) if action.help else ""
            assert "None" not in text, (sub.prog, action.option_strings, text)
            shown = action.default not in (None, [], argparse.SUPPRESS) and not isinstance(action.default, bool)
            if shown:
                assert "default" in text.lower(), (sub.prog, action.option_strings, text)
    fly = _subparsers(parser)["fly"].format_help()
    assert "(default: 57600)" in " ".join(fly.split())  # --baud
    assert "(default: fuseplan-report)" in " ".join(fly.split())


def test_version_prints_the_installed_version(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0
    assert capsys.readouterr().out == f"fuseplan {importlib.metadata.version('fuseplan')}\n"


def test_every_subcommand_runs_its_own_function() -> None:
    parser = _parser()
    funcs = {name: parser.parse_args([name, *MINIMAL[name]]).func for name in MINIMAL}
    assert all(callable(f) for f in funcs.values())
    assert len({id(f) for f in funcs.values()}) == len(funcs)


def _fly(*argv: str) -> FlyArgs:
    return FlyArgs.from_args(_parser().parse_args(["fly", *argv]))


def test_fly_options_defaults_are_the_parsers() -> None:
    assert _fly("s.toml", "--sim") == FlyArgs(scenario=Path("s.toml"), sim=True)
    assert _fly("s.toml", "--connect", "/dev/ttyUSB0", "--baud", "115200").baud == 115200


def test_demo_flies_what_fuseplan_fly_would_with_the_same_options() -> None:
    demo = demo_flight(DemoArgs.from_args(_parser().parse_args(["demo"])))
    assert demo == _fly(str(SCENARIOS / "rescue_dynamic.toml"), "--sim", "--speedup", "20", "--report",
                        "fuseplan-demo")
    # what the hand-built Namespace said, and what fly read from it with getattr(args, ..., default)
    assert (demo.connect, demo.sim, demo.speedup, demo.sim_loss, demo.arm, demo.no_fence, demo.densify) == (
        None, True, 20.0, 0.0, False, False, False)
    assert (demo.report, demo.scenario_file, demo.overrides, demo.seed, demo.algorithm, demo.quiet) == (
        Path("fuseplan-demo"), None, (), None, None, False)
    assert (demo.no_replan, demo.replan_budget, demo.traffic, demo.backend, demo.target_system) == (
        False, None, None, "pymavlink", None)
    assert (demo.heartbeat_timeout, demo.flight_timeout, demo.paper) == (None, None, False)
    assert (demo.fence_from_vehicle, demo.goal_from_vehicle) == (False, False)
    assert demo.signing == SigningArgs() and demo.sources == SourceArgs() and demo.status == StatusArgs()


def test_demo_passes_its_status_page_and_quiet_to_the_flight(tmp_path: Path) -> None:
    token = tmp_path / "token"
    argv = ["--status-page", "0", "--status-token", str(token), "--status-host", "box.example", "--insecure-key-file"]
    demo = demo_flight(DemoArgs.from_args(_parser().parse_args(["demo", "-q", *argv])))
    fly = _fly(str(SCENARIOS / "rescue_dynamic.toml"), "--sim", "--speedup", "20", "--report", "fuseplan-demo", "-q",
               *argv)
    assert demo.status == StatusArgs("0", token, ("box.example",), True) and demo.quiet
    assert dataclasses.replace(demo, signing=fly.signing) == fly  # fly's --insecure-key-file also covers signing


def test_report_status_options_name_serve_in_their_messages(tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["report", str(tmp_path), "--status-token", str(tmp_path / "t")]) == 2
    assert "--status-token goes with --serve" in capsys.readouterr().err


def _speed(fd: int) -> int:
    return termios.tcgetattr(fd)[5]  # the output speed; on a pty pair the master reads the slave's settings


@pytest.mark.parametrize("extra,speed", [([], termios.B57600), (["--baud", "115200"], termios.B115200)])
def test_baud_reaches_the_serial_port_fly_opens(tmp_path: Path, extra: list[str], speed: int,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """fly on a pseudo-terminal (a serial port nobody answers on): the port is opened at --baud, then the flight is
    refused for want of a HEARTBEAT (exit 4)."""
    master, slave = os.openpty()
    try:
        termios.tcsetattr(slave, termios.TCSANOW, [*termios.tcgetattr(slave)[:4], termios.B9600, termios.B9600,
                                                   termios.tcgetattr(slave)[6]])
        assert _speed(master) == termios.B9600
        code = main(["fly", str(STATIC), "--connect", os.ttyname(slave), *extra, "--heartbeat-timeout", "0.5",
                     "--report", str(tmp_path / "report"), "-q", *QUICK_PLAN])
        assert code == 4, capsys.readouterr().err
        assert _speed(master) == speed
    finally:
        os.close(slave)
        os.close(master)


def test_a_baud_that_is_not_a_rate_is_refused_before_planning(tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["fly", str(STATIC), "--connect", "/dev/ttyUSB0", "--baud", "0", "--report",
                 str(tmp_path / "r")]) == 2
    assert "--baud 0" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()
