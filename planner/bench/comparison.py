"""``fuseplan bench compare-static`` / ``compare-dynamic``: the algorithm comparison of paper §6.1 and §6.2
(Table 6 budget; Figures 13–18 static, 19–26 dynamic).

Variants: fusion (SPSO → GKDM → ACO, the paper's proposal), SPSO alone, QPSO, PSOGSA, BPSO and the traditional
PSO of Figures 9–12; the algorithm is a scenario override (``planner.algorithm``). Table 6 budget: nPop 500,
MaxIt 200 for every PSO variant; the stagnation stop is off (``stagnation_iters = max_iter``) so every run uses
the whole budget, as in the paper. Writes ``NAME.md`` (table, the paper's numbers where it gives any, a verdict
per claim), ``NAME.csv`` (mean ± std per algorithm), ``NAME_runs.csv`` (one row per run), ``NAME.png``
(bars with error bars), ``NAME_convergence.png`` (median best cost per iteration) and ``NAME_radar.png``
(Fig. 26: six axes, larger = better, each divided by the best algorithm's value).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from planner.bench.runner import (
    PAPER_MODE,
    ROADMAP_MODE,
    SCENARIO_DIR,
    Bench,
    BenchSettings,
    Variant,
    claims_table,
    command_line,
    settings_list,
    summarise,
    write_csv,
)

ALGORITHMS = ("fusion", "spso", "qpso", "psogsa", "bpso", "pso", "roadmap")
LABELS = {"fusion": "fusion (SPSO+GKDM+ACO)", "spso": "SPSO", "qpso": "QPSO", "psogsa": "PSOGSA",
          "bpso": "BPSO", "pso": "PSO (traditional)", "roadmap": "fusion, roadmap pipeline (fuseplan's default)"}
PAPER_FOUR = ("fusion", "qpso", "psogsa", "bpso")  # the four algorithms of Figures 13–26
CATEGORIES = ("collision", "altitude", "turn", "climb", "bounds")
COLUMNS = ("cost", "length_m", "smoothness", "time_s", "robustness", "violations", "convergence_iteration",
           "penalty")
RUN_COLUMNS = ("variant", "label", "run", "seed", "status", "feasible", "cost", "penalty", "length_m",
               "smoothness", "time_s", "robustness", "convergence_iteration", "iterations", "evaluations",
               "violations", *(f"violations_{c}" for c in CATEGORIES))
# Table 6: nPop 500, MaxIt 200 for every compared algorithm; stagnation stop off.
BUDGET = (PAPER_MODE, "planner.pso.n_pop=500", "planner.pso.max_iter=200",
          "planner.pso.stagnation_iters=200")
VARIANTS = tuple(Variant(a, LABELS[a], (f'planner.algorithm="{a}"',) if a != "roadmap"
                         else ('planner.algorithm="fusion"', ROADMAP_MODE)) for a in ALGORITHMS)
RADAR_AXES = ("1/cost", "1/length", "1/smoothness", "1/time", "R", "success")

ALPHA = 0.05  # significance level of the Wilcoxon rank-sum test
COMPARABLE_PCT = 10.0  # "comparable" / "slightly" / "marginal": a difference of at most this many per cent
TIME_FACTOR = 2.0  # "comparable planning time": within this factor
FACTOR = 2.0  # a quantified claim reproduces when our number is within this factor of the paper's
PRONOUNCED = 1.2  # "pronounced degradation": at least this many times the fusion's value

Claim = tuple[str, str, str, str, bool]  # (claim, paper, ours, rule, reproduced)


# ---------------------------------------------------------------------------------------------------- stats
def run_rows(records: Sequence[dict[str, Any]], labels: dict[str, str]) -> list[dict[str, Any]]:
    """One flat row per run, per-category violation counts as columns."""
    out = []
    for r in records:
        cat = r.get("violations_by_category") or {}
        out.append({**r, "label": labels[r["variant"]], **{f"violations_{c}": int(cat.get(c, 0)) for c in CATEGORIES}})
    return out


def table_rows(records: Sequence[dict[str, Any]], variants: Sequence[Variant] = VARIANTS,
               ) -> list[dict[str, Any]]:
    """summarise() plus the Wilcoxon rank-sum p of cost and of R against the first variant (fusion)."""
    from scipy.stats import ranksums

    rows = summarise(records, variants, COLUMNS)
    ref = variants[0].key

    def col(key: str, c: str) -> np.ndarray:
        return np.array([r[c] for r in records if r["variant"] == key], dtype=float)

    for row in rows:
        for c, name in (("cost", "p_cost"), ("robustness", "p_robustness")):
            x, y = col(row["variant"], c), col(ref, c)
            same = row["variant"] == ref or (np.ptp(np.concatenate([x, y])) == 0)
            row[name] = math.nan if same else float(ranksums(x, y).pvalue)
    return rows


def radar_scores(rows: Sequence[dict[str, Any]]) -> dict[str, list[float]]:
    """Per algorithm, the six radar values (larger = better), each divided by the best algorithm's value."""
    def inv(x: float) -> float:
        return 1.0 / x if x > 0 else 0.0

    raw = np.array([[inv(r["cost_mean"]), inv(r["length_m_mean"]), inv(r["smoothness_mean"]),
                     inv(r["time_s_mean"]), r["robustness_mean"], r["success_rate"]] for r in rows], dtype=float)
    top = raw.max(axis=0)
    norm = np.divide(raw, top, out=np.zeros_like(raw), where=top > 0)
    return {r["variant"]: [float(v) for v in norm[i]] for i, r in enumerate(rows)}


# ---------------------------------------------------------------------------------------------------- claims
def _pct(a: float, b: float) -> float:
    return 100.0 * (a - b) / b if b else math.inf


def _p(x: float) -> str:
    return "—" if math.isnan(x) else f"{x:.2g}"


def claims_static(rows: Sequence[dict[str, Any]], records: Sequence[dict[str, Any]]) -> list[Claim]:
    """Paper §6.1 (Figures 11–18): words and figures only, no numbers in the text."""
    by = {r["variant"]: r for r in rows}
    f, q = by["fusion"], by["qpso"]
    four = [by[k] for k in PAPER_FOUR]
    d_cost_q = _pct(q["cost_mean"], f["cost_mean"])
    d_len = _pct(f["length_m_mean"], q["length_m_mean"])
    med_f, med_q = _median_history(records, "fusion"), _median_history(records, "qpso")
    n = min(len(med_f), len(med_q))
    below = int(np.sum(med_f[:n] <= med_q[:n]))
    t_ratio = {k: f["time_s_mean"] / by[k]["time_s_mean"] for k in ("qpso", "bpso")}
    conv_others = {k: by[k]["convergence_iteration_mean"] for k in ("qpso", "psogsa", "bpso")}
    return [
        ("improved algorithm's cost converges lower than traditional PSO's (Figs 11/12)", "words only",
         f"fusion {f['cost_mean']:.0f}, SPSO {by['spso']['cost_mean']:.0f} vs PSO {by['pso']['cost_mean']:.0f} "
         f"(p = {_p(by['pso']['p_cost'])})",
         f"fusion and SPSO mean cost < PSO's, p < {ALPHA}",
         max(f["cost_mean"], by["spso"]["cost_mean"]) < by["pso"]["cost_mean"] and by["pso"]["p_cost"] < ALPHA),
        ("fusion gives the best trajectory of the four (Fig. 13)", "words only",
         "lowest mean cost: " + min(four, key=lambda r: r["cost_mean"])["variant"],
         "fusion's mean cost lowest of fusion, QPSO, PSOGSA, BPSO",
         all(f["cost_mean"] <= r["cost_mean"] for r in four)),
        ("QPSO reaches an optimal cost comparable to fusion's (Figs 15/16)", "words only",
         f"QPSO {d_cost_q:+.1f} % vs fusion", f"−{COMPARABLE_PCT:g} % ≤ Δ mean cost ≤ +{COMPARABLE_PCT:g} %",
         abs(d_cost_q) <= COMPARABLE_PCT),
        ("fusion keeps a lower cost than QPSO along the whole convergence (Figs 15/16)", "words only",
         f"fusion median ≤ QPSO median at {below}/{n} iterations",
         "median best cost of fusion ≤ QPSO's at every common iteration", below == n),
        ("fusion converges faster than QPSO, PSOGSA, BPSO (Figs 15/16)", "words only",
         f"fusion {f['convergence_iteration_mean']:.0f} it.; "
         + ", ".join(f"{k} {v:.0f}" for k, v in conv_others.items()),
         "fusion's mean 90 %-convergence iteration below each of theirs",
         all(f["convergence_iteration_mean"] < v for v in conv_others.values())),
        ("fusion's path is slightly longer than QPSO's (Figs 17/18)", "words only",
         f"fusion {f['length_m_mean']:.0f} m vs QPSO {q['length_m_mean']:.0f} m ({d_len:+.1f} %)",
         f"0 < Δ length ≤ {COMPARABLE_PCT:g} %", 0 < d_len <= COMPARABLE_PCT),
        ("fusion is markedly smoother than the baselines (Fig. 18)", "words only",
         f"fusion {f['smoothness_mean']:.2f} rad; " + ", ".join(
             f"{k} {by[k]['smoothness_mean']:.2f}" for k in ("qpso", "psogsa", "bpso")),
         "fusion's mean smoothness (Σ turn angles, lower = smoother) below QPSO's, PSOGSA's and BPSO's",
         all(f["smoothness_mean"] < by[k]["smoothness_mean"] for k in ("qpso", "psogsa", "bpso"))),
        ("fusion's planning time is comparable to QPSO's and BPSO's (Fig. 14)", "words only",
         ", ".join(f"fusion/{k} = {v:.2f}×" for k, v in t_ratio.items()),
         f"mean time ratio within [1/{TIME_FACTOR:g}, {TIME_FACTOR:g}]",
         all(1 / TIME_FACTOR <= v <= TIME_FACTOR for v in t_ratio.values())),
    ]


PAPER_R_FUSION = 0.26
PAPER_R_BASELINES = (0.10, 0.16)


def claims_dynamic(rows: Sequence[dict[str, Any]], records: Sequence[dict[str, Any]]) -> list[Claim]:
    """Paper §6.2 (Figures 19–26): R is the only number in the text."""
    by = {r["variant"]: r for r in rows}
    f, q = by["fusion"], by["qpso"]
    four = [by[k] for k in PAPER_FOUR]
    base = ("qpso", "psogsa", "bpso")
    d_smooth = _pct(f["smoothness_mean"], q["smoothness_mean"])
    t_ratio = f["time_s_mean"] / q["time_s_mean"]
    lo, hi = PAPER_R_BASELINES
    radar = radar_scores(four)
    best_axes = [RADAR_AXES[i] for i in range(len(RADAR_AXES))
                 if radar["fusion"][i] >= max(v[i] for v in radar.values())]
    return [
        ("fusion reaches the best global optimum of the four (Figs 20/21)", "words only",
         "lowest mean cost: " + min(four, key=lambda r: r["cost_mean"])["variant"] + " ("
         + ", ".join(f"{r['variant']} {r['cost_mean']:.0f}" for r in four) + ")",
         "fusion's mean cost lowest of fusion, QPSO, PSOGSA, BPSO",
         all(f["cost_mean"] <= r["cost_mean"] for r in four)),
        ("fusion has the shortest path; QPSO and PSOGSA are circuitous (Figs 19, 22)", "words only",
         ", ".join(f"{r['variant']} {r['length_m_mean']:.0f} m" for r in four),
         "fusion's mean length lowest of the four", all(f["length_m_mean"] <= r["length_m_mean"] for r in four)),
        ("fusion is marginally less smooth than QPSO (Fig. 23 text)", "words only",
         f"fusion {f['smoothness_mean']:.2f} vs QPSO {q['smoothness_mean']:.2f} rad ({d_smooth:+.1f} %)",
         f"0 < Δ smoothness ≤ {COMPARABLE_PCT:g} %", 0 < d_smooth <= COMPARABLE_PCT),
        ("BPSO's smoothness shows pronounced degradation vs fusion", "words only",
         f"BPSO {by['bpso']['smoothness_mean']:.2f} vs fusion {f['smoothness_mean']:.2f} rad",
         f"BPSO's mean smoothness ≥ {PRONOUNCED:g}× fusion's",
         by["bpso"]["smoothness_mean"] >= PRONOUNCED * f["smoothness_mean"]),
        ("fusion's planning time is similar to QPSO's (Fig. 24)", "words only", f"fusion/QPSO = {t_ratio:.2f}×",
         f"mean time ratio within [1/{TIME_FACTOR:g}, {TIME_FACTOR:g}]",
         1 / TIME_FACTOR <= t_ratio <= TIME_FACTOR),
        ("fusion's mean R ≈ 0.26 (Fig. 25)", f"≈ {PAPER_R_FUSION}", f"{f['robustness_mean']:.3f}",
         f"within ×{FACTOR:g} of the paper's", PAPER_R_FUSION / FACTOR <= f["robustness_mean"]
         <= PAPER_R_FUSION * FACTOR),
        ("baselines' R between 0.10 and 0.16 (Fig. 25)", f"{lo}–{hi}",
         ", ".join(f"{k} {by[k]['robustness_mean']:.3f}" for k in base),
         f"each within [{lo}/{FACTOR:g}, {hi}×{FACTOR:g}]",
         all(lo / FACTOR <= by[k]["robustness_mean"] <= hi * FACTOR for k in base)),
        ("fusion's R is significantly higher than every baseline's (Fig. 25)", "0.26 vs 0.10–0.16",
         f"fusion {f['robustness_mean']:.3f}; " + ", ".join(
             f"{k} {by[k]['robustness_mean']:.3f} (p = {_p(by[k]['p_robustness'])})" for k in base),
         f"fusion's mean R above each baseline's, p < {ALPHA}",
         all(f["robustness_mean"] > by[k]["robustness_mean"] and by[k]["p_robustness"] < ALPHA for k in base)),
        ("fusion is superior in multiple dimensions of the radar chart (Fig. 26)", "words only",
         f"best on {len(best_axes)}/6: {', '.join(best_axes) or 'none'}",
         "fusion best (or tied) on at least 3 of the 6 axes among the four", len(best_axes) >= 3),
    ]


def _median_history(records: Sequence[dict[str, Any]], key: str) -> np.ndarray:
    hs = [list(r["history"]) for r in records if r["variant"] == key]
    n = max(len(h) for h in hs)
    return np.median(np.array([h + [h[-1]] * (n - len(h)) for h in hs]), axis=0)


# ---------------------------------------------------------------------------------------------------- report
def markdown(name: str, title: str, rows: Sequence[dict[str, Any]], claims: Sequence[Claim],
             settings: BenchSettings, paper_col: dict[str, str], paper_head: str, notes: Sequence[str]) -> str:
    runs = settings.runs
    lines = [
        f"# {title}", "",
        command_line(settings), "",
        f"Scenario `{settings.bench.scenario.name}`; settings: "
        + settings_list(settings)
        + f" (later ones win); each variant adds its `planner.algorithm`. Run r of every algorithm uses seed "
        f"{settings.seed_base} + r (r = 0…{runs - 1}). Mean ± sample std over the runs. Smoothness: sum of the "
        "turn angles of the waypoint path (rad, lower = smoother); R: robustness (docs/method.md §13.2, paper "
        "Eq. (52)); violations: checker + cost violation counts per run; success: share of runs whose smoothed "
        "path passes every check; p: Wilcoxon rank-sum test of the costs against fusion's. Times are wall clock "
        "per run and vary between machines and worker counts; every other number is exactly reproducible from the "
        "seeds.", "",
        "| algorithm | cost | path length (m) | smoothness (rad) | time (s) | R | violations | conv. iter. "
        f"| success | p cost vs fusion | {paper_head} |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['label']} | {r['cost_mean']:.1f} ± {r['cost_std']:.1f} "
            f"| {r['length_m_mean']:.1f} ± {r['length_m_std']:.1f} "
            f"| {r['smoothness_mean']:.3f} ± {r['smoothness_std']:.3f} "
            f"| {r['time_s_mean']:.3f} ± {r['time_s_std']:.3f} "
            f"| {r['robustness_mean']:.3f} ± {r['robustness_std']:.3f} "
            f"| {r['violations_mean']:.1f} ± {r['violations_std']:.1f} "
            f"| {r['convergence_iteration_mean']:.0f} ± {r['convergence_iteration_std']:.0f} "
            f"| {100 * r['success_rate']:.0f} % | {_p(r['p_cost'])} | {paper_col.get(r['variant'], 'not given')} |")
    radar = radar_scores(rows)
    lines += ["", "Radar scores (`" + name + "_radar.png`, Fig. 26): each axis divided by the best algorithm's "
              "value, so 1 = best; time depends on the machine.", "",
              "| algorithm | " + " | ".join(RADAR_AXES) + " |", "|---|" + "---|" * len(RADAR_AXES)]
    for r in rows:
        lines.append(f"| {r['label']} | " + " | ".join(f"{v:.2f}" for v in radar[r["variant"]]) + " |")
    lines += ["", "## The paper's claims", "",
              f"Rule: a claim with a number reproduces when ours lies within a factor of {FACTOR:g} of it; a claim "
              f"in words reproduces when the stated rule holds (\"comparable\", \"slightly\", \"marginal\": within "
              f"{COMPARABLE_PCT:g} %; \"significant\": rank-sum p < {ALPHA}).", "",
              *claims_table(claims)]
    n_ok = sum(c[4] for c in claims)
    lines += ["", f"{n_ok} of {len(claims)} claims reproduced.", "", *notes, ""]
    return "\n".join(lines)


def _plt() -> ModuleType:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_bars(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    """Mean ± std per algorithm of cost, length, smoothness, time, R and violations (Figs 14, 17, 18, 21–25)."""
    plt = _plt()
    names = [r["variant"] for r in rows]
    panels = (("cost", "best cost J"), ("length_m", "path length (m)"), ("smoothness", "smoothness (rad)"),
              ("time_s", "planning time (s)"), ("robustness", "robustness R"), ("violations", "violations / run"))
    fig, axes = plt.subplots(2, 3, figsize=(14, 7.5))
    for ax, (col, title) in zip(axes.flat, panels):
        mean = np.array([r[f"{col}_mean"] for r in rows])
        std = np.array([r[f"{col}_std"] for r in rows])
        ax.bar(names, mean, yerr=std, capsize=4, color=[f"C{i}" for i in range(len(rows))], alpha=0.85)
        if col == "cost" and mean.min() > 0 and mean.max() / mean.min() > 20:
            ax.set_yscale("log")
        ax.set_title(title)
        ax.grid(True, axis="y", alpha=0.3)
        ax.tick_params(axis="x", labelrotation=30)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_radar(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    """Fig. 26: six axes, larger = better, each divided by the best algorithm's value."""
    plt = _plt()
    scores = radar_scores(rows)
    ang = np.linspace(0, 2 * np.pi, len(RADAR_AXES), endpoint=False)
    fig = plt.figure(figsize=(7, 7))
    ax = fig.add_subplot(projection="polar")
    for i, r in enumerate(rows):
        v = scores[r["variant"]]
        ax.plot(np.append(ang, ang[0]), v + v[:1], color=f"C{i}", label=r["label"])
        ax.fill(np.append(ang, ang[0]), v + v[:1], color=f"C{i}", alpha=0.08)
    ax.set_xticks(ang)
    ax.set_xticklabels(RADAR_AXES)
    ax.set_ylim(0, 1.05)
    ax.legend(loc="upper right", bbox_to_anchor=(1.3, 1.1), fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _report(out_dir: Path, records: list[dict[str, Any]], settings: BenchSettings, *, title: str,
            claims: Callable[[Sequence[dict[str, Any]], Sequence[dict[str, Any]]], list[Claim]],
            paper_col: dict[str, str], paper_head: str, notes: Sequence[str]) -> list[Path]:
    from planner.bench.compare import plot_convergence

    name = settings.bench.name
    rows = table_rows(records)
    labels = {v.key: v.label for v in VARIANTS}
    paths = [out_dir / f"{name}.csv", out_dir / f"{name}_runs.csv", out_dir / f"{name}.md",
             out_dir / f"{name}.png", out_dir / f"{name}_convergence.png", out_dir / f"{name}_radar.png"]
    write_csv(paths[0], rows, list(rows[0].keys()))
    write_csv(paths[1], run_rows(records, labels), RUN_COLUMNS)
    paths[2].write_text(markdown(name, title, rows, claims(rows, records), settings, paper_col, paper_head, notes))
    plot_bars(paths[3], rows)
    plot_convergence(paths[4], [{"algorithm": labels[r["variant"]], "history": list(r["history"])}
                                for r in records], [labels[a] for a in ALGORITHMS])
    plot_radar(paths[5], rows)
    return paths


COMMON_NOTES = (
    "Absolute costs, lengths and times are not comparable with the paper's: the scenarios use d_safe 40 m / "
    "d_coll 10 m (the paper's 300 m / 50 m leave no corridor, see the scenario files), the cost includes the "
    "constraint penalty of docs/method.md §5.1, and the paper averages 50 trials on obstacles re-drawn per "
    "trial while we use the fixed Table 1 map. The paper compares four algorithms (the proposal, QPSO, PSOGSA, "
    "BPSO); SPSO alone and the traditional PSO of Figs 9–12 are extra rows here. Fusion's convergence curve has "
    "MaxIt + T_ACO points (PSO phase, then ACO).",
)

STATIC = Bench(
    name="compare-static",
    description="algorithm comparison in the static rescue scenario, paper §6.1 (Table 6 budget: fusion, SPSO, "
                "QPSO, PSOGSA, BPSO, PSO)",
    scenario=SCENARIO_DIR / "rescue_static.toml",
    base_overrides=BUDGET,
    variants=VARIANTS,
    default_runs=10,
    report=functools.partial(
        _report, title="Algorithm comparison, static threats (paper §6.1, Table 6, Figures 11–18)",
        claims=claims_static, paper_head="paper (§6.1)",
        paper_col={a: "figures only, no numbers" for a in ALGORITHMS},
        notes=("§6.1 gives no numbers: every claim below is read from its text about Figures 11–18, and the "
               "verdict follows the stated rule.", *COMMON_NOTES)),
)

DYNAMIC = Bench(
    name="compare-dynamic",
    description="algorithm comparison with static and dynamic threats, paper §6.2 (Table 6 budget: fusion, "
                "SPSO, QPSO, PSOGSA, BPSO, PSO)",
    scenario=SCENARIO_DIR / "rescue_dynamic.toml",
    base_overrides=BUDGET,
    variants=VARIANTS,
    default_runs=10,
    report=functools.partial(
        _report, title="Algorithm comparison, static + dynamic threats (paper §6.2, Figures 19–26)",
        claims=claims_dynamic, paper_head="paper R (Fig. 25)",
        paper_col={"fusion": f"≈ {PAPER_R_FUSION}",
                   **{k: f"{PAPER_R_BASELINES[0]}–{PAPER_R_BASELINES[1]}" for k in ("qpso", "psogsa", "bpso")}},
        notes=("§6.2 quantifies only R (fusion ≈ 0.26, baselines 0.10–0.16); length, smoothness and time are "
               "compared in words (Figs 22–24). The paper's threat speeds (40, 140 m/s, UAV 150 m/s) are replaced "
               "by realistic ones in `rescue_dynamic.toml`. Our R (docs/method.md §13.2, paper Eq. (52)) is the "
               "mean over trajectory samples of clip((clearance − d_safe)/d_safe, 0, 1)/(1 + κ²): it rewards "
               "distance from obstacles, so a long detour far from every hazard scores high even when it is "
               "costly.", *COMMON_NOTES)),
)

BENCHES = (STATIC, DYNAMIC)
