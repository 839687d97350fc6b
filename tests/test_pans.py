"""Pan refinement's pairwise shift against the direct computation (every circular roll of the
whole fine profile), and on a known shift."""

from __future__ import annotations

import numpy as np

from skyfix.profile.pans import pair_shift


def direct_costs(fi, fj, step, search, min_overlap, clip):
    """The squared-difference cost of every shift, rolling the whole circle (slow, obvious)."""
    ks = np.arange(-int(round(search / step)), int(round(search / step)) + 1)
    out = np.full(ks.size, np.inf)
    for m, k in enumerate(ks):
        g = np.roll(fj, k)
        ok = np.isfinite(fi) & np.isfinite(g)
        if ok.sum() >= min_overlap:
            out[m] = np.mean(np.minimum(np.square(fi[ok] - g[ok]), clip * clip))
    return ks, out


def frames(n=18000, shift=37, seed=0, start=17500, noise=0.0):
    """Two partial views of one skyline on a circle of n samples, the second shifted by
    ``shift`` samples and with ``noise`` [deg] rms added; the first crosses the circle's seam
    (from ``start``)."""
    rng = np.random.default_rng(seed)
    sky = np.cumsum(rng.normal(0, 0.05, n))
    sky -= np.linspace(0, sky[-1] - sky[0], n)  # close the circle
    fi = np.full(n, np.nan)
    fj = np.full(n, np.nan)
    a = (start + np.arange(2250)) % n
    fi[a] = sky[a]
    b = (start + 1500 + np.arange(2250)) % n
    fj[(b - shift) % n] = sky[b] + rng.normal(0, noise, b.size) if noise else sky[b]  # fj(az - s) = fi(az)
    return fi, fj


def test_the_shift_is_the_direct_search_s_optimum_and_the_known_one():
    step = 360.0 / 18000
    for shift, start in ((37, 17500), (-90, 3000), (0, 100)):
        fi, fj = frames(shift=shift, start=start)
        s, info, resid, nov = pair_shift(fi, fj, step, 3.0, 100, clip=0.1)
        ks, costs = direct_costs(fi, fj, step, 3.0, 100, 0.1)
        assert ks[int(np.argmin(costs))] == shift
        assert abs(s - shift * step) < 0.2 * step
        assert resid < 1e-9 and nov == 750 and info > 0


def test_a_noisy_overlap_gives_the_direct_search_s_sub_sample_shift():
    """With noise the optimum is interpolated: the parabola through the direct costs around
    their minimum gives the same shift."""
    step = 360.0 / 18000
    for seed in range(4):
        fi, fj = frames(shift=-12, start=9000 + 900 * seed, seed=seed, noise=0.02)
        s = pair_shift(fi, fj, step, 3.0, 100, clip=0.05)[0]
        ks, c = direct_costs(fi, fj, step, 3.0, 100, 0.05)
        m = int(np.argmin(c))
        ref = ks[m] + 0.5 * (c[m - 1] - c[m + 1]) / (c[m - 1] - 2 * c[m] + c[m + 1])
        assert abs(s - ref * step) < 1e-9 * step
        assert abs(s / step + 12) < 1.0


def test_too_small_an_overlap_gives_no_shift():
    step = 360.0 / 18000
    fi, fj = frames()
    assert pair_shift(fi, fj, step, 3.0, 2000, clip=0.1) is None


def test_pans_two_degrees_off_either_way_are_refined_to_one_common_offset():
    """Nine 60 deg frames over 20 deg overlaps, their pans off by +2 and -2 deg in turn: two
    neighbours are 4 deg apart, beyond the 3 deg the pair search reached, and two passes stopped
    short (0.4 deg between frames, the profile 0.24 deg off). The refined pans keep only a common
    offset (which no overlap sees: the prior sets it)."""
    from skyfix.camera import camera_from_fov, r_world_cam
    from skyfix.formats import Skyline
    from skyfix.profile import horizon_rows
    from skyfix.profile.pans import refine_pans

    az = np.arange(36000) * 0.01
    el = (6 + 3 * np.sin(np.radians(3 * az)) + 1.5 * np.cos(np.radians(7 * az + 20))
          + 0.5 * np.sin(np.radians(13 * az)))
    cam = camera_from_fov(1024, 768, 60.0)
    pans = np.arange(0, 360, 40.0) - 20
    sky = [Skyline(horizon_rows(cam, az, el, r_world_cam(37, 5, -4, p, 8)), 1024, 768)
           for p in pans]
    err = np.tile([2.0, -2.0], 5)[:9]
    d, _ = refine_pans(cam, sky, pans + err, np.full(9, 8.0))
    left = err + d
    assert np.max(np.abs(left - left.mean())) < 0.01
