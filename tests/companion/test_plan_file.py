"""A PLAN.json is checked before anything leaves the companion (issue 33): `fly` and `export` check its route again
against its scenario and refuse a tampered one (exit 3, one line), refuse a malformed one (exit 2, one line), and
leave nothing half-written; `export --force` writes it marked UNCHECKED. Every option is checked before planning."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from companion.cli import main
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]
STATIC = ROOT / "sitl_scenarios" / "rescue_static.toml"
FAST = ["--set", "planner.pso.n_pop=200", "--set", "planner.pso.max_iter=80"]


@pytest.fixture(scope="module")
def good_plan(static_plan_doc) -> dict:
    return static_plan_doc()


def _one_line(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, lines
    return lines[0]


def _tampered(good: dict, how: str) -> dict:
    doc = json.loads(json.dumps(good))
    sc = load_scenario(STATIC)
    wp = doc["waypoints"]
    i = len(wp) // 2
    if how == "into a cylinder":
        cx, cy = sc.environment.cylinders.x[0], sc.environment.cylinders.y[0]
        wp[i] = [float(cx), float(cy), wp[i][2]]
    elif how == "5 km outside the map":
        wp[i] = [wp[i][0] + 5000.0, wp[i][1], wp[i][2]]
    elif how == "z = -200 m":
        wp[i] = [wp[i][0], wp[i][1], -200.0]
    elif how == "z = 1e6 m":
        wp[i] = [wp[i][0], wp[i][1], 1e6]
    elif how == "status infeasible":
        doc["status"] = "infeasible"
    return doc


TAMPERED = {"into a cylinder": "collision", "5 km outside the map": "bounds", "z = -200 m": "altitude",
            "z = 1e6 m": "altitude", "status infeasible": "infeasible"}


@pytest.mark.parametrize("how", list(TAMPERED))
def test_a_tampered_plan_is_refused_by_fly_and_export_with_exit_3(good_plan, tmp_path, capsys, how) -> None:
    path = tmp_path / "PLAN.json"
    path.write_text(json.dumps(_tampered(good_plan, how)))
    report = tmp_path / "report"
    assert main(["fly", str(path), "--sim", "--speedup", "20", "--report", str(report), "-q"]) == 3
    line = _one_line(capsys)
    assert line.startswith(f"fuseplan: {path}: refused: checked against scenario 'rescue_static'"), line
    assert TAMPERED[how] in line, line
    assert not report.exists()  # nothing written, nothing flown
    for fmt in ("waypoints", "plan", "geojson"):
        out = tmp_path / f"m.{fmt}"
        assert main(["export", str(path), "--format", fmt, "-o", str(out)]) == 3
        assert TAMPERED[how] in _one_line(capsys)
        assert not out.exists() and not list(tmp_path.glob("*.part"))


def test_the_refusal_names_the_obstacle_and_how_far_inside(good_plan, tmp_path, capsys) -> None:
    path = tmp_path / "PLAN.json"
    path.write_text(json.dumps(_tampered(good_plan, "into a cylinder")))
    assert main(["export", str(path), "--format", "plan", "-o", str(tmp_path / "x.plan")]) == 3
    line = _one_line(capsys)
    assert "comes -" in line and "cylinders[0]" in line and "d_coll" in line, line


@pytest.mark.parametrize("fmt", ["waypoints", "plan", "geojson"])
def test_export_force_writes_it_marked_unchecked(good_plan, tmp_path, capsys, fmt) -> None:
    from pymavlink import mavwp

    path = tmp_path / "PLAN.json"
    path.write_text(json.dumps(_tampered(good_plan, "into a cylinder")))
    out = tmp_path / f"m.{fmt}"
    assert main(["export", str(path), "--format", fmt, "-o", str(out), "--force"]) == 0
    assert "UNCHECKED" in _one_line(capsys)  # the warning on stderr
    text = out.read_text()
    assert "UNCHECKED" in text and "collision" in text
    if fmt == "waypoints":  # still loads where '#' lines are comments (pymavlink, MAVProxy's `wp load`)
        assert mavwp.MAVWPLoader().load(str(out)) > 2
    else:
        json.loads(text)


def test_an_untouched_plan_passes_its_check_and_is_exported(good_plan, tmp_path, capsys) -> None:
    path = tmp_path / "PLAN.json"
    path.write_text(json.dumps(good_plan))
    out = tmp_path / "m.plan"
    assert main(["export", str(path), "--format", "plan", "-o", str(out)]) == 0
    assert "UNCHECKED" not in out.read_text()


def _malformed(good: dict, how: str) -> str:
    doc = json.loads(json.dumps(good))
    if how == "NaN waypoint":
        doc["waypoints"][1][0] = math.nan
        return json.dumps(doc, allow_nan=True)
    if how == "missing waypoints":
        del doc["waypoints"]
    elif how == "home as a list":
        doc["home"] = [1, 2, 3]
    elif how == "empty waypoints":
        doc["waypoints"] = []
    elif how == "a string waypoint":
        doc["waypoints"][1] = "x"
    elif how == "no status":
        del doc["status"]
    elif how == "not JSON":
        return "{ this is not json"
    elif how == "nested 100000 deep":
        return "[" * 100_000 + "]" * 100_000
    elif how == "a list":
        return "[1, 2]"
    elif how == "a huge integer":
        doc["waypoints"][1][2] = 10**400
    return json.dumps(doc)


MALFORMED = ["NaN waypoint", "missing waypoints", "home as a list", "empty waypoints", "a string waypoint",
             "no status", "not JSON", "nested 100000 deep", "a list", "a huge integer"]


@pytest.mark.parametrize("how", MALFORMED)
def test_a_malformed_plan_gives_one_line_and_exit_2_and_writes_nothing(good_plan, tmp_path, capsys, how) -> None:
    path = tmp_path / "PLAN.json"
    path.write_text(_malformed(good_plan, how))
    report = tmp_path / "report"
    assert main(["fly", str(path), "--sim", "--report", str(report), "-q"]) == 2
    line = _one_line(capsys)
    assert line.startswith(f"fuseplan: error: {path}"), line
    assert not report.exists()
    out = tmp_path / "m.plan"
    assert main(["export", str(path), "--format", "plan", "-o", str(out)]) == 2
    _one_line(capsys)
    assert not out.exists()


def test_a_plan_file_that_is_a_fifo_or_dev_zero_is_refused_at_once(tmp_path, capsys) -> None:
    import os

    fifo = tmp_path / "PLAN.json"
    os.mkfifo(fifo)
    assert main(["export", str(fifo), "--format", "plan", "-o", str(tmp_path / "m.plan")]) == 2
    assert "FIFO" in _one_line(capsys)
    link = tmp_path / "zero.json"
    link.symlink_to("/dev/zero")
    assert main(["export", str(link), "--format", "plan", "-o", str(tmp_path / "m.plan")]) == 2
    assert "device" in _one_line(capsys)


@pytest.mark.parametrize("option,value,words", [
    ("--heartbeat-timeout", "0", "--heartbeat-timeout must be"),
    ("--flight-timeout", "-1", "--flight-timeout must be"),
    ("--replan-budget", "-1", "--replan-budget must be"),
    ("--connect", "tcp:127.0.0.1:notaport", "--connect 'tcp:127.0.0.1:notaport'"),
    ("--connect", "bogus", "unknown connection type"),
    ("--target-system", "300", "--target-system 300"),
])
def test_every_fly_option_is_checked_before_planning(tmp_path, capsys, option, value, words) -> None:
    """A bad option is refused in one line, exit 2, before any planning (a scenario that would take minutes to
    plan is refused at once) and before the report directory exists."""
    report = tmp_path / "report"
    where = [] if option == "--connect" else ["--connect", "tcp:127.0.0.1:5760"]
    code = main(["fly", str(STATIC), *where, option, value, "--report", str(report), "-q",
                 "--set", "planner.pso.max_iter=100000"])
    assert code == 2
    assert words in _one_line(capsys)
    assert not report.exists()


def test_a_plan_with_moving_threats_is_checked_at_the_time_it_will_be_flown(tmp_path, capsys) -> None:
    """The mission time of the route's start is not taken from the file on trust: `export` takes 0 (as `plan`
    writes) or the scenario's time to the start (as `fly` writes), and refuses any other in one line."""
    dynamic = ROOT / "sitl_scenarios" / "rescue_dynamic.toml"
    path = tmp_path / "PLAN.json"
    assert main(["plan", str(dynamic), "-o", str(path), *FAST]) == 0
    capsys.readouterr()
    doc = json.loads(path.read_text())
    for start, code in ((None, None), (0, None), (999.0, 2)):
        doc["start_time_s"] = start
        path.write_text(json.dumps(doc))
        got = main(["export", str(path), "--format", "geojson", "-o", str(tmp_path / "m.geojson")])
        if code is None:
            assert got in (0, 3)  # checked at that time: whichever the route's verdict there
            capsys.readouterr()
        else:
            assert got == code and "start_time_s: 999 s is neither 0" in _one_line(capsys)
