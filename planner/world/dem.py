"""Terrain sources (docs/method.md §2.5): seeded synthetic hills, ESRI ASCII grids and SRTM ``.hgt`` tiles →
:class:`Terrain`.

Every reader returns heights in metres above home on a regular ENU grid; every failure is a ``ValueError`` with a
message fit for the user (``planner.world.scenario`` adds the file and field).
"""

from __future__ import annotations

import logging
import math
import re
from pathlib import Path

import numpy as np
import pymap3d

from planner.files import FileRefused, read_regular_file
from planner.world.home import Home
from planner.world.terrain import Terrain

logger = logging.getLogger(__name__)

HGT_VOID = -32768
HGT_SIZES = (1201, 3601)  # samples per side: 3 arc-second (SRTM3) and 1 arc-second (SRTM1) tiles
_HGT_NAME = re.compile(r"([NS])(\d{2})([EW])(\d{3})", re.IGNORECASE)
_ESRI_KEYS = {"ncols", "nrows", "xllcorner", "yllcorner", "xllcenter", "yllcenter", "cellsize", "nodata_value"}
# an SRTM1 tile's 3601² heights written as ESRI ASCII take about 60 MB; the text is parsed in memory, ~10× its size
MAX_ESRI_BYTES = 64 * 2**20
MAX_HGT_BYTES = 2 * max(HGT_SIZES) ** 2  # a .hgt tile is exactly 2 n² bytes


def grid_nodes(size_x: float, size_y: float, spacing: float) -> int:
    """Nodes of the grid :func:`grid_axis` lays over [0, size_x] × [0, size_y] at ``spacing`` m, without making
    it (a scenario's loader refuses a grid too fine for memory before any array exists)."""
    return (max(math.ceil(size_x / spacing - 1e-9), 1) + 1) * (max(math.ceil(size_y / spacing - 1e-9), 1) + 1)


def _read(path: Path, max_bytes: int) -> bytes:
    try:
        return read_regular_file(path, max_bytes, "terrain")
    except FileRefused as exc:
        raise ValueError(f"cannot read {exc}") from None


def grid_axis(size: float, spacing: float) -> np.ndarray:
    """Node coordinates 0, spacing, … covering [0, size] (the last node is at or just past ``size``), metres."""
    if size <= 0 or spacing <= 0:
        raise ValueError(f"grid size ({size:g} m) and spacing ({spacing:g} m) must be positive")
    n = max(int(math.ceil(size / spacing - 1e-9)), 1) + 1
    return np.arange(n) * float(spacing)


def synthetic_hills(
    size_x: float, size_y: float, rng: np.random.Generator, count: int, max_height: float,
    sigma_range: tuple[float, float], spacing: float,
) -> Terrain:
    """Sum of ``count`` Gaussian hills over [0, size_x] × [0, size_y], scaled so the highest node is ``max_height``.

    Centres are uniform over the bounds, widths σ uniform in ``sigma_range`` (m), relative peaks uniform in
    [0.3, 1]; the grid has ``spacing`` metres between nodes. Same generator state → identical heights.
    """
    lo, hi = sigma_range
    if count < 0 or max_height <= 0 or not 0 < lo <= hi:
        raise ValueError("hills need count >= 0, max_height > 0 and 0 < sigma min <= sigma max")
    xs = grid_axis(size_x, spacing)
    ys = grid_axis(size_y, spacing)
    cx = rng.uniform(0.0, size_x, count)
    cy = rng.uniform(0.0, size_y, count)
    sigma = rng.uniform(lo, hi, count)
    peak = rng.uniform(0.3, 1.0, count)
    gx = np.exp(-0.5 * ((xs[None, :] - cx[:, None]) / sigma[:, None]) ** 2)  # (count, nx)
    gy = np.exp(-0.5 * ((ys[None, :] - cy[:, None]) / sigma[:, None]) ** 2)  # (count, ny)
    heights = np.einsum("k,kj,ki->ji", peak, gy, gx)  # separable Gaussians → (ny, nx)
    top = heights.max(initial=0.0)
    if top > 0:
        heights *= max_height / top
    return Terrain(0.0, 0.0, float(spacing), float(spacing), heights)


def read_esri_ascii(path: str | Path, home: Home) -> Terrain:
    """ESRI ASCII grid with coordinates in the local ENU frame (m) and heights in m AMSL → heights above home."""
    path = Path(path)
    try:
        text = _read(path, MAX_ESRI_BYTES).decode("ascii")
    except UnicodeError as exc:
        raise ValueError(f"cannot read ESRI ASCII grid {path}: {exc}") from exc
    return parse_esri_ascii(text, home, path)


def parse_esri_ascii(text: str, home: Home, path: str | Path = "grid.asc") -> Terrain:
    """The text of an ESRI ASCII grid (see :func:`read_esri_ascii`; ``path`` names it in errors) → heights above
    home: what the loader makes of a file with this text, number for number."""
    path = Path(path)
    lines = text.splitlines()
    header: dict[str, float] = {}
    n_header = 0
    for line in lines[: len(_ESRI_KEYS)]:
        parts = line.split()
        if len(parts) != 2 or parts[0].lower() not in _ESRI_KEYS:
            break
        try:
            header[parts[0].lower()] = float(parts[1])
        except ValueError as exc:
            raise ValueError(f"{path.name}: header {parts[0]} has non-numeric value {parts[1]!r}") from exc
        n_header += 1
    missing = [k for k in ("ncols", "nrows", "cellsize") if k not in header]
    if "xllcorner" not in header and "xllcenter" not in header:
        missing.append("xllcorner")
    if "yllcorner" not in header and "yllcenter" not in header:
        missing.append("yllcorner")
    if missing:
        raise ValueError(f"{path.name}: ESRI ASCII header lacks {', '.join(missing)}")
    ncols, nrows, cell = int(header["ncols"]), int(header["nrows"]), header["cellsize"]
    if ncols != header["ncols"] or nrows != header["nrows"] or ncols < 2 or nrows < 2 or not cell > 0:
        raise ValueError(f"{path.name}: need whole ncols, nrows >= 2 and cellsize > 0")
    try:
        values = np.array(" ".join(lines[n_header:]).split(), dtype=float)
    except ValueError as exc:
        raise ValueError(f"{path.name}: non-numeric height value ({exc})") from exc
    if values.size != ncols * nrows:
        raise ValueError(f"{path.name}: expected {nrows}×{ncols} = {ncols * nrows} heights, found {values.size}")
    grid = values.reshape(nrows, ncols)[::-1]  # file rows run north → south; Terrain rows run south → north
    if "nodata_value" in header:
        holes = int(np.count_nonzero(grid == header["nodata_value"]))
        if holes:
            raise ValueError(f"{path.name}: {holes} NODATA cells; fill the grid before using it")
    if not np.all(np.isfinite(grid)):
        raise ValueError(f"{path.name}: non-finite heights")
    half = 0.5 * cell
    x0 = header["xllcenter"] if "xllcenter" in header else header["xllcorner"] + half
    y0 = header["yllcenter"] if "yllcenter" in header else header["yllcorner"] + half
    logger.debug("ESRI grid %s: %d×%d nodes, %.1f m cells", path.name, nrows, ncols, cell)
    return Terrain(float(x0), float(y0), float(cell), float(cell), grid - home.alt)


def hgt_tile_origin(path: str | Path) -> tuple[int, int]:
    """South-west corner (lat, lon) in whole degrees from an SRTM file name such as ``N47E008.hgt``."""
    match = _HGT_NAME.match(Path(path).name)
    if match is None:
        raise ValueError(f"{Path(path).name}: SRTM file name must start like N47E008 or S36E149")
    ns, lat, ew, lon = match.groups()
    return (int(lat) * (1 if ns.upper() == "N" else -1), int(lon) * (1 if ew.upper() == "E" else -1))


def read_hgt(path: str | Path, home: Home, size_x: float, size_y: float, spacing: float) -> Terrain:
    """SRTM ``.hgt`` tile resampled (bilinear in lat/lon) onto an ENU grid over [0, size_x] × [0, size_y] (m)."""
    path = Path(path)
    lat0, lon0 = hgt_tile_origin(path)
    data = _read(path, MAX_HGT_BYTES)
    raw = np.frombuffer(data, dtype=">i2", count=len(data) // 2)
    n = math.isqrt(raw.size)
    if n * n != raw.size or n not in HGT_SIZES or len(data) % 2:
        raise ValueError(f"{path.name}: {len(data)} bytes is not a {' or '.join(f'{s}²' for s in HGT_SIZES)} tile "
                         "of 2-byte samples")
    tile = raw.reshape(n, n)  # row 0 = north edge (lat0 + 1), column 0 = west edge (lon0)
    xs = grid_axis(size_x, spacing)
    ys = grid_axis(size_y, spacing)
    east, north = np.meshgrid(xs, ys)  # (ny, nx)
    lat, lon, _ = pymap3d.enu2geodetic(east, north, np.zeros_like(east), home.lat, home.lon, home.alt)
    row = (lat0 + 1 - np.asarray(lat)) * (n - 1)
    col = (np.asarray(lon) - lon0) * (n - 1)
    eps = 1e-9 * n
    if row.min() < -eps or row.max() > n - 1 + eps or col.min() < -eps or col.max() > n - 1 + eps:
        raise ValueError(
            f"{path.name}: the scenario bounds (lat {np.min(lat):.4f}…{np.max(lat):.4f}, lon {np.min(lon):.4f}…"
            f"{np.max(lon):.4f}) reach outside the tile ({lat0}…{lat0 + 1}, {lon0}…{lon0 + 1})")
    row = np.clip(row, 0.0, n - 1.0)
    col = np.clip(col, 0.0, n - 1.0)
    r0 = np.minimum(row.astype(np.intp), n - 2)
    c0 = np.minimum(col.astype(np.intp), n - 2)
    corners = np.stack([tile[r0, c0], tile[r0, c0 + 1], tile[r0 + 1, c0], tile[r0 + 1, c0 + 1]])
    if np.any(corners == HGT_VOID):
        raise ValueError(f"{path.name}: void samples (-32768) inside the scenario bounds; use a void-filled tile")
    tr = row - r0
    tc = col - c0
    h = corners.astype(float)
    heights = (h[0] * (1 - tc) + h[1] * tc) * (1 - tr) + (h[2] * (1 - tc) + h[3] * tc) * tr
    logger.debug("SRTM tile %s (%d²) resampled to %s nodes at %.1f m", path.name, n, heights.shape, spacing)
    return Terrain(0.0, 0.0, float(spacing), float(spacing), heights - home.alt)
