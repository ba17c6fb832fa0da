"""`fuseplan bench compare-static / compare-dynamic / constraints` at a tiny budget: files and columns,
statistics from the runs, worker-count independence, per-variant scenarios."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from companion.cli import main

TINY = ["--runs", "2", "--set", "planner.pso.n_pop=20", "--set", "planner.pso.max_iter=5",
        "--set", "planner.aco.max_iter=5", "-q"]
TIME_COLUMNS = ("time_s", "time_s_mean", "time_s_std")  # wall clock: the only numbers allowed to differ
ALGS = ["fusion", "spso", "qpso", "psogsa", "bpso", "pso", "roadmap"]
CATS = ("collision", "altitude", "turn", "climb", "bounds")
FILES = {
    "compare-static": ("compare-static.png", "compare-static_convergence.png", "compare-static_radar.png"),
    "compare-dynamic": ("compare-dynamic.png", "compare-dynamic_convergence.png", "compare-dynamic_radar.png"),
    "constraints": ("constraints.png",),
}
VARIANTS = {"compare-static": ALGS, "compare-dynamic": ALGS,
            "constraints": [f"{s}-{a}" for s in ("static", "dynamic") for a in ALGS]}


def _rows(path: Path) -> list[dict[str, str]]:
    return list(csv.DictReader(path.open()))


def _without_times(rows: list[dict[str, str]]) -> list[dict[str, str]]:
    return [{k: v for k, v in r.items() if k not in TIME_COLUMNS} for r in rows]


@pytest.fixture(scope="module", params=sorted(FILES))
def bench(request, tmp_path_factory) -> tuple[str, Path]:
    name = request.param
    out = tmp_path_factory.mktemp(name)
    assert main(["bench", name, "-o", str(out), *TINY, "--workers", "1"]) == 0
    return name, out


def test_files_and_columns(bench) -> None:
    name, out = bench
    for f in (f"{name}.md", f"{name}.csv", f"{name}_runs.csv", f"{name}.jsonl", *FILES[name]):
        assert (out / f).stat().st_size > 0, f
    for f in FILES[name]:
        assert (out / f).read_bytes()[:4] == b"\x89PNG", f
    summary = _rows(out / f"{name}.csv")
    assert [r["variant"] for r in summary] == VARIANTS[name]
    runs = _rows(out / f"{name}_runs.csv")
    assert [(r["variant"], int(r["run"]), int(r["seed"])) for r in runs] == [
        (v, r, 2000 + r) for v in VARIANTS[name] for r in range(2)]
    for c in CATS:
        assert f"violations_{c}" in runs[0]
    md = (out / f"{name}.md").read_text()
    assert "| claim | paper | ours | rule | verdict |" in md and "reproduced" in md


def test_table_statistics_come_from_the_runs(bench) -> None:
    name, out = bench
    runs = _rows(out / f"{name}_runs.csv")
    summary = {r["variant"]: r for r in _rows(out / f"{name}.csv")}
    for v in VARIANTS[name]:
        mine = [r for r in runs if r["variant"] == v]
        row = summary[v]
        viol = np.array([float(r["violations"]) for r in mine])
        assert float(row["violations_mean"]) == pytest.approx(viol.mean(), rel=1e-12, abs=1e-12)
        assert float(row["success_rate"]) == pytest.approx(np.mean([r["feasible"] == "True" for r in mine]))
        if name == "constraints":
            for c in CATS:
                assert int(row[f"{c}_total"]) == sum(int(r[f"violations_{c}"]) for r in mine)
            assert int(row["violations_total"]) == int(viol.sum())
            assert float(row["runs_with_violation_share"]) == pytest.approx(np.mean(viol > 0))
            continue
        for col in ("cost", "length_m", "smoothness", "robustness", "convergence_iteration", "time_s"):
            x = np.array([float(r[col]) for r in mine])
            assert float(row[f"{col}_mean"]) == pytest.approx(x.mean(), rel=1e-12, abs=1e-12), (v, col)
            assert float(row[f"{col}_std"]) == pytest.approx(x.std(ddof=1), rel=1e-12, abs=1e-12), (v, col)
    if name != "constraints":
        md = (out / f"{name}.md").read_text()
        assert f"{float(summary['fusion']['cost_mean']):.1f} ± " in md


def test_constraints_plans_each_variant_on_its_scenario() -> None:
    from planner.bench import BENCHES
    from planner.bench.runner import BenchSettings, specs_for

    specs = specs_for(BenchSettings(BENCHES["constraints"], 1, 2000))
    assert {Path(s.scenario).name for s in specs if s.variant.startswith("static-")} == {"rescue_static.toml"}
    assert {Path(s.scenario).name for s in specs if s.variant.startswith("dynamic-")} == {"rescue_dynamic.toml"}
    by = {s.variant: s for s in specs}
    assert by["static-fusion"].fingerprint != by["dynamic-fusion"].fingerprint  # same seed and overrides
    assert by["static-fusion"].overrides == by["dynamic-fusion"].overrides
    # a bench whose variants name no scenario keeps using the bench's
    assert {Path(s.scenario).name for s in specs_for(BenchSettings(BENCHES["ablation"], 1, 2000))} == {
        "rescue_static.toml"}


def test_same_seeds_same_tables_whatever_the_workers(bench, tmp_path) -> None:
    name, out = bench
    assert main(["bench", name, "-o", str(tmp_path), *TINY, "--workers", "2"]) == 0
    for f in (f"{name}.csv", f"{name}_runs.csv"):
        assert _without_times(_rows(tmp_path / f)) == _without_times(_rows(out / f)), f


@pytest.mark.parametrize("chosen", ["compiled", "numpy"])
def test_every_report_says_which_cost_kernel_its_runs_used(monkeypatch: pytest.MonkeyPatch, chosen: str) -> None:
    """Times differ several-fold between the kernels, so a report's command line names the one that ran."""
    from planner import kernel
    from planner.bench import BENCHES
    from planner.bench.runner import BenchSettings, command_line

    monkeypatch.setenv("FUSEPLAN_KERNEL", chosen)
    line = command_line(BenchSettings(BENCHES["ablation"], 3, 2000))
    assert line.startswith("`fuseplan bench ablation --runs 3 --seed-base 2000`")
    assert line.endswith(f"(cost kernel: {kernel.chosen()})")
    assert kernel.chosen() == chosen or kernel.njit is None
