"""Separation actually flown: the vehicle's truth track against every threat's truth (flight.json;
docs/design.md, "Live replanning").

Separation is distance between centres minus the threat's protected radius, the same measure the conflict
prediction uses, so ``min_separation ≥ d_coll`` means the vehicle never entered the d_coll shell.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from planner.world.environment import Threats


@dataclass(frozen=True)
class Separation:
    """Closest the vehicle came to one threat: ``separation`` m at sim time ``t`` (NaN/inf: never met)."""

    threat_id: str
    separation: float
    t: float
    distance: float


def separation_to_track(vehicle: np.ndarray, threat: np.ndarray, radius: float, threat_id: str) -> Separation:
    """``vehicle`` (N, 4) and ``threat`` (M, 4) rows (t, x, y, z), each sorted by t; the threat is linearly
    interpolated at the vehicle's times inside its own time span (it is not in the air outside it)."""
    if len(vehicle) == 0 or len(threat) == 0:
        return Separation(threat_id, float("inf"), float("nan"), float("inf"))
    t = vehicle[:, 0]
    inside = (t >= threat[0, 0]) & (t <= threat[-1, 0])
    if not inside.any():
        return Separation(threat_id, float("inf"), float("nan"), float("inf"))
    tt = t[inside]
    where = np.stack([np.interp(tt, threat[:, 0], threat[:, k]) for k in (1, 2, 3)], axis=1)
    dist = np.linalg.norm(vehicle[inside, 1:4] - where, axis=1)
    i = int(np.argmin(dist))
    return Separation(threat_id, float(dist[i] - radius), float(tt[i]), float(dist[i]))


def separation_to_law(vehicle: np.ndarray, threats: Threats, clock_offset: float) -> list[Separation]:
    """Scripted threats whose laws run on mission time: law time = vehicle time − ``clock_offset``."""
    if len(threats) == 0 or len(vehicle) == 0:
        return []
    t = vehicle[:, 0] - clock_offset
    centres = threats.positions(t)  # (k, N, 3)
    dist = np.linalg.norm(centres - vehicle[None, :, 1:4], axis=-1)
    sep = dist - threats.radii(t)
    j = np.argmin(sep, axis=1)
    return [Separation(it.id, float(sep[i, j[i]]), float(vehicle[j[i], 0]), float(dist[i, j[i]]))
            for i, it in enumerate(threats.items)]


def min_separations(vehicle: np.ndarray, intruders: Mapping[str, tuple[np.ndarray, float]],
                    scripted: Threats | None = None, mission_t0: float | None = None) -> dict[str, Separation]:
    """Per threat id: the truth-track minimum separation (intruders from their own truth tracks; scripted
    threats from their laws, only once the mission clock has started)."""
    out = {tid: separation_to_track(vehicle, np.asarray(trk, dtype=float).reshape(-1, 4), radius, tid)
           for tid, (trk, radius) in intruders.items()}
    if scripted is not None and mission_t0 is not None:
        flying = vehicle[vehicle[:, 0] >= mission_t0]
        out.update({s.threat_id: s for s in separation_to_law(flying, scripted, mission_t0)})
    return out
