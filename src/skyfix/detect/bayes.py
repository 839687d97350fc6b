"""The ``bayes`` detector: the NASA Ames formulation (sky/ground segmentation by column
transitions).

Per-pixel observations (intensity, local edge density at two scales, chroma); sky and ground
likelihoods start from priors (the sky is smooth and high in the image) and are re-learned by a
random forest from the current segmentation; the column log-likelihood of a transition at each
row comes from prefix sums, plus a boundary term (a transition where the grey level does not step
costs up to ``w_boundary``); a Viterbi pass with a smoothness window and a no-skyline state gives
the segmentation; iterate until the total likelihood stops improving.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..optional import require
from .image import (downscale, downscale_factor, downscale_valid, fill_invalid, resample_to,
                    to_float_gray, trusted)
from .options import BayesOptions, DpOptions
from .path import BIG, column_prefix, solve_path
from .refine import refine_full, skyline_allowed, vertical_step
from .skymodel import resolve_model, sky_log_odds
from .texture import texture_region


def _bayes_features(gray_s, rgb_s, valid_s):
    """Per-pixel observations: intensity, edge density at two scales, chroma; (h w, k)."""
    import cv2

    h, w = gray_s.shape
    med = np.median(gray_s[valid_s]) if valid_s.any() else 1.0
    feats = [gray_s / max(med, 1e-6)]
    sm = cv2.GaussianBlur(gray_s, (3, 3), 0.8)
    gx = cv2.Sobel(sm, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(sm, cv2.CV_32F, 0, 1, ksize=3)
    mag = np.sqrt(gx * gx + gy * gy)
    mmed = np.median(mag[valid_s]) if valid_s.any() else 1.0
    # edge density averaged along the row only: a square window lets the terrain's edges bleed
    # into the sky just above the skyline, which the forest then learns as terrain (the dev-set
    # skyline came out 5-20 px too high: 8 % of columns within 3 px, 56 % with this window)
    for k in (5, 15):
        feats.append(np.log1p(cv2.blur(mag, (2 * k + 1, 3)) / max(mmed, 1e-6)))
    if rgb_s is not None:
        s = rgb_s.astype(np.float32).sum(axis=2) + 1.0
        feats.append(rgb_s[..., 0] / s)
        feats.append(rgb_s[..., 2] / s)
    return np.stack([np.asarray(f, np.float32) for f in feats], axis=-1).reshape(h * w, -1)


def _boundary_strength(gray_s, valid_s):
    """:func:`vertical_step` over its 99th percentile, clipped to [0, 1]."""
    step = vertical_step(gray_s)
    scale = np.percentile(step[valid_s], 99) if valid_s.any() else 1.0
    return np.clip(step / max(scale, 1e-6), 0, 1).astype(np.float64)


def detect_bayes(img, valid, opt: BayesOptions, model=None):
    """The ``bayes`` detector on a prepared image.

    img : H x W (grey) or H x W x 3 image; valid : H x W bool, pixels holding data;
    opt : :class:`BayesOptions`; model : the sky classifier for the initial likelihoods.
    Returns (rows (W,) [px, NaN = no skyline], confidence (W,) in [0, 1], column validity (W,)).
    """
    RandomForestClassifier = require("sklearn.ensemble", "--method bayes (its per-image random "
                                     "forest)").RandomForestClassifier

    H, W = img.shape[:2]
    col_valid = valid.any(axis=0)
    valid = trusted(valid)
    gray = fill_invalid(to_float_gray(img), valid)
    f = downscale_factor(H, W, opt.work_pixels)
    gray_s = downscale(gray, f)
    valid_s = downscale_valid(valid, f)
    rgb_s = None
    if img.ndim == 3:
        rgb_s = downscale(fill_invalid(img[..., :3].astype(np.float32), valid), f)
    h, w = gray_s.shape
    X = _bayes_features(gray_s, rgb_s, valid_s)
    vflat = valid_s.ravel()

    # priors: the sky is smooth (low edge density relative to the image) and high in the frame
    rows = np.arange(h, dtype=np.float64)[:, None] * np.ones((1, w))
    # the dp detector's texture term, whose sky threshold is floored by the image's textured part
    # and its sensor noise: a threshold at a fixed share of the median edge density sits inside
    # the sky's own noise when the sky fills over half the frame (simulated frames: 75 % of the
    # skyline columns were then called all-sky)
    lo_s = None
    if img.ndim == 3 and (opt.init == "model" or opt.sure_sky_q > 0):
        lo, _, fm = sky_log_odds(img, valid, gray, resolve_model(model), DpOptions().model_pixels)
        lo_s = resample_to(lo, fm, f, (h, w))
    # the prior has no classifier term to outweigh a sky that reads as textured, so the sure
    # sky's threshold must sit high in its texture (see BayesOptions.sure_sky_q)
    dpo = replace(DpOptions(), sure_sky_q=opt.sure_sky_q)
    sure = valid_s & (lo_s > dpo.sure_sky_llr) if lo_s is not None and opt.sure_sky_q > 0 else None
    llr = 2.0 * texture_region(gray_s, valid_s, dpo, sure_sky=sure) + 0.5 * (rows / h - 0.5)
    if opt.init == "model" and lo_s is not None:
        # start from the learned sky classifier's log-odds (terrain positive) added to the prior
        llr = llr - opt.w_model * np.clip(lo_s, -3.0, 3.0)
    ok = skyline_allowed(valid_s, opt.min_sky_rows)
    B = _boundary_strength(gray_s, valid_s)
    rng = np.random.default_rng(opt.seed)
    prev_ll = -np.inf
    best = None
    for it in range(opt.max_iter):
        # llr > 0: terrain more likely. Cost of transition at r = sum of llr above r (sky there)
        # minus the sum below (terrain there) = 2 P[r] - P[h] up to the constant P[h].
        P = column_prefix(llr, valid_s)
        enter = np.where(ok, P[:-1] + opt.w_boundary * (1.0 - B), BIG)
        none = opt.none_cost + np.minimum(0.0, P[h])
        vert = np.full_like(enter, BIG)
        top, _ = solve_path(enter, vert, np.zeros_like(enter), none, opt.window, opt.jump_cost,
                           0.0, opt.switch_cost)
        # total cost of this segmentation under the current likelihoods (lower is better)
        cols = np.arange(w)
        tt = np.maximum(top, 0)
        tot = np.where(top >= 0, P[tt, cols] + opt.w_boundary * (1.0 - B[tt, cols]),
                       none - opt.none_cost).sum()
        ll = -tot
        if best is not None and ll <= prev_ll + 1e-3 * abs(prev_ll):
            break
        prev_ll = ll
        best = top
        # labels from the current segmentation: sky above the skyline (or everywhere in an
        # all-sky column), terrain below
        sky = np.zeros((h, w), dtype=bool)
        for c in range(w):
            if top[c] >= 0:
                sky[: top[c], c] = True
            elif P[h, c] < 0:
                sky[:, c] = True
        lab = sky.ravel()
        idx = np.flatnonzero(vflat)
        if idx.size == 0:
            break
        n_sky = int(lab[idx].sum())
        if n_sky < 20 or n_sky > idx.size - 20:
            break  # one class only: nothing to learn, keep the prior's answer
        pick = rng.choice(idx, size=min(opt.n_train, idx.size), replace=False)
        rf = RandomForestClassifier(n_estimators=20, max_depth=8, min_samples_leaf=20,
                                    n_jobs=1, random_state=opt.seed)
        rf.fit(X[pick], lab[pick])
        proba = rf.predict_proba(X)[:, list(rf.classes_).index(True)]
        p = np.clip(proba, 0.02, 0.98).reshape(h, w)
        llr = np.log((1 - p) / p)
    top = best
    full_cols = np.minimum(np.arange(W) // f, w - 1)
    top_f = np.where(top >= 0, top * float(f), np.nan)
    # the smoothness window lets the coarse path jump: widen the band to the neighbours' rows
    lo_f = np.copy(top_f)
    hi_f = np.copy(top_f)
    lo_f[1:] = np.fmin(lo_f[1:], top_f[:-1])
    hi_f[:-1] = np.fmax(hi_f[:-1], top_f[1:])
    lo_f[~np.isfinite(top_f)] = np.nan
    hi_f[~np.isfinite(top_f)] = np.nan
    rows = refine_full(gray, valid, lo_f[full_cols], hi_f[full_cols], f, DpOptions().refine_band)
    p_sky = 1 / (1 + np.exp(llr))
    conf_s = np.empty(w)
    for c in range(w):
        v = valid_s[:, c]
        if not v.any():
            conf_s[c] = 0.0
        elif top[c] >= 0:
            r = top[c]
            a = p_sky[max(0, r - 5):r, c].mean() if r > 0 else 0.5
            b = 1 - p_sky[r:r + 5, c].mean()
            conf_s[c] = float(np.clip(a * b, 0, 1))
        else:  # how sure the column is all one thing: all terrain, or all sky (that read ~0)
            pc = p_sky[v, c]
            conf_s[c] = float(np.clip(max(1.0 - pc.max(), pc.min()), 0, 1))
    conf = conf_s[full_cols]
    rows[~col_valid] = np.nan
    conf[~col_valid] = 0.0
    return rows, conf, col_valid
