"""Terrain sources: synthetic hills, ESRI ASCII grids and SRTM .hgt tiles against analytic surfaces."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pymap3d
import pytest

from planner.world.dem import (
    hgt_tile_origin,
    parse_esri_ascii,
    read_esri_ascii,
    read_hgt,
    synthetic_hills,
)
from planner.world.home import Home

HILLS = dict(count=12, max_height=180.0, sigma_range=(120.0, 300.0), spacing=25.0)


# --- synthetic hills --------------------------------------------------------------------------------------------

def test_hills_same_seed_identical() -> None:
    a = synthetic_hills(2000.0, 1500.0, np.random.default_rng(3), **HILLS)
    b = synthetic_hills(2000.0, 1500.0, np.random.default_rng(3), **HILLS)
    np.testing.assert_array_equal(a.heights, b.heights)


def test_hills_other_seed_differs() -> None:
    a = synthetic_hills(2000.0, 1500.0, np.random.default_rng(3), **HILLS)
    b = synthetic_hills(2000.0, 1500.0, np.random.default_rng(4), **HILLS)
    assert not np.array_equal(a.heights, b.heights)


def test_hills_grid_covers_bounds_and_peaks_at_max_height() -> None:
    t = synthetic_hills(2010.0, 1500.0, np.random.default_rng(3), **HILLS)
    ny, nx = t.heights.shape
    assert (t.x0, t.y0, t.dx, t.dy) == (0.0, 0.0, 25.0, 25.0)
    assert (nx - 1) * t.dx >= 2010.0 and (ny - 1) * t.dy >= 1500.0
    assert (nx, ny) == (82, 61)
    assert t.max_height == pytest.approx(180.0)
    assert t.heights.min() >= 0.0


def test_one_hill_is_a_gaussian() -> None:
    rng = np.random.default_rng(0)
    t = synthetic_hills(1000.0, 1000.0, rng, count=1, max_height=100.0, sigma_range=(200.0, 200.0), spacing=10.0)
    replay = np.random.default_rng(0)
    cx, cy = replay.uniform(0, 1000.0, 1)[0], replay.uniform(0, 1000.0, 1)[0]
    ys, xs = np.mgrid[0:101, 0:101] * 10.0
    expected = np.exp(-((xs - cx) ** 2 + (ys - cy) ** 2) / (2 * 200.0**2))
    np.testing.assert_allclose(t.heights, 100.0 * expected / expected.max(), rtol=1e-12)


# --- ESRI ASCII ---------------------------------------------------------------------------------------------------

def _plane(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return 600.0 + 0.1 * x + 0.05 * y  # m AMSL


def _write_esri(path: Path, nodata: bool = False, centre: bool = False) -> None:
    ncols, nrows, cell, xll, yll = 6, 4, 200.0, -100.0, -100.0
    xs = xll + cell / 2 + cell * np.arange(ncols)
    ys = yll + cell / 2 + cell * np.arange(nrows)
    grid = _plane(xs[None, :], ys[:, None])[::-1]  # file order: north row first
    if nodata:
        grid[1, 2] = -9999.0
    corner = f"xllcenter {xs[0]}\nyllcenter {ys[0]}\n" if centre else f"xllcorner {xll}\nyllcorner {yll}\n"
    header = f"ncols {ncols}\nnrows {nrows}\n{corner}cellsize {cell}\nNODATA_value -9999\n"
    body = "\n".join(" ".join(f"{v:.3f}" for v in row) for row in grid)
    path.write_text(header + body + "\n")


@pytest.mark.parametrize("centre", [False, True], ids=["xllcorner", "xllcenter"])
def test_esri_round_trip(tmp_path: Path, centre: bool) -> None:
    home = Home(-35.36, 149.16, 580.0)
    _write_esri(tmp_path / "plane.asc", centre=centre)
    t = read_esri_ascii(tmp_path / "plane.asc", home)
    assert (t.x0, t.y0, t.dx) == (0.0, 0.0, 200.0)
    x = np.array([0.0, 123.0, 640.5, 1000.0])
    y = np.array([0.0, 550.0, 321.0, 600.0])
    np.testing.assert_allclose(t.height_at(x, y), _plane(x, y) - home.alt, atol=1e-9)


def test_esri_text_parses_as_the_file_reads(tmp_path: Path) -> None:
    """parse_esri_ascii is the reader without the file: same heights, same grid (the hard-map generator checks its
    routes on what the loader will make of the DEM it writes)."""
    home = Home(-35.36, 149.16, 580.0)
    _write_esri(tmp_path / "plane.asc")
    a = read_esri_ascii(tmp_path / "plane.asc", home)
    b = parse_esri_ascii((tmp_path / "plane.asc").read_text(), home)
    assert (a.x0, a.y0, a.dx, a.dy) == (b.x0, b.y0, b.dx, b.dy)
    np.testing.assert_array_equal(a.heights, b.heights)
    with pytest.raises(ValueError, match="text.asc: expected 2×3"):
        parse_esri_ascii("ncols 3\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 10\n1 2 3\n4 5\n", home, "text.asc")


def test_esri_nodata_is_an_error(tmp_path: Path) -> None:
    _write_esri(tmp_path / "holes.asc", nodata=True)
    with pytest.raises(ValueError, match="NODATA"):
        read_esri_ascii(tmp_path / "holes.asc", Home(0.0, 0.0, 0.0))


def test_esri_wrong_count_is_an_error(tmp_path: Path) -> None:
    (tmp_path / "short.asc").write_text("ncols 3\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 10\n1 2 3\n4 5\n")
    with pytest.raises(ValueError, match="expected 2×3"):
        read_esri_ascii(tmp_path / "short.asc", Home(0.0, 0.0, 0.0))


def test_esri_missing_header_is_an_error(tmp_path: Path) -> None:
    (tmp_path / "bare.asc").write_text("ncols 2\nnrows 2\ncellsize 10\n1 2\n3 4\n")
    with pytest.raises(ValueError, match="xllcorner"):
        read_esri_ascii(tmp_path / "bare.asc", Home(0.0, 0.0, 0.0))


# --- SRTM .hgt ----------------------------------------------------------------------------------------------------

def _write_ramp(path: Path, n: int = 1201) -> None:
    """A tile whose heights (m AMSL) are 1000 + column − row: linear in lat/lon and exact in int16."""
    rows, cols = np.mgrid[0:n, 0:n]
    (1000 + cols - rows).astype(">i2").tofile(path)


@pytest.mark.parametrize(
    ("name", "lat0", "lon0", "home"),
    [("N47E008.hgt", 47, 8, Home(47.3, 8.5, 900.0)), ("S36E149.hgt", -36, 149, Home(-35.363261, 149.165230, 584.0))],
)
def test_hgt_round_trip(tmp_path: Path, name: str, lat0: int, lon0: int, home: Home) -> None:
    n = 1201
    path = tmp_path / name
    _write_ramp(path, n)
    t = read_hgt(path, home, 2000.0, 1500.0, 30.0)
    assert t.heights.shape == (51, 68)
    east = np.array([0.0, 1234.5, 2000.0, 777.0])
    north = np.array([0.0, 987.6, 1500.0, 1400.0])
    lat, lon, _ = pymap3d.enu2geodetic(east, north, np.zeros(4), home.lat, home.lon, home.alt)
    expected = 1000.0 + (np.asarray(lon) - lon0) * (n - 1) - (lat0 + 1 - np.asarray(lat)) * (n - 1) - home.alt
    np.testing.assert_allclose(t.height_at(east, north), expected, atol=0.01)


def test_hgt_void_is_an_error(tmp_path: Path) -> None:
    home = Home(47.3, 8.5, 900.0)
    row = int(round((48 - home.lat) * 1200))
    col = int(round((home.lon - 8) * 1200))
    path = tmp_path / "N47E008.hgt"
    tile = np.full((1201, 1201), 500, dtype=">i2")
    tile[row, col] = -32768
    tile.tofile(path)
    with pytest.raises(ValueError, match="void"):
        read_hgt(path, home, 500.0, 500.0, 30.0)


def test_hgt_void_outside_the_bounds_is_ignored(tmp_path: Path) -> None:
    path = tmp_path / "N47E008.hgt"
    tile = np.full((1201, 1201), 500, dtype=">i2")
    tile[0, 0] = -32768
    tile.tofile(path)
    t = read_hgt(path, Home(47.3, 8.5, 400.0), 500.0, 500.0, 30.0)
    np.testing.assert_allclose(t.heights, 100.0)


def test_hgt_bounds_outside_tile(tmp_path: Path) -> None:
    path = tmp_path / "N47E008.hgt"
    np.zeros((1201, 1201), dtype=">i2").tofile(path)
    with pytest.raises(ValueError, match="outside the tile"):
        read_hgt(path, Home(47.999, 8.5, 0.0), 1000.0, 1000.0, 30.0)


def test_hgt_wrong_size(tmp_path: Path) -> None:
    path = tmp_path / "N47E008.hgt"
    np.zeros((100, 100), dtype=">i2").tofile(path)
    with pytest.raises(ValueError, match="tile"):
        read_hgt(path, Home(47.3, 8.5, 0.0), 100.0, 100.0, 30.0)


@pytest.mark.parametrize(("name", "origin"), [("N47E008.hgt", (47, 8)), ("S36E149.hgt", (-36, 149)),
                                              ("n00w001.hgt", (0, -1)), ("S01W180.HGT", (-1, -180))])
def test_hgt_tile_origin(name: str, origin: tuple[int, int]) -> None:
    assert hgt_tile_origin(name) == origin


def test_hgt_bad_name() -> None:
    with pytest.raises(ValueError, match="N47E008"):
        hgt_tile_origin("terrain.hgt")
