"""The ``dp`` detector (default before ``net``): a dense multi-stage graph over the pixels of a
downscaled working copy, solved exactly by :func:`skyfix.detect.path.solve_path`.

A pixel costs ``w_grad (1 - |grad|) + w_edge (1 - canny) + w_height row/H``, a step between
columns adds ``w_diff | |grad|(r, c) - |grad|(r', c-1) |`` (the source study's four terms, on
CLAHE'd, smoothed grey with Canny thresholds from Otsu), and entering a column at row ``r`` adds
a region term: ``w_region`` times the sum, over the pixels above ``r``, of how unlike sky they
look: a texture likelihood ratio (the sky is smooth, terrain is not) plus ``w_model`` times the
log-odds of a small learned sky-vs-terrain classifier (:mod:`skyfix.detect.skymodel`, trained by
``scripts/train_sky_model.py`` on the dev mosaics; prefix sums make the cost of every row O(1)).
A textured pixel that the classifier calls sky and that is brighter than the clear sky in every
colour channel is taken for cloud, and its texture counts for neither (``cloud_llr``). Each column
also has an explicit *no-skyline* state whose cost is that of calling the whole column terrain (or
the whole column sky) plus ``none_cost``; switching between it and the skyline costs
``switch_cost``. The exact optimum is found on the working copy, then each column is refined at
full resolution by a narrow band DP on the vertical intensity step (:mod:`.refine`).
"""

from __future__ import annotations

import numpy as np

from ..jit import njit
from .image import (downscale, downscale_factor, downscale_rgb, downscale_valid, fill_invalid,
                    resample_to, to_float_gray, trusted)
from .options import DpOptions, NetOptions
from .path import BIG, column_prefix, solve_path
from .quantile import percentile
from .refine import refine_full, skyline_allowed
from .runs import drop_short_runs, drop_unanchored_runs
from .skymodel import resolve_model, sky_log_odds
from .texture import texture_region


def _dp_costs(gray_s, valid_s, opt: DpOptions, d=None):
    import cv2

    h, w = gray_s.shape
    g8 = np.clip(gray_s, 0, 255).astype(np.uint8)
    clahe = cv2.createCLAHE(clipLimit=2.0, tileGridSize=(8, 8))
    eq = clahe.apply(g8)
    sm = cv2.GaussianBlur(eq, (5, 5), 1.2)
    otsu, _ = cv2.threshold(sm[valid_s] if valid_s.any() else sm, 0, 255,
                            cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    edges = cv2.Canny(sm, 0.5 * otsu, otsu) > 0
    gx = cv2.Sobel(sm, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(sm, cv2.CV_32F, 0, 1, ksize=3)
    mag = np.sqrt(gx * gx + gy * gy)
    scale = percentile(mag[valid_s], 99) if valid_s.any() else 1.0
    G = np.clip(mag / max(scale, 1e-6), 0, 1).astype(np.float64)
    # edge-ness falls off over a couple of pixels from a Canny edge
    dist = cv2.distanceTransform((~edges).astype(np.uint8), cv2.DIST_L2, 3)
    E = np.exp(-dist / 1.5).astype(np.float64)

    if d is None:
        d = texture_region(gray_s, valid_s, opt)
    P = column_prefix(d, valid_s)  # (h + 1, w)

    rows = np.arange(h, dtype=np.float64)[:, None]
    pix = opt.w_grad * (1 - G) + opt.w_edge * (1 - E) + opt.w_height * rows / h
    ok = skyline_allowed(valid_s, opt.min_sky_rows)
    enter = pix + opt.w_region * P[:-1]
    enter = np.where(ok, enter, BIG)
    vert = np.where(ok, pix + opt.vertical_cost, BIG)
    # no skyline: the whole column terrain (region 0) or the whole column sky (P[h])
    none = opt.none_cost + opt.w_region * np.minimum(0.0, P[h])
    return enter, vert, G, none, d


def _net_region(img, valid, opt: DpOptions, f, shape):
    """The sky network's evidence as a region term on the working grid (``shape``, downscale
    factor ``f``): minus its log-odds of sky, clipped to +-``opt.llr_clip`` [nats]."""
    # imported here: the network (OpenCV's dnn and the ONNX file) loads only when it is asked for
    from .net import sky_net_log_odds

    lo, _, fn, _ = sky_net_log_odds(img, valid, NetOptions(member=opt.net_member, flip=opt.net_flip))
    lo = resample_to(lo, fn, f, shape)
    return -np.clip(lo, -opt.llr_clip, opt.net_sky_clip).astype(np.float64)


def _cloud_like(tex, lo, rgb_s, valid_s, min_llr, sure_llr=2.0, min_sure=100, sky_q=10.0,
                min_share=0.0):
    """Pixels (bool, working scale) that look like a cloud: textured (``tex`` > 0), called sky by
    the classifier (log-odds ``lo`` > ``min_llr`` [nats]) and brighter in every channel of
    ``rgb_s`` (h, w, 3) than the ``sky_q`` percentile of the image's unmistakable sky (smooth
    and ``lo`` > ``sure_llr``). None when under ``min_sure`` pixels of such sky exist, or when
    they are under ``min_share`` of the pixels the classifier calls sky: without a sky level,
    or with one taken from an unrepresentative remnant of the sky, a bright textured pixel may
    be sunlit rock."""
    sure = valid_s & (lo > sure_llr) & (tex < 0)
    n_sure = np.count_nonzero(sure)
    if n_sure < min_sure or n_sure < min_share * np.count_nonzero(valid_s & (lo > min_llr)):
        return np.zeros_like(valid_s)
    # the 10th percentile, not the median: the clear sky darkens towards the horizon, and a
    # cloud's soft lower fringe mixes with that darker sky
    brighter = np.all(rgb_s > np.percentile(rgb_s[sure], sky_q, axis=0), axis=-1)
    return valid_s & (tex > 0) & (lo > min_llr) & brighter


@njit(cache=True)
def _median_above(d, valid, rows, cols, n_rows):
    """Median of ``d`` over the valid pixels of the ``n_rows`` rows above ``rows[i]`` in column
    ``cols[i]``; 0 where there are none."""
    out = np.zeros(rows.size)
    buf = np.empty(n_rows)
    for i in range(rows.size):
        r, c = rows[i], cols[i]
        m = 0
        for rr in range(max(0, r - n_rows), r):
            if valid[rr, c]:
                buf[m] = d[rr, c]
                m += 1
        if m:
            out[i] = np.median(buf[:m])
    return out


@njit(cache=True)
def _valid_column_mean(d, valid):
    """Mean of ``d`` over each column's valid pixels (0 where none)."""
    h, w = d.shape
    s = np.zeros(w)
    n = np.zeros(w)
    for r in range(h):
        for c in range(w):
            if valid[r, c]:
                s[c] += d[r, c]
                n[c] += 1
    return np.where(n > 0, s / np.maximum(n, 1), 0.0)


def _working_path(img, valid, gray, opt: DpOptions, model, f):
    """The path at the working scale (``f`` times smaller): (top, bottom) rows per working column
    (-1 = no skyline) and the confidence of each. Its own function so that the working-scale
    arrays (costs, region terms, colour: ~15 MB for a navcam frame) are freed before the
    full-resolution refinement, whose band can be the whole image: they were the board's peak."""
    gray_s = downscale(gray, f)
    valid_s = downscale_valid(valid, f)
    d = None
    region = opt.region
    grey = img.ndim == 2
    if region in ("model", "both"):
        # a grey image gets the model trained on grey copies: without chroma the colour model's
        # input is off its training distribution (it called a smooth grey sky terrain)
        lo, _, fm = sky_log_odds(img, valid, gray, resolve_model(model, grey=grey), opt.model_pixels)
        # d > 0: terrain more likely; the region cost of a skyline at r is the sum of d above r
        lo_s = resample_to(lo, fm, f, gray_s.shape)
        d = -np.clip(lo_s, -opt.llr_clip, opt.llr_clip)
        d = d.astype(np.float64)
        if region == "both":
            tex = texture_region(gray_s, valid_s, opt,
                                   sure_sky=valid_s & (lo_s > opt.sure_sky_llr))
            # the cloud rule needs colour: a grey-level "brighter than the sky" took sunlit
            # ground for cloud (see DpOptions.cloud_llr)
            if opt.cloud_llr > 0 and not grey:
                rgb_s = downscale_rgb(img, f)
                cloud = _cloud_like(tex, lo_s, rgb_s, valid_s, opt.cloud_llr,
                                    min_share=opt.cloud_sure_share)
                tex = np.where(cloud, 0.0, tex)
            d = opt.w_model * d + tex
    if opt.w_net > 0:
        if d is None:
            d = texture_region(gray_s, valid_s, opt)
        d = d + opt.w_net * _net_region(img, valid, opt, f, gray_s.shape)
    enter, vert, G, none, d = _dp_costs(gray_s, valid_s, opt, d)
    top, bottom = solve_path(enter, vert, G, none, 1, opt.jump_cost, opt.w_diff, opt.switch_cost)
    # confidence: edge strength at the chosen pixel times how sky-like the pixels above are
    conf_s = np.zeros(top.size)
    have = top >= 0
    cs = np.flatnonzero(have)
    if cs.size:
        r = top[cs]
        edge = G[r, cs]
        # the median over 30 rows: the texture term is blurred 7 columns wide, so on a steep
        # flank the rows just above the skyline look like the terrain beside them
        above = _median_above(d, valid_s, r, cs, 30)
        conf_s[cs] = np.clip(edge, 0, 1) * np.clip(0.5 - 0.5 * above, 0, 1)
    no = ~have
    # no-skyline: confident when the column clearly lacks sky (mean d well above 0)
    col_mean = _valid_column_mean(d, valid_s)
    conf_s[no] = np.clip(0.5 + 0.5 * np.abs(col_mean[no]), 0, 1)
    return top, bottom, conf_s


def detect_dp(img, valid, opt: DpOptions, model=None):
    """The ``dp`` detector on a prepared image.

    img : H x W (grey) or H x W x 3 image; valid : H x W bool, pixels holding data;
    opt : :class:`DpOptions`; model : the sky classifier (None = the shipped one).
    Returns (rows (W,) [px, NaN = no skyline], confidence (W,) in [0, 1], column validity (W,)).
    """
    H, W = img.shape[:2]
    col_valid = valid.any(axis=0)
    valid = trusted(valid)
    gray = fill_invalid(to_float_gray(img), valid)
    f = downscale_factor(H, W, opt.work_pixels)
    top, bottom, conf_s = _working_path(img, valid, gray, opt, model, f)
    w = top.size
    # working column j covers full-res columns j f .. j f + f - 1; rows scale by f
    full_cols = np.minimum(np.arange(W) // f, w - 1)
    top_f = np.where(top >= 0, top * float(f), np.nan)[full_cols]
    bot_f = np.where(top >= 0, bottom * float(f), np.nan)[full_cols]
    rows = refine_full(gray, valid, top_f, bot_f, f, opt.refine_band)
    conf = conf_s[full_cols]
    unsure = np.isfinite(rows) & (conf < opt.min_confidence)
    rows[unsure] = np.nan
    conf[unsure] = 0.0
    if opt.min_run > 1:
        drop_short_runs(rows, conf, opt.min_run * f)
    if opt.anchor_conf > 0:
        # the widths are fractions of the image's, not working columns: a mosaic and a single
        # frame differ in width far more than in working scale
        drop_unanchored_runs(rows, conf, opt.anchor_conf, opt.anchor_gap * W,
                              opt.anchor_len * W)
    rows[~col_valid] = np.nan
    conf[~col_valid] = 0.0
    return rows, conf, col_valid
