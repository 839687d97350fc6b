"""Figures: the hillshade against its closed form, and the demo's figures drawn from known data."""

import math

import numpy as np
import pytest

from conftest import plane_dem
from skyfix.figures import hillshade, plot_fix_map, plot_frame_skyline
from skyfix.formats import Skyline


@pytest.mark.parametrize("slope", [0.0, 0.3, -0.5])
def test_hillshade_of_a_plane_is_the_lamberts_cosine(slope):
    """A plane rising east at ``slope``; light from the north-west, 45 deg up: the cosine between
    the light (-cos45 sin45, cos45 cos45, sin45) and the normal (-slope, 0, 1) / sqrt(1 + slope^2)."""
    dem = plane_dem(1000.0, 10.0, slope_x=slope)
    x0, y0, x1, y1 = dem.bounds
    shade, ext = hillshade(dem, x0, x1, y0, y1)
    c = math.cos(math.radians(45))
    want = (slope * c * math.sin(math.radians(45)) + math.sin(math.radians(45))) / math.sqrt(1 + slope ** 2)
    assert np.allclose(shade[2:-2, 2:-2], np.clip(want, 0, 1), atol=1e-9)
    assert ext[0] == pytest.approx(x0 - 5.0) and ext[3] == pytest.approx(y1 + 5.0)


def test_the_demo_figures_are_drawn(tmp_path):
    from skyfix.pose.fix import Fix

    dem = plane_dem(1000.0, 10.0, slope_x=0.1)
    cx, cy = dem.bounds[0] + 500.0, dem.bounds[1] + 500.0
    fix = Fix(x=cx, y=cy, crs="", lon=math.nan, lat=math.nan, heading_deg=30.0,
              grid_heading_deg=30.0, meridian_convergence_deg=0.0, pitch_deg=0.0, roll_deg=0.0,
              position_sigma_m=3.0, heading_sigma_deg=0.1, confidence=0.95, score=0.01,
              candidates=({"x": cx + 100, "y": cy, "heading_deg": 10.0, "score": 0.5},))
    p = plot_fix_map(tmp_path / "map.png", fix, dem, area=(cx - 300, cy - 300, cx + 300, cy + 300),
                     truth=(cx + 1.0, cy - 1.0))
    assert p.stat().st_size > 10_000
    rgb = np.zeros((60, 80, 3), np.uint8)
    sky = Skyline(rows=np.where(np.arange(80) < 40, 20.0, np.nan), width=80, height=60)
    assert plot_frame_skyline(tmp_path / "frame.png", rgb, sky, "t").stat().st_size > 2_000
