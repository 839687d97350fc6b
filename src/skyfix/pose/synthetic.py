"""Synthetic query profiles rendered from the DEM, for tests, benchmarks and calibration.
"""

from __future__ import annotations

import numpy as np

from ..north import wrap_deg
from .forward import body_profile


def synthetic_profile(dem, x, y, heading_deg, pitch_deg=0.0, roll_deg=0.0, *, camera_height_m=1.5,
                      planet=None, n_bins=360, noise_deg=0.0, outlier_fraction=0.0,
                      coverage_deg=360.0, rng=None, render_bins=3600, prior_pitch_deg=0.0,
                      prior_roll_deg=0.0):
    """A body-frame :class:`~skyfix.formats.Profile` as a rover at (x, y) [m] with this attitude
    [deg] would measure it: a dense rendered horizon rotated exactly into the body frame, then
    Gaussian noise [deg], outlier bins (+/- 1..5 deg) and a view of ``coverage_deg`` centred on a
    random azimuth."""
    from ..formats import Profile
    from ..horizon import render_horizons

    rng = np.random.default_rng(rng)
    world = render_horizons(dem, [x], [y], camera_height_m=camera_height_m, planet=planet,
                            azimuth_bins=render_bins).elevation_deg[0]
    # Average the dense world horizon onto sub-bins before rotating: a measured bin is an average.
    q = body_profile(world, heading_deg, pitch_deg, roll_deg, n_bins=n_bins * 10,
                     prior_pitch_deg=prior_pitch_deg, prior_roll_deg=prior_roll_deg)
    if n_bins * 10 == q.size:
        # bin j spans j - 0.5 .. j + 0.5 bins: 11 sub-bin samples, the two ends half-weighted
        # (a plain mean of 10 is centred 0.05 bin off, a heading bias of 0.05 deg at 360 bins)
        idx = (10 * np.arange(n_bins)[:, None] + np.arange(-5, 6)[None, :]) % q.size
        w = np.r_[0.5, np.ones(9), 0.5] / 10.0
        q = q[idx] @ w
    q = q + rng.normal(0.0, noise_deg, n_bins) if noise_deg > 0 else q
    if outlier_fraction > 0:
        k = rng.random(n_bins) < outlier_fraction
        q[k] += rng.choice([-1, 1], k.sum()) * rng.uniform(1, 5, k.sum())
    if coverage_deg < 360.0:
        c = rng.uniform(0, 360)
        az = np.arange(n_bins) * 360.0 / n_bins
        d = np.abs(wrap_deg(az - c))
        q[d > coverage_deg / 2] = np.nan
    sig = np.where(np.isfinite(q), max(noise_deg, 0.05), np.nan)
    return Profile(q, sig, "body", {"camera_height_m": camera_height_m})
