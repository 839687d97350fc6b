"""Merging several frames' samples of one azimuth bin: a weighted median and its spread.
"""

from __future__ import annotations

import warnings

import numpy as np


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Per row of (bins, F) arrays (NaN = missing): the weighted median; NaN where a row is empty."""
    v = np.where(np.isfinite(values), values, np.inf)
    w = np.where(np.isfinite(values), np.maximum(weights, 1e-6), 0.0)
    order = np.argsort(v, axis=1)
    vs = np.take_along_axis(v, order, axis=1)
    ws = np.take_along_axis(w, order, axis=1)
    cw = np.cumsum(ws, axis=1)
    tot = cw[:, -1:]
    # lower and upper weighted medians, averaged (the plain median for equal weights)
    lo = np.argmax(cw >= 0.5 * tot - 1e-12, axis=1)
    hi = np.argmax(cw > 0.5 * tot + 1e-12, axis=1)
    r = np.arange(v.shape[0])
    med = 0.5 * (vs[r, lo] + vs[r, np.minimum(hi, v.shape[1] - 1)])
    med[tot[:, 0] <= 0] = np.nan
    return med


def merge_samples(values: np.ndarray, sigmas: np.ndarray, weights: np.ndarray):
    """Merge per-frame bin samples (bins, F) into one profile.

    values : [deg] elevation samples, NaN where a frame does not cover the bin
    sigmas : [deg] per-sample 1-sigma; weights : detection confidence in [0, 1]
    Returns ``(elevation, sigma, count)``: the confidence-weighted median; its sigma is the larger of
    the samples' combined sigma and the robust spread between frames (1.4826 MAD / sqrt(n)), so a
    bin where frames disagree says so.
    """
    med = _weighted_median(values, weights)
    have = np.isfinite(values)
    count = have.sum(axis=1)
    inv = np.where(have, 1.0 / np.square(np.where(have, sigmas, 1.0)), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        sig_comb = 1.0 / np.sqrt(inv.sum(axis=1))
        dev = np.abs(values - med[:, None])
        with warnings.catch_warnings():  # empty bins: NaN is the answer
            warnings.simplefilter("ignore", RuntimeWarning)
            mad = np.nanmedian(np.where(have, dev, np.nan), axis=1)
        spread = np.where(count >= 2, 1.4826 * mad / np.sqrt(np.maximum(count, 1)), 0.0)
    sigma = np.where(count > 0, np.maximum(sig_comb, np.nan_to_num(spread)), np.nan)
    return med, sigma, count
