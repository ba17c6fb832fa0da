"""`fuseplan compare`: every algorithm N times on one scenario, on an executor (a local process pool or a dask
cluster), summarised as a table (mean ± std), a CSV and a PNG of convergence curves. Run r of every algorithm uses
seed S + r, so the numbers do not depend on the executor or the number of workers (only the times do). Each run is
appended to ``compare.jsonl`` as it finishes, so an interrupted comparison resumes (the bench runner's machinery,
:mod:`planner.bench.runner`, with the algorithm as the variant)."""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from planner.bench import runner
from planner.bench.executor import ExecutorSpec
from planner.world.config import ALGORITHM_NAMES, Algorithm, is_algorithm
from planner.world.scenario_text import ScenarioText

COLUMNS = ("cost", "length_m", "smoothness", "time_s", "robustness", "violations")
KEYS = ("run", "seed", "status", "feasible", "cost", "length_m", "smoothness", "time_s", "robustness", "violations",
        "history")  # of a bench record, what a comparison keeps


def specs_for(scenario: str, overrides: Sequence[str], algorithms: Sequence[str], runs: int,
              seed: int) -> list[runner.RunSpec]:
    """Bench runs whose variant is the algorithm, each carrying the scenario's text."""
    text = ScenarioText.read(scenario, overrides)
    return [runner.RunSpec(scenario, (*overrides, f'planner.algorithm="{alg}"'), alg, r, seed + r, source=text)
            for alg in algorithms for r in range(runs)]


def run_all(specs: Sequence[runner.RunSpec], jsonl: Path, executor: ExecutorSpec,
            progress: runner.Progress | None = None) -> tuple[list[dict[str, Any]], runner.BenchOutcome]:
    """Run what ``jsonl`` does not hold yet; the comparison's records in spec order, and what the runner did."""
    outcome = runner.run_specs(specs, jsonl, executor, progress)
    return [{"algorithm": rec["variant"], **{k: rec[k] for k in KEYS}} for rec in outcome.records], outcome


def summarise(records: Sequence[dict[str, Any]], algorithms: Sequence[str]) -> list[dict[str, Any]]:
    """Per algorithm: mean and sample std of every column, and the success (feasible) rate."""
    rows = []
    for alg in algorithms:
        rec = [r for r in records if r["algorithm"] == alg]
        row: dict[str, Any] = {"algorithm": alg, "runs": len(rec)}
        for col in COLUMNS:
            v = np.array([r[col] for r in rec], dtype=float)
            row[f"{col}_mean"] = float(v.mean())
            row[f"{col}_std"] = float(v.std(ddof=1)) if len(v) > 1 else 0.0
        row["success_rate"] = float(np.mean([r["feasible"] for r in rec]))
        rows.append(row)
    return rows


def format_table(rows: Sequence[dict[str, Any]]) -> str:
    """A Markdown table of mean ± std per algorithm."""
    head = ["algorithm", "cost", "length (m)", "smoothness (rad)", "time (s)", "robustness R", "violations",
            "success"]
    fmt = {"cost": ".1f", "length_m": ".1f", "smoothness": ".2f", "time_s": ".2f", "robustness": ".3f",
           "violations": ".1f"}
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [r["algorithm"]] + [f"{r[c + '_mean']:{fmt[c]}} ± {r[c + '_std']:{fmt[c]}}" for c in COLUMNS]
        cells.append(f"{100 * r['success_rate']:.0f} %")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_outputs(out_dir: Path, name: str, records: Sequence[dict[str, Any]],
                  rows: Sequence[dict[str, Any]], header: str = "") -> list[Path]:
    """``NAME.md`` (``header``, then the table), ``NAME.csv`` (summary), ``NAME_runs.csv`` (one row per run) and
    ``NAME.png`` (convergence)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    md, summary, runs, png = (out_dir / f"{name}{ext}" for ext in (".md", ".csv", "_runs.csv", ".png"))
    md.write_text(f"# {name}\n\n" + (f"{header}\n\n" if header else "") + format_table(rows) + "\n")
    with summary.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
        w.writeheader()
        w.writerows(rows)
    with runs.open("w", newline="") as f:
        keys = [k for k in records[0] if k != "history"]
        w = csv.DictWriter(f, fieldnames=keys, extrasaction="ignore")
        w.writeheader()
        w.writerows(records)
    plot_convergence(png, records, [r["algorithm"] for r in rows])
    return [md, summary, runs, png]


def plot_convergence(path: Path, records: Sequence[dict[str, Any]], algorithms: Sequence[str]) -> None:
    """Median best cost per iteration for each algorithm, with its interquartile band (log scale)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 5.5))
    for alg in algorithms:
        hs = [r["history"] for r in records if r["algorithm"] == alg]
        n = max(len(h) for h in hs)
        arr = np.array([h + [h[-1]] * (n - len(h)) for h in hs])  # a stopped run keeps its best
        med = np.median(arr, axis=0)
        ax.plot(np.arange(n), med, label=alg)
        ax.fill_between(np.arange(n), np.percentile(arr, 25, axis=0), np.percentile(arr, 75, axis=0), alpha=0.2)
    ax.set_yscale("log")
    ax.set_xlabel("iteration (fusion: SPSO then ACO)")
    ax.set_ylabel("best cost J (median, IQR band)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def check_algorithms(names: Sequence[str]) -> list[Algorithm]:
    """Known names, each once, in the order given."""
    known = [n for n in names if is_algorithm(n)]
    bad = [n for n in names if not is_algorithm(n)]
    if bad:
        raise ValueError(f"unknown algorithm(s) {', '.join(bad)}; choose from {', '.join(ALGORITHM_NAMES)}")
    if not known:
        raise ValueError(f"no algorithm given; choose from {', '.join(ALGORITHM_NAMES)}")
    return list(dict.fromkeys(known))


