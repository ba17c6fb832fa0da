"""The flown track's safety verdict (flight.json; README, "Exit codes of fly").

A plan is only a promise: what a pilot is owed is the *flown* track's clearance. This module measures it from the
track (the simulator's truth, or the autopilot's GLOBAL_POSITION_INT) against every static obstacle, names the
nearest one, and puts it beside the traffic separations, each against d_coll.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from planner.trajectory.checks import obstacle_distances
from planner.world.environment import Environment

AIRBORNE_M = 1.0  # m above home: samples below this are the vehicle on the ground (not in anyone's airspace)


@dataclass(frozen=True)
class FlownSafety:
    """Closest the flown track came to the static world and to traffic, and what broke d_coll."""

    static_clearance_m: float  # signed distance to the nearest obstacle surface (inf: no obstacle, no track)
    nearest_obstacle: str | None  # e.g. "cylinders[3]"
    traffic_separation_m: float  # min over every threat of (centre distance − protected radius); inf: none
    nearest_traffic: str | None
    d_coll_m: float
    breaches: list[str] = field(default_factory=list)  # one phrase each, empty when safe

    @property
    def safe(self) -> bool:
        return not self.breaches


def flown_safety(flown: np.ndarray, env: Environment, d_coll: float,
                 separations: Mapping[str, float]) -> FlownSafety:
    """The verdict on a flown track ``flown`` (N, 3) ENU m (z above home) and the per-threat minimum separations
    measured elsewhere (truth tracks or the traffic feed)."""
    flown = np.asarray(flown, dtype=float).reshape(-1, 3)
    airborne = flown[flown[:, 2] > AIRBORNE_M]
    per = {k: float(v.min()) for k, v in obstacle_distances(airborne, env).items()}
    nearest = min(per, key=per.__getitem__, default=None)
    static = per[nearest] if nearest is not None else float("inf")
    finite = {k: float(v) for k, v in separations.items() if np.isfinite(v)}
    traffic_id = min(finite, key=finite.__getitem__, default=None)
    traffic = finite[traffic_id] if traffic_id is not None else float("inf")
    breaches = []
    if static < d_coll:
        where = "inside" if static < 0 else f"{static:.1f} m from"
        breaches.append(f"the flown track came {where} {nearest}" + (f" ({-static:.1f} m in)" if static < 0 else "")
                        + f", d_coll {d_coll:g} m")
    for k, v in sorted(finite.items(), key=lambda kv: kv[1]):
        if v < d_coll:
            breaches.append(f"separation from {k} {v:.1f} m, d_coll {d_coll:g} m")
    return FlownSafety(static, nearest, traffic, traffic_id, d_coll, breaches)
