"""``--zones FILE``: which format a zones file is in, decided by its structure, and its zones (docs/imports.md,
"Zones files").

- a GeoJSON ``FeatureCollection`` (or one ``Feature``): each feature in our property names
  (planner/world/imports/geojson.py), or OpenAIP's when its properties carry ``lowerLimit``/``upperLimit``;
- an object whose ``features`` (or ``UASZoneList``) hold zones with a ``geometry`` *array*: EUROCAE ED-269 UAS zones;
- an object with ``items`` (an OpenAIP API page), or an array of airspaces (an OpenAIP export): OpenAIP airspace;
  an array of zones with a ``geometry`` array is ED-269.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from planner.errors import ScenarioError
from planner.world.geo_inputs import Zone
from planner.world.imports.airspace import ed269_zones, openaip_zones
from planner.world.imports.common import kind, load_json, read_text
from planner.world.imports.geojson import feature_zones, properties

OPENAIP_LIMITS = ("lowerLimit", "upperLimit")  # the properties that make a GeoJSON feature OpenAIP's
OURS = ("floor_m", "floor_ref", "ceiling_m", "ceiling_ref", "radius_m", "inclusion")
ED269_LISTS = ("features", "UASZoneList")  # where ED-269 files keep their zones (the latter: the standard's name)
FORMATS = ("a GeoJSON FeatureCollection or Feature, ED-269 UAS zones (features whose geometry is an array of "
           "volumes) or OpenAIP airspace (items, or an array of airspaces)")


def read_zones(path: str | Path) -> tuple[Zone, ...]:
    """The zones in a zones file (our GeoJSON, OpenAIP airspace or ED-269 UAS zones); anything that cannot be used
    is refused in one line naming the file, the zone and the reason."""
    _, file, text = read_text(path, "zones")
    return tuple(zones_of(file, load_json(file, text)))


def zones_of(file: str, doc: Any) -> list[Zone]:
    """The zones of a parsed zones document, its format told by its structure (the module's docstring)."""
    if isinstance(doc, list):
        read = ed269_zones if _ed269(doc) else _openaip_item
        return [z for i, item in enumerate(doc) for z in read(file, f"[{i}]", item)]
    if not isinstance(doc, dict):
        raise ScenarioError(file, "", f"{kind(doc)} is not {FORMATS}")
    if doc.get("type") == "Feature":
        return _geojson_feature(file, "feature", doc)
    for key in ED269_LISTS:
        zones = doc.get(key)
        # UASZoneList is ED-269's alone; features are ED-269's when a zone has a geometry array, or when the list is
        # empty in an object that is not GeoJSON (a zone file with no zones left in it)
        if isinstance(zones, list) and (key == "UASZoneList" or _ed269(zones) or (not zones and "type" not in doc)):
            return [z for i, zone in enumerate(zones) for z in ed269_zones(file, f"{key}[{i}]", zone)]
    if doc.get("type") == "FeatureCollection":
        features = doc.get("features")
        if not isinstance(features, list):
            raise ScenarioError(file, "features", f"expected an array of features, got {kind(features)}")
        return [z for i, f in enumerate(features) for z in _geojson_feature(file, f"features[{i}]", f)]
    if "items" in doc:
        items = doc["items"]
        if not isinstance(items, list):
            raise ScenarioError(file, "items", f"expected an array of OpenAIP airspaces, got {kind(items)}")
        return [z for i, item in enumerate(items) for z in _openaip_item(file, f"items[{i}]", item)]
    if "type" in doc:
        raise ScenarioError(file, "type", f"{doc['type']!r} is not {FORMATS}")
    raise ScenarioError(file, "", f"an object without a GeoJSON type, ED-269 zones or OpenAIP items is not {FORMATS}")


def _ed269(zones: list[Any]) -> bool:
    """Whether a list holds ED-269 zones: one of them has a ``geometry`` array (GeoJSON's is an object)."""
    return any(isinstance(z, dict) and isinstance(z.get("geometry"), list) for z in zones)


def _geojson_feature(file: str, where: str, feature: Any) -> list[Zone]:
    """A GeoJSON feature in our property names, or OpenAIP's when it has ``lowerLimit``/``upperLimit``."""
    props = properties(file, where, feature)
    if not any(k in props for k in OPENAIP_LIMITS):
        return feature_zones(file, where, feature)
    mixed = [k for k in OURS if k in props]
    if mixed:
        raise ScenarioError(file, f"{where}.properties", f"both OpenAIP's lowerLimit/upperLimit and our {mixed[0]}: "
                            "give one or the other")
    return openaip_zones(file, where, props, "properties.", feature.get("geometry"))


def _openaip_item(file: str, where: str, item: Any) -> list[Zone]:
    """One airspace of an OpenAIP API page or export: its attributes and ``geometry`` side by side."""
    if not isinstance(item, dict):
        raise ScenarioError(file, where, f"expected an OpenAIP airspace (an object), got {kind(item)}")
    return openaip_zones(file, where, item, "", item.get("geometry"))
