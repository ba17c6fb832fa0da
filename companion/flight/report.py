"""The flight report directory: PLAN.json, mission files, event log, flight.json and a track picture."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from planner.plan import json_safe
from planner.world.environment import Environment


def write_json(path: Path, doc: dict[str, Any]) -> None:
    path.write_text(json.dumps(json_safe(doc), indent=1, allow_nan=False) + "\n")


def plot_track(path: Path, env: Environment, planned: np.ndarray, flown: np.ndarray, title: str,
               intruders: dict[str, np.ndarray] | None = None,
               replans: list[tuple[np.ndarray, np.ndarray]] | None = None) -> None:
    """Planned trajectory vs flown track: plan view with obstacles, intruder tracks, each replan's old
    (abandoned) and new route from its commit point, and altitude along the way."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from planner.plot import draw_plan_view

    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(15, 6.5), gridspec_kw={"width_ratios": [1.2, 1]})
    draw_plan_view(ax, env)
    ax.plot(planned[:, 0], planned[:, 1], "--", color="tab:blue", lw=1.5, label="planned")
    if len(flown):
        ax.plot(flown[:, 0], flown[:, 1], color="tab:green", lw=1.5, label="flown")
    for i, (old, new) in enumerate(replans or []):
        ax.plot(old[:, 0], old[:, 1], "-", color="tab:gray", lw=1.0, alpha=0.7,
                label="abandoned route" if i == 0 else None)
        ax.plot(new[:, 0], new[:, 1], "-o", color="tab:orange", lw=1.2, ms=3,
                label="replanned route" if i == 0 else None)
        ax.plot(*new[0, :2], "s", color="tab:orange", ms=6)
        ax.annotate(f"R{i + 1}", new[0, :2], textcoords="offset points", xytext=(5, 5), fontsize=8)
    for name, trk in (intruders or {}).items():
        if len(trk):
            ax.plot(trk[:, 0], trk[:, 1], ":", color="tab:red", lw=1.2, label=f"intruder {name}")
            ax.annotate("", trk[-1, :2], trk[max(len(trk) - 20, 0), :2],
                        arrowprops={"arrowstyle": "->", "color": "tab:red"})
    ax.plot(*planned[0, :2], "o", color="green")
    ax.plot(*planned[-1, :2], "*", color="black", ms=10)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(title)

    def along(p: np.ndarray) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p[:, :2], axis=0), axis=1))])

    ax2.plot(along(planned), planned[:, 2], "--", color="tab:blue", label="planned")
    if len(flown):
        ax2.plot(along(flown), flown[:, 2], color="tab:green", label="flown")
    ax2.axhline(env.z_min, color="gray", lw=0.8, ls=":")
    ax2.axhline(env.z_max, color="gray", lw=0.8, ls=":")
    ax2.set_xlabel("horizontal distance flown (m)")
    ax2.set_ylabel("altitude above home (m)")
    ax2.grid(True, alpha=0.3)
    ax2.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
