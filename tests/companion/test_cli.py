"""`fuseplan plan` end to end: the README example, its JSON, determinism, exit codes and bad input."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from companion.cli import main

REQUIRED = {"status", "algorithm", "seed", "cost", "cost_terms", "waypoints", "trajectory", "violations",
            "metrics", "history", "home"}


def _run(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    exe = shutil.which("fuseplan")
    cmd = [exe] if exe else [sys.executable, "-m", "companion.cli"]
    return subprocess.run([*cmd, *args], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_readme_plan_example_twice_byte_identical(tmp_path, rescue_static) -> None:
    """The README's worked example: exit 0, exact, zero violations, ≤ 1.3 × direct, same waypoints twice."""
    outs = []
    for name in ("a.json", "b.json"):
        proc = _run("plan", str(rescue_static), "--algorithm", "spso", "--seed", "1", "-o", name, cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr
        assert "-> exact" in proc.stdout
        outs.append(json.loads((tmp_path / name).read_text()))
    a, b = outs
    assert REQUIRED <= a.keys()
    assert a["status"] == "exact" and a["algorithm"] == "spso" and a["seed"] == 1
    assert set(a["violations"]) >= {"collision", "altitude", "turn", "climb"}
    assert all(v == 0 for v in a["violations"].values())
    start, goal = a["waypoints"][0], a["waypoints"][-1]
    direct = sum((g - s) ** 2 for s, g in zip(start, goal)) ** 0.5
    assert a["metrics"]["length_m"] <= 1.3 * direct
    assert {"length_m", "smoothness", "robustness", "plan_time_s", "convergence_iteration"} <= a["metrics"].keys()
    assert json.dumps(a["waypoints"]) == json.dumps(b["waypoints"])
    assert a["history"] == b["history"] and len(a["history"]) == a["metrics"]["iterations"] + 1
    assert a["home"]["lat"] == pytest.approx(-35.363261)
    assert start == [200.0, 200.0, 50.0] and goal == [800.0, 800.0, 50.0]


def test_plot_and_overrides(tmp_path, rescue_static, capsys) -> None:
    png = tmp_path / "route.png"
    code = main(["plan", str(rescue_static), "--set", "planner.pso.n_pop=40", "--set", "planner.pso.max_iter=20",
                 "--algorithm", "spso", "--plot", str(png), "-q", "-o", str(tmp_path / "p.json")])
    assert code in (0, 3)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    doc = json.loads((tmp_path / "p.json").read_text())
    assert len(doc["history"]) <= 21


def test_infeasible_plan_exits_3(tmp_path, rescue_static, capsys) -> None:
    # d_coll larger than every gap between the Table 1 cylinders and a tiny budget: no feasible route
    # (the paper's planner: the roadmap pipeline finds the way round all six, 1.36 × the direct distance)
    code = main(["plan", str(rescue_static), "-q", "--set", "hazard.d_coll=60", "--set", "hazard.d_safe=80",
                 "--set", "planner.pso.n_pop=30", "--set", "planner.pso.max_iter=10", "--set",
                 "planner.roadmap.enabled=false", "-o", str(tmp_path / "p.json")])
    assert code == 3
    doc = json.loads((tmp_path / "p.json").read_text())
    assert doc["status"] == "infeasible" and doc["violations"]["collision"] > 0


def _bad(tmp_path: Path, rescue_static: Path, old: str, new: str) -> Path:
    text = rescue_static.read_text()
    assert old in text
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace(old, new, 1))
    return bad


BAD_CASES = {
    "unknown key": ("[vehicle]\n", "[vehicle]\nwingspan = 2.0\n", "vehicle", "wingspan"),
    "nan": ("cruise_speed = 18.0", "cruise_speed = nan", "vehicle.cruise_speed", None),
    "negative radius": ("radius = 80.0", "radius = -80.0", "cylinders[0].radius", None),
    "start inside obstacle": ("start = [200.0, 200.0, 50.0]", "start = [400.0, 500.0, 100.0]", "route.start",
                              "cylinders[0]"),
    "malformed toml": ("[vehicle]\n", "[vehicle\n", "bad.toml", None),
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_bad_scenario_one_line_exit_2(tmp_path, rescue_static, capsys, case) -> None:
    old, new, field, word = BAD_CASES[case]
    bad = _bad(tmp_path, rescue_static, old, new)
    code = main(["plan", str(bad), "-q"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1, err
    assert err.startswith("fuseplan: error: ") and "bad.toml" in err and field in err
    if word:
        assert word in err


def test_missing_file_exit_2(tmp_path, capsys) -> None:
    code = main(["plan", str(tmp_path / "nope.toml"), "-q"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "nope.toml" in err


def test_bad_input_in_a_real_process_has_no_traceback(tmp_path, rescue_static) -> None:
    bad = _bad(tmp_path, rescue_static, "radius = 80.0", "radius = -80.0")
    proc = _run("plan", str(bad), cwd=tmp_path)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("fuseplan: error: ")


def _empty_map(tmp_path: Path, rescue_static: Path) -> Path:
    text = rescue_static.read_text()
    cut = text.index("[[cylinders]]")
    path = tmp_path / "empty.toml"
    path.write_text(text[:cut])
    return path


def test_empty_map_plan_is_feasible_strict_json(tmp_path, rescue_static) -> None:
    """No obstacles: the destination term pulls P_n onto G; the near-zero last leg must not read as a turn
    violation, and the infinite clearance must not become a non-JSON Infinity."""
    empty = _empty_map(tmp_path, rescue_static)
    for seed in ("1", "8"):
        code = main(["plan", str(empty), "-q", "--seed", seed, "--set", "planner.pso.n_pop=100",
                     "-o", str(tmp_path / "e.json")])
        assert code == 0
        text = (tmp_path / "e.json").read_text()
        doc = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-JSON constant {c}"))
        assert doc["status"] == "exact"
        assert doc["metrics"]["min_clearance_m"] is None
        wp = doc["waypoints"]
        gaps = [sum((q - p) ** 2 for p, q in zip(a, b)) ** 0.5 for a, b in zip(wp, wp[1:])]
        assert min(gaps) >= 1.0


MORE_BAD = {
    "zero d_safe": (["--set", "hazard.d_safe=0", "--set", "hazard.d_coll=0"], "hazard.d_safe"),
    "negative seed": (["--seed", "-1"], "planner.seed"),
    "huge swarm": (["--set", "planner.pso.n_pop=100000000"], "planner.pso.n_pop"),
    "tiny sample spacing": (["--set", "planner.sample_spacing=1e-9"], "planner.sample_spacing"),
    "runaway damping": (["--set", "planner.pso.w_damp=1e300"], "planner.pso.w_damp"),
    "goal on start": (["--set", "route.goal=[200.0, 200.0, 50.0]"], "route.goal"),
    "plot not png": (["--plot", "out.xyz"], "out.xyz"),
    "output dir missing": (["-o", "/nonexistent/dir/p.json"], "/nonexistent/dir"),
}


@pytest.mark.parametrize("case", sorted(MORE_BAD))
def test_more_user_mistakes_exit_2_with_one_line(rescue_static, capsys, case) -> None:
    extra, word = MORE_BAD[case]
    code = main(["plan", str(rescue_static), "-q", *extra])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and word in err


@pytest.mark.parametrize("init", ["gkdm", "hard", "uniform"])
def test_fusion_plan_json_records_phases(tmp_path, rescue_static, init) -> None:
    out = tmp_path / "f.json"
    code = main(["plan", str(rescue_static), "-q", "--aco-init", init, "--set", "planner.pso.n_pop=60",
                 "--set", "planner.pso.max_iter=30", "--set", "planner.aco.max_iter=10", "-o", str(out)])
    assert code in (0, 3)
    doc = json.loads(out.read_text())
    assert doc["algorithm"] == "fusion"
    ph = doc["phases"]
    assert {"pso", "aco", "winner"} <= ph.keys()
    for name in ("pso", "aco"):
        assert {"best_cost", "iterations", "time_s"} <= ph[name].keys()
    assert ph["winner"] in ph.keys() - {"winner", "roadmap"}
    assert doc["cost"] <= ph["pso"]["best_cost"] + 1e-9
    # the history: SPSO's initial best, then the best so far after every iteration of every search phase (the
    # roadmap's routes and the guide's repair rounds are not iterations of a search)
    assert len(doc["history"]) == 1 + sum(p["iterations"] for k, p in ph.items()
                                          if k not in ("winner", "roadmap", "repair"))
    assert doc["history"][-1] == doc["cost"] and all(np.diff(doc["history"]) <= 0)


def test_compare_table_csv_and_png_from_the_runs(tmp_path, rescue_static, capsys) -> None:
    import csv

    small = ["--set", "planner.pso.n_pop=30", "--set", "planner.pso.max_iter=8", "--set", "planner.aco.max_iter=4"]
    args = ["compare", str(rescue_static), "--runs", "3", "--seed", "5", "--algorithms", "spso,qpso,fusion", "-q"]
    assert main([*args, *small, "--workers", "1", "-o", str(tmp_path / "w1")]) == 0
    table = capsys.readouterr().out
    assert table.count("\n| ") == 3 and table.startswith("| algorithm |") and "| fusion |" in table
    assert main([*args, *small, "--workers", "2", "-o", str(tmp_path / "w2")]) == 0
    runs1 = list(csv.DictReader((tmp_path / "w1" / "compare_runs.csv").open()))
    runs2 = list(csv.DictReader((tmp_path / "w2" / "compare_runs.csv").open()))
    assert [r["cost"] for r in runs1] == [r["cost"] for r in runs2]  # workers change nothing but times
    assert [int(r["seed"]) for r in runs1 if r["algorithm"] == "spso"] == [5, 6, 7]
    summary = {r["algorithm"]: r for r in csv.DictReader((tmp_path / "w1" / "compare.csv").open())}
    assert set(summary) == {"spso", "qpso", "fusion"}
    for alg, row in summary.items():
        costs = [float(r["cost"]) for r in runs1 if r["algorithm"] == alg]
        assert float(row["cost_mean"]) == pytest.approx(sum(costs) / 3)
        assert float(row["runs"]) == 3
        ok = [r["feasible"] == "True" for r in runs1 if r["algorithm"] == alg]
        assert float(row["success_rate"]) == pytest.approx(sum(ok) / 3)
    assert (tmp_path / "w1" / "compare.png").read_bytes()[:4] == b"\x89PNG"


def test_compare_rejects_unknown_algorithm(rescue_static, capsys) -> None:
    assert main(["compare", str(rescue_static), "--algorithms", "spso,magic", "-q"]) == 2
    assert "magic" in capsys.readouterr().err


@pytest.mark.parametrize("extra,word", [
    (["--algorithms", ""], "no algorithm"),
    (["--algorithms", ","], "no algorithm"),
    (["--workers", "-1"], "--workers"),
    (["--runs", "0"], "--runs"),
    (["--set", "planner.aco.n_ants=0"], "planner.aco.n_ants"),
    (["--set", "planner.aco.sigma=0"], "planner.aco.sigma"),
    (["--set", "planner.bpso.bits_cross=30"], "planner.bpso.bits_cross"),
])
def test_compare_user_mistakes_exit_2(rescue_static, capsys, tmp_path, extra, word) -> None:
    code = main(["compare", str(rescue_static), "-q", "-o", str(tmp_path / "c"), *extra])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and word in err


def test_compare_output_checked_before_running(rescue_static, capsys, tmp_path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["compare", str(rescue_static), "-q", "-o", str(blocker)]) == 2
    assert "cannot create the output directory" in capsys.readouterr().err


def _run_on_a_terminal(*args: str, cwd: Path) -> tuple[int, str]:
    """Run ``fuseplan`` with stdout and stderr on a pseudo-terminal, as a person at a shell would: exit code and
    all it drew."""
    import os
    import pty

    exe = shutil.which("fuseplan")
    cmd = [exe] if exe else [sys.executable, "-m", "companion.cli"]
    master, slave = pty.openpty()
    env = {**os.environ, "TERM": "xterm-256color", "COLUMNS": "120"}
    proc = subprocess.Popen([*cmd, *args], cwd=cwd, stdin=slave, stdout=slave, stderr=slave, env=env)
    os.close(slave)
    chunks = []
    while True:
        try:
            data = os.read(master, 65536)
        except OSError:  # EIO: the child closed the terminal
            break
        if not data:
            break
        chunks.append(data)
    os.close(master)
    return proc.wait(timeout=300), b"".join(chunks).decode(errors="replace")


SMALL = ["--set", "planner.pso.n_pop=30", "--set", "planner.pso.max_iter=8", "--set", "planner.aco.max_iter=4"]


def test_compare_on_a_terminal_draws_a_bar_and_a_table_and_on_a_pipe_stays_plain(tmp_path, rescue_static) -> None:
    args = ["compare", str(rescue_static), "--runs", "1", "--algorithms", "spso,qpso", "--workers", "1", *SMALL]
    code, drawn = _run_on_a_terminal(*args, "-o", str(tmp_path / "tty"), cwd=tmp_path)
    assert code == 0, drawn
    assert "\x1b[" in drawn  # styled
    assert "2/2" in drawn  # the progress bar's count at the end
    assert "|---|" not in drawn and "───" in drawn and "spso" in drawn and "qpso" in drawn  # a drawn table
    piped = _run(*args, "-o", str(tmp_path / "pipe"), cwd=tmp_path)
    assert piped.returncode == 0, piped.stderr
    assert "\x1b[" not in piped.stdout + piped.stderr
    assert piped.stdout.startswith("| algorithm |") and "|---|" in piped.stdout
    assert "  runs: 2/2" in piped.stderr  # a log gets one line per tenth, not a redrawn bar


def test_plan_on_a_terminal_shows_the_search_progress(tmp_path, rescue_static) -> None:
    code, drawn = _run_on_a_terminal("plan", str(rescue_static), "--algorithm", "spso", *SMALL, cwd=tmp_path)
    assert code in (0, 3), drawn  # a budget this small may end infeasible; the bar is what is tested
    assert "iteration" in drawn and "best cost" in drawn and "8/8" in drawn
    assert "rescue_static: spso seed" in drawn


@pytest.mark.parametrize("var,value", [("FUSEPLAN_KERNEL", "reference"), ("FUSEPLAN_BROAD_PHASE", "maybe")])
def test_an_unknown_kernel_setting_is_one_line_and_exit_2(rescue_static, capsys, monkeypatch, var, value) -> None:
    monkeypatch.setenv(var, value)
    assert main(["plan", str(rescue_static), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{var}={value!r}" in err and "Traceback" not in err, err
