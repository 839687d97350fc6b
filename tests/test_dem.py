"""DEM ingest: CRS handling, voids, bilinear heights, the max pyramid, clear errors."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from conftest import plane_dem, shared_dem_path
from skyfix.dem import Dem, build_max_pyramid, load_dem
from skyfix.errors import DemError, OutsideDemError


def test_bilinear_height_is_exact_on_a_plane():
    dem = plane_dem(1_000, 10, z0=50, slope_x=0.3, slope_y=-0.1)
    rng = np.random.default_rng(1)
    x, y = rng.uniform(0, 1_000, 100), rng.uniform(0, 1_000, 100)
    np.testing.assert_allclose(dem.height_at(x, y), 50 + 0.3 * x - 0.1 * y, atol=1e-3)
    assert np.isnan(dem.height_at(-1.0, 5.0))


@settings(max_examples=30, deadline=None)
@given(arrays(np.float32, st.tuples(st.integers(2, 40), st.integers(2, 40)),
              elements=st.floats(-500, 5000, width=32)))
def test_pyramid_blocks_bound_every_height_inside(z):
    levels = build_max_pyramid(z)
    ny, nx = z.shape
    assert levels[-1].shape == (1, 1) and levels[-1][0, 0] == z.max()
    for lv, arr in enumerate(levels):
        size = 1 << lv
        for bi in range(arr.shape[0]):
            for bj in range(arr.shape[1]):
                block = z[bi * size: min((bi + 1) * size + 1, ny), bj * size: min((bj + 1) * size + 1, nx)]
                assert arr[bi, bj] == block.max()


def test_geographic_dem_is_reprojected_to_its_utm_zone_and_voids_filled():
    dem = load_dem(shared_dem_path("alps_srtm3_n46e008"))
    assert dem.crs_name == "EPSG:32632"  # 8-9 deg E, northern hemisphere
    assert 60 < dem.dx < 100 and dem.dx == dem.dy
    assert dem.voids.n_void > 0 and dem.voids.n_remaining == 0
    assert np.isfinite(dem.z).all()
    assert 150 < np.nanmin(dem.z) and np.nanmax(dem.z) < 4_300


def test_projected_dem_keeps_its_crs_and_grid():
    dem = load_dem(shared_dem_path("south_glacier_20m"))
    assert dem.crs_name == "EPSG:32607"
    assert dem.z.shape == (300, 248) and dem.dx == 20.0
    assert len(dem.checksum) == 64


def test_explicit_target_crs(tmp_dem_file):
    path = tmp_dem_file(plane_dem(2_000, 20, z0=10))
    dem = load_dem(path, crs="EPSG:32612")
    assert dem.crs_name == "EPSG:32612"
    assert np.nanmax(dem.z) == pytest.approx(10, abs=1e-3)


def test_dem_without_crs_is_refused(tmp_path):
    import rasterio
    from rasterio.transform import from_origin

    path = tmp_path / "nocrs.tif"
    with rasterio.open(path, "w", driver="GTiff", width=4, height=4, count=1, dtype="float32",
                       transform=from_origin(0, 40, 10, 10)) as dst:
        dst.write(np.ones((4, 4), np.float32), 1)
    with pytest.raises(DemError, match="no CRS"):
        load_dem(path)


def test_unreadable_and_missing_files(tmp_path):
    bad = tmp_path / "notes.tif"
    bad.write_text("not a raster")
    with pytest.raises(DemError, match="cannot read"):
        load_dem(bad)
    with pytest.raises(DemError, match="does not exist"):
        load_dem(tmp_path / "missing.tif")


def test_large_voids_stay_masked_and_points_in_them_are_refused():
    z = np.full((50, 50), 100.0)
    z[10:40, 10:40] = np.nan
    from skyfix.dem import _fill_voids

    rep = _fill_voids(z, max_cells=5)
    assert rep.n_void == 900 and 0 < rep.n_filled < 900 and rep.n_remaining == 900 - rep.n_filled
    dem = Dem.from_array(z, 10.0)
    with pytest.raises(OutsideDemError, match="void"):
        dem.require_inside(250.0, 250.0)


def test_fractal_dem_is_reproducible_and_has_the_requested_relief():
    from skyfix.dem import fractal_dem

    a = fractal_dem(128, 30.0, relief_m=800.0, seed=5)
    b = fractal_dem(128, 30.0, relief_m=800.0, seed=5)
    c = fractal_dem(128, 30.0, relief_m=800.0, seed=6)
    np.testing.assert_array_equal(a.z, b.z)
    assert not np.array_equal(a.z, c.z)
    assert float(a.z.max() - a.z.min()) == pytest.approx(800.0, rel=1e-4)
    assert a.crs_name == "EPSG:32611" and a.dx == 30.0
