"""``fuseplan bench speed``: SPSO planning time against the work it is given (issue 5).

One factor at a time around a base of nPop 250, MaxIt 100, 16 waypoints, 100 obstacles on
``large_obstacle_field.toml`` (stagnation stop off, so every run uses its whole budget): nPop 100/250/500/1000,
MaxIt 50/100/200, n waypoints 4/8/16, obstacle count 25/50/100 (``random_obstacles.count``). Default 3 runs.
Fits per factor the log–log slope of time against the factor (1 = linear), and over all runs
time = a + b · evaluations · n_waypoints · obstacles (b: seconds per waypoint-obstacle test of one evaluation).
Writes ``speed.md``, ``speed.csv``, ``speed_runs.csv`` and ``speed.png``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from planner.bench.runner import (
    PAPER_MODE,
    SCENARIO_DIR,
    Bench,
    BenchSettings,
    Variant,
    command_line,
    settings_list,
    summarise,
    write_csv,
)

BASE = {"n_pop": 250, "max_iter": 100, "n_waypoints": 16, "obstacles": 100}
LEVELS = {"n_pop": (100, 250, 500, 1000), "max_iter": (50, 100, 200), "n_waypoints": (4, 8, 16),
          "obstacles": (25, 50, 100)}
SET = {"n_pop": "planner.pso.n_pop", "max_iter": "planner.pso.max_iter", "n_waypoints": "planner.pso.n_waypoints",
       "obstacles": "random_obstacles.count"}
COLUMNS = ("time_s", "evaluations", "cost", "time_per_eval_us")
RUN_COLUMNS = ("variant", "label", "factor", "level", "run", "seed", "status", "feasible", "cost", "time_s",
               "iterations", "evaluations", "time_per_eval_us")


def _variants() -> tuple[Variant, ...]:
    out = []
    for factor, levels in LEVELS.items():
        for x in levels:
            out.append(Variant(f"{factor}={x}", f"{factor} {x}" + (" (base)" if x == BASE[factor] else ""),
                               (f"{SET[factor]}={x}",)))
    return tuple(out)


VARIANTS = _variants()


def _split(key: str) -> tuple[str, int]:
    factor, level = key.split("=")
    return factor, int(level)


def run_rows(records: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    labels = {v.key: v.label for v in VARIANTS}
    out = []
    for r in records:
        factor, level = _split(r["variant"])
        out.append({**r, "label": labels[r["variant"]], "factor": factor, "level": level,
                    "time_per_eval_us": 1e6 * r["time_s"] / r["evaluations"]})
    return out


def slopes(rows: Sequence[dict[str, Any]]) -> dict[str, float]:
    """Per factor: least-squares slope of log(mean time) against log(level)."""
    out = {}
    for factor in LEVELS:
        rr = [r for r in rows if _split(r["variant"])[0] == factor]
        x = np.log([_split(r["variant"])[1] for r in rr])
        y = np.log([r["time_s_mean"] for r in rr])
        out[factor] = float(np.polyfit(x, y, 1)[0])
    return out


def work(run: dict[str, Any]) -> float:
    """evaluations × n_waypoints × obstacles of one run (the count of waypoint-obstacle tests)."""
    levels = {**BASE, run["factor"]: run["level"]}
    return float(run["evaluations"]) * levels["n_waypoints"] * levels["obstacles"]


def linear_fit(runs: Sequence[dict[str, Any]]) -> tuple[float, float, float]:
    """time = a + b · work over all runs: (a s, b s per unit, R²)."""
    x = np.array([work(r) for r in runs])
    y = np.array([r["time_s"] for r in runs])
    b, a = np.polyfit(x, y, 1)
    r2 = 1.0 - float(np.sum((y - (a + b * x)) ** 2)) / float(np.sum((y - y.mean()) ** 2))
    return float(a), float(b), r2


def _report(out_dir: Path, records: list[dict[str, Any]], settings: BenchSettings) -> list[Path]:
    runs = run_rows(records)
    rows = summarise(runs, VARIANTS, COLUMNS)
    for row in rows:
        row["factor"], row["level"] = _split(row["variant"])
    paths = [out_dir / "speed.csv", out_dir / "speed_runs.csv", out_dir / "speed.md", out_dir / "speed.png"]
    write_csv(paths[0], rows, list(rows[0].keys()))
    write_csv(paths[1], runs, list(RUN_COLUMNS))
    paths[2].write_text(markdown(rows, runs, settings))
    plot(paths[3], rows, runs)
    return paths


BENCH = Bench(
    name="speed",
    description="SPSO planning time vs nPop, MaxIt, n waypoints and obstacle count (large obstacle field)",
    scenario=SCENARIO_DIR / "large_obstacle_field.toml",
    base_overrides=(PAPER_MODE, 'planner.algorithm="spso"', "planner.pso.stagnation_iters=100000",
                    *(f"{SET[k]}={v}" for k, v in BASE.items())),
    variants=VARIANTS,
    default_runs=3,
    report=_report,
)


def markdown(rows: Sequence[dict[str, Any]], runs: Sequence[dict[str, Any]], settings: BenchSettings) -> str:
    sl = slopes(rows)
    a, b, r2 = linear_fit(runs)
    lines = [
        "# Planning time vs work (SPSO, large obstacle field)", "",
        command_line(settings), "",
        f"Scenario `{settings.bench.scenario.name}`; base settings "
        + settings_list(settings)
        + "; each row changes one factor (the others stay at the base: "
        + ", ".join(f"{k} {v}" for k, v in BASE.items()) + "). Stagnation stop off, so every run uses its "
        "whole budget: evaluations = nPop × (MaxIt + 1). Wall-clock times on this machine, with as many runs "
        "in parallel as `--workers`; only the evaluations and costs are reproducible bit for bit. The paper "
        "reports no timing study; this bench answers issue 5's \"how cost grows with work\".", "",
        "| factor | level | runs | time (s) | evaluations | µs per evaluation | cost | success |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['factor']} | {r['level']}{' (base)' if r['level'] == BASE[r['factor']] else ''} "
                     f"| {r['runs']} | {r['time_s_mean']:.3f} ± {r['time_s_std']:.3f} | {r['evaluations_mean']:.0f} "
                     f"| {r['time_per_eval_us_mean']:.1f} | {r['cost_mean']:.0f} | {100 * r['success_rate']:.0f} % |")
    lines += ["", "## How time grows", "",
              "Log–log slope of mean time against each factor (1 = proportional):", "",
              "| factor | slope |", "|---|---|"]
    lines += [f"| {k} | {v:.2f} |" for k, v in sl.items()]
    lines += ["", f"Linear fit over all {len(runs)} runs: time = {a:.3f} s + {b * 1e9:.3f} ns × (evaluations × "
              f"waypoints × obstacles), R² = {r2:.3f}. Time per evaluation of one path: "
              f"{min(r['time_per_eval_us_mean'] for r in rows):.1f}–{max(r['time_per_eval_us_mean'] for r in rows):.1f} µs "
              "across the settings.", ""]
    return "\n".join(lines)


def plot(path: Path, rows: Sequence[dict[str, Any]], runs: Sequence[dict[str, Any]]) -> None:
    """Mean time (± std) against each factor on log–log axes with its fitted slope, plus time vs work."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sl = slopes(rows)
    fig, axes = plt.subplots(1, 5, figsize=(20, 4))
    for ax, factor in zip(axes, LEVELS):
        rr = [r for r in rows if r["factor"] == factor]
        x = np.array([r["level"] for r in rr], dtype=float)
        y = np.array([r["time_s_mean"] for r in rr])
        ax.errorbar(x, y, yerr=[r["time_s_std"] for r in rr], marker="o", capsize=4)
        c = np.polyfit(np.log(x), np.log(y), 1)
        ax.plot(x, np.exp(np.polyval(c, np.log(x))), "--", lw=0.8, label=f"slope {sl[factor]:.2f}")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(factor)
        ax.set_ylabel("planning time (s)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    a, b, r2 = linear_fit(runs)
    w = np.array([work(r) for r in runs])
    axes[-1].scatter(w, [r["time_s"] for r in runs], s=12)
    xs = np.linspace(0, w.max(), 50)
    axes[-1].plot(xs, a + b * xs, "--", lw=0.8, label=f"{b * 1e9:.2f} ns/unit, R² {r2:.2f}")
    axes[-1].set_xlabel("evaluations × waypoints × obstacles")
    axes[-1].set_ylabel("planning time (s)")
    axes[-1].grid(True, alpha=0.3)
    axes[-1].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


BENCHES = (BENCH,)
