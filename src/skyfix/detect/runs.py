"""Hysteresis over runs of skyline columns: short isolated runs and runs with no confident anchor
among their neighbours are reported unknown (as Canny's hysteresis over edge pixels).
"""

from __future__ import annotations

import numpy as np


def finite_runs(rows):
    """[(start, stop)] of each run of finite ``rows``, stop exclusive [columns]."""
    have = np.isfinite(rows).astype(np.int8)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], have, [0]])))
    return list(zip(edges[::2], edges[1::2]))


def drop_short_runs(rows, conf, min_len):
    """Set runs of finite ``rows`` shorter than ``min_len`` columns to NaN (confidence 0), in
    place. A run across the whole image is kept however narrow the image (one 2-3 px wide lost
    its skyline)."""
    min_len = min(min_len, rows.size)
    for a, b in finite_runs(rows):
        if b - a < min_len:
            rows[a:b] = np.nan
            conf[a:b] = 0.0


def drop_unanchored_runs(rows, conf, min_conf, max_gap, self_len):
    """Hysteresis on runs of finite ``rows``, in place: a run is kept when it is an anchor (mean
    ``conf`` >= ``min_conf``, or at least ``self_len`` columns long) or is linked to one through
    runs separated by gaps of at most ``max_gap`` columns; the rest become NaN (confidence 0)."""
    runs = finite_runs(rows)
    chain = np.cumsum([0] + [b0 - a1 > max_gap for (_, a1), (b0, _) in zip(runs, runs[1:])])
    anchored = {c for c, (a, b) in zip(chain, runs)
                if b - a >= self_len or conf[a:b].mean() >= min_conf}
    for c, (a, b) in zip(chain, runs):
        if c not in anchored:
            rows[a:b] = np.nan
            conf[a:b] = 0.0
