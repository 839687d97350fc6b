"""From a working-scale path to full-resolution rows: where a skyline may lie, a narrow band DP on
the vertical intensity step, and the sub-pixel half-level crossing.
"""

from __future__ import annotations

import math

import numpy as np

from ..jit import njit
from .path import BIG, solve_path
from .quantile import percentile

#: cost of one row's move within a column of the full-resolution band (a cell's is 0..1.3): three
#: times a row of jump between columns, so it serves only a step wider than the jump window
REFINE_VERT_COST = 0.3


def skyline_allowed(valid, min_sky_rows=1):
    """Where a skyline row may lie (bool, shape of ``valid``): the pixel and the one above it are
    valid (sky above, terrain at r) and at least ``min_sky_rows`` valid rows lie above it."""
    ok = valid.copy()
    ok[1:] &= valid[:-1]
    ok[0] = False
    if min_sky_rows > 1:
        ok &= (np.cumsum(valid, axis=0) - valid) >= min_sky_rows
    return ok


def vertical_step(gray):
    """|grey(r) - grey(r - 1)| [grey levels] on the grey smoothed with sigma 1 px; row 0 is 0."""
    import cv2

    sm = cv2.GaussianBlur(np.asarray(gray, np.float32), (0, 0), 1.0)
    step = np.empty_like(sm)
    step[0] = 0.0
    np.subtract(sm[1:], sm[:-1], out=step[1:])  # in place: no full-size temporaries
    return np.abs(step, out=step)


def refine_full(gray, valid, top_full, bottom_full, f, refine_band: float):
    """Full-resolution rows from the working-scale path: a DP on the vertical intensity step.

    top_full, bottom_full (W,): full-resolution rows [px] spanned by the working-scale path in
    each column (NaN = no skyline). The search band is that span widened by ``refine_band`` f
    rows; the row change between columns is free within the band, so steep sections survive.
    """
    import cv2

    H, W = gray.shape
    have = np.isfinite(top_full)
    out = np.full(W, np.nan)
    if not have.any():
        return out
    step = vertical_step(gray)  # the skyline is at r when the step into r is large
    ok = skyline_allowed(valid)
    m = int(math.ceil(refine_band * f)) + 1
    a = np.where(have, np.floor(np.nan_to_num(top_full)) - m, 0).astype(np.int64)
    b = np.where(have, np.ceil(np.nan_to_num(bottom_full)) + f - 1 + m, -1).astype(np.int64)
    a = np.clip(a, 0, H - 1)
    b = np.clip(b, -1, H - 1)
    lo = int(a[have].min())
    hi = int(b[have].max()) + 1
    rows = np.arange(lo, hi)[:, None]
    sub_ok = ok[lo:hi] & (rows >= a[None, :]) & (rows <= b[None, :])
    scale = percentile(step[ok], 99.5) if ok.any() else 1.0
    del ok
    # prefer the coarse span (its centre) a little, so texture steps nearby do not pull the row
    mid = 0.5 * (np.nan_to_num(top_full) + np.nan_to_num(bottom_full) + f - 1)
    span = 0.5 * (np.nan_to_num(bottom_full) - np.nan_to_num(top_full) + f) + 1.0
    # cost = 1 - clip(step / scale) + 0.3 off-centre, BIG outside the band: built in place, the
    # band being up to the image's height for a skyline that spans it
    cost = rows - mid[None, :]
    np.abs(cost, out=cost)
    cost -= span[None, :]
    np.clip(cost, 0, None, out=cost)
    cost /= max(m, 1)
    cost *= 0.3
    lvl = np.clip(step[lo:hi] / max(scale, 1e-6), 0, 1)
    np.subtract(1.0, lvl, out=lvl)
    cost += lvl
    del lvl
    cost[~sub_ok] = BIG
    # columns the coarse pass called no-skyline stay so; the others follow the band optimum
    none = np.where(have, BIG, 0.0)
    # moves within a column, inside the band: a cliff steeper than the window between two
    # columns left no allowed path, and the solver walked through forbidden cells (half a
    # skyline lost at a 40-row step)
    vert = np.where(sub_ok, REFINE_VERT_COST, BIG)
    win = int(min(hi - lo, 2 * m + 2 * f))
    top, _ = solve_path(cost, vert, np.zeros_like(cost), none, win, 0.1, 0.0, 0.0)
    got = top >= 0
    cols = np.flatnonzero(got)
    r = top[got] + lo
    # sub-pixel: parabola through the step magnitude around the chosen row
    rm = np.clip(r - 1, 0, H - 1)
    rp = np.clip(r + 1, 0, H - 1)
    s0, s1, s2 = step[rm, cols], step[r, cols], step[rp, cols]
    den = s0 - 2 * s1 + s2
    safe = np.where(den < -1e-6, den, -1.0)
    off = np.where(den < -1e-6, 0.5 * (s0 - s2) / safe, 0.0)
    out[cols] = r + np.clip(off, -0.5, 0.5)
    del step, cost, vert
    g_row = cv2.GaussianBlur(np.asarray(gray, np.float32), (0, 0), sigmaX=1.0, sigmaY=0.01)
    peak = out.copy()
    _edge_crossing(g_row, valid, out)
    # where no half-level crossing moved it (near the image's top or bottom, beside no-data, or
    # none within 2 px) the row is the step's peak, between rows r - 1 and r: the edge lies half
    # a row above it (edges at 196.5 and 3.5 read 197.0 and 4.0)
    kept = np.isfinite(out) & (out == peak)
    out[kept] -= 0.5
    return out


@njit(cache=True)
def _edge_crossing(gray, valid, rows):
    """Move each column's row (in place) to where the grey level crosses halfway between the sky
    just above and the ground just below: the edge's position in pixel-centre coordinates.

    The step-magnitude peak sits between two pixel centres (half a pixel below the edge) and
    moves with the ground's texture; the half-level crossing does not (simulated frames: per-frame
    bias 0.18 +- 0.30 px -> 0.05 +- 0.04 px, spread 0.35 -> 0.08 px). gray is smoothed along rows
    only, so the vertical profile stays sharp. Columns whose neighbourhood holds no-data, or
    without a crossing within 2 px, keep their row."""
    H, W = gray.shape
    buf = np.empty(3)
    for c in range(W):
        r = rows[c]
        if not math.isfinite(r):
            continue
        ri = int(round(r))
        if ri < 6 or ri > H - 5:
            continue
        ok = True
        for v in range(ri - 5, ri + 4):
            if not valid[v, c]:
                ok = False
                break
        if not ok:
            continue
        for k in range(3):
            buf[k] = gray[ri - 5 + k, c]
        sky = np.median(buf)
        for k in range(3):
            buf[k] = gray[ri + 1 + k, c]
        ground = np.median(buf)
        if abs(sky - ground) < 1e-3:
            continue
        mid = 0.5 * (sky + ground)
        best = np.nan
        for v in range(ri - 3, ri + 2):
            a = gray[v, c] - mid
            b = gray[v + 1, c] - mid
            if a == 0.0 or a * b < 0.0:
                t = v + (a / (a - b) if a != b else 0.0)
                if not math.isfinite(best) or abs(t - r) < abs(best - r):
                    best = t
        if math.isfinite(best) and abs(best - r) < 2.0:
            rows[c] = best
