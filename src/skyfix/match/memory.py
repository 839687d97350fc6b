"""An in-memory skyline store with the database's block interface (tests, small areas, skylines
rendered on the fly).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..database import Block


#: raw value for "no skyline" in an int16 database
MISSING_RAW = -32768


@dataclass
class MemoryStore:
    """A skyline store in memory with the read API of ``skyfix.database`` (tests, small areas).

    elevation : (ny, nx, bins) float [deg] over a north-up grid; stored as int16 of ``scale_deg``.
    """

    x_coords: np.ndarray
    y_coords: np.ndarray
    raw: np.ndarray
    scale_deg: float = 0.01
    block: int = 64
    missing: int = MISSING_RAW
    camera_height_m: float = 1.5
    planet: str = "earth"
    crs_wkt: str = ""
    attrs: dict = field(default_factory=dict)

    @classmethod
    def from_dem(cls, dem, x_coords, y_coords, *, camera_height_m=1.5, planet=None,
                 azimuth_bins=360, block=64, scale_deg=0.01):
        """Render the skylines of a grid (x ascending, y descending) from a DEM."""
        from ..horizon import render_horizons

        xx, yy = np.meshgrid(np.asarray(x_coords, float), np.asarray(y_coords, float))
        hb = render_horizons(dem, xx.ravel(), yy.ravel(), camera_height_m=camera_height_m,
                             planet=planet, azimuth_bins=azimuth_bins)
        el = hb.elevation_deg.reshape(len(y_coords), len(x_coords), azimuth_bins)
        return cls.from_elevation(x_coords, y_coords, el, scale_deg=scale_deg, block=block,
                                  camera_height_m=camera_height_m, planet=hb.planet.name,
                                  crs_wkt=dem.crs_wkt)

    @classmethod
    def from_elevation(cls, x_coords, y_coords, elevation_deg, *, scale_deg=0.01, block=64, **kw):
        el = np.asarray(elevation_deg, np.float64)
        raw = np.where(np.isfinite(el), np.round(np.nan_to_num(el) / scale_deg), MISSING_RAW)
        return cls(np.asarray(x_coords, float), np.asarray(y_coords, float),
                   raw.astype(np.int16), scale_deg, block, **kw)

    @property
    def shape(self):
        return self.raw.shape[:2]

    @property
    def azimuth_bins(self):
        return self.raw.shape[2]

    @property
    def spacing_m(self):
        return float(abs(self.x_coords[1] - self.x_coords[0])) if self.x_coords.size > 1 else 1.0

    def iter_blocks(self):
        ny, nx = self.shape
        for r0 in range(0, ny, self.block):
            for c0 in range(0, nx, self.block):
                r1, c1 = min(ny, r0 + self.block), min(nx, c0 + self.block)
                xx, yy = np.meshgrid(self.x_coords[c0:c1], self.y_coords[r0:r1])
                yield Block(r0, c0, r1 - r0, c1 - c0, xx.ravel(), yy.ravel(),
                            self.raw[r0:r1, c0:c1].reshape(-1, self.azimuth_bins))

    def index_of(self, x, y):
        return grid_index(self, x, y)

    def xy_of(self, row, col):
        return self.x_coords[col], self.y_coords[row]

    def profiles_at(self, x, y):
        r, c = self.index_of(x, y)
        raw = self.raw[np.atleast_1d(r), np.atleast_1d(c)]
        return np.where(raw == self.missing, np.nan, raw * self.scale_deg).astype(np.float32)


def grid_index(db, x, y):
    """(row, col) of the grid node nearest to (x, y) [m] of a store with ``x_coords`` (east) and
    ``y_coords`` (north to south) [m]; arrays broadcast like x, y."""
    xc, yc = np.asarray(db.x_coords), np.asarray(db.y_coords)
    dx = xc[1] - xc[0] if xc.size > 1 else 1.0
    dy = yc[1] - yc[0] if yc.size > 1 else -1.0
    col = np.rint((np.asarray(x, float) - xc[0]) / dx).astype(np.int64)
    row = np.rint((np.asarray(y, float) - yc[0]) / dy).astype(np.int64)
    return row, col
