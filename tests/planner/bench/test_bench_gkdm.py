"""`fuseplan bench gkdm | large-scale` at tiny budgets: files and columns, table statistics computed from
the runs CSV, and the same tables (times aside) whatever the number of workers. Also the `aco` algorithm.
(`bench speed` has its own parts and tests: tests/planner/bench/test_speed.py.)"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from companion.cli import main

TINY = ["--runs", "2", "--set", "planner.pso.n_pop=20", "--set", "planner.pso.max_iter=5",
        "--set", "planner.aco.n_ants=8", "-q"]
FILES = {
    "gkdm": ("gkdm.md", "gkdm.csv", "gkdm_runs.csv", "gkdm.png", "gkdm_convergence.png"),
    "large-scale": ("large-scale.md", "large-scale.csv", "large-scale_runs.csv", "large-scale.png",
                    "large-scale_convergence.png"),
}
MEAN_COLUMNS = {  # columns whose table mean must equal the runs CSV mean (NaN runs excluded)
    "gkdm": ("cost", "length_m", "evaluations", "pso_cost", "aco_gain_pct", "evals_to_target",
             "time_to_target_s"),
    "large-scale": ("cost", "length_m", "smoothness", "convergence_iteration", "violations"),
}
TIME_COLUMNS = ("time_s", "time_s_mean", "time_s_std", "time_per_eval_us", "time_per_eval_us_mean",
                "time_per_eval_us_std", "time_to_target_s", "time_to_target_s_mean", "time_to_target_s_std")


def _rows(path: Path) -> list[dict[str, str]]:
    return list(csv.DictReader(path.open()))


def _without_times(rows: list[dict[str, str]]) -> list[dict[str, str]]:
    return [{k: v for k, v in r.items() if k not in TIME_COLUMNS} for r in rows]


@pytest.fixture(scope="module", params=sorted(FILES))
def bench(request, tmp_path_factory) -> tuple[str, Path]:
    out = tmp_path_factory.mktemp(request.param)
    assert main(["bench", request.param, "-o", str(out), *TINY, "--workers", "1"]) == 0
    return request.param, out


def test_files_exist(bench) -> None:
    name, out = bench
    for f in FILES[name]:
        assert (out / f).stat().st_size > 0, f
        if f.endswith(".png"):
            assert (out / f).read_bytes()[:4] == b"\x89PNG"
    md = (out / f"{name}.md").read_text()
    assert "|---|" in md
    assert "reproduced" in md


def test_table_means_come_from_the_runs(bench) -> None:
    name, out = bench
    runs = _rows(out / f"{name}_runs.csv")
    table = _rows(out / f"{name}.csv")
    assert [int(r["runs"]) for r in table] == [2] * len(table)
    assert sorted({r["variant"] for r in runs}) == sorted(r["variant"] for r in table)
    for row in table:
        mine = [r for r in runs if r["variant"] == row["variant"]]
        for col in MEAN_COLUMNS[name]:
            x = np.array([float(r[col]) for r in mine])
            x = x[~np.isnan(x)]
            want = x.mean() if len(x) else math.nan
            got = float(row[f"{col}_mean"])
            assert (math.isnan(got) and math.isnan(want)) or got == pytest.approx(want, rel=1e-12, abs=1e-12), \
                (row["variant"], col)
        assert float(row["success_rate"]) == pytest.approx(np.mean([r["feasible"] == "True" for r in mine]))


def test_same_tables_whatever_the_workers(bench, tmp_path) -> None:
    name, out = bench
    assert main(["bench", name, "-o", str(tmp_path), *TINY, "--workers", "2"]) == 0
    for f in (f"{name}.csv", f"{name}_runs.csv"):
        assert _without_times(_rows(tmp_path / f)) == _without_times(_rows(out / f)), f


def test_gkdm_arms_and_target(tmp_path) -> None:
    from planner.bench import gkdm

    assert main(["bench", "gkdm", "-o", str(tmp_path), *TINY, "--workers", "2"]) == 0
    runs = _rows(tmp_path / "gkdm_runs.csv")
    assert [r["variant"] for r in runs] == [k for k in ("G", "H", "U", "A", "E") for _ in range(2)]
    target = gkdm.TARGET_FACTOR * float(np.median([float(r["cost"]) for r in runs if r["variant"] == "G"]))
    assert f"{target:.2f}" in (tmp_path / "gkdm.md").read_text()
    for r in runs:  # fusion arms record their SPSO phase; cold colonies have none
        assert math.isnan(float(r["pso_cost"])) == (r["variant"] in ("A", "E"))
        if r["variant"] in ("G", "H", "U"):
            assert float(r["cost"]) <= float(r["pso_cost"])
        if not math.isnan(float(r["evals_to_target"])):
            assert 0 < float(r["evals_to_target"]) <= float(r["evaluations"])
    assert {int(r["evaluations"]) for r in runs if r["variant"] == "E"} == {8 * gkdm.COLD_MATCHED_ITERS + 1}


def test_cold_colony_algorithm() -> None:
    from planner.bench.runner import SCENARIO_DIR
    from planner.plan import plan, problem_from_scenario
    from planner.world.scenario import load_scenario

    sc = load_scenario(SCENARIO_DIR / "rescue_static.toml",
                       ['planner.algorithm="aco"', "planner.aco.max_iter=3", "planner.aco.n_ants=5"])
    res = plan(problem_from_scenario(sc), sc.planner, np.random.default_rng(1))
    assert res.algorithm == "aco"
    assert res.optimiser.iterations == 3 and res.optimiser.evaluations == 16
    assert len(res.optimiser.history) == 3 and res.optimiser.history[-1] == res.optimiser.cost
