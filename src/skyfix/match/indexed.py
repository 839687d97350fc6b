"""The search of a store that holds its coarse index (``skyfix.database``, array ``coarse``):
the coarse pass from the index, then the exact pass on only the blocks its survivors lie in."""

from __future__ import annotations

import math
import time

import numpy as np

from ..database.layout import COARSE_STRIDE
from .passes import EXACT_BATCH, ExactPass, read_blocks, scoring_threads
from .scores import score_dense


def _neighbourhoods(node_r, node_c, reach: int, shape) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of every position within ``reach`` rows and columns of a node, inside the
    grid of ``shape``, each once (row-major order)."""
    ny, nx = shape
    rows = (node_r[:, None] + np.repeat(np.arange(-reach, reach + 1), 2 * reach + 1)).ravel()
    cols = (node_c[:, None] + np.tile(np.arange(-reach, reach + 1), 2 * reach + 1)).ravel()
    ok = (rows >= 0) & (rows < ny) & (cols >= 0) & (cols < nx)
    flat = np.unique(rows[ok] * nx + cols[ok])
    return flat // nx, flat % nx


def indexed_search(db, coarse_q, exact: ExactPass, config, prior_xy, prior_radius_m) -> tuple[int, dict]:
    """The search of a store with its coarse index, in two passes.

    1. The coarse pass over the index (every second position, four bins averaged: a sixteenth of
       the skylines' bytes): one score per node, the whole store's kept in memory (4 bytes each).
    2. The best ``keep_fraction`` of the store's positions (in nodes, each bringing its 3 x 3
       neighbourhood, as the slice-wise pass counts them), chosen over the whole store
       rather than per slice, are scored exactly: only the blocks holding one are decoded.

    For a full turn the survivors gather in the few basins that look like the query: on the 7 x 7
    km Sierra store at 5 m they lie in 20-30 % of the blocks (96-141 of 484, median 129 over 60
    queries: ``benchmarks/bench_search_recall.py``).
    Queues the exact positions on ``exact``; returns (positions searched, timing).
    """
    grid = db.grid
    s = COARSE_STRIDE
    reach = s - 1
    w = (2 * reach + 1) ** 2
    scale = exact.scale
    disc = prior_xy is not None and prior_radius_m is not None
    # a node just outside the disc may be the only one beside a position inside it
    node_radius = (prior_radius_m + reach * grid.spacing_m * math.sqrt(2.0)) if disc else None
    t_read = t_reader = t_coarse = 0.0
    scores, node_r, node_c = [], [], []
    n_pos = 0

    def coarse_chunks():
        for br, bc in grid.blocks():
            yield br, bc, db.read_coarse(br, bc)

    def inside(rows, cols, radius):
        x, y = db.xy_of(rows, cols)
        return (x - prior_xy[0]) ** 2 + (y - prior_xy[1]) ** 2 <= radius ** 2

    chunks = read_blocks(coarse_chunks(), config)
    with scoring_threads(config):
        cpu0 = time.thread_time()
        t0 = time.perf_counter()
        for (br, bc, raw), dt in chunks:
            t1 = time.perf_counter()
            t_read += t1 - t0
            t_reader += dt
            rs, cs = grid.block_slices(br, bc)
            # int32: the whole store's nodes stay in memory until the selection
            rr, cc = (a.ravel() for a in np.meshgrid(np.arange(rs.start, rs.stop, s, dtype=np.int32),
                                                      np.arange(cs.start, cs.stop, s, dtype=np.int32),
                                                      indexing="ij"))
            prof = raw.reshape(rr.size, -1)
            if disc:
                pr, pc = (a.ravel() for a in np.meshgrid(np.arange(rs.start, rs.stop),
                                                          np.arange(cs.start, cs.stop), indexing="ij"))
                n_pos += int(inside(pr, pc, prior_radius_m).sum())
                keep = np.flatnonzero(inside(rr, cc, node_radius))
                rr, cc = rr[keep], cc[keep]
                # ... and only if one is: a node with no position inside the disc in its
                # neighbourhood would take an exact slot and score nothing (all of them: none
                # scored, and the search failed on an empty set)
                near = np.zeros(rr.size, bool)
                r64, c64 = rr.astype(np.int64), cc.astype(np.int64)
                for dr in range(-reach, reach + 1):
                    for dc in range(-reach, reach + 1):
                        r2, c2 = r64 + dr, c64 + dc
                        ok = (r2 >= 0) & (r2 < grid.shape[0]) & (c2 >= 0) & (c2 < grid.shape[1])
                        near[ok] |= inside(r2[ok], c2[ok], prior_radius_m)
                keep, rr, cc = keep[near], rr[near], cc[near]
                prof = prof[keep]
            else:
                n_pos += (rs.stop - rs.start) * (cs.stop - cs.start)
            for k in range(0, rr.size, config.slice_rows):
                p = prof[k:k + config.slice_rows].astype(np.float32)
                p *= np.float32(scale)
                scores.append(score_dense(p, coarse_q)[0].astype(np.float32))
            node_r.append(rr)
            node_c.append(cc)
            t0 = time.perf_counter()
            t_coarse += t0 - t1
        if n_pos == 0:
            return 0, {}
        scores = np.concatenate(scores)
        node_r, node_c = np.concatenate(node_r), np.concatenate(node_c)
        # keep_fraction counts a node as its 3 x 3 neighbourhood; they overlap, so about 85 %
        # as many positions are scored (2.55 % of a store for 3 %)
        keep = int(math.ceil(max(config.keep_min, config.keep_fraction * n_pos) / w))
        least = min(n_pos, config.keep_min)
        node_r, node_c = node_r.astype(np.int64), node_c.astype(np.int64)
        # ... but at least keep_min positions (all of a small disc's): neighbourhoods reaching
        # past the disc left 6 of a 9-position disc unscored. A partition, not a sort, of the
        # whole store's nodes (half a million on the 7 x 7 km store); more only for a small disc
        while True:
            best = (np.argpartition(scores, keep - 1)[:keep] if keep < scores.size
                    else slice(None))
            rows, cols = _neighbourhoods(node_r[best], node_c[best], reach, grid.shape)
            if disc:
                ok = inside(rows, cols, prior_radius_m)
                rows, cols = rows[ok], cols[ok]
            if rows.size >= least or keep >= scores.size:
                break
            keep = min(scores.size, 2 * keep)
        if rows.size == 0:  # no node kept (none near the disc): nothing to score exactly
            return n_pos, {}
        b = grid.block
        key = (rows // b) * grid.n_blocks[1] + cols // b
        order = np.argsort(key, kind="stable")
        rows, cols, key = rows[order], cols[order], key[order]
        starts = np.flatnonzero(np.r_[True, np.diff(key) != 0])
        ends = np.r_[starts[1:], key.size]
        t_coarse += time.perf_counter() - t0

        def blocks_read():
            for a, e in zip(starts, ends):
                br, bc = divmod(int(key[a]), grid.n_blocks[1])
                yield a, e, br, bc, db.read_raw("elevation", br, bc)

        # One reader, as in the full pass: two (this pass scores little, so the scoring thread
        # mostly waits) gained 3 % (search 1.44 -> 1.39 s wall, eight runs each alternated, load
        # 1.2, 2026-11-27) for 6 MB more peak RSS: not taken.
        blocks = read_blocks(blocks_read(), config)
        t0 = time.perf_counter()
        for (a, e, br, bc, raw), dt in blocks:
            t_read += time.perf_counter() - t0
            t_reader += dt
            rs, cs = grid.block_slices(br, bc)
            elev = raw.reshape((rs.stop - rs.start) * (cs.stop - cs.start), -1)
            r, c = rows[a:e], cols[a:e]
            idx = (r - rs.start) * (cs.stop - cs.start) + (c - cs.start)
            for k in range(0, idx.size, EXACT_BATCH):
                exact.push(elev[idx[k:k + EXACT_BATCH]], r[k:k + EXACT_BATCH], c[k:k + EXACT_BATCH])
            t0 = time.perf_counter()
        t_read += time.perf_counter() - t0
        exact.flush()
        cpu_main = time.thread_time() - cpu0
    return n_pos, {"read_s": t_read, "reader_cpu_s": t_reader, "main_cpu_s": cpu_main,
                   "coarse_s": t_coarse, "blocks_read": int(starts.size),
                   "coarse_index": True}
