"""Airspace as operators get it → :class:`Zone` values (docs/imports.md, "OpenAIP airspace" and "ED-269 UAS
geographical zones").

- **OpenAIP** airspace (its API's ``items`` and its exports): a GeoJSON Polygon per airspace and vertical limits as
  ``{value, unit, referenceDatum}`` codes (:data:`OPENAIP_UNITS`, :data:`OPENAIP_DATUMS`).
- **EUROCAE ED-269** UAS geographical zones, as EU states publish them: each zone a ``restriction`` and a list of
  volumes, each with its own horizontal projection (Polygon or Circle), limits, unit and vertical references.

Every zone read is no-fly (the operator chose the file); an ED-269 zone with no restriction is informational and is
skipped with a warning. Heights become :class:`Altitude` values in metres above ground or above sea level; a flight
level is read on the standard atmosphere (:func:`openaip_limit`), and an ED-269 height above the WGS-84 ellipsoid is
refused (no geoid model here). Which format a file is in is decided in planner/world/imports/zones.py.
"""

from __future__ import annotations

import logging
from typing import Any, TypeGuard

from planner.errors import ScenarioError
from planner.world.geo_inputs import Altitude, AltitudeRef, Zone
from planner.world.imports.common import check_band, kind, number
from planner.world.imports.geojson import labelled, name_of, outer_ring, polygon_parts, position, what_geometry

log = logging.getLogger(__name__)

FOOT_M = 0.3048  # the international foot, exactly
FLIGHT_LEVEL_FT = 100  # FL nnn: a pressure altitude of nnn × 100 ft

# OpenAIP's vertical-limit codes (Core API airspace schema): unit → (its name, the value's multiplier, metres per
# multiplied unit), so FL 65 is 65 × 100 × 0.3048 m, the same float as 6500 ft
OPENAIP_UNITS: dict[int, tuple[str, int, float]] = {0: ("metres", 1, 1.0), 1: ("feet", 1, FOOT_M),
                                                    6: ("a flight level", FLIGHT_LEVEL_FT, FOOT_M)}
OPENAIP_FLIGHT_LEVEL = 6
# referenceDatum → (its name, our reference): GND above ground, MSL above sea level, STD the standard pressure
# datum, read as above sea level on the standard atmosphere (docs/imports.md says what that costs)
OPENAIP_DATUMS: dict[int, tuple[str, AltitudeRef]] = {0: ("GND", "ground"), 1: ("MSL", "amsl"), 2: ("STD", "amsl")}
OPENAIP_STD = 2

# ED-269: uomDimensions → metres per unit (limits and a circle's radius); vertical references → ours
ED269_UNITS: dict[str, float] = {"M": 1.0, "FT": FOOT_M}
ED269_REFS: dict[str, AltitudeRef] = {"AGL": "ground", "AMSL": "amsl"}
# restrictions that make a zone no-fly (REQ_AUTHORIZATION: the ED-318 spelling some files use); NO_RESTRICTION is
# informational. An operator holding an authorisation removes that zone from the file.
ED269_NO_FLY = ("PROHIBITED", "REQ_AUTHORISATION", "REQ_AUTHORIZATION", "CONDITIONAL")
ED269_INFORMATIONAL = "NO_RESTRICTION"


# --- OpenAIP ---------------------------------------------------------------------------------------------------

def openaip_zones(file: str, where: str, attrs: dict[str, Any], rel: str, geometry: Any) -> list[Zone]:
    """The no-fly zones of one OpenAIP airspace: ``attrs`` holds its ``name`` and ``lowerLimit``/``upperLimit``
    (``rel`` is their path from ``where``: ``properties.`` in GeoJSON, empty in an API item); ``geometry`` is a
    GeoJSON Polygon or MultiPolygon."""
    label = labelled(where, name_of(file, f"{where}.{rel.rstrip('.')}" if rel else where, attrs))
    floor = openaip_limit(file, f"{label} {rel}lowerLimit", attrs.get("lowerLimit"))
    ceiling = openaip_limit(file, f"{label} {rel}upperLimit", attrs.get("upperLimit"))
    check_band(file, label, floor, ceiling, ("lowerLimit", "upperLimit"), " m")
    parts = polygon_parts(file, f"{label} geometry", label, geometry)
    if parts is None:
        raise ScenarioError(file, f"{label} geometry", f"{what_geometry(geometry)} is not an airspace (a Polygon or "
                            "MultiPolygon)")
    return [Zone(name, False, polygon=vertices, floor=floor, ceiling=ceiling) for name, vertices in parts]


def openaip_limit(file: str, where: str, limit: Any) -> Altitude:
    """An OpenAIP vertical limit ``{value, unit, referenceDatum}`` in metres. A flight level (unit 6) must be on the
    standard pressure datum (STD) and becomes its pressure altitude, nnn × 100 ft, taken as AMSL on the standard
    atmosphere; a value in metres or feet on STD is a pressure altitude too."""
    if limit is None:
        raise ScenarioError(file, where, "missing (an OpenAIP airspace gives lowerLimit and upperLimit as "
                            "{value, unit, referenceDatum})")
    if not isinstance(limit, dict):
        raise ScenarioError(file, where, f"expected an object {{value, unit, referenceDatum}}, got {kind(limit)}")
    value = number(file, f"{where}.value", limit.get("value"))
    unit, datum = limit.get("unit"), limit.get("referenceDatum")
    if not _code(unit, OPENAIP_UNITS):
        raise ScenarioError(file, where, f"unit {unit!r} is not metres (0), feet (1) or a flight level (6)")
    if not _code(datum, OPENAIP_DATUMS):
        raise ScenarioError(file, where, f"referenceDatum {datum!r} is not GND (0), MSL (1) or STD (2)")
    if unit == OPENAIP_FLIGHT_LEVEL and datum != OPENAIP_STD:
        raise ScenarioError(file, where, f"a flight level is on the standard pressure datum (STD, 2), not "
                            f"{OPENAIP_DATUMS[datum][0]} ({datum})")
    _, multiplier, metres = OPENAIP_UNITS[unit]
    return Altitude(value * multiplier * metres, OPENAIP_DATUMS[datum][1])


def _code(value: Any, codes: dict[int, Any]) -> TypeGuard[int]:
    """Whether ``value`` is one of OpenAIP's integer ``codes`` (not a boolean, a string or a list that looks like
    one)."""
    return isinstance(value, int) and not isinstance(value, bool) and value in codes


# --- ED-269 ----------------------------------------------------------------------------------------------------

def ed269_zones(file: str, where: str, zone: Any) -> list[Zone]:
    """The no-fly zones of one ED-269 UAS zone, one per volume of its ``geometry`` (named ``… geometry[j]`` when
    there are several); none, with a warning, when its restriction is NO_RESTRICTION."""
    if not isinstance(zone, dict):
        raise ScenarioError(file, where, f"expected an ED-269 UAS zone (an object), got {kind(zone)}")
    label = labelled(where, name_of(file, where, zone) or name_of(file, where, zone, "identifier"))
    restriction = zone.get("restriction")
    if restriction == ED269_INFORMATIONAL:
        log.warning("%s: %s: restriction %s is informational: not a no-fly zone, skipped", file, label,
                    ED269_INFORMATIONAL)
        return []
    if restriction not in ED269_NO_FLY:
        raise ScenarioError(file, f"{label} restriction", _not_one_of(
            restriction, f"PROHIBITED, REQ_AUTHORISATION, CONDITIONAL or {ED269_INFORMATIONAL}"))
    volumes = zone.get("geometry")
    if not isinstance(volumes, list) or not volumes:
        raise ScenarioError(file, f"{label} geometry", "expected a non-empty array of airspace volumes, got "
                            f"{kind(volumes) if volumes != [] else 'an empty array'}")
    return [_ed269_volume(file, f"{label} geometry[{j}]", label if len(volumes) == 1 else f"{label} geometry[{j}]",
                          volume) for j, volume in enumerate(volumes)]


def _ed269_volume(file: str, at: str, name: str, volume: Any) -> Zone:
    """One ED-269 airspace volume: its projection (Polygon, or Circle with ``center`` [lon, lat] and ``radius``)
    between its limits, all in ``uomDimensions``."""
    if not isinstance(volume, dict):
        raise ScenarioError(file, at, f"expected an airspace volume (an object), got {kind(volume)}")
    uom = volume.get("uomDimensions")
    if not isinstance(uom, str) or uom not in ED269_UNITS:
        raise ScenarioError(file, f"{at}.uomDimensions", _not_one_of(uom, "M or FT"))
    scale = ED269_UNITS[uom]
    floor = _ed269_limit(file, at, volume, "lower", scale)
    ceiling = _ed269_limit(file, at, volume, "upper", scale)
    check_band(file, at, floor, ceiling, ("lowerLimit", "upperLimit"), " m")
    here = f"{at}.horizontalProjection"
    projection = volume.get("horizontalProjection")
    ptype = projection.get("type") if isinstance(projection, dict) else None
    if ptype == "Circle" and isinstance(projection, dict):
        centre = position(file, f"{here}.center", projection.get("center"))
        radius = number(file, f"{here}.radius", projection.get("radius")) * scale
        if radius <= 0.0:
            raise ScenarioError(file, f"{here}.radius", f"{radius:g} m (a radius must be > 0)")
        return Zone(name, False, centre=centre, radius_m=radius, floor=floor, ceiling=ceiling)
    if ptype == "Polygon" and isinstance(projection, dict):
        vertices = outer_ring(file, f"{here}.coordinates", projection.get("coordinates"))
        return Zone(name, False, polygon=vertices, floor=floor, ceiling=ceiling)
    raise ScenarioError(file, here, f"{what_geometry(projection)} is not a Polygon or Circle")


def _ed269_limit(file: str, at: str, volume: dict[str, Any], which: str, scale: float) -> Altitude | None:
    """``lowerLimit`` or ``upperLimit`` (absent or null: from the ground / unlimited) in metres, measured from its
    ``…VerticalReference``: AGL → ground, AMSL → amsl; WGS84 (above the ellipsoid) is refused."""
    value = volume.get(f"{which}Limit")
    if value is None:
        return None
    value = number(file, f"{at}.{which}Limit", _numeral(value)) * scale
    key = f"{which}VerticalReference"
    ref = volume.get(key)
    if ref == "WGS84":
        raise ScenarioError(file, f"{at}.{key}", "WGS84 heights (above the ellipsoid) are not read: they differ "
                            "from heights above sea level by the geoid, up to about 100 m, and fuseplan has no geoid "
                            "model; ask for the zone in AMSL or AGL")
    if not isinstance(ref, str) or ref not in ED269_REFS:
        raise ScenarioError(file, f"{at}.{key}", _not_one_of(ref, "AGL or AMSL"))
    return Altitude(value, ED269_REFS[ref])


def _numeral(value: Any) -> Any:
    """A limit written as a decimal string (some ED-269 producers do: InterUSS's sample has ``"lowerLimit": "0"``)
    as its number; anything else as it is, for :func:`number` to judge."""
    if isinstance(value, str):
        try:
            return float(value.strip())
        except ValueError:
            return value
    return value


def _not_one_of(value: Any, allowed: str) -> str:
    """The reason a code is refused: ``'KM' is not M or FT``, or ``missing (expected M or FT)``."""
    return f"missing (expected {allowed})" if value is None else f"{value!r} is not {allowed}"
