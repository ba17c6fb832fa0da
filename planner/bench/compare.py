"""`fuseplan compare`: every algorithm N times on one scenario, in a process pool, summarised as a table
(mean ± std), a CSV and a PNG of convergence curves. Run r of every algorithm uses seed S + r, so the
numbers do not depend on the number of workers (only the times do)."""

from __future__ import annotations

import csv
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from planner.errors import FuseplanError
from planner.world.config import ALGORITHM_NAMES

COLUMNS = ("cost", "length_m", "smoothness", "time_s", "robustness", "violations")


@dataclass(frozen=True)
class RunSpec:
    scenario: str
    overrides: tuple[str, ...]
    algorithm: str
    run: int
    seed: int


def run_one(spec: RunSpec) -> dict[str, Any]:
    """Plan once (in a worker process): the bench runner's record, keyed by algorithm."""
    from planner.bench import runner

    rec = runner.run_one(runner.RunSpec(spec.scenario, (*spec.overrides, f'planner.algorithm="{spec.algorithm}"'),
                                        spec.algorithm, spec.run, spec.seed))
    keys = ("run", "seed", "status", "feasible", "cost", "length_m", "smoothness", "time_s", "robustness",
            "violations", "history")
    return {"algorithm": spec.algorithm, **{k: rec[k] for k in keys}}


def run_all(specs: Sequence[RunSpec], workers: int,
            progress: Callable[[int, int], None] | None = None) -> list[dict[str, Any]]:
    """Run every spec, calling ``progress(done, total)`` as runs finish; records come back in spec order whatever
    the pool did."""
    out: dict[int, dict[str, Any]] = {}
    done = 0
    with ProcessPoolExecutor(max_workers=workers) as pool:
        futures = {pool.submit(run_one, s): i for i, s in enumerate(specs)}
        for fut in as_completed(futures):
            try:
                out[futures[fut]] = fut.result()
            except Exception as e:  # a failed run stops the comparison, with what failed and why
                pool.shutdown(wait=False, cancel_futures=True)
                spec = specs[futures[fut]]
                if isinstance(e, FuseplanError):
                    raise
                raise FuseplanError(f"{spec.algorithm} run {spec.run} (seed {spec.seed}) failed: "
                                    f"{type(e).__name__}: {e}") from e
            done += 1
            if progress is not None:
                progress(done, len(specs))
    return [out[i] for i in range(len(specs))]


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
                  rows: Sequence[dict[str, Any]]) -> list[Path]:
    """``NAME.csv`` (summary), ``NAME_runs.csv`` (one row per run) and ``NAME.png`` (convergence)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    summary, runs, png = out_dir / f"{name}.csv", out_dir / f"{name}_runs.csv", out_dir / f"{name}.png"
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
    return [summary, runs, png]


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


def default_workers() -> int:
    return max(1, min(os.cpu_count() or 1, 8))


def specs_for(scenario: str, overrides: Sequence[str], algorithms: Sequence[str], runs: int,
              seed: int) -> list[RunSpec]:
    return [RunSpec(scenario, tuple(overrides), alg, r, seed + r) for alg in algorithms for r in range(runs)]


def check_algorithms(names: Sequence[str]) -> list[str]:
    """Known names, each once, in the order given."""
    bad = [n for n in names if n not in ALGORITHM_NAMES]
    if bad:
        raise ValueError(f"unknown algorithm(s) {', '.join(bad)}; choose from {', '.join(ALGORITHM_NAMES)}")
    if not names:
        raise ValueError(f"no algorithm given; choose from {', '.join(ALGORITHM_NAMES)}")
    return list(dict.fromkeys(names))


