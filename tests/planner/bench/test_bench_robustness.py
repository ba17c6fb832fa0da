"""``fuseplan bench robustness`` and ``peers`` on generated hard maps (a tiny budget: the plumbing, not the
numbers; the numbers are in docs/results/robustness.md and peers.md)."""

from __future__ import annotations

import csv
import json

import pytest

from companion.cli import main
from planner.bench.hardmaps import FAMILIES

TINY = ["--set", "planner.pso.n_pop=20", "--set", "planner.pso.max_iter=3", "--set", "planner.aco.max_iter=2",
        "--set", "planner.roadmap.colony_iter=2"]


def test_robustness_runs_every_family_both_pipelines_both_budgets_and_reports_targets(tmp_path, capsys) -> None:
    assert main(["bench", "robustness", "--runs", "1", "--workers", "2", "-q", "-o", str(tmp_path), *TINY]) == 0
    recs = [json.loads(x) for x in (tmp_path / "robustness.jsonl").read_text().splitlines()]
    assert sorted(r["variant"] for r in recs) == sorted(
        f"{f}/{p}{b}" for f in FAMILIES for p in ("roadmap", "paper") for b in ("", "@0.15s"))
    for r in recs:
        assert r["family"] == r["variant"].split("/")[0] and r["planted_length_m"] > 0
        assert r["seed"] == 2000 and isinstance(r["feasible"], bool)
        assert (r["roadmap_build_s"] is None) == r["variant"].split("/")[1].startswith("paper")
    rows = list(csv.DictReader((tmp_path / "robustness.csv").open()))
    assert len(rows) == 4 * len(FAMILIES)
    md = (tmp_path / "robustness.md").read_text()
    assert "## Targets (issue 15), roadmap pipeline" in md and "![the roadmap pipeline on a maze]" in md
    assert (tmp_path / "robustness_pipeline.png").read_bytes()[:4] == b"\x89PNG"
    # resumed: nothing recomputed
    capsys.readouterr()
    assert main(["bench", "robustness", "--runs", "1", "--workers", "2", "-q", "-o", str(tmp_path), *TINY]) == 0
    assert f"0 runs computed, {4 * len(FAMILIES)} reused" in capsys.readouterr().out


def test_peers_bench_puts_ompl_beside_the_roadmap_pipeline(tmp_path) -> None:
    pytest.importorskip("ompl")
    assert main(["bench", "peers", "--runs", "1", "--workers", "2", "-q", "-o", str(tmp_path), *TINY]) == 0
    recs = {r["variant"]: r for r in map(json.loads, (tmp_path / "peers.jsonl").read_text().splitlines())}
    assert set(recs) == {f"{f}/{p}" for f in FAMILIES for p in ("roadmap@1s", "rrtconnect", "bitstar")}
    for f in FAMILIES:
        assert recs[f"{f}/rrtconnect"]["found"] in (True, False)
        assert recs[f"{f}/bitstar"]["time_s"] >= 1.9  # BIT* is anytime: it uses its 2 s
    md = (tmp_path / "peers.md").read_text()
    assert "| map family | planner | runs | found | flyable success |" in md
    assert "| family | flyable ≥ OMPL's found | median time < BIT*'s |" in md
