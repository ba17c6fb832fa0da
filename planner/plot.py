"""Pictures of a plan: the 3-D route among its obstacles and the convergence curve (matplotlib, Agg)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from planner.world.environment import Environment

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from mpl_toolkits.mplot3d import Axes3D


def draw_environment(ax: Axes3D, env: Environment, z_top: float) -> None:
    """Cylinders (to their top, or to the ceiling when unlimited), prisms' walls, spheres and terrain on a 3-D
    axis."""
    th = np.linspace(0, 2 * np.pi, 40)
    cyl = env.cylinders
    for x, y, r, top in zip(cyl.x, cyl.y, cyl.radius, cyl.top):
        h = z_top if np.isinf(top) else top
        zz = np.array([0.0, h])
        tt, hh = np.meshgrid(th, zz)
        ax.plot_surface(x + r * np.cos(tt), y + r * np.sin(tt), hh, color="tab:red", alpha=0.25,
                        linewidth=0)
    prisms = env.prisms
    for k in range(len(prisms)):  # walls between floor and ceiling (ground and the plot's top when unlimited)
        ring = np.vstack([prisms.polygon(k), prisms.polygon(k)[:1]])
        lo, hi = max(float(prisms.floor[k]), 0.0), min(float(prisms.ceiling[k]), z_top)
        keep_in = bool(prisms.keep_in[k])
        ax.plot_surface(np.tile(ring[:, 0], (2, 1)), np.tile(ring[:, 1], (2, 1)),
                        np.array([[lo] * len(ring), [hi] * len(ring)]), color="tab:green" if keep_in else "tab:red",
                        alpha=0.08 if keep_in else 0.25, linewidth=0)
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 24), np.linspace(0, np.pi, 12))
    for c, r in zip(env.spheres.center, env.spheres.radius):
        ax.plot_surface(c[0] + r * np.cos(u) * np.sin(v), c[1] + r * np.sin(u) * np.sin(v),
                        np.maximum(c[2] + r * np.cos(v), 0.0), color="tab:orange", alpha=0.25, linewidth=0)
    for c, r in zip(env.radars.center, env.radars.r_det):
        ax.plot_wireframe(c[0] + r * np.cos(u) * np.sin(v), c[1] + r * np.sin(u) * np.sin(v),
                          np.maximum(c[2] + r * np.cos(v), 0.0), color="tab:purple", alpha=0.2,
                          linewidth=0.5)
    if env.terrain is not None:
        xs = np.linspace(0, env.size_x, 60)
        ys = np.linspace(0, env.size_y, 60)
        gx, gy = np.meshgrid(xs, ys)
        ax.plot_surface(gx, gy, env.terrain.height_at(gx, gy), cmap="terrain", alpha=0.5, linewidth=0)


def draw_plan_view(ax: Axes, env: Environment) -> None:
    """Top-down view: cylinders, prisms, spheres (full radius), radar detection ranges, threat tracks, terrain."""
    from matplotlib.patches import Circle, Polygon

    if env.terrain is not None:
        xs = np.linspace(0, env.size_x, 120)
        ys = np.linspace(0, env.size_y, 120)
        gx, gy = np.meshgrid(xs, ys)
        cs = ax.contourf(gx, gy, env.terrain.height_at(gx, gy), levels=12, cmap="terrain", alpha=0.6)
        ax.figure.colorbar(cs, ax=ax, shrink=0.7, label="ground (m)")
    cyl = env.cylinders
    for x, y, r in zip(cyl.x, cyl.y, cyl.radius):
        ax.add_patch(Circle((x, y), r, color="tab:red", alpha=0.35, lw=0))
    prisms = env.prisms
    for k in range(len(prisms)):  # no-fly polygons filled (hatched when they have a floor or ceiling); keep-in outlined
        if prisms.keep_in[k]:
            ax.add_patch(Polygon(prisms.polygon(k), closed=True, fill=False, color="tab:green", lw=1.5, ls="-."))
            continue
        slab = np.isfinite(prisms.floor[k]) or np.isfinite(prisms.ceiling[k])
        ax.add_patch(Polygon(prisms.polygon(k), closed=True, facecolor="tab:red", edgecolor="tab:red", alpha=0.35,
                             lw=0.5 if slab else 0.0, hatch="//" if slab else None))
    for c, r in zip(env.spheres.center, env.spheres.radius):
        ax.add_patch(Circle((c[0], c[1]), r, color="tab:orange", alpha=0.35, lw=0))
    for c, r in zip(env.radars.center, env.radars.r_det):
        ax.add_patch(Circle((c[0], c[1]), r, fill=False, color="tab:purple", ls="--"))
    if len(env.threats):
        t = np.linspace(0.0, 600.0, 600)
        for k, track in enumerate(env.threats.positions(t)):
            ax.plot(track[:, 0], track[:, 1], ":", color="tab:purple", lw=1.2,
                    label="threat tracks" if k == 0 else None)
    ax.set_xlim(0, env.size_x)
    ax.set_ylim(0, env.size_y)
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")


def plot_plan(
    path: str | Path, env: Environment, waypoints: np.ndarray, trajectory: np.ndarray,
    history: list[float], title: str,
) -> None:
    """Write a PNG: 3-D route, top-down view and the best-cost curve."""
    fig = plt.figure(figsize=(18, 6))
    ax = fig.add_subplot(1, 3, 1, projection="3d")
    z_top = max(env.z_max, float(np.max(trajectory[:, 2])) * 1.2)
    draw_environment(ax, env, z_top)
    ax.plot(*waypoints.T, "o--", color="tab:gray", ms=3, lw=0.8, label="waypoints")
    ax.plot(*trajectory.T, color="tab:blue", lw=2, label="smoothed trajectory")
    ax.scatter(*waypoints[0], color="green", s=40, label="start")
    ax.scatter(*waypoints[-1], color="black", marker="*", s=80, label="goal")
    ax.set_xlim(0, env.size_x)
    ax.set_ylim(0, env.size_y)
    ax.set_zlim(0, z_top)
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_zlabel("up (m)")
    ax.view_init(elev=55, azim=-120)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(title)
    top = fig.add_subplot(1, 3, 2)
    draw_plan_view(top, env)
    top.plot(waypoints[:, 0], waypoints[:, 1], "o--", color="tab:gray", ms=3, lw=0.8)
    sc = top.scatter(trajectory[:, 0], trajectory[:, 1], c=trajectory[:, 2], s=3, cmap="viridis")
    fig.colorbar(sc, ax=top, shrink=0.7, label="altitude (m)")
    top.plot(*waypoints[0, :2], "o", color="green")
    top.plot(*waypoints[-1, :2], "*", color="black", ms=10)
    top.set_title("plan view")
    if len(env.threats):
        top.legend(loc="upper left", fontsize=8)
    ax2 = fig.add_subplot(1, 3, 3)
    ax2.plot(np.arange(len(history)), history, color="tab:blue")
    ax2.set_yscale("log")
    ax2.set_xlabel("iteration")
    ax2.set_ylabel("best cost J")
    ax2.set_title("convergence")
    ax2.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_pipeline(path: str | Path, env: Environment, roadmap_edges: np.ndarray, guides: list[np.ndarray],
                  ants: list[np.ndarray], trajectory: np.ndarray, planted: np.ndarray | None, title: str) -> None:
    """Top-down PNG of the roadmap pipeline (docs/method.md §15): roadmap edges (M, 2, 2), the diverse guide
    routes, the colony's last ants, the flown (smoothed) route and, on a generated map, the planted route."""
    from matplotlib.collections import LineCollection

    fig, ax = plt.subplots(figsize=(8, 7))
    draw_plan_view(ax, env)
    ax.add_collection(LineCollection(list(roadmap_edges), colors="0.6", linewidths=0.3, alpha=0.35, label="roadmap"))
    for k, a in enumerate(ants):
        ax.plot(a[:, 0], a[:, 1], color="tab:olive", lw=0.7, alpha=0.5, label="colony's ants" if k == 0 else None)
    for k, g in enumerate(guides):
        ax.plot(g[:, 0], g[:, 1], "--", color="tab:green", lw=1.4, label="guides (diverse seeds)" if k == 0 else None)
    if planted is not None:
        ax.plot(planted[:, 0], planted[:, 1], ":", color="k", lw=1.2, label="planted route")
    ax.plot(trajectory[:, 0], trajectory[:, 1], color="tab:blue", lw=2.2, label="final route (smoothed)")
    ax.plot(*trajectory[0, :2], "go", ms=8)
    ax.plot(*trajectory[-1, :2], "r*", ms=12)
    ax.set_title(title)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
