"""What the flight looks like in the local frame, as plain JSON values for the event log (``scene``, ``mission``,
``contacts`` records): the status page draws from these alone (docs/design.md, "The status page").

Local frame: ENU metres from home, z above home, rounded to 0.1 m (what a picture needs, a tenth of the size).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from companion.mavlink.items import MissionItem
from companion.mission.builder import is_home_item
from companion.mission.geo import geodetic_to_enu
from planner.world.environment import Threats
from planner.world.home import Home
from planner.world.scenario import Scenario

ROUTE_POINTS = 400  # at most this many points of a drawn trajectory (thinned evenly, ends kept)
SCRIPTED_PATH_S = 600.0  # a scripted threat's law drawn over this many seconds of mission time
SCRIPTED_PATH_POINTS = 240


def _round(a: np.ndarray) -> list:
    return np.round(np.asarray(a, dtype=float), 1).tolist()


def thinned(points: np.ndarray, limit: int = ROUTE_POINTS) -> np.ndarray:
    """At most ``limit`` rows of ``points``, evenly spaced, first and last kept."""
    points = np.asarray(points, dtype=float)
    if len(points) <= limit:
        return points
    return points[np.unique(np.linspace(0, len(points) - 1, limit).round().astype(int))]


def scene(scenario: Scenario, plan_doc: dict[str, Any]) -> dict[str, Any]:
    """The ``scene`` record: map bounds, obstacles, scripted threats' paths and the planned route."""
    env = scenario.environment
    cyl, sph, rad = env.cylinders, env.spheres, env.radars
    threats = env.threats
    paths = threats.positions(np.linspace(0.0, SCRIPTED_PATH_S, SCRIPTED_PATH_POINTS))[..., :2] if len(threats) \
        else np.zeros((0, 0, 2))
    return {
        "name": scenario.name,
        "vehicle": scenario.vehicle.type,
        "home": {"lat": scenario.home.lat, "lon": scenario.home.lon, "alt": scenario.home.alt},
        "bounds": {"x": env.size_x, "y": env.size_y, "z_min": env.z_min, "z_max": env.z_max},
        "d_coll": scenario.hazard.d_coll,
        "cylinders": _round(np.column_stack([cyl.x, cyl.y, cyl.radius])) if len(cyl) else [],
        "spheres": _round(np.column_stack([sph.center, sph.radius])) if len(sph) else [],
        "radars": _round(np.column_stack([rad.center, rad.r_det])) if len(rad) else [],
        "prisms": [{"xy": _round(env.prisms.polygon(k)), "keep_in": bool(env.prisms.keep_in[k]),
                    "slab": bool(np.isfinite(env.prisms.floor[k]) or np.isfinite(env.prisms.ceiling[k]))}
                   for k in range(len(env.prisms))],
        "launch": _round(np.asarray(scenario.launch, dtype=float)),
        "threat_paths": {t.id: _round(p) for t, p in zip(threats.items, paths)},
        "route": _round(thinned(np.asarray(plan_doc["trajectory"]["points"]))),
        "waypoints": _round(np.asarray(plan_doc["waypoints"])),
        "terrain": env.terrain is not None,
    }


def mission(items: Sequence[MissionItem], home: Home) -> dict[str, Any]:
    """The ``mission`` record: every item with a position (not item 0, home), as ``[seq, x, y, z]``."""
    placed = [it for it in items if (it.x or it.y) and not is_home_item(it)]
    if not placed:
        return {"count": len(items), "items": []}
    lat = np.array([it.lat for it in placed])
    lon = np.array([it.lon for it in placed])
    enu = geodetic_to_enu(lat, lon, home.alt, home)
    rows = np.column_stack([[it.seq for it in placed], enu[:, :2], [it.z for it in placed]])
    return {"count": len(items), "items": [[int(r[0]), *_round(r[1:])] for r in rows]}


def contacts(threats: Threats, now: float, horizon_s: float, steps: int = 10) -> list[dict[str, Any]]:
    """Every threat at mission time ``now``: position, radius and predicted path over ``horizon_s`` (one
    broadcast for all of them)."""
    if not len(threats):
        return []
    t = now + np.linspace(0.0, horizon_s, steps + 1)
    pos = threats.positions(t)  # (k, steps+1, 3)
    radii = threats.radii(np.array([now]))[:, 0]
    return [{"id": th.id, "kind": th.kind, "source": "adsb" if th.kind == "track" else "scripted",
             "p": _round(p[0]), "r": round(float(r), 1), "path": _round(p[:, :2])}
            for th, p, r in zip(threats.items, pos, radii)]
