"""Matcher: FFT scoring against explicit loops, invariances, streaming vs brute force."""

from dataclasses import replace

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


def test_candidates_are_a_suppression_radius_apart(store):
    _, st = store
    q = st.profiles_at(600.0, 500.0)[0].astype(float)
    res = match_database(st, q, MatchConfig(coarse_factor=1, top_k=4, nms_radius_m=60.0))
    pts = [(c.x, c.y) for c in res.candidates]
    assert len(pts) == 4  # a 400 m square of bumps holds four basins 60 m apart and more
    for i in range(len(pts)):
        for j in range(i):
            assert max(abs(pts[i][0] - pts[j][0]), abs(pts[i][1] - pts[j][1])) > 60.0
    assert [c.score for c in res.candidates] == sorted(c.score for c in res.candidates)


def test_prior_disc_restricts_the_search(store):
    _, st = store
    q = st.profiles_at(600.0, 500.0)[0].astype(float)
    res = match_database(st, q, MatchConfig(coarse_factor=1), prior_xy=(440.0, 760.0),
                         prior_radius_m=50.0)
    # the grid's nodes within 50 m of (440, 760), counted directly: every one scored, no other
    gx, gy = np.meshgrid(np.arange(400.0, 800.1, 20.0), np.arange(800.0, 399.9, -20.0))
    inside = np.hypot(gx - 440.0, gy - 760.0) <= 50.0
    assert res.n_positions == inside.sum() == 21
    assert res.candidates
    for c in res.candidates:
        assert np.hypot(c.x - 440.0, c.y - 760.0) <= 50.0


@pytest.mark.parametrize("tilt", [False, True])
@pytest.mark.parametrize("masked", [False, True])
def test_dense_scores_equal_brute_force(tilt, masked):
    from skyfix.match import dense_query, score_dense

    rng = np.random.default_rng(3)
    n = 90
    p = _random_skylines(rng, 10, n)
    q = np.roll(p[4], -13) + rng.normal(0, 0.2, n)
    if masked:
        q[50:80] = np.nan
    query = prepare_query(q, tilt, min_observed=10)
    s = score_dense(p, dense_query(query), all_shifts=True)
    ref = brute_force_scores(p, q, tilt)
    assert np.allclose(s, ref, atol=1e-4 * ref.max())
    best, shift = score_dense(p, dense_query(query))
    assert int(np.argmin(best)) == 4
    assert abs(shift[4] - 13) < 0.3


@pytest.fixture(scope="module")
def store360():
    dem = _bumpy_dem()
    xs = np.arange(300.0, 900.1, 20.0)
    ys = np.arange(900.0, 299.9, -20.0)
    return dem, MemoryStore.from_dem(dem, xs, ys, azimuth_bins=360, block=16)


@pytest.mark.parametrize("stride", [1, 2])
def test_coarse_prefilter_keeps_the_exact_winner_on_realistic_queries(store360, stride):
    """Off-grid truths, 0.2 deg noise, 150 deg views, 10 deg tilts: the fast search (coarse
    pre-filter, 3 % kept; on every position or every other row and column) returns the same best
    position and heading as the exhaustive exact one."""
    from skyfix.pose import synthetic_profile

    dem, st = store360
    rng = np.random.default_rng(7)
    fast_cfg = MatchConfig(slice_rows=256, coarse_stride=stride, stride_min_coverage=0.0)
    exact_cfg = MatchConfig(coarse_factor=1, slice_rows=256)
    cases = 0
    for i in range(10):
        x, y = rng.uniform(340, 860, 2)
        tilt = (10.0, 0.0) if i % 3 == 1 else (0.0, -10.0) if i % 3 == 2 else (0.0, 0.0)
        prof = synthetic_profile(dem, x, y, rng.uniform(0, 360), *tilt, noise_deg=0.2,
                                 coverage_deg=150.0 if i % 2 else 360.0, rng=i)
        q = np.asarray(prof.elevation_deg, float)
        fast = match_database(st, q, fast_cfg)
        exact = match_database(st, q, exact_cfg)
        assert fast.n_scored_exact < 0.2 * fast.n_positions
        fc, ec = fast.candidates[0], exact.candidates[0]
        assert (fc.row, fc.col) == (ec.row, ec.col)
        assert abs(fc.heading_deg - ec.heading_deg) < 1e-3
        assert abs(fc.score - ec.score) <= 1e-6 + 1e-5 * ec.score
        cases += 1
    assert cases == 10


def test_zarr_store_elevation_path_equals_brute_force(tmp_path):
    """A real (zarr) store goes through the elevation-only reader; the winner map must equal an
    exhaustive brute-force search over its profiles."""
    from skyfix.database import build_database, open_database
    from skyfix.dem import write_dem

    dem = _bumpy_dem()
    write_dem(tmp_path / "dem.tif", dem)
    build_database(tmp_path / "dem.tif", tmp_path / "db.zarr", (405.0, 405.0, 645.0, 605.0), 20.0,
                   azimuth_bins=72, block=8, workers=0, progress=False)
    db = open_database(tmp_path / "db.zarr")
    assert db.is_complete
    xs, ys = np.meshgrid(db.x_coords, db.y_coords)
    p = db.profiles_at(xs.ravel(), ys.ravel()).astype(float)
    k0 = int(np.argmin((xs.ravel() - 525.0) ** 2 + (ys.ravel() - 505.0) ** 2))
    q = np.roll(p[k0], -20)
    q[10:25] = np.nan
    res = match_database(db, q, MatchConfig(coarse_factor=1, min_observed=10))
    full = brute_force_scores(np.nan_to_num(p), q, True)
    k = full.argmin(axis=1)
    r = np.arange(full.shape[0])
    s0, sm, sp = full[r, k], full[r, (k - 1) % 72], full[r, (k + 1) % 72]
    off = np.clip(0.5 * (sm - sp) / (sm - 2 * s0 + sp), -0.5, 0.5)  # the matcher's sub-bin parabola
    ref = np.maximum(s0 - 0.25 * (sm - sp) * off, 0.0).reshape(db.shape)
    assert res.n_positions == ref.size
    assert np.allclose(res.score_map, ref, rtol=1e-4, atol=2e-3)
    c = res.candidates[0]
    assert (c.x, c.y) == (xs.ravel()[k0], ys.ravel()[k0])
    assert abs((c.heading_deg - 100.0 + 180) % 360 - 180) < 1.0


def test_stores_of_both_chunk_layouts_give_the_same_search(tmp_path):
    """A store written since the transposed layout and the same skylines in the earlier layout
    (database/chunks.py reads the first as a transposed view, which the coarse pass gathers
    along azimuth rows): the same candidates and scores, with and without the coarse stride and
    the prior disc."""
    import shutil

    import zarr
    from zarr.codecs import Delta, Shuffle, ZstdCodec

    from skyfix.database import build_database, open_database
    from skyfix.dem import write_dem

    write_dem(tmp_path / "dem.tif", _bumpy_dem())
    now = tmp_path / "now.zarr"
    build_database(tmp_path / "dem.tif", now, (405.0, 405.0, 645.0, 605.0), 10.0,
                   azimuth_bins=72, block=8, workers=0, progress=False)
    earlier = tmp_path / "earlier.zarr"
    shutil.copytree(now, earlier)
    g = zarr.open_group(str(earlier), mode="r+")
    old = g["elevation"]
    x, attrs = np.asarray(old[:]), dict(old.attrs)
    del g["elevation"]
    a = g.create_array("elevation", shape=x.shape, chunks=old.chunks, dtype="int16",
                       fill_value=old.fill_value, dimension_names=("y", "x", "azimuth"),
                       attributes=attrs, filters=[Delta(dtype="i2")],
                       compressors=[Shuffle(elementsize=2), ZstdCodec(level=9, checksum=True)])
    a[:] = x
    names = {p: [c["name"] for c in zarr.open_array(str(p / "elevation")).metadata.to_dict()["codecs"]]
             for p in (now, earlier)}
    assert names[now][0] == "transpose" and names[earlier][0] == "numcodecs.delta"
    dbs = [open_database(p) for p in (now, earlier)]
    assert all(d.is_complete for d in dbs)
    xs, ys = np.meshgrid(dbs[0].x_coords, dbs[0].y_coords)
    p = dbs[0].profiles_at(xs.ravel(), ys.ravel()).astype(float)
    q = np.roll(p[int(np.argmin((xs.ravel() - 525.0) ** 2 + (ys.ravel() - 505.0) ** 2))], -20)
    q[10:25] = np.nan
    for cfg, kw in ((MatchConfig(min_observed=10, coarse_stride=2, stride_min_coverage=0.0,
                                 keep_fraction=0.2), {}),
                    (MatchConfig(min_observed=10, coarse_stride=1, keep_fraction=0.2), {}),
                    (MatchConfig(min_observed=10, coarse_stride=2, stride_min_coverage=0.0),
                     {"prior_xy": (525.0, 505.0), "prior_radius_m": 60.0})):
        got = [match_database(d, q, cfg, **kw) for d in dbs]
        assert got[0].n_positions == got[1].n_positions > 0
        assert [(c.x, c.y, c.heading_deg, c.score) for c in got[0].candidates] == \
            [(c.x, c.y, c.heading_deg, c.score) for c in got[1].candidates]


@pytest.mark.parametrize("disc", [False, True])
def test_subgrid_coarse_pass_reaches_every_position(store, disc):
    """With every subgrid node kept, the neighbourhoods of a stride-2 coarse pass cover every
    position (inside the prior disc, when given) exactly once, and the scores are the exact ones."""
    _, st = store
    q = st.profiles_at(600.0, 500.0)[0].astype(float)
    kw = dict(prior_xy=(530.0, 650.0), prior_radius_m=95.0) if disc else {}
    exact = match_database(st, q, MatchConfig(coarse_factor=1, min_observed=10), **kw)
    sub = match_database(st, q, MatchConfig(coarse_factor=4, coarse_stride=2, keep_fraction=9.0,
                                            min_observed=10, stride_min_coverage=0.0), **kw)
    scored = np.isfinite(exact.score_map)
    assert sub.n_positions == exact.n_positions == scored.sum()
    assert sub.n_scored_exact == scored.sum()
    assert np.array_equal(np.isfinite(sub.score_map), scored)
    assert np.allclose(sub.score_map[scored], exact.score_map[scored], rtol=1e-6, atol=1e-6)


def test_score_sums_are_numpys_to_the_bit():
    """The scores' last step in one numba pass gives the floats NumPy's whole-array passes gave
    (float32 throughout, the same order; NaN carried)."""
    from skyfix.match.scores import _finish_scores

    def numpy_passes(s, corr, sq, u_q, m_obs):
        s += np.float32(sq)
        s -= 2.0 * corr[:, 0]
        for i in range(1, corr.shape[1]):
            d = corr[:, i]
            d -= np.float32(u_q[i - 1])
            d *= d
            s -= d
        np.maximum(s, 0.0, out=s)
        s /= m_obs
        return s

    rng = np.random.default_rng(7)
    for k in range(30):
        N, K, n = int(rng.integers(1, 300)), int(rng.integers(1, 6)), int(rng.choice([90, 360]))
        s = (rng.random((N, n)) * rng.uniform(0.1, 100)).astype(np.float32)
        corr = rng.normal(0, rng.uniform(0.1, 30), (N, K, n)).astype(np.float32)
        corr[0, 0, :2] = np.nan if k % 4 == 0 else corr[0, 0, :2]
        sq, u_q, m_obs = float(rng.uniform(0, 200)), rng.normal(0, 5, K - 1).astype(np.float32), int(rng.integers(20, 360))
        ref = numpy_passes(s.copy(), corr.copy(), sq, u_q, m_obs)
        got = _finish_scores(s.copy(), corr.copy(), sq, u_q, m_obs, all_shifts=True)
        assert np.array_equal(got.view(np.int32), ref.view(np.int32))


@pytest.fixture(scope="module")
def indexed_store(tmp_path_factory):
    """A zarr store with its coarse index: 25 x 25 positions at 20 m, 360 bins, 8 x 8 blocks."""
    from skyfix.database import build_database, open_database
    from skyfix.dem import write_dem

    d = tmp_path_factory.mktemp("indexed")
    dem = _bumpy_dem()
    write_dem(d / "dem.tif", dem)
    build_database(d / "dem.tif", d / "db.zarr", (340.0, 340.0, 820.0, 820.0), 20.0,
                   azimuth_bins=360, block=8, workers=0, progress=False)
    db = open_database(d / "db.zarr")
    assert db.has_coarse_index and db.n_blocks == 16
    return dem, db


@pytest.mark.parametrize("disc", [False, True])
def test_coarse_index_pass_reaches_every_position(indexed_store, disc):
    """With every node kept, the search from the coarse index scores every position (inside the
    prior disc, when given) exactly once, with the exact scores, as the pass over every block does."""
    _, db = indexed_store
    q = db.profiles_at(600.0, 500.0)[0].astype(float)
    kw = dict(prior_xy=(530.0, 650.0), prior_radius_m=95.0) if disc else {}
    exact = match_database(db, q, MatchConfig(coarse_factor=1), **kw)
    sub = match_database(db, q, MatchConfig(keep_fraction=9.0, stride_min_coverage=0.0), **kw)
    assert sub.timing["coarse_index"]
    scored = np.isfinite(exact.score_map)
    assert sub.n_positions == exact.n_positions == scored.sum()
    assert sub.n_scored_exact == scored.sum()
    assert np.array_equal(np.isfinite(sub.score_map), scored)
    # float32 FFTs in batches of other sizes: equal to ~1e-6 of scores up to 70 deg^2
    assert np.allclose(sub.score_map[scored], exact.score_map[scored], rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize("centre, radius", [((522.0, 642.0), 7.0), ((529.0, 651.0), 13.0), ((530.0, 650.0), 31.0),
                                            ((521.0, 641.0), 33.0)])
def test_a_small_prior_disc_is_searched_from_the_coarse_index(indexed_store, centre, radius):
    """Nodes kept out to the disc's radius plus a node's reach may have no position inside the
    disc beside them: with only such nodes the search failed (IndexError on an empty set), with
    some they took exact slots and scored nothing. Every position inside is scored, as by the
    exhaustive search."""
    _, db = indexed_store
    q = db.profiles_at(600.0, 500.0)[0].astype(float)
    kw = dict(prior_xy=centre, prior_radius_m=radius)
    exact = match_database(db, q, MatchConfig(coarse_factor=1), **kw)
    fast = match_database(db, q, MatchConfig(), **kw)
    assert fast.timing["coarse_index"] and fast.n_positions == exact.n_positions >= 1
    assert fast.n_scored_exact == exact.n_positions
    best = exact.candidates[0]
    assert (fast.candidates[0].x, fast.candidates[0].y) == (best.x, best.y)


def test_coarse_index_search_finds_the_exact_winner_and_reads_fewer_blocks(indexed_store):
    """Off-grid truths, 0.2 deg noise, full turns with 0-10 deg tilts: the search from the coarse
    index returns the exhaustive exact search's best position and heading, the search over
    every block likewise, and it decodes the skylines of fewer blocks than the store holds."""
    from skyfix.pose import synthetic_profile

    dem, db = indexed_store
    rng = np.random.default_rng(11)
    fast = MatchConfig(keep_fraction=0.02, keep_min=4)
    for i in range(8):
        x, y = rng.uniform(380, 780, 2)
        tilt = (10.0, 0.0) if i % 3 == 1 else (0.0, -10.0) if i % 3 == 2 else (0.0, 0.0)
        q = np.asarray(synthetic_profile(dem, x, y, rng.uniform(0, 360), *tilt, noise_deg=0.2,
                                         rng=i).elevation_deg, float)
        idx = match_database(db, q, fast)
        full = match_database(db, q, replace(fast, coarse_index=False))
        exact = match_database(db, q, MatchConfig(coarse_factor=1))
        assert idx.timing["coarse_index"] and "coarse_index" not in full.timing
        assert idx.n_positions == full.n_positions == exact.n_positions == 625
        assert idx.timing["blocks_read"] < db.n_blocks
        for got in (idx, full):
            c, e = got.candidates[0], exact.candidates[0]
            assert (c.row, c.col) == (e.row, e.col)
            assert abs(c.heading_deg - e.heading_deg) < 1e-3
            assert abs(c.score - e.score) <= 1e-4 * (1 + e.score)  # float32 FFT batches


def test_a_narrow_view_is_searched_from_the_coarse_index(indexed_store):
    """Views of 180-250 deg (under ``stride_min_coverage``, at least ``index_min_coverage``): a
    store with its coarse index serves them too, returning the exhaustive exact search's best
    position and heading while decoding fewer blocks; a 120-deg view, or a store searched
    without the index, takes stride 1 over every block, as before."""
    from skyfix.pose import synthetic_profile

    dem, db = indexed_store
    rng = np.random.default_rng(5)
    fast = MatchConfig(keep_fraction=0.02, keep_min=4)
    for i, view in enumerate((250.0, 180.0, 120.0, 250.0, 180.0, 120.0)):
        x, y = rng.uniform(380, 780, 2)
        q = np.asarray(synthetic_profile(dem, x, y, rng.uniform(0, 360), noise_deg=0.2, rng=i,
                                         coverage_deg=view).elevation_deg, float)
        assert np.isfinite(q).mean() < fast.stride_min_coverage
        idx = match_database(db, q, fast)
        full = match_database(db, q, replace(fast, coarse_index=False))
        exact = match_database(db, q, MatchConfig(coarse_factor=1))
        assert "coarse_index" not in full.timing
        if view >= 180.0:
            assert idx.timing["coarse_index"] and idx.timing["blocks_read"] < db.n_blocks
        else:
            assert "coarse_index" not in idx.timing
        for got in (idx, full):
            c, e = got.candidates[0], exact.candidates[0]
            assert (c.row, c.col) == (e.row, e.col) and abs(c.heading_deg - e.heading_deg) < 1e-3


def test_a_scattered_profile_the_exact_search_takes_is_searched_fast_too(indexed_store):
    """Every fourth bin observed (90 of 360): enough to match, but no coarse bin holds half its
    bins, and the fast search refused it ("0 observed azimuth bins", of the coarse query)."""
    _, db = indexed_store
    q0 = db.profiles_at(600.0, 500.0)[0].astype(float)
    sparse = np.full(q0.size, np.nan)
    sparse[::4] = q0[::4]
    fast = match_database(db, sparse, MatchConfig())
    exact = match_database(db, sparse, MatchConfig(coarse_factor=1))
    best = exact.candidates[0]
    assert (fast.candidates[0].x, fast.candidates[0].y) == (best.x, best.y) == (600.0, 500.0)
    with pytest.raises(ParameterError, match="one row of azimuth bins"):
        match_database(db, q0[None], MatchConfig())
