"""``fuseplan bench gkdm``: the GKDM ablation of paper §6.2 (Tables 7, 8; Figure 29) and the "40–60 % less
computation than ACO from scratch" claim of §5 (complexity paragraph, "validated in Section 6.1").

Arms, all on ``rescue_static.toml`` with the same Table 7 colony and lattice (only the pheromone start differs):

- G fusion, GKDM initialisation (Table 8: τ0 0.1, A 12, σ 40 m)
- H fusion, hard binary initialisation (τ0 + 2.9 on the SPSO route's edges)
- U fusion, uniform τ0 (the SPSO route is still the colony's first best)
- A ACO from scratch (algorithm ``aco``): uniform τ0 on the lattice around the straight S→G line, Table 7
  budget (30 ants × 50 iterations)
- E the same cold colony given as many evaluations as a fusion run (T_ACO 217: 30 × 217 + 1 = 6511 ≈ 6601)

The SPSO phase is deliberately short (nPop 100, MaxIt 50, stagnation stop off) so the colony has something
left to do. Computation to reach a target: the target is the median final cost of the G arm × 1.001; for each
run, the number of cost evaluations (and the wall-clock seconds, interpolated linearly within each phase from the
phase times) until its best-so-far cost first reaches it. Writes ``gkdm.md``, ``gkdm.csv``, ``gkdm_runs.csv``,
``gkdm_convergence.png`` (best cost vs evaluations, and the ACO phase alone) and ``gkdm.png`` (bars).
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
    claims_table,
    command_line,
    settings_list,
    summarise,
    write_csv,
)

TARGET_FACTOR = 1.001  # target cost = median final cost of the G arm × this (0.1 %: inside the ACO phase's gain)
PAPER_SAVING = (40.0, 60.0)  # % less computation than ACO from scratch (paper §5)
ALPHA = 0.05
COLUMNS = ("cost", "length_m", "time_s", "evaluations", "pso_cost", "aco_gain_pct")
TARGET_COLUMNS = ("evals_to_target", "time_to_target_s")  # NaN when a run never reached the target
RUN_COLUMNS = ("variant", "label", "run", "seed", "status", "feasible", "cost", "pso_cost", "aco_gain_pct",
               "penalty", "length_m", "smoothness", "time_s", "iterations", "evaluations", "violations",
               "evals_to_target", "time_to_target_s")
COLD_MATCHED_ITERS = 217  # 30 ants × 217 + 1 = 6511 evaluations, a fusion run's 100 × 51 + 30 × 50 + 1 = 6601

VARIANTS = (
    Variant("G", "fusion, GKDM init", ('planner.aco.init="gkdm"',)),
    Variant("H", "fusion, hard init", ('planner.aco.init="hard"',)),
    Variant("U", "fusion, uniform init", ('planner.aco.init="uniform"',)),
    Variant("A", "ACO from scratch (Table 7 budget)", ('planner.algorithm="aco"',)),
    Variant("E", "ACO from scratch (fusion's evaluations)",
            ('planner.algorithm="aco"', f"planner.aco.max_iter={COLD_MATCHED_ITERS}",
             f"planner.aco.stagnation_iters={COLD_MATCHED_ITERS}")),
)
FUSION = ("G", "H", "U")
COLD = ("A", "E")


def _report(out_dir: Path, records: list[dict[str, Any]], settings: BenchSettings) -> list[Path]:
    runs, target = run_rows(records)
    rows = table_rows(runs)
    paths = [out_dir / "gkdm.csv", out_dir / "gkdm_runs.csv", out_dir / "gkdm.md", out_dir / "gkdm.png",
             out_dir / "gkdm_convergence.png"]
    write_csv(paths[0], rows, list(rows[0].keys()))
    write_csv(paths[1], runs, list(RUN_COLUMNS))
    paths[2].write_text(markdown(rows, target, settings))
    plot_bars(paths[3], rows)
    plot_curves(paths[4], records, target)
    return paths


BENCH = Bench(
    name="gkdm",
    description="GKDM ablation, paper Tables 7/8, Fig. 29: fusion with gkdm vs hard vs uniform pheromone "
                "initialisation, and ACO from scratch",
    scenario=SCENARIO_DIR / "rescue_static.toml",
    base_overrides=(PAPER_MODE, 'planner.algorithm="fusion"', "planner.pso.n_pop=100", "planner.pso.max_iter=50",
                    "planner.pso.stagnation_iters=100000"),
    variants=VARIANTS,
    default_runs=10,
    report=_report,
)


def cumulative_work(rec: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """(evaluations, seconds) spent when each entry of ``rec["history"]`` was recorded.

    Fusion: SPSO entry i (0 = initial swarm) after n_pop (i + 1) evaluations, then ACO iteration j (1-based)
    after E_pso + 1 + n_ants j (the + 1 scores the seed route); a cold colony: 1 + n_ants j. Seconds are
    interpolated linearly within each phase from its measured time (whole run's time for a cold colony)."""
    h = len(rec["history"])
    ph = rec.get("phases") or {}
    if "pso" in ph:
        p, a = ph["pso"], ph["aco"]
        n_pso = p["iterations"] + 1
        per_p = p["evaluations"] / n_pso
        i = np.arange(1, n_pso + 1)
        ev = list(per_p * i)
        t = list(p["time_s"] * i / n_pso)
        n_aco = h - n_pso
        if n_aco > 0:
            j = np.arange(1, n_aco + 1)
            per_a = (a["evaluations"] - 1) / max(a["iterations"], 1)
            ev += list(p["evaluations"] + 1 + per_a * j)
            t += list(p["time_s"] + a["time_s"] * j / n_aco)
        return np.array(ev), np.array(t)
    j = np.arange(1, h + 1)
    per = (rec["evaluations"] - 1) / max(rec["iterations"], 1)
    return 1 + per * j, rec["time_s"] * j / h


def target_cost(records: Sequence[dict[str, Any]]) -> float:
    return TARGET_FACTOR * float(np.median([r["cost"] for r in records if r["variant"] == "G"]))


def run_rows(records: Sequence[dict[str, Any]]) -> tuple[list[dict[str, Any]], float]:
    """Per-run rows with the derived columns (SPSO-phase cost, ACO gain, work to reach the target)."""
    target = target_cost(records)
    labels = {v.key: v.label for v in VARIANTS}
    out = []
    for r in records:
        hist = np.array(r["history"], dtype=float)
        ev, t = cumulative_work(r)
        hit = np.flatnonzero(hist <= target)
        pso_cost = r["phases"]["pso"]["best_cost"] if r.get("phases") else math.nan
        out.append({**r, "label": labels[r["variant"]], "pso_cost": pso_cost,
                    "aco_gain_pct": 100.0 * (pso_cost - r["cost"]) / pso_cost if r.get("phases") else math.nan,
                    "evals_to_target": float(ev[hit[0]]) if len(hit) else math.nan,
                    "time_to_target_s": float(t[hit[0]]) if len(hit) else math.nan})
    return out, target


def table_rows(runs: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """summarise() (NaN columns stay NaN for the cold arms), reach rate and mean work to the target over the
    runs that reached it, Wilcoxon rank-sum p of cost vs G."""
    from scipy.stats import ranksums

    rows = summarise(runs, VARIANTS, COLUMNS)
    g = np.array([r["cost"] for r in runs if r["variant"] == "G"], dtype=float)
    for row in rows:
        rec = [r for r in runs if r["variant"] == row["variant"]]
        x = np.array([r["cost"] for r in rec], dtype=float)
        row["p_cost_vs_G"] = math.nan if row["variant"] == "G" else float(ranksums(x, g).pvalue)
        reached = [r for r in rec if not math.isnan(r["evals_to_target"])]
        row["reached_target"] = len(reached)
        row["pso_cost_median"] = float(np.median([r["pso_cost"] for r in rec]))
        for col in TARGET_COLUMNS:
            y = np.array([r[col] for r in reached], dtype=float)
            row[f"{col}_mean"] = float(y.mean()) if len(y) else math.nan
            row[f"{col}_std"] = float(y.std(ddof=1)) if len(y) > 1 else (0.0 if len(y) else math.nan)
    return rows


def saving(rows: Sequence[dict[str, Any]], cold: str) -> tuple[float, bool]:
    """% fewer evaluations to the target for G than for a cold arm; (value, is a lower bound). When the cold
    colony never reached the target its whole budget is the (lower-bound) work."""
    by = {r["variant"]: r for r in rows}
    g, c = by["G"]["evals_to_target_mean"], by[cold]
    if c["reached_target"] == c["runs"]:
        return 100.0 * (1.0 - g / c["evals_to_target_mean"]), False
    return 100.0 * (1.0 - g / c["evaluations_mean"]), True


def verdicts(rows: Sequence[dict[str, Any]]) -> list[tuple[str, str, str, str, str]]:
    """(claim, paper, ours, rule, verdict); verdict "reproduced", "not reproduced" or "not measurable"."""
    by = {r["variant"]: r for r in rows}
    out = []
    for cold in COLD:
        s, bound = saving(rows, cold)
        c = by[cold]
        ours = (f"{'≥ ' if bound else ''}{s:.1f} % fewer evaluations (cold colony reached the target in "
                f"{c['reached_target']}/{c['runs']} runs; its budget {c['evaluations_mean']:.0f} evaluations; "
                f"best cold cost {c['cost_mean']:.0f} vs G {by['G']['cost_mean']:.1f})")
        out.append((f"fusion needs 40–60 % less computation than ACO from scratch ({cold}: {c['label']})",
                    "40–60 %", ours, "saving ≥ 40 % (a larger saving counts); when the cold colony never "
                    "reached the target its whole budget is used, giving a lower bound: not measurable if that "
                    "bound is below 40 %",
                    "not measurable" if bound and s < PAPER_SAVING[0] else _word(s >= PAPER_SAVING[0])))
    for k in ("H", "U"):
        r = by[k]
        out.append((f"GKDM gives lower cost than {r['label']} (Fig. 29)", "lower (curve only, no number)",
                    f"G {by['G']['cost_mean']:.2f} vs {r['cost_mean']:.2f} (p = {r['p_cost_vs_G']:.2g})",
                    f"G mean below and rank-sum p < {ALPHA}",
                    _word(by["G"]["cost_mean"] < r["cost_mean"] and r["p_cost_vs_G"] < ALPHA)))
    out.append(("GKDM improves success rate over hard/uniform (§6.2 text)", "higher (no number)",
                ", ".join(f"{k} {100 * by[k]['success_rate']:.0f} %" for k in FUSION),
                "G success strictly above H's and U's",
                _word(all(by["G"]["success_rate"] > by[k]["success_rate"] for k in ("H", "U")))))
    out.append(("GKDM improves efficiency over hard/uniform (§6.2 text)", "higher (no number)",
                ", ".join(f"{k} {by[k]['evals_to_target_mean']:.0f} evals ({by[k]['reached_target']}/"
                          f"{by[k]['runs']} reached)" for k in FUSION),
                "G reaches the target in at least as many runs as H and U, with fewer mean evaluations",
                _word(all(by["G"]["reached_target"] >= by[k]["reached_target"]
                    and (math.isnan(by[k]["evals_to_target_mean"])
                         or by["G"]["evals_to_target_mean"] < by[k]["evals_to_target_mean"]) for k in ("H", "U")))))
    return out


def _word(ok: bool) -> str:
    return "reproduced" if ok else "not reproduced"


def _median_pso(rows: Sequence[dict[str, Any]]) -> float:
    return float(next(r for r in rows if r["variant"] == "G")["pso_cost_median"])


def _f(x: float, fmt: str = ".1f") -> str:
    return "—" if math.isnan(x) else format(x, fmt)


def markdown(rows: Sequence[dict[str, Any]], target: float, settings: BenchSettings) -> str:
    lines = [
        "# GKDM ablation and ACO cold start (paper §5, §6.2, Tables 7/8, Figure 29)", "",
        command_line(settings), "",
        f"Scenario `{settings.bench.scenario.name}`; settings: "
        + settings_list(settings)
        + " (later ones win; each arm adds its own). The SPSO phase is kept short (nPop 100, MaxIt 50, no "
        "stagnation stop) so the colony has room to improve; the colony uses Table 7 (30 ants, 50 iterations, "
        "α 1, β 2, ρ 0.08, τ0 0.1) and Table 8 (A 12, σ 40 m) for every arm, the same corridor lattice, and "
        "only the pheromone start differs. Arm A is the `aco` algorithm: the same colony with uniform τ0 on the "
        "lattice around the straight S→G line and no PSO phase; arm E is A with T_ACO "
        f"{COLD_MATCHED_ITERS}, i.e. about as many cost evaluations as a fusion run.", "",
        f"Target cost = median final cost of arm G × {TARGET_FACTOR} = **{target:.2f}**. A 1 % margin was "
        "tried first and is too loose: the colony improves on the SPSO phase by only a few tenths of a per "
        "cent, so a 1 % target is met inside the SPSO phase and says nothing about the colony; 0.1 % is meant "
        f"to lie below the SPSO phase's result (median SPSO-phase cost of G: {_median_pso(rows):.2f}). The "
        "target is computed from these runs. Evaluations to target: cost evaluations spent until the run's "
        "best-so-far cost first reaches "
        "it (SPSO: nPop per iteration incl. the initial swarm; ACO: 1 for the seed + 30 per iteration); time "
        "to target interpolates each phase's measured time linearly. Means of the work to target are over "
        "the runs that reached it. ACO gain = (SPSO-phase cost − final cost) / SPSO-phase cost. Times are "
        "wall clock and vary between machines; all else is reproducible from the seeds "
        f"({settings.seed_base} + run).", "",
        "| arm | cost | SPSO-phase cost | ACO gain % | success | evaluations | time (s) | reached target "
        "| evals to target | time to target (s) | p cost vs G |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['variant']} {r['label']} | {r['cost_mean']:.2f} ± {r['cost_std']:.2f} "
            f"| {_f(r['pso_cost_mean'], '.2f')} | {_f(r['aco_gain_pct_mean'], '.3f')} "
            f"| {100 * r['success_rate']:.0f} % | {r['evaluations_mean']:.0f} "
            f"| {r['time_s_mean']:.3f} ± {r['time_s_std']:.3f} | {r['reached_target']}/{r['runs']} "
            f"| {_f(r['evals_to_target_mean'], '.0f')} ± {_f(r['evals_to_target_std'], '.0f')} "
            f"| {_f(r['time_to_target_s_mean'], '.4f')} | {_f(r['p_cost_vs_G'], '.2g')} |")
    lines += ["", "## The paper's claims", "",
              "The paper gives no table for Figure 29 (curves only) and states the 40–60 % saving without a "
              "measurement protocol; the rules below are ours.", "",
              *claims_table(verdicts(rows))]
    by = {r["variant"]: r for r in rows}
    means = [by[k]["cost_mean"] for k in FUSION]
    spread = 100.0 * (max(means) - min(means)) / min(means)
    cold_ok = max(by[k]["success_rate"] for k in COLD)
    lines += ["", f"Reading: the cold colony works on the fusion's own lattice around the straight line (±31 m "
              f"across, ±3 m vertically with the default ACO settings), so it cannot get far from the obstacles "
              f"the line crosses; it was feasible in {100 * cold_ok:.0f} % of runs at best. A saving measured "
              "against it says more about that lattice than about ACO's mixing time. Between the three "
              f"initialisations the mean final costs differ by {spread:.2f} %; the colony's mean gain over the "
              "SPSO phase is "
              + ", ".join(f"{k} {by[k]['aco_gain_pct_mean']:.3f} %" for k in FUSION) + ".", ""]
    return "\n".join(lines)


def plot_bars(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    """Final cost of the fusion arms (± std) and mean evaluations to the target per arm."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.8))
    fr = [r for r in rows if r["variant"] in FUSION]
    a.bar([f"{r['variant']}\n{r['label']}" for r in fr], [r["cost_mean"] for r in fr],
          yerr=[r["cost_std"] for r in fr], capsize=5, alpha=0.8)
    lo = min(r["cost_mean"] - r["cost_std"] for r in fr)
    hi = max(r["cost_mean"] + r["cost_std"] for r in fr)
    a.set_ylim(lo - 0.2 * (hi - lo + 1), hi + 0.2 * (hi - lo + 1))
    a.set_ylabel("final cost J (mean ± std)")
    a.set_title("fusion: pheromone initialisation")
    names = [f"{r['variant']}\n{r['label']}".replace(" (", "\n(") for r in rows]
    vals = [r["evals_to_target_mean"] if r["reached_target"] else r["evaluations_mean"] for r in rows]
    colors = ["tab:blue" if r["reached_target"] else "tab:gray" for r in rows]
    b.bar(names, vals, color=colors, alpha=0.8)
    for i, r in enumerate(rows):
        if r["reached_target"] < r["runs"]:
            b.text(i, vals[i], f"{r['reached_target']}/{r['runs']}\nreached", ha="center", va="bottom", fontsize=8)
    b.set_ylabel("cost evaluations to target (grey: whole budget, not reached)")
    b.set_title("computation to reach the target cost")
    for ax in (a, b):
        ax.grid(True, axis="y", alpha=0.3)
        ax.tick_params(axis="x", labelsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_curves(path: Path, records: Sequence[dict[str, Any]], target: float) -> None:
    """Median best-so-far cost vs evaluations for every arm (log y), and the ACO phase of the fusion arms
    alone as cost relative to the SPSO phase's best (per cent)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(13, 5))
    for v in VARIANTS:
        rec = [r for r in records if r["variant"] == v.key]
        if not rec:
            continue
        n = max(len(r["history"]) for r in rec)
        hs = np.array([r["history"] + [r["history"][-1]] * (n - len(r["history"])) for r in rec], dtype=float)
        ev = cumulative_work(max(rec, key=lambda r: len(r["history"])))[0]
        a.plot(ev, np.median(hs, axis=0), label=f"{v.key} {v.label}")
        if v.key in FUSION:
            k = rec[0]["phases"]["pso"]["iterations"] + 1
            rel = 100.0 * (hs[:, k - 1:] / hs[:, k - 1:k] - 1.0)
            b.plot(np.arange(rel.shape[1]), np.median(rel, axis=0), label=f"{v.key} {v.label}")
            b.fill_between(np.arange(rel.shape[1]), np.percentile(rel, 25, axis=0),
                           np.percentile(rel, 75, axis=0), alpha=0.2)
    a.axhline(target, color="k", ls="--", lw=0.8, label=f"target {target:.1f}")
    a.set_yscale("log")
    a.set_xlabel("cost evaluations (fusion: SPSO, then ACO)")
    a.set_ylabel("best cost J (median over runs)")
    a.set_title("cost vs computation")
    b.set_xlabel("ACO iteration (0 = SPSO phase's best)")
    b.set_ylabel("best cost vs SPSO phase, % (median, IQR)")
    b.set_title("ACO phase of the fusion")
    for ax in (a, b):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


BENCHES = (BENCH,)
