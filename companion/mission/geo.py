"""Local ENU ↔ WGS84 conversions and the integer encodings autopilots use (docs/method.md §1.1).

The local frame is ENU metres with its origin at the scenario's home; ``home.alt`` (AMSL) is used as the
origin's ellipsoidal height, the usual local simplification (the geoid offset is constant over a mission
area and cancels). Mission altitudes are *not* taken from here: items carry ENU z as height above home.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pymap3d

from planner.world.environment import Cylinders
from planner.world.home import Home

WGS84 = pymap3d.Ellipsoid.from_name("wgs84")
CIRCLE_VERTICES = 64  # polygon approximation of a no-fly circle in drawings


def enu_to_geodetic(points: np.ndarray, home: Home) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ENU points (..., 3) m → (lat deg, lon deg, alt m AMSL), each (...)."""
    p = np.asarray(points, dtype=float)
    lat, lon, alt = pymap3d.enu2geodetic(p[..., 0], p[..., 1], p[..., 2], home.lat, home.lon, home.alt, ell=WGS84)
    return np.asarray(lat, dtype=float), np.asarray(lon, dtype=float), np.asarray(alt, dtype=float)


def geodetic_to_enu(lat: np.ndarray | float, lon: np.ndarray | float, alt: np.ndarray | float,
                    home: Home) -> np.ndarray:
    """(lat deg, lon deg, alt m AMSL), broadcastable → ENU points (..., 3) m."""
    e, n, u = pymap3d.geodetic2enu(lat, lon, alt, home.lat, home.lon, home.alt, ell=WGS84)
    return np.stack(np.broadcast_arrays(np.asarray(e, float), np.asarray(n, float), np.asarray(u, float)), axis=-1)


def to_int_e7(deg: float) -> int:
    """Degrees → degrees × 1e7 as an integer, rounding half away from zero (MAVLink ``*_INT`` lat/lon)."""
    scaled = float(deg) * 1e7
    return int(math.copysign(math.floor(abs(scaled) + 0.5), scaled))


@dataclass(frozen=True)
class Circle:
    """A no-fly zone's footprint on the map: centre (deg), radius (m), top (m above home; inf = unlimited)."""

    lat: float
    lon: float
    radius_m: float
    top_m: float = math.inf
    kind: str = "cylinder"


def circles_from_cylinders(cylinders: Cylinders, home: Home) -> list[Circle]:
    """One :class:`Circle` per ENU cylinder."""
    if not len(cylinders):
        return []
    centres = np.stack([cylinders.x, cylinders.y, np.zeros(len(cylinders))], axis=-1)
    lat, lon, _ = enu_to_geodetic(centres, home)
    return [Circle(float(a), float(o), float(r), float(t))
            for a, o, r, t in zip(lat, lon, cylinders.radius, cylinders.top)]


def circle_ring(circle: Circle, vertices: int = CIRCLE_VERTICES) -> list[tuple[float, float]]:
    """Closed (lon, lat) ring approximating ``circle``: ``vertices`` points counter-clockwise (RFC 7946
    exterior-ring order), then the first point again."""
    theta = np.linspace(0.0, 2.0 * math.pi, vertices, endpoint=False)
    centre = Home(circle.lat, circle.lon, 0.0)
    ring = np.stack([circle.radius_m * np.cos(theta), circle.radius_m * np.sin(theta), np.zeros(vertices)], axis=-1)
    lat, lon, _ = enu_to_geodetic(ring, centre)
    points = [(float(o), float(a)) for a, o in zip(lat, lon)]
    return points + points[:1]


def lonlatalt(points: np.ndarray, home: Home) -> list[tuple[float, float, float]]:
    """ENU points (N, 3) → [(lon, lat, alt AMSL)] for map formats (GeoJSON order)."""
    lat, lon, alt = enu_to_geodetic(np.asarray(points, dtype=float).reshape(-1, 3), home)
    return [(float(o), float(a), float(h)) for a, o, h in zip(lat, lon, alt)]


def as_circles(zones: Cylinders | Sequence[Circle], home: Home) -> list[Circle]:
    """Circles as given, or converted from ENU cylinders."""
    return circles_from_cylinders(zones, home) if isinstance(zones, Cylinders) else list(zones)
