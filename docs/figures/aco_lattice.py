"""Draws docs/figures/aco_lattice.png: the ACO corridor lattice around an SPSO route on rescue_static,
with the GKDM pheromone of every edge (plan view). Run: python docs/figures/aco_lattice.py"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import LineCollection

from planner.plan import plan, problem_from_scenario
from planner.plot import draw_plan_view
from planner.search.aco import build_lattice, initial_pheromone
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]


def main() -> None:
    sc = load_scenario(ROOT / "sitl_scenarios" / "rescue_static.toml", ['planner.algorithm="spso"'])
    res = plan(problem_from_scenario(sc), sc.planner, np.random.default_rng(1))
    cfg = sc.planner.aco
    lat = build_lattice(res.optimiser.path, cfg)
    fig, axes = plt.subplots(1, 2, figsize=(15, 7))
    for ax, mode in zip(axes, ("gkdm", "hard")):
        tau = initial_pheromone(lat, cfg, mode)
        level = lat.offsets[:, 1] == 0  # the lattice level at the route's own height
        segs, vals = [], []
        for k in range(lat.n_layers - 1):
            i_nodes = np.flatnonzero(level) if 0 < k else [lat.centre]
            j_nodes = np.flatnonzero(level) if k + 1 < lat.n_layers - 1 else [lat.centre]
            for i in i_nodes:
                for j in j_nodes:
                    segs.append([lat.nodes[k, i, :2], lat.nodes[k + 1, j, :2]])
                    vals.append(tau[k, i, j])
        order = np.argsort(vals)
        lc = LineCollection(np.array(segs)[order], array=np.array(vals)[order], cmap="viridis", lw=0.8)
        draw_plan_view(ax, sc.environment)
        ax.add_collection(lc)
        fig.colorbar(lc, ax=ax, shrink=0.7, label="initial pheromone τ")
        ax.plot(*lat.nodes[1:-1][:, level].reshape(-1, 3)[:, :2].T, ".", color="black", ms=2)
        ax.plot(*res.optimiser.path[:, :2].T, "--", color="red", lw=1, label="SPSO route")
        ax.set_title(f"{mode}: τ0 = {cfg.tau0}, " + (f"A = {cfg.amplitude}, σ = {cfg.sigma} m" if mode == "gkdm"
                                                      else f"boost = {cfg.hard_boost}"))
        ax.legend(loc="upper left")
    fig.suptitle("ACO corridor lattice (level of the route; 11 cross-track × 5 vertical nodes per layer, "
                 "offsets ±1, 3, 7, 15, 31 m)")
    fig.tight_layout()
    fig.savefig(Path(__file__).with_suffix(".png"), dpi=90)


if __name__ == "__main__":
    main()
