"""Shared fixtures: the reference data folder and tiny synthetic DEMs with known answers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from skyfix.dem import Dem

#: ../shared/data beside the repository (CI has it there too)
SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
DEM_DIR = SHARED_DATA / "dem"
SHARED_DEMS = ["sierra_nevada_30m", "south_glacier_20m", "alps_srtm3_n46e008"]


def shared_dem_path(name: str) -> Path:
    path = DEM_DIR / f"{name}.tif"
    if not path.exists():
        pytest.skip(f"shared reference DEM {path} not found (expected ../shared/data beside the repo)")
    return path


def plane_dem(size_m: float, spacing_m: float, z0: float = 100.0, slope_x: float = 0.0,
              slope_y: float = 0.0) -> Dem:
    """A plane z = z0 + slope_x * x + slope_y * y over [0, size] x [0, size]."""
    n = int(round(size_m / spacing_m)) + 1
    xs = np.arange(n) * spacing_m
    ys = xs[::-1]  # row 0 is north
    z = z0 + slope_x * xs[None, :] + slope_y * ys[:, None]
    return Dem.from_array(z, spacing_m)


@pytest.fixture
def tmp_dem_file(tmp_path):
    """Write a Dem to a GeoTIFF and return the path."""
    from skyfix.dem import write_dem

    def make(dem: Dem, name: str = "dem.tif") -> Path:
        return write_dem(tmp_path / name, dem)

    return make
