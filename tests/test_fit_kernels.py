"""The attitude fits' inner pieces against the plain NumPy they replace, to the bit: the median
by partition, and the body profile ordered by a roll instead of a sort (from contiguous
coordinates, wrapped to [0, 360) without np.remainder)."""

import numpy as np
import pytest

from skyfix.camera import r_world_body
from skyfix.pose.forward import BodyProfiler
from skyfix.pose.lm import median


@pytest.mark.parametrize("n", [1, 2, 3, 359, 360, 1441])
def test_median_is_numpys(n):
    rng = np.random.default_rng(n)
    for k in range(50):
        a = rng.normal(size=n)
        if k % 2:
            a = np.round(a, 1)  # ties
        assert median(a) == np.median(a)


def _sorted_reference(w, bins, prior, yaw, pitch, roll):
    """The profile as it was computed before the roll: the horizon's directions rotated into the
    levelled body frame, sorted by azimuth, np.interp's periodic path."""
    az = np.radians(np.arange(w.size) * 360.0 / w.size)
    el = np.radians(w)
    d = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], axis=1)
    b = d @ (r_world_body(0.0, *prior) @ r_world_body(yaw, pitch, roll).T).T
    azb = np.degrees(np.arctan2(b[:, 0], b[:, 1])) % 360.0
    elb = np.degrees(np.arctan2(b[:, 2], np.hypot(b[:, 0], b[:, 1])))
    order = np.argsort(azb)
    return np.interp(np.arange(bins) * 360.0 / bins, azb[order], elb[order], period=360.0)


@pytest.mark.parametrize("m,bins", [(1440, 360), (7200, 360), (360, 360)])
def test_body_profile_is_the_sorted_interpolation(m, bins):
    """Small tilts (the roll), steep ones (a folded curve: the sort) and a yaw of exactly 0
    (azimuths at -0.0, which the periodic wrap turns into 360)."""
    rng = np.random.default_rng(m)
    w = 3.0 + np.cumsum(rng.normal(0, 0.3, m))
    w -= np.linspace(0, w[-1] - w[0], m)
    bp = BodyProfiler(w, n_bins=bins, prior_pitch_deg=1.0, prior_roll_deg=-2.0)
    for k in range(400):
        sd = 25.0 if k % 2 else 4.0
        att = (rng.uniform(0, 360) if k % 5 else 0.0, rng.normal(0, sd), rng.normal(0, sd))
        assert np.array_equal(bp(*att), _sorted_reference(w, bins, (1.0, -2.0), *att))
