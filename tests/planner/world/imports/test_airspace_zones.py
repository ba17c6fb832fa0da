"""planner.world.imports.read_zones on airspace as operators get it: OpenAIP airspace (an API page, an export array,
a GeoJSON export) and EUROCAE ED-269 UAS zones, each told by its structure; heights converted exactly (feet × 0.3048,
a flight level as nnn × 100 ft on the standard atmosphere), and every refusal one line naming the file, the zone
and the reason."""

from __future__ import annotations

import copy
import json
import logging
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from planner.errors import ScenarioError
from planner.world.geo_inputs import Altitude
from planner.world.imports import read_zones

DATA = Path(__file__).parents[3] / "data" / "imports"
OPENAIP = DATA / "cmac_openaip.json"
ED269 = DATA / "cmac_ed269.json"
FT = 0.3048  # written out here, not imported: the test checks the reader's constant


def _doc(path: Path) -> Any:
    return json.loads(path.read_text())


def _write(tmp_path: Path, doc: Any, name: str = "zones.json") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(doc, indent=1))
    return path


# --- OpenAIP -----------------------------------------------------------------------------------------------------

OPENAIP_BANDS = [  # (name, floor, ceiling) of cmac_openaip.json's three airspaces
    ("'CMAC CTR'", Altitude(0.0, "ground"), Altitude(4500 * FT, "amsl")),  # 0 ft GND - 4500 ft MSL
    ("'R405 MAJURA'", Altitude(500 * FT, "ground"), Altitude(6500 * FT, "amsl")),  # 500 ft GND - FL65
    ("'D510 RANGE'", Altitude(700.0, "amsl"), Altitude(12500 * FT, "amsl")),  # 700 m MSL - FL125
]


def test_an_openaip_api_page_gives_each_airspace_with_its_limits_in_metres():
    zones = read_zones(OPENAIP)
    assert [(z.name, z.floor, z.ceiling) for z in zones] == [(f"items[{i}] {n}", f, c)
                                                             for i, (n, f, c) in enumerate(OPENAIP_BANDS)]
    assert zones[1].ceiling.value == 1981.2 and zones[0].ceiling.value == pytest.approx(1371.6, abs=1e-9)
    assert zones[0].polygon == ((-35.35, 149.15), (-35.35, 149.18), (-35.375, 149.18), (-35.375, 149.15))
    assert len(zones[2].polygon) == 3 and all(not z.inclusion and z.centre is None for z in zones)


@pytest.mark.parametrize("shape", ["array", "geojson"])
def test_openaip_export_shapes_read_as_the_api_page(tmp_path: Path, shape: str):
    items = _doc(OPENAIP)["items"]
    if shape == "array":
        doc, prefix = items, ""
    else:
        doc = {"type": "FeatureCollection", "features": [
            {"type": "Feature", "geometry": it["geometry"],
             "properties": {k: v for k, v in it.items() if k != "geometry"}} for it in items]}
        prefix = "features"
    zones = read_zones(_write(tmp_path, doc))
    page = read_zones(OPENAIP)
    assert [z.name for z in zones] == [f"{prefix}[{i}] {n}" for i, (n, _, _) in enumerate(OPENAIP_BANDS)]
    assert [(z.polygon, z.floor, z.ceiling) for z in zones] == [(z.polygon, z.floor, z.ceiling) for z in page]


def _openaip_item(k: int, **changes: Any) -> Callable[[Any], None]:
    def edit(doc: Any) -> None:
        item = doc["items"][k]
        for key, value in changes.items():
            if value is None:
                item.pop(key, None)
            elif isinstance(value, dict) and isinstance(item.get(key), dict):
                item[key] = {**item[key], **value}
            else:
                item[key] = value
    return edit


OPENAIP_ERRORS = [
    (_openaip_item(1, lowerLimit={"referenceDatum": 3}), "items[1] 'R405 MAJURA' lowerLimit",
     "referenceDatum 3 is not GND (0), MSL (1) or STD (2)"),
    (_openaip_item(1, upperLimit={"referenceDatum": 0}), "items[1] 'R405 MAJURA' upperLimit",
     "a flight level is on the standard pressure datum (STD, 2), not GND (0)"),
    (_openaip_item(1, upperLimit=None), "items[1] 'R405 MAJURA' upperLimit", "missing (an OpenAIP airspace gives"),
    (_openaip_item(0, lowerLimit={"value": "0"}), "items[0] 'CMAC CTR' lowerLimit.value",
     "expected a number, got a string"),
    (_openaip_item(0, lowerLimit={"unit": True}), "items[0] 'CMAC CTR' lowerLimit", "unit True is not metres"),
    (_openaip_item(0, lowerLimit={"unit": [1]}), "items[0] 'CMAC CTR' lowerLimit", "unit [1] is not metres"),
    (_openaip_item(0, lowerLimit={"referenceDatum": "GND"}), "items[0] 'CMAC CTR' lowerLimit",
     "referenceDatum 'GND' is not GND (0)"),
    (_openaip_item(0, upperLimit={"referenceDatum": {}}), "items[0] 'CMAC CTR' upperLimit",
     "referenceDatum {} is not GND (0)"),
    (_openaip_item(2, lowerLimit={"value": 4000}), "items[2] 'D510 RANGE'",
     "lowerLimit 4000 m is not below upperLimit 3810 m (both above amsl)"),
    (_openaip_item(0, geometry={"type": "Point", "coordinates": [149.16, -35.36]}), "items[0] 'CMAC CTR' geometry",
     "'Point' is not an airspace (a Polygon or MultiPolygon)"),
    (_openaip_item(2, geometry={"type": "Polygon", "coordinates": [[[149.158, -35.366], [149.162, -35.366]]]}),
     "items[2] 'D510 RANGE' geometry.coordinates[0]", "2 vertices (a polygon needs at least 3)"),
    (_openaip_item(0, name=7), "items[0].name", "expected a string, got a number"),
]


@pytest.mark.parametrize(("edit", "where", "reason"), OPENAIP_ERRORS, ids=[e[2][:32] for e in OPENAIP_ERRORS])
def test_openaip_refusals_name_file_airspace_and_reason(tmp_path: Path, edit: Callable[[Any], None], where: str,
                                                        reason: str):
    doc = _doc(OPENAIP)
    edit(doc)
    path = _write(tmp_path, doc)
    with pytest.raises(ScenarioError) as err:
        read_zones(path)
    assert (err.value.file, err.value.field) == (str(path), where)
    assert reason in err.value.reason, err.value.reason
    assert str(err.value).startswith(f"{path}: {where}: ") and "\n" not in str(err.value)


def test_the_bad_unit_sample_is_refused_in_one_line():
    bad = DATA / "cmac_openaip_bad_unit.json"
    with pytest.raises(ScenarioError) as err:
        read_zones(bad)
    assert str(err.value) == (f"{bad}: items[1] 'R405 MAJURA' lowerLimit: unit 7 is not metres (0), feet (1) or a "
                              "flight level (6)")


def test_a_feature_mixing_openaip_limits_and_our_names_is_refused(tmp_path: Path):
    feature = {"type": "Feature", "geometry": _doc(OPENAIP)["items"][0]["geometry"],
               "properties": {"name": "x", "lowerLimit": {"value": 0, "unit": 1, "referenceDatum": 0},
                              "ceiling_m": 100}}
    with pytest.raises(ScenarioError, match=r"features\[0\]\.properties: both OpenAIP's lowerLimit/upperLimit and "
                                            "our ceiling_m"):
        read_zones(_write(tmp_path, {"type": "FeatureCollection", "features": [feature]}))


# --- ED-269 ------------------------------------------------------------------------------------------------------

def test_ed269_zones_volumes_circles_units_and_references(caplog: pytest.LogCaptureFixture):
    with caplog.at_level(logging.WARNING, logger="planner.world.imports.airspace"):
        zones = read_zones(ED269)
    assert [z.name for z in zones] == ["features[0] 'Field prohibited'", "features[1] 'Hospital'",
                                       "features[2] 'Reservoir' geometry[0]", "features[2] 'Reservoir' geometry[1]"]
    field, hospital, low, high = zones
    assert field.polygon == ((-35.362, 149.164), (-35.362, 149.168), (-35.365, 149.168), (-35.365, 149.164))
    assert (field.floor, field.ceiling) == (Altitude(0.0, "ground"), Altitude(120.0, "ground"))
    # a circle: center [lon, lat], radius and limits in uomDimensions (feet); no lowerLimit: from the ground
    assert (hospital.centre, hospital.radius_m, hospital.polygon) == ((-35.3605, 149.166), 500 * FT, None)
    assert hospital.floor is None and hospital.ceiling == Altitude(400 * FT, "ground")
    assert (low.floor, low.ceiling) == (Altitude(0.0, "ground"), Altitude(50.0, "ground"))
    assert (high.floor, high.ceiling) == (Altitude(2000 * FT, "amsl"), Altitude(3000 * FT, "amsl"))
    assert not any(z.inclusion for z in zones)
    # the NO_RESTRICTION zone is informational: skipped, and said so on one line naming it
    skipped = [r.getMessage() for r in caplog.records]
    assert skipped == [f"{ED269}: features[3] 'Park information': restriction NO_RESTRICTION is informational: not a "
                       "no-fly zone, skipped"]


@pytest.mark.parametrize("shape", ["UASZoneList", "array", "FeatureCollection"])
def test_ed269_containers_read_alike(tmp_path: Path, shape: str):
    features = _doc(ED269)["features"]
    doc = {"UASZoneList": features} if shape == "UASZoneList" else features if shape == "array" else \
        {"type": "FeatureCollection", "features": features}
    prefix = {"UASZoneList": "UASZoneList", "array": "", "FeatureCollection": "features"}[shape]
    zones = read_zones(_write(tmp_path, doc))
    reference = read_zones(ED269)
    assert [z.name for z in zones] == [z.name.replace("features", prefix, 1) for z in reference]
    assert [(z.polygon, z.centre, z.radius_m, z.floor, z.ceiling) for z in zones] == \
        [(z.polygon, z.centre, z.radius_m, z.floor, z.ceiling) for z in reference]


@pytest.mark.parametrize("doc", [{"features": []}, {"UASZoneList": []}, {"type": "FeatureCollection", "features": []},
                                 {"items": []}, []])
def test_a_zones_file_with_no_zones_gives_none(tmp_path: Path, doc: Any):
    assert read_zones(_write(tmp_path, doc)) == ()


def test_ed318_spelling_of_req_authorisation_is_no_fly_too(tmp_path: Path):
    doc = _doc(ED269)
    doc["features"][1]["restriction"] = "REQ_AUTHORIZATION"
    assert [z.name for z in read_zones(_write(tmp_path, doc))][1] == "features[1] 'Hospital'"


def test_ed269_limits_written_as_decimal_strings_read_as_numbers(tmp_path: Path):
    """InterUSS's ED-269 sample writes ``"lowerLimit": "0"``: a decimal string is its number."""
    doc = _doc(ED269)
    want = read_zones(_write(tmp_path, doc))[0]
    volume = doc["features"][0]["geometry"][0]
    volume["lowerLimit"], volume["upperLimit"] = str(volume["lowerLimit"]), f" {volume['upperLimit']} "
    got = read_zones(_write(tmp_path, doc))[0]
    assert (got.floor, got.ceiling) == (want.floor, want.ceiling)


def _ed269_volume(k: int, j: int = 0, **changes: Any) -> Callable[[Any], None]:
    def edit(doc: Any) -> None:
        volume = doc["features"][k]["geometry"][j]
        for key, value in changes.items():
            if isinstance(value, dict) and isinstance(volume.get(key), dict):
                volume[key] = {**volume[key], **value}
            else:
                volume[key] = value
    return edit


def _ed269_zone(k: int, **changes: Any) -> Callable[[Any], None]:
    def edit(doc: Any) -> None:
        doc["features"][k].update(changes)
    return edit


def _both(*edits: Callable[[Any], None]) -> Callable[[Any], None]:
    def edit(doc: Any) -> None:
        for e in edits:
            e(doc)
    return edit


ED269_ERRORS = [
    (_ed269_volume(0, uomDimensions="KM"), "features[0] 'Field prohibited' geometry[0].uomDimensions",
     "'KM' is not M or FT"),
    (_ed269_volume(0, upperVerticalReference="WGS84"),
     "features[0] 'Field prohibited' geometry[0].upperVerticalReference",
     "WGS84 heights (above the ellipsoid) are not read"),
    (_ed269_volume(0, uomDimensions=None), "features[0] 'Field prohibited' geometry[0].uomDimensions",
     "missing (expected M or FT)"),
    (_ed269_volume(0, lowerVerticalReference="MSL"),
     "features[0] 'Field prohibited' geometry[0].lowerVerticalReference", "'MSL' is not AGL or AMSL"),
    (_ed269_volume(0, lowerLimit="ground"), "features[0] 'Field prohibited' geometry[0].lowerLimit",
     "expected a number, got a string"),
    (_ed269_volume(0, lowerLimit=150), "features[0] 'Field prohibited' geometry[0]",
     "lowerLimit 150 m is not below upperLimit 120 m (both above ground)"),
    (_ed269_volume(1, horizontalProjection={"radius": 0}), "features[1] 'Hospital' geometry[0].horizontalProjection"
     ".radius", "0 m (a radius must be > 0)"),
    (_ed269_volume(1, horizontalProjection={"center": [149.166, -95.0]}),
     "features[1] 'Hospital' geometry[0].horizontalProjection.center", "latitude -95 is outside"),
    (_ed269_volume(1, horizontalProjection={"type": "Point"}),
     "features[1] 'Hospital' geometry[0].horizontalProjection", "'Point' is not a Polygon or Circle"),
    (_ed269_volume(2, 1, horizontalProjection={"coordinates": [[[149.170, -35.358], [149.173, -35.360],
                                                                [149.173, -35.358], [149.170, -35.360]]]}),
     "features[2] 'Reservoir' geometry[1].horizontalProjection.coordinates[0]", "intersects itself"),
    (_ed269_zone(0, restriction="FORBIDDEN"), "features[0] 'Field prohibited' restriction",
     "'FORBIDDEN' is not PROHIBITED, REQ_AUTHORISATION, CONDITIONAL or NO_RESTRICTION"),
    (_ed269_zone(0, restriction=None), "features[0] 'Field prohibited' restriction",
     "missing (expected PROHIBITED, REQ_AUTHORISATION, CONDITIONAL or NO_RESTRICTION)"),
    (_ed269_zone(1, geometry=[]), "features[1] 'Hospital' geometry",
     "expected a non-empty array of airspace volumes, got an empty array"),
    (_both(_ed269_zone(1, name=None), _ed269_volume(1, horizontalProjection={"radius": 0})),  # the identifier
     "features[1] 'CMAC-H1' geometry[0].horizontalProjection.radius", "0 m"),
]


@pytest.mark.parametrize(("edit", "where", "reason"), ED269_ERRORS, ids=[e[1][-30:] + e[2][:12] for e in ED269_ERRORS])
def test_ed269_refusals_name_file_zone_volume_and_reason(tmp_path: Path, edit: Callable[[Any], None], where: str,
                                                         reason: str):
    doc = copy.deepcopy(_doc(ED269))
    edit(doc)
    path = _write(tmp_path, doc)
    with pytest.raises(ScenarioError) as err:
        read_zones(path)
    assert (err.value.file, err.value.field) == (str(path), where)
    assert reason in err.value.reason, err.value.reason
    assert str(err.value).startswith(f"{path}: {where}: ") and "\n" not in str(err.value)


# --- telling the formats apart -----------------------------------------------------------------------------------

@pytest.mark.parametrize(("doc", "where", "reason"), [
    (42, "", "a number is not a GeoJSON FeatureCollection or Feature, ED-269 UAS zones"),
    ({"zones": []}, "", "an object without a GeoJSON type, ED-269 zones or OpenAIP items is not"),
    ({"features": [{"type": "Feature", "geometry": None}]}, "", "an object without a GeoJSON type"),
    ({"type": "Topology", "features": []}, "type", "'Topology' is not a GeoJSON FeatureCollection"),
    ({"items": {}}, "items", "expected an array of OpenAIP airspaces, got an object"),
    ([{"name": "x", "geometry": [], "restriction": "PROHIBITED"}], "[0] 'x' geometry", "got an empty array"),
    ([3], "[0]", "expected an OpenAIP airspace (an object), got a number"),
])
def test_what_is_no_zones_file_is_refused(tmp_path: Path, doc: Any, where: str, reason: str):
    path = _write(tmp_path, doc)
    with pytest.raises(ScenarioError) as err:
        read_zones(path)
    assert err.value.field == where and reason in err.value.reason, str(err.value)


def test_the_examples_in_docs_imports_read_as_the_doc_says(tmp_path: Path):
    """docs/imports.md's OpenAIP and ED-269 examples, read from the doc itself, give the zones it states."""
    doc = (Path(__file__).parents[4] / "docs" / "imports.md").read_text()
    openaip, ed269 = (json.loads(b) for b in re.findall(r"```json\n(.*?)```", doc, re.S))
    (restricted,) = read_zones(_write(tmp_path, openaip, "openaip.json"))
    assert (restricted.name, restricted.floor, restricted.ceiling) == (
        "items[0] 'R405 MAJURA'", Altitude(152.4, "ground"), Altitude(1981.2, "amsl"))
    (hospital,) = read_zones(_write(tmp_path, ed269, "ed269.json"))
    assert (hospital.name, hospital.centre, hospital.radius_m, hospital.floor, hospital.ceiling) == (
        "features[0] 'Hospital'", (-35.3605, 149.166), 152.4, None, Altitude(121.92, "ground"))
