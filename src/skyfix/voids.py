"""No-data cells of a DEM: holes in the data, filled where they are small, and the cells around
the data (a reprojection's wedges, a raster's no-data collar), which hold no terrain.

Filling a hole interpolates between heights on its sides; filling the cells around the data would
extrapolate from one side, a ramp of made-up terrain up to the fill distance wide (100 cells by
default) that no source holds. A ray sees no terrain in a NaN cell, and no position stands in one.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .errors import DemError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class VoidReport:
    """What happened to no-data cells on load (counts in cells). Voids are holes inside the data;
    ``n_outside`` cells lie around it (a reprojection's wedges, a raster's no-data collar): no
    terrain there, never filled."""

    n_void: int = 0
    n_filled: int = 0
    n_remaining: int = 0
    fraction: float = 0.0
    n_outside: int = 0

    def __str__(self) -> str:
        parts = []
        if self.n_void:
            parts.append(f"{self.n_void} void cell{'s' * (self.n_void != 1)} "
                         f"({100 * self.fraction:.1f} %): {self.n_filled} filled, {self.n_remaining} "
                         "left masked")
        if self.n_outside:
            parts.append(f"{self.n_outside} cell{'s' * (self.n_outside != 1)} around the data (no terrain)")
        return "; ".join(parts) or "no voids"


def collar_cells(void: np.ndarray) -> np.ndarray:
    """The void cells outside the convex hull of the valid ones: a raster's no-data collar (a
    map-projected HiRISE DTM's, the wedges of a grid written by gdalwarp), around the data rather
    than a hole in it. A void with data on both sides (an SRTM tile's, even one on the tile's
    edge) lies inside the hull. No cell where there is no void, or no valid cell to hull (a
    raster of no-data alone, which :func:`fill_voids` refuses)."""
    import cv2

    has = ~void
    if has.all() or not has.any():
        return np.zeros(void.shape, bool)
    rows = np.flatnonzero(has.any(axis=1))
    first = np.argmax(has[rows], axis=1)
    last = has.shape[1] - 1 - np.argmax(has[rows, ::-1], axis=1)
    pts = np.concatenate([np.stack([first, rows], 1), np.stack([last, rows], 1)]).astype(np.int32)
    poly = cv2.convexHull(pts)
    hull = np.zeros(void.shape, np.uint8)
    cv2.fillConvexPoly(hull, poly, 1)
    # The raster fill also takes cells whose centres lie up to about half a cell outside the
    # hull (collar cells beside a slanted edge, which filling would extrapolate): the cells on
    # the fill's rim are tested exactly against the hull's edges.
    rim = (hull == 1) & void & (cv2.erode(hull, np.ones((3, 3), np.uint8),
                                           borderType=cv2.BORDER_CONSTANT, borderValue=0) == 0)
    v = poly.reshape(-1, 2).astype(np.float64)
    e = np.roll(v, -1, axis=0) - v
    area = np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1])
    if v.shape[0] < 3 or area == 0:  # a hull of a line or a point: the raster fill is exact
        return void & (hull == 0)
    rr, cc = np.nonzero(rim)
    for k in range(0, rr.size, 4096):  # every edge against a few thousand cells at a time
        r, c = rr[k:k + 4096], cc[k:k + 4096]
        # each edge's cross product with each cell centre, signed so that inside is >= 0
        cross = (e[:, 0, None] * (r[None, :] - v[:, 1, None])
                 - e[:, 1, None] * (c[None, :] - v[:, 0, None])) * np.sign(area)
        out = np.any(cross < -1e-9, axis=0)
        hull[r[out], c[out]] = 0
    return void & (hull == 0)


def fill_voids(z: np.ndarray, max_cells: int, outside: np.ndarray | None = None) -> VoidReport:
    """Fill NaN voids in place where a valid height is within ``max_cells``; report counts.

    Cells ``outside`` the data (a reprojection's wedges and the source's collar; by default the
    raster's no-data collar, :func:`collar_cells`) stay NaN, no terrain: filling them would extrapolate
    terrain from one side, a ramp up to ``max_cells`` wide that no source holds."""
    void = ~np.isfinite(z)
    if not void.any():
        return VoidReport()
    if void.all():
        raise DemError("the DEM holds no valid heights at all")
    around = (collar_cells(void) if outside is None else outside) & void
    hole = void & ~around
    n_void, n_outside = int(hole.sum()), int(around.sum())
    n_filled = 0
    if max_cells > 0 and n_void:
        from rasterio.fill import fillnodata

        filled = fillnodata(np.where(void, 0, z).astype(np.float32), mask=(~void).astype(np.uint8),
                            max_search_distance=float(max_cells), smoothing_iterations=0)
        # fillnodata leaves cells it could not reach untouched (0 here): keep them NaN.
        reach = _within_distance(~void, max_cells)
        fill_here = hole & reach
        z[fill_here] = filled[fill_here]
        n_filled = int(fill_here.sum())
    rep = VoidReport(n_void, n_filled, n_void - n_filled, n_void / z.size, n_outside)
    log.info("DEM voids: %s", rep)
    return rep


def _within_distance(valid: np.ndarray, max_cells: int) -> np.ndarray:
    from .nearest import nearest_valid

    dist2, _, _ = nearest_valid(valid)
    return dist2 <= float(max_cells) ** 2  # squares of whole cells: exact in float64


