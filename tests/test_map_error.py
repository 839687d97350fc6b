"""The map's height error and the position it leaves: the error model's closed forms, and the
position sigma's map share against a Monte Carlo of maps that differ from the world."""

import math

import numpy as np
import pytest

from skyfix.dem import Dem
from skyfix.pose.map_error import MAP_CORRELATION_M, error_covariance, map_error_scatter


def test_error_covariance_closed_forms():
    """One skyline point ``d`` away: ``var(e_sky - e_cam) = 2 sigma^2 (1 - exp(-d / L))``; two
    far points ``r`` apart share the camera's error and ``exp(-r / L)`` of their own."""
    L, s, g = MAP_CORRELATION_M, 2.0, 0.01
    for d in (0.0, 75.0, 150.0, 3000.0):
        c = error_covariance([[d, 0.0]], [g], s)
        assert c[0, 0] == pytest.approx(2 * s * s * (1 - math.exp(-d / L)) * g * g, abs=1e-15)
    far = 1e6  # both points far from the camera: only their own errors and the camera's remain
    c = error_covariance([[far, 0.0], [far, 300.0]], [g, g], s)
    assert c[0, 1] == pytest.approx(s * s * (math.exp(-300.0 / L) + 1.0) * g * g, rel=1e-9)


def _terrain():
    y, x = np.mgrid[0:200, 0:200] * 10.0
    z = (250 * np.exp(-((x - 400) ** 2 + (y - 1300) ** 2) / 3e4)
         + 180 * np.exp(-((x - 1500) ** 2 + (y - 600) ** 2) / 6e4)
         + 60 * np.sin(x / 90.0) * np.cos(y / 130.0) + 0.03 * x)
    return z


def test_map_covariance_matches_the_scatter_of_fits_on_maps_that_differ_from_the_world():
    """Worlds drawn as the map plus a correlated height error (2 m rms over 150 m); from each the
    profile a level camera 1.5 m above that world's ground measures; the least-squares position
    (with yaw, pitch, roll and an offset) against the map, linearised with a Jacobian of its
    own (1 m steps). The spread of those positions and yaws is what the map shares must say."""
    z = _terrain()
    cov, moves = map_error_scatter(Dem.from_array(z, 10.0), 1000.0, 1000.0, 40.0, sigma_m=2.0,
                                   draws=60, rng=np.random.default_rng(3), noise_deg=0.05)
    claimed, claimed_yaw = math.sqrt(cov[0, 0] + cov[1, 1]), math.sqrt(cov[2, 2])
    spread = float(np.sqrt(np.mean(np.sum(np.square(moves[:, :2]), axis=1))))
    spread_yaw = float(np.sqrt(np.mean(np.square(moves[:, 2]))))
    # measured: claimed 7.6 m, spread 6.4 m; 60 draws know the rms to ~10 %, and the model's points are
    # the skyline's, not every bilinear cell the error moves
    assert 1.0 < spread < 50.0, "the map's error must move this fix by metres"
    assert claimed == pytest.approx(spread, rel=0.35)
    assert claimed_yaw == pytest.approx(spread_yaw, rel=0.35)  # measured 0.33 and 0.32 deg
