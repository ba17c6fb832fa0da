"""The operator's world as read from a ground station's files, airspace data or the vehicle: geographic values.

Importers (``planner/world/imports/``) and the vehicle's fence download (the companion) produce these; the
scenario builder turns them into local metres (docs/scenario_format.md, "Geographic scenarios"). Latitudes and
longitudes are WGS-84 degrees; every altitude states its reference, as QGroundControl and MAVLink frames do.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

LAT_LIMIT_DEG, LON_LIMIT_DEG = 90.0, 180.0  # a latitude lies in ±90°, a longitude in ±180° (WGS-84 degrees)
AltitudeRef = Literal["home", "ground", "amsl"]  # above home (MAVLink relative alt), above ground (terrain), AMSL
ALTITUDE_REFS: tuple[AltitudeRef, ...] = ("home", "ground", "amsl")


@dataclass(frozen=True)
class Altitude:
    """A height in metres and what it is measured from."""

    value: float
    ref: AltitudeRef = "home"


@dataclass(frozen=True)
class GeoPoint:
    """A position: degrees, and an altitude when the source gives one."""

    lat: float
    lon: float
    alt: Altitude | None = None


@dataclass(frozen=True)
class Zone:
    """A fence or airspace zone: a polygon (``polygon``, (lat, lon) vertices, not closed) or a circle (``centre``,
    ``radius_m``), no-fly (``inclusion`` False) or the region to stay inside (True), between an optional ``floor``
    and ``ceiling`` (None: from the ground / unlimited). ``name`` says where it came from, for messages
    (``geoFence.polygons[2]``, ``features[3] "Danger area D123"``)."""

    name: str
    inclusion: bool = False
    polygon: tuple[tuple[float, float], ...] | None = None
    centre: tuple[float, float] | None = None
    radius_m: float | None = None
    floor: Altitude | None = None
    ceiling: Altitude | None = None


@dataclass(frozen=True)
class OperatorMission:
    """What a ground-station mission file (or the vehicle) holds: its ``home`` (planned home, or None), the
    ``start`` (home or the first position), the ``goal`` (the last navigation item), the ``vias`` the operator set
    between them, the fence ``zones`` and the ``rally`` points. ``source`` is the file it was read from."""

    source: Path
    home: GeoPoint | None = None
    start: GeoPoint | None = None
    goal: GeoPoint | None = None
    vias: tuple[GeoPoint, ...] = ()
    zones: tuple[Zone, ...] = ()
    rally: tuple[GeoPoint, ...] = ()
    extras: dict[str, object] = field(default_factory=dict)  # format-specific values kept for writing back
