"""Matcher: FFT scoring against explicit loops, invariances, streaming vs brute force."""

import numpy as np
import pytest

from skyfix.dem import Dem
from skyfix.errors import ParameterError
from skyfix.match import (MatchConfig, MemoryStore, brute_force_scores, match_database,
                          prepare_query, score_profiles)


def _random_skylines(rng, n_pos, n):
    p = np.cumsum(rng.normal(size=(n_pos, n)), axis=1)
    p -= np.linspace(0, 1, n)[None] * p[:, -1:]  # periodic
    return (3 + p).astype(np.float32)


@pytest.mark.parametrize("tilt", [False, True])
@pytest.mark.parametrize("masked", [False, True])
def test_fft_scores_equal_brute_force(tilt, masked):
    rng = np.random.default_rng(0)
    n = 72
    p = _random_skylines(rng, 12, n)
    q = np.roll(p[5], -7) + rng.normal(0, 0.2, n)
    if masked:
        q[20:45] = np.nan
    s = score_profiles(p, prepare_query(q, tilt, min_observed=10), all_shifts=True)
    ref = brute_force_scores(p, q, tilt)
    assert np.allclose(s, ref, atol=1e-4 * ref.max())
    best, shift = score_profiles(p, prepare_query(q, tilt, min_observed=10))
    assert int(np.argmin(best)) == 5
    assert abs(shift[5] - 7) < 0.3


def test_constant_offset_and_tilt_invariance():
    rng = np.random.default_rng(1)
    n = 90
    p = _random_skylines(rng, 5, n)
    q = np.roll(p[2], -11).astype(float)
    az = np.radians(np.arange(n) * 4.0)
    base = score_profiles(p, prepare_query(q, False), all_shifts=True)
    off = score_profiles(p, prepare_query(q + 2.7, False), all_shifts=True)
    assert np.allclose(base, off, atol=1e-3)
    assert off[2, 11] < 1e-4
    tilted = q + 1.5 * np.sin(az - 0.7)
    assert score_profiles(p, prepare_query(tilted, False))[0][2] > 0.5  # level model is hurt
    assert score_profiles(p, prepare_query(tilted, True))[0][2] < 1e-4  # harmonic removes it


def test_query_with_too_few_bins_is_refused():
    q = np.full(360, np.nan)
    q[:5] = 1.0
    with pytest.raises(ParameterError, match="observed azimuth bins"):
        prepare_query(q)


def _bumpy_dem():
    y, x = np.mgrid[0:120, 0:120] * 10.0
    z = (200 * np.exp(-((x - 300) ** 2 + (y - 800) ** 2) / 2e4) + 120 * np.exp(-((x - 900) ** 2 + (y - 400) ** 2) / 5e4)
         + 60 * np.sin(x / 90.0) * np.cos(y / 130.0) + 0.02 * x)
    return Dem.from_array(z, 10.0)


@pytest.fixture(scope="module")
def store():
    dem = _bumpy_dem()
    xs = np.arange(400.0, 800.1, 20.0)
    ys = np.arange(800.0, 399.9, -20.0)
    return dem, MemoryStore.from_dem(dem, xs, ys, azimuth_bins=72, block=8)


def test_streaming_equals_brute_force_on_a_small_store(store):
    dem, st = store
    q = st.profiles_at(520.0, 620.0)[0].astype(float)
    q = np.roll(q, -9)  # heading 45 deg
    q[30:40] = np.nan
    res = match_database(st, q, MatchConfig(coarse_factor=1, top_k=3, min_observed=10, slice_rows=50))
    p = st.raw.reshape(-1, 72) * st.scale_deg
    full = brute_force_scores(p, q, True)
    k = full.argmin(axis=1)
    r = np.arange(full.shape[0])
    s0, sm, sp = full[r, k], full[r, (k - 1) % 72], full[r, (k + 1) % 72]
    den = sm - 2 * s0 + sp
    off = np.clip(0.5 * (sm - sp) / den, -0.5, 0.5)  # the same parabola through three shifts
    ref = (s0 - 0.25 * (sm - sp) * off).reshape(st.shape)
    assert np.allclose(res.score_map, ref, atol=2e-3)
    assert np.allclose(res.heading_map, ((k + off) * 5.0).reshape(st.shape) % 360, atol=0.05)
    c = res.candidates[0]
    assert (c.x, c.y) == (520.0, 620.0)
    assert abs((c.heading_deg - 45.0 + 180) % 360 - 180) < 1.0
    # The coarse pre-pass keeps the same winner.
    fast = match_database(st, q, MatchConfig(coarse_factor=4, keep_fraction=0.1, min_observed=10))
    assert (fast.candidates[0].x, fast.candidates[0].y) == (520.0, 620.0)
    assert fast.n_scored_exact < fast.n_positions


def test_candidates_are_in_distinct_basins(store):
    _, st = store
    q = st.profiles_at(600.0, 500.0)[0].astype(float)
    res = match_database(st, q, MatchConfig(coarse_factor=1, top_k=4, nms_radius_m=60.0))
    pts = [(c.x, c.y) for c in res.candidates]
    for i in range(len(pts)):
        for j in range(i):
            assert max(abs(pts[i][0] - pts[j][0]), abs(pts[i][1] - pts[j][1])) > 60.0
    assert [c.score for c in res.candidates] == sorted(c.score for c in res.candidates)


def test_prior_disc_restricts_the_search(store):
    _, st = store
    q = st.profiles_at(600.0, 500.0)[0].astype(float)
    res = match_database(st, q, MatchConfig(coarse_factor=1), prior_xy=(440.0, 760.0),
                         prior_radius_m=50.0)
    for c in res.candidates:
        assert np.hypot(c.x - 440.0, c.y - 760.0) <= 50.0
