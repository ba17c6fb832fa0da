"""`fuseplan bench ablation` at a tiny budget: files and columns, statistics from the runs, worker-count
independence, resume after an interruption, unknown bench names."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from companion.cli import main

TINY = ["--runs", "2", "--set", "planner.pso.n_pop=20", "--set", "planner.pso.max_iter=5", "-q"]
VARIANTS = ["V1", "V2", "V3", "V4", "V5", "V1R"]
TIME_COLUMNS = ("time_s", "time_s_mean", "time_s_std")  # wall clock: the only numbers allowed to differ


def _bench(out: Path, *extra: str) -> int:
    return main(["bench", "ablation", "-o", str(out), *TINY, *extra])


def _rows(path: Path) -> list[dict[str, str]]:
    return list(csv.DictReader(path.open()))


def _without_times(rows: list[dict[str, str]]) -> list[dict[str, str]]:
    return [{k: v for k, v in r.items() if k not in TIME_COLUMNS} for r in rows]


@pytest.fixture(scope="module")
def bench_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("ablation")
    assert _bench(out, "--workers", "1") == 0
    return out


def test_files_and_columns(bench_dir) -> None:
    for name in ("ablation.md", "ablation.csv", "ablation_runs.csv", "ablation.jsonl", "ablation.png",
                 "ablation_convergence.png"):
        assert (bench_dir / name).stat().st_size > 0, name
    assert (bench_dir / "ablation.png").read_bytes()[:4] == b"\x89PNG"
    summary = _rows(bench_dir / "ablation.csv")
    assert [r["variant"] for r in summary] == VARIANTS
    for col in ("cost_mean", "cost_std", "length_m_mean", "length_m_std", "time_s_mean", "time_s_std",
                "convergence_iteration_mean", "convergence_iteration_std", "delta_cost_pct", "p_ranksums",
                "success_rate", "runs"):
        assert col in summary[0], col
    runs = _rows(bench_dir / "ablation_runs.csv")
    assert [(r["variant"], int(r["run"]), int(r["seed"])) for r in runs] == [
        (v, r, 2000 + r) for v in VARIANTS for r in range(2)]
    md = (bench_dir / "ablation.md").read_text()
    assert "+83.3" in md and "w/o spherical" in md and "not given" in md
    assert "reproduced" in md


def test_table_statistics_come_from_the_runs(bench_dir) -> None:
    from scipy.stats import ranksums

    runs = _rows(bench_dir / "ablation_runs.csv")
    summary = {r["variant"]: r for r in _rows(bench_dir / "ablation.csv")}
    cost = {v: np.array([float(r["cost"]) for r in runs if r["variant"] == v]) for v in VARIANTS}
    for v in VARIANTS:
        row = summary[v]
        for col in ("cost", "length_m", "convergence_iteration"):
            x = np.array([float(r[col]) for r in runs if r["variant"] == v])
            assert float(row[f"{col}_mean"]) == pytest.approx(x.mean(), rel=1e-12)
            assert float(row[f"{col}_std"]) == pytest.approx(x.std(ddof=1), rel=1e-12, abs=1e-12)
        assert float(row["delta_cost_pct"]) == pytest.approx(
            100 * (cost[v].mean() - cost["V1"].mean()) / cost["V1"].mean(), rel=1e-12, abs=1e-12)
        feasible = [r["feasible"] == "True" for r in runs if r["variant"] == v]
        assert float(row["success_rate"]) == pytest.approx(np.mean(feasible))
        if v != "V1":
            assert float(row["p_ranksums"]) == pytest.approx(ranksums(cost[v], cost["V1"]).pvalue, rel=1e-12)
    assert f"{float(summary['V1']['cost_mean']):.1f} ± " in (bench_dir / "ablation.md").read_text()


def test_same_seeds_same_tables_whatever_the_workers(bench_dir, tmp_path) -> None:
    assert _bench(tmp_path, "--workers", "2") == 0
    for name in ("ablation.csv", "ablation_runs.csv"):
        assert _without_times(_rows(tmp_path / name)) == _without_times(_rows(bench_dir / name)), name


def test_resume_runs_only_what_is_missing(bench_dir, tmp_path, capsys) -> None:
    assert _bench(tmp_path, "--workers", "2") == 0
    jsonl = tmp_path / "ablation.jsonl"
    lines = jsonl.read_text().splitlines()
    assert len(lines) == 2 * len(VARIANTS)
    dropped = json.loads(lines[3])
    jsonl.write_text("\n".join(lines[:3] + lines[4:]) + "\n" + lines[3][:17])  # and a line cut mid-write
    capsys.readouterr()
    assert _bench(tmp_path, "--workers", "2") == 0
    assert f"1 runs computed, {2 * len(VARIANTS) - 1} reused" in capsys.readouterr().out
    recs = [json.loads(x) for x in jsonl.read_text().splitlines() if x.startswith("{") and x.endswith("}")]
    assert sorted((r["variant"], r["run"]) for r in recs) == sorted((v, r) for v in VARIANTS for r in range(2))
    redone = next(r for r in recs if (r["variant"], r["run"]) == (dropped["variant"], dropped["run"]))
    assert redone["cost"] == dropped["cost"] and redone["history"] == dropped["history"]
    for name in ("ablation.csv", "ablation_runs.csv"):
        assert _without_times(_rows(tmp_path / name)) == _without_times(_rows(bench_dir / name)), name
    assert _bench(tmp_path, "--workers", "2") == 0  # nothing left to do
    assert f"0 runs computed, {2 * len(VARIANTS)} reused" in capsys.readouterr().out


def test_resume_refuses_records_made_with_other_settings(bench_dir, tmp_path, capsys) -> None:
    (tmp_path / "ablation.jsonl").write_text((bench_dir / "ablation.jsonl").read_text())
    assert main(["bench", "ablation", "-o", str(tmp_path), *TINY, "--seed-base", "7"]) == 2
    assert "other settings" in capsys.readouterr().err


def test_unknown_bench_exits_2(tmp_path, capsys) -> None:
    assert main(["bench", "nosuch", "-o", str(tmp_path), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "nosuch" in err and "ablation" in err
    assert not (tmp_path / "nosuch.jsonl").exists()
