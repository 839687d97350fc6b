"""The grid sweep against closed forms and against the per-point kernel (an independent algorithm:
one pyramid walk per ray, tested against the slow reference in test_horizon.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyfix.dem import Dem, fractal_dem
from skyfix.errors import OutsideDemError, ParameterError
from skyfix.horizon import render_horizons
from skyfix.planets import EARTH, MARS
from skyfix.sweep import render_grid


def _ridge_dem(height_m=300.0, crest_y=3_000.0):
    """Flat ground at 0 m with a triangular ridge along x, its crest at y = crest_y (north)."""
    spacing = 10.0
    n = int(6_000 / spacing) + 1
    y = (np.arange(n) * spacing)[::-1]
    z = height_m * np.clip(1 - np.abs(y - crest_y) / 200.0, 0, None)
    return Dem.from_array(np.repeat(z[:, None], n, axis=1), spacing)


@pytest.mark.parametrize("camera_height_m", [1.5, 30.0])
@pytest.mark.parametrize("planet", [EARTH, MARS], ids=["earth", "mars"])
def test_ridge_at_known_distance_from_every_grid_position(camera_height_m, planet):
    dem = _ridge_dem()
    # 7 x 9 positions 7.5 m apart, 1.9-2 km south of the crest: the crest is far beyond the
    # near field, so the lines find it and the exact windows give its value.
    hb = render_grid(dem, 2_950.0, 1_100.0, 7.5, 7, 9, camera_height_m=camera_height_m,
                     planet=planet, skip_tol_deg=0)
    az = np.radians(hb.azimuth_deg)
    c = planet.curvature_coeff
    for k in range(hb.x.size):
        d0 = 3_000.0 - hb.y[k]
        for b in list(range(0, 41)) + list(range(320, 360)):
            d = d0 / math.cos(az[b])  # the crest seen obliquely
            want = math.degrees(math.atan((300 - camera_height_m) / d - c * d))
            assert hb.elevation_deg[k, b] == pytest.approx(want, abs=1e-4), (k, b)
            assert hb.skyline_distance_m[k, b] == pytest.approx(d, abs=0.01)
        # due south only the plane, to the DEM edge
        assert hb.ray_length_m[k, 180] == pytest.approx(hb.y[k], rel=1e-6)


def test_grid_is_row_major_north_to_south_west_to_east():
    dem = fractal_dem(128, 30.0, seed=3)
    x_w, y_n = dem.x0 + 1_500.0, dem.y0 - 1_500.0
    hb = render_grid(dem, x_w, y_n, 10.0, 3, 4)
    np.testing.assert_array_equal(hb.x.reshape(3, 4)[0], x_w + np.arange(4) * 10.0)
    np.testing.assert_array_equal(hb.y.reshape(3, 4)[:, 0], y_n - np.arange(3) * 10.0)
    np.testing.assert_allclose(hb.ground_z_m, dem.height_at(hb.x, hb.y), atol=1e-3)


@pytest.mark.parametrize("seed", [1, 2])
def test_agrees_with_the_per_point_kernel_on_rough_terrain(seed):
    """Every bin of a 31 x 31 grid at 5 m on 3 km of relief: as the kernel, never above it."""
    dem = fractal_dem(384, 30.0, relief_m=3_000.0, seed=seed)
    xmin, ymin, xmax, ymax = dem.bounds
    hb = render_grid(dem, (xmin + xmax) / 2 - 75, (ymin + ymax) / 2 + 75, 5.0, 31, 31)
    ref = render_horizons(dem, hb.x, hb.y)
    np.testing.assert_array_equal(np.isnan(hb.elevation_deg), np.isnan(ref.elevation_deg))
    np.testing.assert_allclose(hb.ray_length_m, ref.ray_length_m, rtol=1e-6)
    d = hb.elevation_deg.astype(np.float64) - ref.elevation_deg
    # Both are maxima over points of the same ray: the sweep's are true points, so it can exceed
    # the kernel only by the kernel's own skip tolerance (0.001 deg).
    assert np.nanmax(d) < 0.0015
    err = np.abs(d)
    assert np.nanpercentile(err, 99) < 0.01
    assert np.nanmean(err > 0.01) < 0.003
    assert np.nanpercentile(err, 50) < 1e-3


def test_nodata_behind_the_grid_is_skipped_as_the_kernel_skips_it():
    dem = fractal_dem(256, 30.0, relief_m=2_000.0, seed=5)
    z = dem.z.copy()
    z[20:60, 100:180] = np.nan  # a void north of the grid
    dem = Dem(z, dem.x0, dem.y0, dem.dx, dem.dy, dem.crs_wkt, dem.crs_name, body=dem.body)
    x_w, y_n = dem.x0 + 3_800.0, dem.y0 - 3_800.0
    hb = render_grid(dem, x_w, y_n, 5.0, 12, 12)
    ref = render_horizons(dem, hb.x, hb.y)
    err = np.abs(hb.elevation_deg.astype(np.float64) - ref.elevation_deg)
    assert np.nanpercentile(err, 99) < 0.01
    assert np.isfinite(hb.elevation_deg).all()


def test_terrain_beside_scattered_voids_is_seen_as_the_kernel_sees_it():
    """Forty small voids around the grid (a reprojected DEM's wedges are such voids): a line's
    grid-line crossing read from the cell beyond it, which touched a void, was NaN and the valid
    piece before it was lost to the hull (0.94 % of bins more than 0.01 deg low, by up to 4.9
    deg). Now as on terrain without voids."""
    d0 = fractal_dem(200, 30.0, seed=3)
    z = d0.z.copy()
    rng = np.random.default_rng(1)
    for _ in range(40):
        i, j = rng.integers(0, 200, 2)
        z[i:i + rng.integers(1, 8), j:j + rng.integers(1, 8)] = np.nan
    z[95:106, 95:106] = d0.z[95:106, 95:106]  # the grid's own ground stays
    dem = Dem(z, d0.x0, d0.y0, 30.0, 30.0, d0.crs_wkt, d0.crs_name, body=d0.body)
    hb = render_grid(dem, d0.x0 + 95 * 30.0, d0.y0 - 95 * 30.0, 7.0, 20, 20)
    ref = render_horizons(dem, hb.x, hb.y)
    np.testing.assert_array_equal(np.isnan(hb.elevation_deg), np.isnan(ref.elevation_deg))
    d = hb.elevation_deg.astype(np.float64) - ref.elevation_deg
    assert np.nanmax(d) < 0.0015
    assert np.nanmean(d < -0.01) < 0.0005 and np.nanmin(d) > -0.5


def test_lines_stay_fine_on_a_coarse_grid():
    """Lines one grid step apart on a 100 m grid saw other terrain than the positions between
    them (4.8 % of bins more than 0.01 deg low on the Sierra, by up to 9.4 deg): they stay
    LINE_SPACING_M apart whatever the grid's spacing."""
    dem = fractal_dem(256, 30.0, relief_m=2_000.0, seed=7)
    xmin, ymin, xmax, ymax = dem.bounds
    hb = render_grid(dem, (xmin + xmax) / 2 - 600, (ymin + ymax) / 2 + 600, 100.0, 12, 12)
    ref = render_horizons(dem, hb.x, hb.y)
    d = hb.elevation_deg.astype(np.float64) - ref.elevation_deg
    assert np.nanmean(d < -0.01) < 0.0005 and np.nanmin(d) > -0.5


def test_bad_parameters_and_positions_raise_clear_errors():
    dem = fractal_dem(64, 30.0, seed=1)
    x_w, y_n = dem.x0 + 600.0, dem.y0 - 600.0
    with pytest.raises(ParameterError, match="spacing"):
        render_grid(dem, x_w, y_n, 0.0, 2, 2)
    with pytest.raises(ParameterError, match="shape"):
        render_grid(dem, x_w, y_n, 5.0, 0, 2)
    with pytest.raises(ParameterError, match="camera height"):
        render_grid(dem, x_w, y_n, 5.0, 2, 2, camera_height_m=-1)
    with pytest.raises(ParameterError, match="near field"):
        render_grid(dem, x_w, y_n, 5.0, 2, 2, near_m=0)
    with pytest.raises(OutsideDemError):
        render_grid(dem, x_w, y_n, 500.0, 2, 5)  # the grid runs off the DEM's east edge


def test_a_positions_skyline_does_not_depend_on_the_rest_of_the_grid():
    """Lines lie on a lattice fixed to the DEM: a block rendered alone (a resumed build) gets the
    very values it gets inside a larger group."""
    dem = fractal_dem(256, 30.0, relief_m=2_500.0, seed=4)
    x_w, y_n = dem.x0 + 3_000.0, dem.y0 - 3_000.0
    big = render_grid(dem, x_w, y_n, 5.0, 14, 12)
    small = render_grid(dem, x_w + 3 * 5.0, y_n - 6 * 5.0, 5.0, 5, 4)
    want = big.elevation_deg.reshape(14, 12, -1)[6:11, 3:7].reshape(20, -1)
    np.testing.assert_array_equal(small.elevation_deg, want)


@pytest.mark.parametrize("corner", ["north-west", "south-east"])
def test_grids_at_the_dem_edge_agree_with_the_kernel(corner):
    """Rays that leave the DEM within metres, and lines that miss it or outlive the ray: the
    lines say nothing there, and the ray is traced whole."""
    dem = fractal_dem(128, 30.0, relief_m=1_500.0, seed=9)
    xmin, ymin, xmax, ymax = dem.bounds
    x_w, y_n = (xmin, ymax) if corner == "north-west" else (xmax - 30.0, ymin + 37.5)
    hb = render_grid(dem, x_w, y_n, 7.5, 6, 5)
    ref = render_horizons(dem, hb.x, hb.y)
    np.testing.assert_array_equal(np.isnan(hb.elevation_deg), np.isnan(ref.elevation_deg))
    np.testing.assert_allclose(hb.ray_length_m, ref.ray_length_m, rtol=1e-6)
    d = hb.elevation_deg.astype(np.float64) - ref.elevation_deg
    assert np.nanmax(d) < 0.0015
    assert np.nanmean(np.abs(d) > 0.01) < 0.002
    assert np.nanmax(np.abs(d)) < 0.5


@pytest.mark.parametrize("seed, rows, cols", [(0, 1, 64), (1, 64, 1)])
def test_a_grid_along_the_dem_edge_renders(seed, rows, cols):
    """Lines entering the DEM right beside positions on its edge start on a grid line, where a
    crossing can round onto the start (a zero-length piece: this raised ZeroDivisionError)."""
    dem = fractal_dem(128, 20.0, relief_m=800.0, seed=seed)
    xmin, ymin, xmax, ymax = dem.bounds
    hb = render_grid(dem, xmin, ymax, 5.0, rows, cols)
    ref = render_horizons(dem, hb.x, hb.y)
    np.testing.assert_array_equal(np.isnan(hb.elevation_deg), np.isnan(ref.elevation_deg))
    d = hb.elevation_deg.astype(np.float64) - ref.elevation_deg
    assert np.nanmax(d) < 0.0015
    assert np.nanmean(np.abs(d) > 0.01) < 0.002
