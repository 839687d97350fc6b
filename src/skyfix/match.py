"""Stage 7: match a measured skyline profile against a database of predicted skylines.

For every database position the best azimuth shift ``s`` (the heading) minimises the sum of
squared differences over the observed bins of the query, after a per-shift least-squares fit of a
nuisance model ``U`` (always a constant: camera height, partial views; optionally the first
azimuthal harmonic ``cos az, sin az``: a small residual pitch/roll shows as ``t sin(az - phi)``):

    score(s) = min_c sum_j m_j (q_j - p_{j+s} - (U c)_j)^2
             = Sq - 2 A(s) + C(s) - (u_q - v(s))^T G^-1 (u_q - v(s))

with ``A = corr(m q, p)``, ``C = corr(m, p^2)``, ``v_i = corr(m U_i, p)``, ``u_q = U^T M q`` and
``G = U^T M U`` (fixed, since the mask is on the query's bins). These are a few circular
cross-correlations per position, done with real FFTs in float32 over slices of a block, so memory
is bounded by the slice size whatever the database size.

Speed: a coarse pass on profiles averaged over ``coarse_factor`` bins (shifts every
``coarse_factor`` deg) scores every position; only the best ``keep_fraction`` of each slice is then
scored exactly at full resolution. The coarse pass is a filter, not a bound: its recall is
measured in ``benchmarks/bench_locate.py``; ``coarse_factor=1`` scores every position exactly.

World/body convention: ``world[az] = body[az - H]``, so query bin ``j`` (body) meets database bin
``j + s`` (world) and the heading is ``H = s * 360 / n``.
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from .database import Block  # one block type for stores on disk and in memory
from .errors import DatabaseError, ParameterError

#: raw value for "no skyline" in an int16 database
MISSING_RAW = -32768


@dataclass(frozen=True)
class MatchConfig:
    """How to match.

    remove_tilt : also fit the first azimuthal harmonic (small pitch/roll errors)
    coarse_factor : bins averaged in the coarse pre-pass (1 = exact scoring everywhere)
    keep_fraction : share of each slice's positions scored exactly after the coarse pass
    keep_min : at least this many per slice are scored exactly
    top_k : candidates returned, in distinct basins
    nms_radius_m : [m] two candidates are at least this far apart
    slice_rows : positions processed at once (memory ~ slice_rows * bins * 40 bytes)
    workers : threads (scipy.fft, BLAS; one goes to the block reader when prefetching)
    prefetch : read and decompress the next blocks in a thread while scoring
    min_observed : refuse queries with fewer observed bins than this
    """

    remove_tilt: bool = True
    coarse_factor: int = 4
    keep_fraction: float = 0.03
    keep_min: int = 16
    top_k: int = 8
    nms_radius_m: float = 40.0
    slice_rows: int = 2048
    workers: int = 2
    min_observed: int = 20
    prefetch: bool = True


PRESETS = {
    "exact": MatchConfig(coarse_factor=1),
    "fast": MatchConfig(),
    "level": MatchConfig(remove_tilt=False),
}


@dataclass
class Query:
    """A prepared query: kernels in the frequency domain for one bin count.

    n : bins; mask : observed bins; m_obs : count; full : every bin observed
    """

    n: int
    q: np.ndarray
    mask: np.ndarray
    m_obs: int
    full: bool
    sq: float
    u_q: np.ndarray  # whitened: (L^T U)^T M q with G^-1 = L L^T
    g_inv: np.ndarray
    k_p: np.ndarray  # (n_kernels, n//2+1) conj spectra correlated with p: [m q, m U_0, m U_1, ...]
    k_p2: np.ndarray | None  # conj spectrum of m, correlated with p^2 (None when full)
    kernels: np.ndarray | None = None  # float64 (n_kernels, n) the same kernels in the bin domain


def _basis(n: int, remove_tilt: bool) -> np.ndarray:
    az = np.radians(np.arange(n) * 360.0 / n)
    cols = [np.ones(n)]
    if remove_tilt:
        cols += [np.cos(az), np.sin(az)]
    return np.stack(cols, axis=1)


def prepare_query(elevation_deg, remove_tilt: bool = True, min_observed: int = 20) -> Query:
    """Kernels for :func:`score_profiles` from a body-frame profile [deg] (NaN = unobserved)."""
    import scipy.fft as sf

    q = np.asarray(elevation_deg, np.float64)
    n = q.size
    mask = np.isfinite(q)
    m_obs = int(mask.sum())
    u = _basis(n, remove_tilt)
    need = max(min_observed, u.shape[1] + 2)
    if m_obs < need:
        raise ParameterError(
            f"the profile has {m_obs} observed azimuth bins; at least {need} are needed to match "
            "(a wider view or more frames)")
    m = mask.astype(np.float64)
    qz = np.where(mask, q, 0.0)
    # Centre q over its observed bins: the constant is fitted anyway and this keeps float32 sums small.
    qz = np.where(mask, qz - qz[mask].mean(), 0.0)
    g = u.T @ (m[:, None] * u)
    try:
        g_inv = np.linalg.inv(g)
    except np.linalg.LinAlgError:
        raise ParameterError("observed bins too few or too clustered to fit the tilt harmonic; "
                             "match with remove_tilt=False") from None
    if np.linalg.cond(g) > 1e6:
        raise ParameterError("observed bins too clustered to fit the tilt harmonic; "
                             "match with remove_tilt=False")
    # Whiten the nuisance kernels with G^-1 = L L^T: the quadratic form becomes a sum of squares.
    chol = np.linalg.cholesky(g_inv)
    uw = u @ chol
    kernels = [m * qz] + [m * uw[:, i] for i in range(u.shape[1])]
    full = bool(mask.all())
    k_p = np.conj(sf.rfft(np.stack(kernels), axis=1)).astype(np.complex64)
    k_p2 = None if full else np.conj(sf.rfft(m)).astype(np.complex64)
    return Query(n, np.where(mask, q, np.nan), mask, m_obs, full, float(np.sum(qz * qz)),
                 uw.T @ (m * qz), g_inv, k_p, k_p2, np.stack(kernels))


@dataclass
class DenseQuery:
    """A query as circulant matrices: every shift's correlations in one matrix product.

    k_lin : float32 (n, n_kernels * n), column ``i * n + s`` correlates kernel i at shift s
    k_sq : float32 (n, n) circulant of the mask, applied to p^2 (None when every bin is observed)
    """

    n: int
    m_obs: int
    sq: float
    u_q: np.ndarray
    k_lin: np.ndarray
    k_sq: np.ndarray | None


def dense_query(query: Query) -> DenseQuery:
    """Circulant form of a prepared query for :func:`score_dense` (cheap for small n, e.g. 90)."""
    n = query.n
    # corr(k, p)(s) = sum_l p_l k_{l-s}: column s of the circulant holds k rolled by s.
    idx = (np.arange(n)[:, None] - np.arange(n)[None, :]) % n
    kern = query.kernels
    k_lin = np.ascontiguousarray(kern[:, idx].transpose(1, 0, 2).reshape(n, -1), np.float32)
    k_sq = None if query.full else np.ascontiguousarray(query.mask.astype(np.float32)[idx])
    return DenseQuery(n, query.m_obs, query.sq, np.asarray(query.u_q, np.float32), k_lin, k_sq)


def score_dense(p: np.ndarray, dq: DenseQuery, all_shifts: bool = False):
    """As :func:`score_profiles` (same scores, same return values) by matrix products.

    For short profiles (the coarse pass, n = 90) BLAS beats small FFTs by an order of magnitude:
    ``N x n x (n_kernels + 1) n`` multiply-adds, streamed at full sgemm speed.
    p : float32 (N, n) [deg]
    """
    n = dq.n
    p = np.asarray(p, np.float32)
    if p.ndim != 2 or p.shape[1] != n:
        raise ParameterError(f"profiles have shape {p.shape}, expected (N, {n})")
    p = p - p.mean(axis=1, keepdims=True)
    corr = (p @ dq.k_lin).reshape(p.shape[0], -1, n)
    p *= p
    if dq.k_sq is None:
        s = np.sum(p, axis=1, keepdims=True) + np.zeros((1, n), np.float32)
    else:
        s = p @ dq.k_sq
    del p
    return _finish_scores(s, corr, dq.sq, dq.u_q, dq.m_obs, all_shifts)


def _finish_scores(s, corr, sq, u_q, m_obs, all_shifts):
    n = s.shape[1]
    s += np.float32(sq)
    s -= 2.0 * corr[:, 0]
    for i in range(1, corr.shape[1]):
        d = corr[:, i]
        d -= np.float32(u_q[i - 1])
        d *= d
        s -= d
    np.maximum(s, 0.0, out=s)
    s /= m_obs
    if all_shifts:
        return s
    k = np.argmin(s, axis=1)
    rows = np.arange(s.shape[0])
    s0 = s[rows, k]
    sm = s[rows, (k - 1) % n]
    sp = s[rows, (k + 1) % n]
    den = sm - 2 * s0 + sp
    off = np.where(den > 1e-12, 0.5 * (sm - sp) / np.where(den > 1e-12, den, 1.0), 0.0)
    off = np.clip(off, -0.5, 0.5)
    best = s0 - 0.25 * (sm - sp) * off
    return np.maximum(best, 0.0).astype(np.float32), ((k + off) % n).astype(np.float32)


def score_profiles(p: np.ndarray, query: Query, workers: int = 2, all_shifts: bool = False):
    """Best shift and score for each database profile.

    p : float32 (N, n) [deg] predicted skylines in the world frame (no NaN)
    Returns ``(score, shift)``: score float32 (N,) = mean squared residual over observed bins
    [deg^2] at the best shift; shift float32 (N,) [bins], sub-bin by a parabola through the
    three scores around the best integer shift. With ``all_shifts`` returns the (N, n) scores.
    """
    import scipy.fft as sf

    n = query.n
    p = np.asarray(p, np.float32)
    if p.ndim != 2 or p.shape[1] != n:
        raise ParameterError(f"profiles have shape {p.shape}, expected (N, {n})")
    p = p - p.mean(axis=1, keepdims=True)
    spec = sf.rfft(p, axis=1, workers=workers)
    corr = sf.irfft(spec[:, None, :] * query.k_p[None], n=n, axis=2, workers=workers)
    del spec
    if query.full:
        s = np.sum(p * p, axis=1, keepdims=True) + np.zeros((1, n), np.float32)
    else:
        s = sf.irfft(sf.rfft(p * p, axis=1, workers=workers) * query.k_p2[None], n=n, axis=1,
                     workers=workers)
    return _finish_scores(s, corr, query.sq, query.u_q, query.m_obs, all_shifts)


def brute_force_scores(p: np.ndarray, q: np.ndarray, remove_tilt: bool = True) -> np.ndarray:
    """Reference: (N, n) scores by explicit loops over shifts and a least-squares fit each time.

    Slow and obvious; tests compare :func:`score_profiles` with it.
    """
    p = np.asarray(p, np.float64)
    q = np.asarray(q, np.float64)
    n = q.size
    mask = np.isfinite(q)
    u = _basis(n, remove_tilt)[mask]
    out = np.empty((p.shape[0], n))
    for i in range(p.shape[0]):
        for s in range(n):
            shifted = np.roll(p[i], -s)  # shifted[j] = p[j + s]
            r = q[mask] - shifted[mask]
            coef, *_ = np.linalg.lstsq(u, r, rcond=None)
            out[i, s] = np.sum((r - u @ coef) ** 2) / mask.sum()
    return out


def decimate_query(q: np.ndarray, factor: int) -> np.ndarray:
    """Average groups of ``factor`` bins [deg]; a coarse bin is observed if half its bins are."""
    n = q.size
    g = q.reshape(n // factor, factor)
    fin = np.isfinite(g)
    cnt = fin.sum(axis=1)
    with np.errstate(invalid="ignore"):
        mean = np.where(fin, g, 0.0).sum(axis=1) / np.maximum(cnt, 1)
    return np.where(cnt * 2 >= factor, mean, np.nan)


# --- an in-memory store with the database's block interface ---------------------------------------


@dataclass
class MemoryStore:
    """A skyline store in memory with the read API of ``skyfix.database`` (tests, small areas).

    elevation : (ny, nx, bins) float [deg] over a north-up grid; stored as int16 of ``scale_deg``.
    """

    x_coords: np.ndarray
    y_coords: np.ndarray
    raw: np.ndarray
    scale_deg: float = 0.01
    block: int = 64
    missing: int = MISSING_RAW
    camera_height_m: float = 1.5
    planet: str = "earth"
    crs_wkt: str = ""
    attrs: dict = field(default_factory=dict)

    @classmethod
    def from_dem(cls, dem, x_coords, y_coords, *, camera_height_m=1.5, planet="earth",
                 azimuth_bins=360, block=64, scale_deg=0.01):
        """Render the skylines of a grid (x ascending, y descending) from a DEM."""
        from .horizon import render_horizons

        xx, yy = np.meshgrid(np.asarray(x_coords, float), np.asarray(y_coords, float))
        hb = render_horizons(dem, xx.ravel(), yy.ravel(), camera_height_m=camera_height_m,
                             planet=planet, azimuth_bins=azimuth_bins)
        el = hb.elevation_deg.reshape(len(y_coords), len(x_coords), azimuth_bins)
        return cls.from_elevation(x_coords, y_coords, el, scale_deg=scale_deg, block=block,
                                  camera_height_m=camera_height_m, planet=str(planet),
                                  crs_wkt=dem.crs_wkt)

    @classmethod
    def from_elevation(cls, x_coords, y_coords, elevation_deg, *, scale_deg=0.01, block=64, **kw):
        el = np.asarray(elevation_deg, np.float64)
        raw = np.where(np.isfinite(el), np.round(np.nan_to_num(el) / scale_deg), MISSING_RAW)
        return cls(np.asarray(x_coords, float), np.asarray(y_coords, float),
                   raw.astype(np.int16), scale_deg, block, **kw)

    @property
    def shape(self):
        return self.raw.shape[:2]

    @property
    def azimuth_bins(self):
        return self.raw.shape[2]

    @property
    def spacing_m(self):
        return float(abs(self.x_coords[1] - self.x_coords[0])) if self.x_coords.size > 1 else 1.0

    def iter_blocks(self):
        ny, nx = self.shape
        for r0 in range(0, ny, self.block):
            for c0 in range(0, nx, self.block):
                r1, c1 = min(ny, r0 + self.block), min(nx, c0 + self.block)
                xx, yy = np.meshgrid(self.x_coords[c0:c1], self.y_coords[r0:r1])
                yield Block(r0, c0, r1 - r0, c1 - c0, xx.ravel(), yy.ravel(),
                            self.raw[r0:r1, c0:c1].reshape(-1, self.azimuth_bins))

    def index_of(self, x, y):
        return _grid_index(self, x, y)

    def xy_of(self, row, col):
        return self.x_coords[col], self.y_coords[row]

    def profiles_at(self, x, y):
        r, c = self.index_of(x, y)
        raw = self.raw[np.atleast_1d(r), np.atleast_1d(c)]
        return np.where(raw == self.missing, np.nan, raw * self.scale_deg).astype(np.float32)


def _grid_index(db, x, y):
    xc, yc = np.asarray(db.x_coords), np.asarray(db.y_coords)
    dx = xc[1] - xc[0] if xc.size > 1 else 1.0
    dy = yc[1] - yc[0] if yc.size > 1 else -1.0
    col = np.rint((np.asarray(x, float) - xc[0]) / dx).astype(np.int64)
    row = np.rint((np.asarray(y, float) - yc[0]) / dy).astype(np.int64)
    return row, col


# --- the streaming search -------------------------------------------------------------------------

@dataclass(frozen=True)
class Candidate:
    """One match: position [m], heading [deg], score = mean squared residual [deg^2]."""

    x: float
    y: float
    heading_deg: float
    score: float
    row: int = -1
    col: int = -1

    def to_dict(self) -> dict:
        return {"x": self.x, "y": self.y, "heading_deg": self.heading_deg, "score": self.score}


@dataclass
class MatchResult:
    """Candidates (best first, distinct basins) and the maps behind them.

    score_map : float32 (ny, nx) [deg^2] exact score where scored, NaN elsewhere
    heading_map : float32 (ny, nx) [deg]
    coarse_map : float32 (ny, nx) coarse-pass score (NaN outside the searched area)
    n_scored_exact, n_positions : counts; timing : seconds per phase
    """

    candidates: list
    score_map: np.ndarray
    heading_map: np.ndarray
    coarse_map: np.ndarray | None
    n_positions: int
    n_scored_exact: int
    timing: dict


def _to_float(raw: np.ndarray, scale: float, missing: int) -> np.ndarray:
    if raw.dtype == np.int16:
        p = raw.astype(np.float32)
        bad = raw == missing
        if bad.any():
            # No terrain along the ray (DEM edge): a flat horizon is the least-committal guess.
            p[bad] = 0.0
        p *= np.float32(scale)
        return p
    p = np.asarray(raw, np.float32)
    return np.where(np.isfinite(p), p, np.float32(0.0))


def _coarse_profiles(raw: np.ndarray, f: int, scale: float, missing: int) -> np.ndarray:
    """float32 (N, n / f) [deg]: groups of ``f`` bins averaged, straight from the int16 store."""
    if raw.dtype == np.int16 and not (raw == missing).any():
        # Strided adds into one float32 array: no full-resolution float copy of the block.
        pc = raw[:, 0::f].astype(np.float32)
        for k in range(1, f):
            pc += raw[:, k::f]
        pc *= np.float32(scale / f)
        return pc
    p = _to_float(raw, scale, missing)
    return p.reshape(p.shape[0], -1, f).mean(axis=2)


def _prefetch(blocks, depth: int = 2):
    """Yield ``blocks`` while a thread reads ahead: decompression (zstd, GIL released) overlaps
    the scoring. Also yields the reader thread's CPU time [s] for each block."""
    import queue
    import threading
    import time

    box: queue.Queue = queue.Queue(depth)
    stop = threading.Event()

    def put(item):
        while not stop.is_set():
            try:
                box.put(item, timeout=0.1)
                return True
            except queue.Full:
                pass
        return False

    def run():
        try:
            it = iter(blocks)
            while True:
                t = time.thread_time()
                try:
                    b = next(it)
                except StopIteration:
                    break
                if not put(("block", b, time.thread_time() - t)):
                    return
            put(("end", None, 0.0))
        except BaseException as e:  # handed to the consumer, raised there
            put(("error", e, 0.0))

    th = threading.Thread(target=run, name="skyfix-block-reader", daemon=True)
    th.start()
    try:
        while True:
            kind, v, dt = box.get()
            if kind == "end":
                return
            if kind == "error":
                raise v
            yield v, dt
    finally:
        stop.set()


def _elevation_blocks(db):
    """Blocks with only what the matcher needs.

    For a complete ``skyfix.database`` store, the elevation chunks alone (``read_raw``):
    ``iter_blocks`` also decodes ground height, ray length and edge bins, ~35 % of the read time for
    data the search does not use. Other stores (and incomplete ones): their ``iter_blocks``. Either
    way a block whose chunk file is gone or undecodable raises a DatabaseError naming it (zarr would
    quietly hand back fill values, and the search a confident wrong fix).
    """
    grid = getattr(db, "grid", None)
    if grid is None or not hasattr(db, "read_raw") or not getattr(db, "is_complete", False):
        yield from db.iter_blocks()
        return
    for br, bc in grid.blocks():
        rs, cs = grid.block_slices(br, bc)
        x, y = grid.block_xy(br, bc)
        raw = db.read_raw("elevation", br, bc).reshape((rs.stop - rs.start) * (cs.stop - cs.start), -1)
        yield Block(rs.start, cs.start, rs.stop - rs.start, cs.stop - cs.start, x, y, raw)


def match_database(db, query_deg, config: MatchConfig = MatchConfig(), *, prior_xy=None,
                   prior_radius_m=None) -> MatchResult:
    """Search a store (``iter_blocks()`` with int16 or float blocks) for a body-frame profile.

    query_deg : (n,) [deg] body-frame elevations, NaN where unobserved; n must equal the store's bins
    prior_xy, prior_radius_m : [m] restrict the search to a disc (positions outside are skipped)

    The coarse pass scores every position at ``n / coarse_factor`` bins by matrix products
    (:func:`score_dense`); the best ``keep_fraction`` of each slice is scored exactly by FFT
    (:func:`score_profiles`). Blocks are read ahead in a thread (``config.prefetch``).
    """
    import time

    q = np.asarray(query_deg, np.float64)
    n = int(db.azimuth_bins)
    if q.size != n:
        raise ParameterError(f"the profile has {q.size} azimuth bins but the database {n}; "
                             "resample the profile to the database's bins")
    f = int(config.coarse_factor)
    if f < 1 or n % f:
        raise ParameterError(f"coarse_factor {f} must divide the {n} azimuth bins")
    query = prepare_query(q, config.remove_tilt, config.min_observed)
    coarse_q = dense_query(prepare_query(decimate_query(q, f), config.remove_tilt,
                                         max(4, config.min_observed // f))) if f > 1 else None
    ny, nx = (int(v) for v in db.shape)
    score_map = np.full((ny, nx), np.nan, np.float32)
    heading_map = np.full((ny, nx), np.nan, np.float32)
    coarse_map = np.full((ny, nx), np.nan, np.float32) if f > 1 else None
    scale = float(getattr(db, "scale_deg", 1.0))
    missing = int(getattr(db, "missing", MISSING_RAW))
    t_read = t_reader = t_coarse = t_exact = 0.0
    n_pos = n_exact = 0
    pend: list = []
    pend_n = 0

    def flush():
        nonlocal pend, pend_n
        if not pend:
            return 0
        raw_ = np.concatenate([a for a, _, _ in pend])
        r_ = np.concatenate([b for _, b, _ in pend])
        c_ = np.concatenate([c for _, _, c in pend])
        pend, pend_n = [], 0
        es, sh = score_profiles(_to_float(raw_, scale, missing), query, config.workers)
        score_map[r_, c_] = es
        heading_map[r_, c_] = sh * (360.0 / n)
        return raw_.shape[0]

    blocks = _elevation_blocks(db)
    blocks = _prefetch(blocks) if config.prefetch else ((b, 0.0) for b in blocks)
    with _blas_threads(max(1, config.workers - 1) if config.prefetch else config.workers):
        t0 = time.perf_counter()
        cpu0 = time.thread_time()
        for blk, dt in blocks:
            t1 = time.perf_counter()
            t_read += t1 - t0
            t_reader += dt
            bx, by = np.asarray(blk.x, float), np.asarray(blk.y, float)
            sel = None
            if prior_xy is not None and prior_radius_m is not None:
                d2 = (bx - prior_xy[0]) ** 2 + (by - prior_xy[1]) ** 2
                sel = np.flatnonzero(d2 <= prior_radius_m ** 2)
                if sel.size == 0:
                    t0 = time.perf_counter()
                    continue
            rr, cc = _grid_index(db, bx, by)
            elev = np.asarray(blk.elevation)
            idx_all = np.arange(bx.size) if sel is None else sel
            for s0 in range(0, idx_all.size, config.slice_rows):
                idx = idx_all[s0:s0 + config.slice_rows]
                ta = time.perf_counter()
                raw = elev[s0:s0 + idx.size] if sel is None else elev[idx]
                n_pos += idx.size
                if coarse_q is not None:
                    cs, _ = score_dense(_coarse_profiles(raw, f, scale, missing), coarse_q)
                    coarse_map[rr[idx], cc[idx]] = cs
                    keep = max(config.keep_min, int(math.ceil(config.keep_fraction * idx.size)))
                    part = np.argpartition(cs, keep - 1)[:keep] if keep < idx.size else \
                        np.arange(idx.size)
                    t_coarse += time.perf_counter() - ta
                    # Survivors are few per slice: batch them, FFT calls cost ~100 us each.
                    pend.append((raw[part], rr[idx[part]], cc[idx[part]]))
                    pend_n += part.size
                else:
                    pend.append((raw, rr[idx], cc[idx]))
                    pend_n += idx.size
                if pend_n >= config.slice_rows:
                    tb = time.perf_counter()
                    n_exact += flush()
                    t_exact += time.perf_counter() - tb
            t0 = time.perf_counter()
        tb = time.perf_counter()
        t_read += tb - t0
        n_exact += flush()
        t_exact += time.perf_counter() - tb
        cpu_main = time.thread_time() - cpu0  # BLAS/FFT helper threads not included
    if n_pos == 0:
        raise DatabaseError("no database position lies inside the prior area: check --prior-x/"
                            "--prior-y/--prior-radius-m against the database extent")
    tn = time.perf_counter()
    cands = _nms(score_map, heading_map, db, config.top_k, config.nms_radius_m)
    timing = {"read_s": t_read, "reader_cpu_s": t_reader, "main_cpu_s": cpu_main,
              "coarse_s": t_coarse, "exact_s": t_exact, "nms_s": time.perf_counter() - tn}
    return MatchResult(cands, score_map, heading_map, coarse_map, n_pos, n_exact, timing)


@contextmanager
def _blas_threads(n: int):
    """Limit BLAS threads (the reader thread takes a core; oversubscription costs more than it gives)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # optional: without it BLAS uses its default
        yield
        return
    with threadpool_limits(limits=n, user_api="blas"):
        yield


def _nms(score_map, heading_map, db, k: int, radius_m: float) -> list:
    """The k best local minima at least ``radius_m`` apart (greedy suppression)."""
    spacing = float(db.spacing_m)
    rad = max(1, int(math.ceil(radius_m / spacing)))
    flat = np.where(np.isfinite(score_map), score_map, np.inf).ravel()
    finite = np.flatnonzero(np.isfinite(flat))
    order = finite[np.argsort(flat[finite], kind="stable")]
    ny, nx = score_map.shape
    taken: list = []
    xs, ys = np.asarray(db.x_coords), np.asarray(db.y_coords)
    for i in order:
        r, c = divmod(int(i), nx)
        if any(abs(r - r2) <= rad and abs(c - c2) <= rad for r2, c2 in taken):
            continue
        taken.append((r, c))
        if len(taken) >= k:
            break
    return [Candidate(float(xs[c]), float(ys[r]), float(heading_map[r, c]) % 360.0,
                      float(score_map[r, c]), r, c) for r, c in taken]
