"""planner.world.imports.read_zones: GeoJSON airspace zones ([lon, lat] in the file, (lat, lon) in the values),
and every refusal naming the file, the feature and the reason in one line."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import pytest

from planner.errors import ScenarioError
from planner.world.geo_inputs import Altitude
from planner.world.imports import read_zones

DATA = Path(__file__).parents[3] / "data" / "imports"
ZONES = DATA / "airspace.geojson"


def test_reads_polygons_multipolygon_parts_and_points():
    zones = read_zones(ZONES)
    assert [z.name for z in zones] == ["features[0] 'Danger area D123'", "features[1] 'Restricted R77' part 0",
                                       "features[1] 'Restricted R77' part 1", "features[2] 'Mast'",
                                       "features[3] 'Operating area'"]
    d123 = zones[0]
    assert d123.polygon == ((-35.362, 149.164), (-35.362, 149.168), (-35.365, 149.168), (-35.365, 149.164))
    assert (d123.floor, d123.ceiling) == (Altitude(0.0, "ground"), Altitude(150.0, "ground"))
    assert not d123.inclusion and d123.centre is None
    assert len(zones[1].polygon) == 3 and len(zones[2].polygon) == 4
    assert zones[1].floor == zones[2].floor == Altitude(700.0, "amsl") and zones[1].ceiling is None
    mast = zones[3]
    assert (mast.centre, mast.radius_m, mast.polygon) == ((-35.3605, 149.166), 60.0, None)
    assert mast.floor is None and mast.ceiling == Altitude(90.0, "home")  # the default reference
    assert zones[4].inclusion and zones[4].floor is None and zones[4].ceiling is None


def test_a_single_feature_and_an_unclosed_ring(tmp_path: Path):
    feature = json.loads(ZONES.read_text())["features"][0]
    feature["geometry"]["coordinates"][0].pop()  # RFC 7946 closes rings; an open one means the same polygon
    path = tmp_path / "one.geojson"
    path.write_text(json.dumps(feature))
    (zone,) = read_zones(path)
    assert zone.polygon == read_zones(ZONES)[0].polygon and zone.name == "feature 'Danger area D123'"


KEEP = object()


def _variant(tmp_path: Path, k: int, geometry: Any = KEEP, **properties: Any) -> Path:
    doc = copy.deepcopy(json.loads(ZONES.read_text()))
    feature = doc["features"][k]
    if geometry is not KEEP:
        feature["geometry"] = geometry
    feature["properties"].update(properties)
    path = tmp_path / "zones.geojson"
    path.write_text(json.dumps(doc, indent=1))
    return path


LINE = {"type": "LineString", "coordinates": [[149.16, -35.36], [149.17, -35.37]]}
BOW_TIE = {"type": "Polygon", "coordinates": [[[149.164, -35.362], [149.168, -35.365], [149.168, -35.362],
                                                [149.164, -35.365], [149.164, -35.362]]]}
HOLE = {"type": "Polygon", "coordinates": [[[149.16, -35.36], [149.17, -35.36], [149.17, -35.37], [149.16, -35.36]],
                                           [[149.165, -35.362], [149.166, -35.362], [149.166, -35.363],
                                            [149.165, -35.362]]]}

ERRORS = [
    (dict(k=0, geometry=LINE), "features[0].geometry", "'LineString' is not a zone"),
    (dict(k=0, geometry=BOW_TIE), "features[0].geometry.coordinates[0]", "intersects itself"),
    (dict(k=0, geometry=HOLE), "features[0].geometry.coordinates", "1 hole(s): holes are not supported"),
    (dict(k=0, floor_m=200), "features[0].properties", "floor_m 200 is not below ceiling_m 150"),
    (dict(k=0, ceiling_ref="agl"), "features[0].properties.ceiling_ref", "unknown reference 'agl'"),
    (dict(k=0, ceiling_m="150"), "features[0].properties.ceiling_m", "expected a number, got a string"),
    (dict(k=2, radius_m=None), "features[2].properties.radius_m", "missing (a Point zone needs a radius"),
    (dict(k=2, radius_m=-5), "features[2].properties.radius_m", "-5 m (a radius must be > 0)"),
    (dict(k=2, geometry={"type": "Point", "coordinates": [149.16, 91.0]}), "features[2].geometry.coordinates",
     "latitude 91 is outside"),
    (dict(k=2, geometry={"type": "Point", "coordinates": [-180.5, -35.0]}), "features[2].geometry.coordinates",
     "longitude -180.5 is outside"),
    (dict(k=1, geometry={"type": "MultiPolygon", "coordinates": [[[[149.17, -35.358], [149.173, -35.358]]]]}),
     "features[1].geometry.coordinates[0][0]", "2 vertices (a polygon needs at least 3)"),
    (dict(k=3, ceiling_m=120), "features[3].properties", "an inclusion zone holds at every height"),
    (dict(k=3, geometry=None), "features[3].geometry", "no geometry is not a zone"),
]


@pytest.mark.parametrize(("variant", "where", "reason"), ERRORS, ids=[e[2][:30] for e in ERRORS])
def test_refusals_name_file_feature_and_reason(tmp_path: Path, variant: dict[str, Any], where: str, reason: str):
    path = _variant(tmp_path, **variant)
    with pytest.raises(ScenarioError) as err:
        read_zones(path)
    assert (err.value.file, err.value.field) == (str(path), where)
    assert reason in err.value.reason
    assert str(err.value).startswith(f"{path}: {where}: ") and "\n" not in str(err.value)


def test_not_a_feature_collection(tmp_path: Path):
    path = tmp_path / "x.geojson"
    path.write_text('{"type": "Topology"}')
    with pytest.raises(ScenarioError, match="'Topology' is not a GeoJSON FeatureCollection"):
        read_zones(path)


def test_malformed_json_gives_line_and_column(tmp_path: Path):
    path = tmp_path / "broken.geojson"
    path.write_text('{"type": "FeatureCollection",\n "features": [\n  {"type": "Feature" "geometry": null}]}\n')
    with pytest.raises(ScenarioError) as err:
        read_zones(path)
    assert err.value.field == "line 3 column 22" and "malformed JSON: Expecting ',' delimiter" in err.value.reason
