"""``fuseplan bench large-scale``: SPSO vs Cartesian PSO in the 3000 × 3000 m field with 100 obstacles
(paper §6.3 "large-scale", Table 9, Figures 30–32).

Table 6 budget (nPop 500, MaxIt 200, stagnation stop off), 16 waypoints (the scenario's), 10 runs. The paper
gives no cost numbers here: Figure 32 is a convergence plot (SPSO lower) and Table 9 is the SPSO trajectory
sampled every 5 s, from (0, 0, 100) to (2500, 2700, 150) in 368 s, nearly straight (heading 50° → 47°).
Writes ``large-scale.md``, ``large-scale.csv``, ``large-scale_runs.csv``, ``large-scale_convergence.png``
(Fig. 32 analogue) and ``large-scale.png`` (bars).
"""

from __future__ import annotations

import math
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
    add_cost_comparison,
    claims_table,
    command_line,
    settings_list,
    summarise,
    write_csv,
)

NAME = "large-scale"
COLUMNS = ("cost", "length_m", "smoothness", "time_s", "convergence_iteration", "violations", "penalty")
RUN_COLUMNS = ("variant", "label", "run", "seed", "status", "feasible", "cost", "penalty", "length_m",
               "smoothness", "time_s", "convergence_iteration", "iterations", "evaluations", "violations")
VARIANTS = (
    Variant("SPSO", "spherical PSO", ('planner.algorithm="spso"',)),
    Variant("PSO", "Cartesian PSO", ('planner.algorithm="pso"',)),
)
ALPHA = 0.05
# Table 9: start (0, 0, 100), goal (2500, 2700, 150), arrival at t = 368 s
PAPER_START, PAPER_GOAL, PAPER_TIME_S = (0.0, 0.0, 100.0), (2500.0, 2700.0, 150.0), 368.0
PAPER_STRAIGHT_M = math.dist(PAPER_START, PAPER_GOAL)
STRAIGHT_TOL = 0.05  # "nearly straight": path length within 5 % of the straight line


def _straight(settings: BenchSettings) -> float:
    from planner.world.scenario import load_scenario

    sc = load_scenario(str(settings.bench.scenario), settings.overrides_for(VARIANTS[0]))
    return float(np.linalg.norm(np.asarray(sc.goal) - np.asarray(sc.start)))


def _report(out_dir: Path, records: list[dict[str, Any]], settings: BenchSettings) -> list[Path]:
    rows = table_rows(records)
    labels = {v.key: v.label for v in VARIANTS}
    paths = [out_dir / f"{NAME}.csv", out_dir / f"{NAME}_runs.csv", out_dir / f"{NAME}.md",
             out_dir / f"{NAME}.png", out_dir / f"{NAME}_convergence.png"]
    write_csv(paths[0], rows, list(rows[0].keys()))
    write_csv(paths[1], [{**r, "label": labels[r["variant"]]} for r in records], list(RUN_COLUMNS))
    paths[2].write_text(markdown(rows, settings, _straight(settings)))
    plot_bars(paths[3], rows)
    from planner.bench.compare import plot_convergence

    plot_convergence(paths[4], [{"algorithm": f"{r['variant']} ({labels[r['variant']]})", "history": r["history"]}
                                for r in records], [f"{v.key} ({v.label})" for v in VARIANTS])
    return paths


BENCH = Bench(
    name=NAME,
    description="large obstacle field (3000 × 3000 m, 100 obstacles), paper §6.3 / Table 9 / Fig. 32: "
                "SPSO vs Cartesian PSO",
    scenario=SCENARIO_DIR / "large_obstacle_field.toml",
    base_overrides=(PAPER_MODE, "planner.pso.n_pop=500", "planner.pso.max_iter=200",
                    "planner.pso.stagnation_iters=100000"),
    variants=VARIANTS,
    default_runs=10,
    report=_report,
)


def table_rows(records: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """summarise() plus Δ % mean cost vs SPSO and the rank-sum p of cost vs SPSO."""
    return add_cost_comparison(summarise(records, VARIANTS, COLUMNS), records)


def verdicts(rows: Sequence[dict[str, Any]], straight_m: float) -> list[tuple[str, str, str, str, bool]]:
    s, p = rows[0], rows[1]
    ratio = s["length_m_mean"] / straight_m
    return [
        ("SPSO reaches a lower cost than PSO (Fig. 32)", "lower (curve only)",
         f"SPSO {s['cost_mean']:.0f} vs PSO {p['cost_mean']:.0f} ({p['delta_cost_pct']:+.1f} % for PSO, "
         f"p = {p['p_ranksums']:.2g})", f"SPSO mean below PSO's and rank-sum p < {ALPHA}",
         s["cost_mean"] < p["cost_mean"] and p["p_ranksums"] < ALPHA),
        ("SPSO completes the mission in the large field (Fig. 30, Table 9)", "yes (one run shown)",
         f"{100 * s['success_rate']:.0f} % of runs feasible", "every run feasible", s["success_rate"] == 1.0),
        ("SPSO route is nearly straight (Table 9: heading 50° → 47°)",
         f"≈ {PAPER_STRAIGHT_M:.0f} m straight line, {PAPER_TIME_S:.0f} s",
         f"length {s['length_m_mean']:.0f} m = {ratio:.3f} × straight line {straight_m:.0f} m",
         f"length ≤ {1 + STRAIGHT_TOL:.2f} × straight line", ratio <= 1 + STRAIGHT_TOL),
        ("PSO is worse in the large field (Fig. 31: traditional PSO)", "worse (words)",
         f"PSO success {100 * p['success_rate']:.0f} %, violations {p['violations_mean']:.1f} per run",
         "PSO success below SPSO's or its cost higher with p < 0.05",
         p["success_rate"] < s["success_rate"] or (p["cost_mean"] > s["cost_mean"] and p["p_ranksums"] < ALPHA)),
    ]


def markdown(rows: Sequence[dict[str, Any]], settings: BenchSettings, straight_m: float) -> str:
    lines = [
        "# Large obstacle field: SPSO vs PSO (paper §6.3, Table 9, Figures 30–32)", "",
        command_line(settings), "",
        f"Scenario `{settings.bench.scenario.name}` (3000 × 3000 m, 100 seeded spheres, cylinders and "
        "hemispheres, start (50, 50, 100), goal (2500, 2700, 150), 16 waypoints); settings: "
        + settings_list(settings)
        + f" (Table 6 budget; later ones win). Run r uses seed {settings.seed_base} + r for both algorithms. "
        "Mean ± sample std; p: Wilcoxon rank-sum of PSO's costs against SPSO's; success: the smoothed path "
        "passes every check. Times are wall clock (vary between machines); the rest is reproducible.", "",
        "| algorithm | cost | path length (m) | smoothness | time (s) | convergence iter. | violations | success "
        "| Δ % cost | p vs SPSO |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        p = "—" if math.isnan(r["p_ranksums"]) else f"{r['p_ranksums']:.2g}"
        lines.append(
            f"| {r['variant']} ({r['label']}) | {r['cost_mean']:.1f} ± {r['cost_std']:.1f} "
            f"| {r['length_m_mean']:.1f} ± {r['length_m_std']:.1f} | {r['smoothness_mean']:.3f} "
            f"| {r['time_s_mean']:.2f} ± {r['time_s_std']:.2f} "
            f"| {r['convergence_iteration_mean']:.1f} ± {r['convergence_iteration_std']:.1f} "
            f"| {r['violations_mean']:.1f} | {100 * r['success_rate']:.0f} % | {r['delta_cost_pct']:+.1f} | {p} |")
    lines += ["", f"Paper: no cost, time or success numbers for this experiment. Table 9 lists one SPSO "
              f"trajectory every 5 s: (0, 0, 100) → (2500, 2700, 150), arrival at {PAPER_TIME_S:.0f} s, straight-"
              f"line distance {PAPER_STRAIGHT_M:.0f} m (≈ {PAPER_STRAIGHT_M / PAPER_TIME_S:.1f} m/s); our start is "
              f"(50, 50, 100), straight line {straight_m:.0f} m.", "",
              "## The paper's claims", "",
              *claims_table(verdicts(rows, straight_m))]
    lines += ["", "Share of mean cost that is constraint penalty: "
              + ", ".join(f"{r['variant']} {100 * r['penalty_mean'] / r['cost_mean']:.0f} %" for r in rows) + ".",
              ""]
    return "\n".join(lines)


def plot_bars(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    """Mean ± std of cost, path length and time per algorithm."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(12, 4))
    names = [r["variant"] for r in rows]
    for ax, col, lab in zip(axes, ("cost", "length_m", "time_s"), ("cost J", "path length (m)", "time (s)")):
        ax.bar(names, [r[f"{col}_mean"] for r in rows], yerr=[r[f"{col}_std"] for r in rows], capsize=5,
               color=["tab:blue", "tab:orange"][: len(rows)], alpha=0.8)
        ax.set_ylabel(f"{lab} (mean ± std)")
        ax.grid(True, axis="y", alpha=0.3)
    axes[0].set_yscale("log")
    fig.suptitle("large obstacle field: SPSO vs PSO (success "
                 + ", ".join(f"{r['variant']} {100 * r['success_rate']:.0f} %" for r in rows) + ")")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


BENCHES = (BENCH,)
