"""The operator's world of issue 35's flights, as a ground station uploads it round the vehicle's home: an inclusion
polygon, three exclusion polygons (a wall, a C open away from the route, a triangle) across the way to the goal, an
exclusion circle, and a one-item mission (the goal); plus the base scenario those flights plan with and the
independent check of a flown track against the zones."""

from __future__ import annotations

from pathlib import Path

import gcs_world
import numpy as np

from companion.mavlink.items import MissionItem
from planner.world.home import Home
from planner.world.polygons import boundary_distance, contains

# (inclusion, vertices as (east, north) metres from home: the flights' plan-view x, y)
POLYGONS = (
    (True, ((-300.0, -250.0), (1450.0, -250.0), (1600.0, 300.0), (1450.0, 1000.0), (-150.0, 1000.0), (-300.0, 400.0))),
    (False, ((280.0, -120.0), (420.0, -120.0), (420.0, 330.0), (280.0, 330.0))),
    (False, ((600.0, 200.0), (880.0, 200.0), (880.0, 280.0), (680.0, 280.0), (680.0, 440.0), (880.0, 440.0),
             (880.0, 540.0), (600.0, 540.0))),
    (False, ((1000.0, 180.0), (1180.0, 260.0), (1040.0, 380.0))),
)
CIRCLE = (520.0, 640.0, 60.0)  # east, north, radius (m)
GOAL = (1180.0, 720.0)  # east, north
D_COLL = 20.0


def fence_items(home: Home) -> list[MissionItem]:
    """The zones as a ground station uploads them, numbered (gcs_world.fence_items, which takes north, east)."""
    polygons = [(inclusion, [(n, e) for e, n in vertices]) for inclusion, vertices in POLYGONS]
    items = gcs_world.fence_items(home, polygons, (CIRCLE[1], CIRCLE[0], CIRCLE[2]))
    return [it.with_seq(k) for k, it in enumerate(items)]


def goal_mission(home: Home, home_item: bool, alt: float = 60.0) -> list[MissionItem]:
    """One navigation item (the goal); on ArduPilot after the home placeholder at item 0."""
    items = gcs_world.goal_mission(home, north=GOAL[1], east=GOAL[0], alt=alt, home_item=home_item)
    return [it.with_seq(k) for k, it in enumerate(items)]


def base_scenario(path: Path, home: Home, vehicle: str, cruise_speed: float) -> Path:
    """The scenario the flights plan with: the vehicle, its band and clearances, a start near home; no zones (they
    come from the vehicle) and a goal the vehicle's mission replaces."""
    path.write_text(f"""name = "operator_course"
[home]
lat = {home.lat}
lon = {home.lon}
alt = {home.alt}
[bounds]
x = 1500.0
y = 1000.0
[altitude]
min = 30.0
max = 120.0
[route]
start = [150.0, 100.0, 60.0]
goal = [1400.0, 900.0, 60.0]
[vehicle]
type = "{vehicle}"
cruise_speed = {cruise_speed}
[hazard]
d_coll = {D_COLL}
d_safe = 60.0
""")
    return path


def track_clearance(points: np.ndarray) -> dict[str, float]:
    """Least plan-view clearance (m) of ``points`` ((n, ≥2) east, north from home) from each zone's edges, by the
    polygon functions (negative when a point is on the wrong side: inside a no-fly zone, outside the inclusion)."""
    out = {}
    xy = np.asarray(points, dtype=float)[:, :2]
    for k, (inclusion, vertices) in enumerate(POLYGONS):
        ring = np.asarray(vertices)
        gap = boundary_distance(ring, xy)
        wrong = ~contains(ring, xy) if inclusion else contains(ring, xy)
        out[f"polygon {k}"] = float(np.min(np.where(wrong, -gap, gap)))
    out["circle"] = float(np.min(np.hypot(xy[:, 0] - CIRCLE[0], xy[:, 1] - CIRCLE[1]) - CIRCLE[2]))
    return out
