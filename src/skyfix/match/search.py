"""The streaming search: every position of a database (or in-memory store) against the query,
slice by slice, keeping the best candidates at least a suppression radius apart (greedy:
a candidate may lie on the flank of a better one's basin, just outside its radius; the
refinement on the DEM then joins them).

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
A store that holds its coarse index (``skyfix.database``) is searched by :mod:`.indexed`: the
coarse pass reads the index instead of every skyline, keeps the best of the whole store rather
than of each slice, and only the blocks holding a survivor are decoded.

World/body convention: ``world[az] = body[az - H]``, so query bin ``j`` (body) meets database bin
``j + s`` (world) and the heading is ``H = s * 360 / n``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from ..database import Block
from ..database.layout import COARSE_FACTOR, COARSE_STRIDE, MIN_SEARCH_BINS
from ..errors import DatabaseError, ParameterError
from .memory import MISSING_RAW, grid_index
from .indexed import indexed_search
from .passes import EXACT_BATCH, ExactPass, read_blocks, scoring_threads, to_float
from .scores import decimate_query, dense_query, prepare_query, score_dense


@dataclass(frozen=True)
class MatchConfig:
    """How to match.

    remove_tilt : also fit the first azimuthal harmonic (small pitch/roll errors)
    coarse_factor : bins averaged in the coarse pre-pass (1 = exact scoring everywhere); for a
        store whose bins it does not divide, the largest factor below it that does
    keep_fraction : share of each slice's positions scored exactly after the coarse pass (from
        the coarse index, of the store's, a node counted as its 3 x 3 neighbourhood: those
        overlap, so about 85 % of it is scored)
    keep_min : at least this many per slice (from the coarse index, in all; every position of a
        smaller prior disc) are scored exactly
    coarse_stride : the coarse pass scores every ``coarse_stride``-th position along rows and
        columns only; each survivor's neighbours within ``coarse_stride - 1`` positions are then
        scored exactly (1 = every position in the coarse pass). Measured on the 7 x 7 km Sierra
        database at 5 m (60 queries rendered at random off-grid positions, half from a world
        with map errors, 0.1 deg noise, pitch and roll N(0, 3 deg)): with 2, the 40 full turns
        gave the same best position as with 1, at 2.8 instead of 5.2 s of CPU; of the 20
        120-deg views, 3 changed and 2 of those lost the true basin (the coarse score of a
        narrow view is rougher from one grid step to the next; ``benchmarks/bench_search_recall.py``).
        Hence ``stride_min_coverage``. End to end (``skyfix locate`` with ``--dem`` on the 40
        scenario-1 cases of ``skyfix evaluate --sets DEMERR,REF --cases 20 --seed 41``, stride 2
        against 1): the same position in 39 of 40; one DEMERR miss at confidence 0.15 went to
        another wrong basin (40 -> 143 m, 0.14); the confidence changed in 12 (the runner-up
        basins differ): REF by <= 0.001, DEMERR by -0.17 to +0.01 (a right fix 0.77 -> 0.60);
        tallies the same (REF 20/20 within 5 m, all at >= 0.9; DEMERR 8/20, none at >= 0.9).
        The confidence model was fitted on stride-1 searches
    stride_min_coverage : the share of the azimuth bins the query must observe for the coarse
        stride to apply over every block; a narrower view is searched with stride 1, unless the
        store's coarse index serves it (``index_min_coverage``)
    index_min_coverage : the share of the bins a view under ``stride_min_coverage`` must
        observe to be searched from the store's coarse index (the best survivors of the whole
        store rather than of each slice) instead of with stride 1 over every block. Measured
        (2026-11-28, the 7 x 7 km Sierra store in UTM 11N, views half from a world with map
        errors, 0.1 deg noise, pitch and roll N(0, 3 deg), ``bench_search_recall.py --views
        250,180,120``, seeds 11 and 12): the index found stride 1's best position in every
        250- and 180-deg view (20 and 20), CPU median 1.8 and 2.2-2.3 s against 6.6-6.9 s (50-300
        of 484 blocks decoded against all); of the 20 120-deg views 3 moved, 2 of them out of the
        true basin (10 -> 24 m), with 3 %, 10 % or 20 % of the store kept alike. Hence 0.5: a
        120-deg view keeps stride 1
    top_k : candidates returned, at least the suppression radius apart
    nms_radius_m : [m] two candidates are at least this far apart
    slice_rows : positions processed at once (memory ~ slice_rows * bins * 40 bytes)
    workers : threads (BLAS; one goes to the block reader when prefetching)
    prefetch : read and decompress the next blocks in a thread while scoring
    coarse_index : where the store holds its coarse index (``skyfix.database``: every second
        position, four bins averaged) and the search uses stride 2 and factor 4, take the coarse
        pass from it and keep the best survivors of the whole store, not of each slice: only the
        blocks holding one are then decoded (False: every block decoded, survivors per slice)
    min_observed : refuse queries with fewer observed bins than this
    """

    remove_tilt: bool = True
    coarse_factor: int = 4
    keep_fraction: float = 0.03
    keep_min: int = 16
    coarse_stride: int = 2
    stride_min_coverage: float = 0.75
    index_min_coverage: float = 0.5
    top_k: int = 8
    nms_radius_m: float = 40.0
    slice_rows: int = 2048
    workers: int = 2
    min_observed: int = MIN_SEARCH_BINS
    prefetch: bool = True
    coarse_index: bool = True


PRESETS = {
    "exact": MatchConfig(coarse_factor=1),
    "fast": MatchConfig(),
    "level": MatchConfig(remove_tilt=False),
}


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
    """Candidates (best first, at least the suppression radius apart) and the exact scores
    behind them.

    rows, cols : int (m,) grid positions scored exactly; scores : float32 (m,) [deg^2] their exact
    score; headings : float32 (m,) [deg] their best heading. Only the positions the coarse pass
    kept are held (about 2.5 % of a database): the full (ny, nx) maps are :attr:`score_map` and
    :attr:`heading_map`, built when asked for (two 7.9 MB arrays on the 7 x 7 km database at 5 m
    that a rover's search does not need).
    shape : (ny, nx); n_scored_exact, n_positions : counts; timing : seconds per phase
    """

    candidates: list
    rows: np.ndarray
    cols: np.ndarray
    scores: np.ndarray
    headings: np.ndarray
    shape: tuple
    n_positions: int
    n_scored_exact: int
    timing: dict

    def _dense(self, values) -> np.ndarray:
        out = np.full(self.shape, np.nan, np.float32)
        out[self.rows, self.cols] = values
        return out

    @property
    def score_map(self) -> np.ndarray:
        """float32 (ny, nx) [deg^2]: the exact score where scored, NaN elsewhere."""
        return self._dense(self.scores)

    @property
    def heading_map(self) -> np.ndarray:
        """float32 (ny, nx) [deg]: the best heading where scored, NaN elsewhere."""
        return self._dense(self.headings)


def _coarse_profiles(elev: np.ndarray, rows: np.ndarray, f: int, scale: float,
                     missing: int) -> np.ndarray:
    """float32 (N, n / f) [deg]: groups of ``f`` bins averaged for the positions ``rows`` of a
    block's (positions, n) skylines, straight from the int16 store."""
    by_bin = elev.T
    if by_bin.flags.c_contiguous:
        # A chunk stored (azimuth, position) and read as a view (database/chunks.py): gathering
        # positions along each azimuth's row reads memory in order; gathering whole skylines
        # would read one value per cache line (the coarse pass took 1.6 s instead of 1.0).
        raw_t = np.take(by_bin, rows, axis=1)  # 5x faster than by_bin[:, rows] here
    else:
        raw_t = elev[rows].T
    if raw_t.dtype == np.int16 and not (raw_t == missing).any():
        # Strided adds into one float32 array: no full-resolution float copy of the block.
        pc = raw_t[0::f].astype(np.float32)
        for k in range(1, f):
            pc += raw_t[k::f]
        pc *= np.float32(scale / f)
        return np.ascontiguousarray(pc.T)  # no copy unless the chunk was stored transposed
    p = to_float(np.ascontiguousarray(raw_t.T), scale, missing)
    return p.reshape(p.shape[0], -1, f).mean(axis=2)


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
    if q.ndim != 1:  # a (1, n) array passed the size check and failed deep in numpy
        raise ParameterError(f"the profile must be one row of azimuth bins, got an array of shape "
                             f"{q.shape}")
    if q.size != n:
        raise ParameterError(f"the profile has {q.size} azimuth bins but the database {n}; "
                             f"make it with `skyfix profile --azimuth-bins {n}`")
    f = int(config.coarse_factor)
    if f < 1:
        raise ParameterError(f"coarse_factor must be >= 1, got {f}")
    # a store of 90 bins is as searchable as one of 360: its coarse pass averages 3 bins, not 4
    f = max(k for k in range(1, f + 1) if n % k == 0)
    stride = int(config.coarse_stride)
    if stride < 1:
        raise ParameterError(f"coarse_stride must be >= 1, got {config.coarse_stride}")
    indexed = (config.coarse_index and stride == COARSE_STRIDE and f == COARSE_FACTOR
               and getattr(db, "has_coarse_index", False))
    coverage = np.isfinite(q).mean()
    if coverage < config.stride_min_coverage and not (indexed and
                                                      coverage >= config.index_min_coverage):
        stride = 1
        indexed = False
    query = prepare_query(q, config.remove_tilt, config.min_observed)
    coarse_q = None
    if f > 1:
        try:
            coarse_q = dense_query(prepare_query(decimate_query(q, f), config.remove_tilt,
                                                 max(4, config.min_observed // f)))
        except ParameterError:
            # observed bins too scattered for the coarse bins (one in four: none has half its
            # bins), though enough to match: every position is scored exactly instead
            f, indexed, stride = 1, False, 1
            logging.getLogger("skyfix.match").info(
                "the profile's observed bins are too scattered for the coarse pass: every "
                "position is scored exactly (tens of times the usual search's work)")
    scale = float(getattr(db, "scale_deg", 1.0))
    missing = int(getattr(db, "missing", MISSING_RAW))
    exact = ExactPass(query, scale, missing, n, min(config.slice_rows, EXACT_BATCH))
    if indexed and coarse_q is not None:
        n_pos, timing = indexed_search(db, coarse_q, exact, config, prior_xy, prior_radius_m)
        return _result(db, exact, n_pos, timing, config)
    t_read = t_reader = t_coarse = 0.0
    n_pos = 0
    push = exact.push

    blocks = read_blocks(_elevation_blocks(db), config)
    with scoring_threads(config):
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
            rr, cc = grid_index(db, bx, by)
            elev = np.asarray(blk.elevation)
            if coarse_q is not None and stride > 1:
                ta = time.perf_counter()
                idx, n_here = _subgrid_survivors(elev, rr, cc, sel, stride, coarse_q, f, scale,
                                                 missing, config)
                n_pos += n_here
                t_coarse += time.perf_counter() - ta
                for s0 in range(0, idx.size, EXACT_BATCH):
                    part = idx[s0:s0 + EXACT_BATCH]
                    push(elev[part], rr[part], cc[part])
                t0 = time.perf_counter()
                continue
            idx_all = np.arange(bx.size) if sel is None else sel
            for s0 in range(0, idx_all.size, config.slice_rows):
                idx = idx_all[s0:s0 + config.slice_rows]
                ta = time.perf_counter()
                n_pos += idx.size
                if coarse_q is not None:
                    cs, _ = score_dense(_coarse_profiles(elev, idx, f, scale, missing), coarse_q)
                    keep = max(config.keep_min, int(math.ceil(config.keep_fraction * idx.size)))
                    part = np.argpartition(cs, keep - 1)[:keep] if keep < idx.size else \
                        np.arange(idx.size)
                    t_coarse += time.perf_counter() - ta
                    # Survivors are few per slice: batch them, FFT calls cost ~100 us each.
                    push(elev[idx[part]], rr[idx[part]], cc[idx[part]])
                else:
                    push(elev[s0:s0 + idx.size] if sel is None else elev[idx], rr[idx], cc[idx])
            t0 = time.perf_counter()
        t_read += time.perf_counter() - t0
        exact.flush()
        cpu_main = time.thread_time() - cpu0  # BLAS/FFT helper threads not included
    timing = {"read_s": t_read, "reader_cpu_s": t_reader, "main_cpu_s": cpu_main,
              "coarse_s": t_coarse}
    return _result(db, exact, n_pos, timing, config)


def _result(db, exact: "ExactPass", n_pos: int, timing: dict, config: MatchConfig) -> MatchResult:
    """The candidates, at least the suppression radius apart, from the exactly scored positions."""
    import time

    if n_pos == 0:
        raise DatabaseError("no database position lies inside the prior area: check --prior-x/"
                            "--prior-y/--prior-radius-m against the database extent")
    tn = time.perf_counter()
    rows, cols, scores, heads = exact.results()
    cands = _nms(rows, cols, scores, heads, db, config.top_k, config.nms_radius_m)
    timing = {**timing, "exact_s": exact.seconds, "nms_s": time.perf_counter() - tn}
    ny, nx = (int(v) for v in db.shape)
    return MatchResult(cands, rows, cols, scores, heads, (ny, nx), n_pos, exact.n_scored, timing)


def _subgrid_survivors(elev, rr, cc, sel, stride, coarse_q, f, scale, missing, config):
    """The coarse pass on every ``stride``-th grid row and column of a block, then the
    neighbourhood (``stride - 1`` positions each way) of each survivor.

    Skylines change little over one grid step except right beside steep near terrain, so a
    neighbour of the true position that survives the coarse filter brings the true position to
    the exact pass. The share kept (and ``keep_min``) is that of the block's positions, expressed
    in subgrid nodes: each survivor brings up to ``(2 stride - 1)^2`` positions.
    Returns (indices into the block to score exactly, positions the block holds in the search).
    """
    on = (rr % stride == 0) & (cc % stride == 0)
    if sel is not None:
        inside = np.zeros(rr.size, bool)
        inside[sel] = True
        # a node just outside the disc may be the only one beside a position inside it
        near = inside.copy()
        r0, c0 = rr.min(), cc.min()
        grid_in = np.zeros((rr.max() - r0 + 1, cc.max() - c0 + 1), bool)
        grid_in[rr - r0, cc - c0] = inside
        for dr in range(-(stride - 1), stride):
            for dc in range(-(stride - 1), stride):
                sr, sc = rr - r0 + dr, cc - c0 + dc
                ok = (sr >= 0) & (sr < grid_in.shape[0]) & (sc >= 0) & (sc < grid_in.shape[1])
                near[ok] |= grid_in[sr[ok], sc[ok]]
        on &= near
    nodes = np.flatnonzero(on)
    n_here = rr.size if sel is None else sel.size
    if nodes.size == 0:
        return nodes, n_here
    w = (2 * stride - 1) ** 2
    kept = []
    for s0 in range(0, nodes.size, config.slice_rows):
        sl = nodes[s0:s0 + config.slice_rows]
        cs, _ = score_dense(_coarse_profiles(elev, sl, f, scale, missing), coarse_q)
        area = sl.size * stride * stride
        keep = int(math.ceil(max(config.keep_min, config.keep_fraction * area) / w))
        kept.append(sl[np.argpartition(cs, keep - 1)[:keep]] if keep < sl.size else sl)
    kept = np.concatenate(kept)
    # the block's positions within reach of a survivor, by (row, col) in a block-sized mask
    r0, c0 = rr.min(), cc.min()
    mask = np.zeros((rr.max() - r0 + 1, cc.max() - c0 + 1), bool)
    for dr in range(-(stride - 1), stride):
        for dc in range(-(stride - 1), stride):
            r, c = rr[kept] - r0 + dr, cc[kept] - c0 + dc
            ok = (r >= 0) & (r < mask.shape[0]) & (c >= 0) & (c < mask.shape[1])
            mask[r[ok], c[ok]] = True
    take = mask[rr - r0, cc - c0]
    if sel is not None:
        take &= inside
    return np.flatnonzero(take), n_here


def _nms(rows, cols, scores, headings, db, k: int, radius_m: float) -> list:
    """The k best scored positions at least ``radius_m`` apart (greedy suppression); ties go to
    the position first in row-major order."""
    spacing = float(db.spacing_m)
    rad = max(1, int(math.ceil(radius_m / spacing)))
    nx = int(db.shape[1])
    ok = np.flatnonzero(np.isfinite(scores))
    by_place = ok[np.argsort(rows[ok] * nx + cols[ok], kind="stable")]
    order = by_place[np.argsort(scores[by_place], kind="stable")]
    taken: list = []
    xs, ys = np.asarray(db.x_coords), np.asarray(db.y_coords)
    for i in order:
        r, c = int(rows[i]), int(cols[i])
        if any(abs(r - r2) <= rad and abs(c - c2) <= rad for r2, c2, _ in taken):
            continue
        taken.append((r, c, i))
        if len(taken) >= k:
            break
    return [Candidate(float(xs[c]), float(ys[r]), float(headings[i]) % 360.0, float(scores[i]), r, c)
            for r, c, i in taken]
