"""The pieces both searches share (:mod:`.search`, :mod:`.indexed`): the exact pass's batches,
the thread that reads blocks ahead, and the BLAS thread limit."""

from __future__ import annotations

import time
from contextlib import contextmanager

import numpy as np

from .scores import score_profiles

#: survivors of the coarse pass scored exactly at once: the FFT's temporaries are ~60 bytes per
#: position and bin (12 MB at 512 x 360), and a larger batch gains nothing (~100 us per call)
EXACT_BATCH = 512


def to_float(raw: np.ndarray, scale: float, missing: int) -> np.ndarray:
    """float32 [deg] skylines from stored int16 ``raw`` (times ``scale``; ``missing`` -> 0 deg) or
    from float ones (NaN -> 0 deg)."""
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


class ExactPass:
    """Positions queued for exact scoring (:func:`score_profiles`), scored a batch at a time: FFT
    calls cost ~100 us each, and the coarse pass's survivors come a few per slice."""

    def __init__(self, query, scale: float, missing: int, bins: int, batch: int):
        self.query, self.scale, self.missing, self.bins, self.batch = query, scale, missing, bins, batch
        self.pending: list = []
        self.n_pending = 0
        self.found: list = []  # (rows, cols, exact scores, headings) of each batch
        self.n_scored = 0
        self.seconds = 0.0

    def push(self, raw: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> None:
        """Queue int16 (or float) skylines (m, bins) at grid (rows, cols); score once a batch is in."""
        self.pending.append((raw, rows, cols))
        self.n_pending += raw.shape[0]
        if self.n_pending >= self.batch:
            self.flush()

    def flush(self) -> None:
        if not self.pending:
            return
        t = time.perf_counter()
        raw, rows, cols = (np.concatenate(a) for a in zip(*self.pending))
        self.pending, self.n_pending = [], 0
        es, sh = score_profiles(to_float(raw, self.scale, self.missing), self.query)
        self.found.append((rows, cols, es.astype(np.float32),
                           (sh * (360.0 / self.bins)).astype(np.float32)))
        self.n_scored += raw.shape[0]
        self.seconds += time.perf_counter() - t

    def results(self):
        """(rows, cols, scores [deg^2], headings [deg]) of every position scored."""
        if not self.found:
            return (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32),
                    np.zeros(0, np.float32))
        return tuple(np.concatenate(a) for a in zip(*self.found))


def prefetch(blocks, depth: int = 2):
    """Yield ``blocks`` while a thread reads ahead: decompression (zstd, GIL released) overlaps
    the scoring. Also yields the reader thread's CPU time [s] for each block.

    One reader: two (a pool decoding two blocks at once, the scoring thread's BLAS at one
    thread) were slower on two cores, 7 x 7 km database at 5 m, four runs each alternated (load
    1.2-1.8): search 2.41-2.66 -> 2.53-2.92 s wall, CPU 4.02-4.34 -> 4.08-4.66 s: the reading
    waited less (0.60 -> 0.38 s) and the coarse pass, sharing its core, took longer. Nor was
    the scoring thread decoding the next block itself while the one it wanted was still being
    decoded (work stealing, blocks still in order; 2026-11-27, four runs each alternated, load
    0.3-1.4): search 2.03-2.13 s wall against 1.96-2.14 s."""
    import queue
    import threading

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


@contextmanager
def blas_threads(n: int):
    """Limit BLAS threads (the reader thread takes a core; oversubscription costs more than it
    gives: BLAS threads spin while they wait, and under load they wait for cores)."""
    from threadpoolctl import threadpool_limits  # here: only the search needs it

    with threadpool_limits(limits=n, user_api="blas"):
        yield


def read_blocks(blocks, config):
    """``(block, reader CPU seconds)`` for each of ``blocks`` in order: read ahead in a thread
    (:func:`prefetch`) when ``config.prefetch``, else one after the other (0 s each)."""
    return prefetch(blocks) if config.prefetch else ((b, 0.0) for b in blocks)


def scoring_threads(config):
    """:func:`blas_threads` for the scoring thread: ``config.workers``, less the core the block
    reader takes when ``config.prefetch``."""
    return blas_threads(max(1, config.workers - 1) if config.prefetch else config.workers)
