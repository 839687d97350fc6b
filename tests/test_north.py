"""True north against grid north: the meridian convergence against pyproj's own factors, and the
fix and heading outputs that carry both norths."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyfix.north import grid_heading_from_true, meridian_convergence_deg, true_heading_deg


def _pyproj_convergence(crs, x, y):
    """PROJ's meridian convergence at (x, y) (via ``Proj.get_factors`` at the point's lon/lat)."""
    from pyproj import CRS, Proj, Transformer

    c = CRS.from_user_input(crs)
    lon, lat = Transformer.from_crs(c, c.geodetic_crs, always_xy=True).transform(x, y)
    return Proj(c).get_factors(lon, lat).meridian_convergence


@pytest.mark.parametrize("crs, x, y", [
    ("ESRI:102003", -2_016_684.0, 241_764.0),   # the Sierra DEM's own Albers: ~14 deg
    ("EPSG:32607", 601_500.0, 6_744_000.0),     # the glacier's UTM 7N, east of its central meridian
    ("EPSG:32611", 300_000.0, 4_100_000.0),     # west of a central meridian: the other sign
    ("EPSG:3031", 1_000_000.0, -1_200_000.0),   # Antarctic polar stereographic: large angles
])
def test_convergence_is_proj_meridian_convergence_with_the_conventions_sign(crs, x, y):
    """conventions.md: heading_deg - grid_heading_deg. A rover facing true north has the grid
    heading of the meridian's direction on the map, so the convergence is minus that azimuth;
    PROJ's ``meridian_convergence`` is the angle from true north to grid north, the same number."""
    mine = meridian_convergence_deg(crs, x, y)
    ref = _pyproj_convergence(crs, x, y)
    assert abs(mine - ref) < 1e-4, (mine, ref)


def test_sierra_grid_north_is_14_degrees_off_in_its_albers_and_1_in_utm():
    """The Sierra DEM's own USA Albers, and UTM 11N it is read into (conventions.md: the Albers
    stretches distances by 0.98 %) at the same place."""
    assert 13.5 < abs(meridian_convergence_deg("ESRI:102003", -2_016_684.0, 241_764.0)) < 14.5
    assert 1.0 < abs(meridian_convergence_deg("EPSG:32611", 301_555.1, 4_146_671.1)) < 1.6


def test_no_crs_means_no_true_north():
    assert math.isnan(meridian_convergence_deg("", 0.0, 0.0))
    assert true_heading_deg(370.0, float("nan")) == pytest.approx(10.0)


def test_true_and_grid_headings_round_trip():
    for g in np.linspace(-720, 720, 37):
        back = grid_heading_from_true(true_heading_deg(g, 14.2), 14.2)
        assert 0.0 <= back < 360.0 and abs((back - g + 180.0) % 360.0 - 180.0) < 1e-9
    assert true_heading_deg(355.0, 14.0) == pytest.approx(9.0)


def test_a_heading_just_under_zero_is_zero_not_360():
    """-1e-17 % 360.0 is 360.0 in floating point: outputs are in [0, 360)."""
    from skyfix.north import heading_360

    assert -1e-17 % 360.0 == 360.0  # the trap
    assert heading_360(-1e-17) == 0.0 and heading_360(-0.5) == 359.5 and heading_360(720.25) == 0.25
    assert true_heading_deg(-1e-17, float("nan")) == 0.0


@pytest.mark.shared_data
def test_heading_reports_both_norths_on_a_projected_dem():
    """estimate_heading works in grid north; its answer adds the true heading, the convergence
    at the position, the CRS and lon/lat."""
    from conftest import shared_dem_path

    from skyfix import pose
    from skyfix.dem import load_dem

    dem = load_dem(shared_dem_path("south_glacier_20m"))
    x, y = 601_500.0, 6_744_000.0
    prof = pose.synthetic_profile(dem, x, y, 80.0, noise_deg=0.05, rng=1)
    h = pose.estimate_heading(prof, dem, x, y, 80.0, 10.0)
    conv = _pyproj_convergence("EPSG:32607", x, y)
    assert abs(h.grid_heading_deg - 80.0) < 0.3
    assert h.meridian_convergence_deg == pytest.approx(conv, abs=1e-4)
    assert h.heading_deg == pytest.approx((h.grid_heading_deg + h.meridian_convergence_deg) % 360.0,
                                          abs=1e-9)
    d = h.to_dict()
    assert d["crs"] == "EPSG:32607" and -141 < d["lon"] < -139 and 60 < d["lat"] < 61
