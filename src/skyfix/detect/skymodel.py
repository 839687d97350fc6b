"""A small learned sky-vs-terrain pixel classifier: the region term of the ``dp`` detector.

Features (:func:`sky_features`) are general image statistics computed on a downscaled copy,
all relative to the image itself so that exposure, white balance and sensor noise level do not
matter (with absolute brightness, chroma and texture the ensemble learnt each dev image's look
and did worse on held-out images): brightness relative to the image and to the top of the
column, chroma relative to the image median, local texture (relative to the image median) at three scales, the signed vertical gradient, and the mean
texture of the column above the pixel (sky lies on top, so texture above a pixel argues for
terrain). The row position is deliberately not a feature: in the dev mosaics the sky is always
a thin band at the top, and a tree ensemble learns that as a hard rule that fails on a frame with
more sky (the detector's own ``w_height`` term is the weak position prior).

The classifier is a gradient-boosted tree ensemble trained by ``scripts/train_sky_model.py``
(scikit-learn ``HistGradientBoostingClassifier``) on the labelled dev mosaics; its trees are
exported to plain arrays in ``skyfix/models/sky_hgb.npz`` and evaluated here by a numba kernel,
so run time needs neither scikit-learn nor a pickle (no version lock, nothing downloaded).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..errors import ParameterError
from ..jit import njit, num_threads, prange
from ..optional import require
from .forest import elimination_tables, float32_thresholds, forest_scores
from .quantile import median
from .image import (as_gray_rgb, downscale, downscale_factor, downscale_rgb, downscale_valid,
                    fill_invalid, to_float_gray, trusted, valid_mask)

FEATURE_NAMES = (
    "log_gray_rel_image", "log_gray_rel_coltop", "log_local_mean_rel",
    "chroma_r_rel", "chroma_b_rel",
    "tex3", "tex9", "tex27",
    "vgrad", "tex_above",
)
N_FEATURES = len(FEATURE_NAMES)

DEFAULT_MODEL = Path(__file__).resolve().parents[1] / "models" / "sky_hgb.npz"
#: the same recipe on grey copies of the training images, for images without colour
DEFAULT_GREY_MODEL = Path(__file__).resolve().parents[1] / "models" / "sky_hgb_grey.npz"

SKY_RGB = (34, 56, 19)  # MarsScapes label colour of sky


@njit(cache=True)
def _column_context(tex, valid, gray):
    """Per pixel: rows below the column's first valid pixel, mean texture of the valid pixels
    above it (itself excluded; 0 at the top), and the mean grey of the first 5 valid rows."""
    H, W = tex.shape
    below = np.zeros((H, W), np.float32)
    above = np.zeros((H, W), np.float32)
    top_gray = np.zeros(W, np.float32)
    for c in range(W):
        t0 = -1
        s = 0.0
        n = 0
        tg = 0.0
        ng = 0
        for r in range(H):
            if valid[r, c]:
                if t0 < 0:
                    t0 = r
                if ng < 5:
                    tg += gray[r, c]
                    ng += 1
            below[r, c] = (r - t0) if t0 >= 0 else 0.0
            above[r, c] = s / n if n > 0 else 0.0
            if valid[r, c]:
                s += tex[r, c]
                n += 1
        top_gray[c] = tg / ng if ng > 0 else 0.0
    return below, above, top_gray


def sky_features(gray_s, rgb_s, valid_s):
    """Per-pixel features of a working-scale image.

    gray_s : (h, w) float grey [0-255 grey levels], no-data already filled
    rgb_s : (h, w, 3) float RGB [0-255] or None (a grey image: neutral chroma)
    valid_s : (h, w) bool
    Returns (h, w, N_FEATURES) float32, finite everywhere.
    """
    import cv2

    h, w = gray_s.shape
    g = np.asarray(gray_s, np.float32)
    anyv = bool(valid_s.any())
    med = median(g[valid_s]) if anyv else float(np.median(g))
    med = max(med, 1.0)
    sm = cv2.GaussianBlur(g, (3, 3), 0.8)
    gx = cv2.Sobel(sm, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(sm, cv2.CV_32F, 0, 1, ksize=3)
    mag = np.sqrt(gx * gx + gy * gy)
    mmed = median(mag[valid_s]) if anyv else float(np.median(mag))
    mmed = max(mmed, 1e-3)
    # each feature written into its plane of one array: the list, the stack and the NaN-free
    # copy of the stack were each a full copy (25 -> 16 MB of temporaries on a 1-MP frame)
    X = np.empty((h, w, N_FEATURES), np.float32)
    for i, k in enumerate((3, 9, 27)):
        X[..., 5 + i] = np.log1p(cv2.blur(mag, (k, k)) / mmed)
    below, above, top_gray = _column_context(np.ascontiguousarray(X[..., 6]), valid_s, g)
    lg = np.log(g + 1.0)
    X[..., 0] = lg - math.log(med + 1.0)
    X[..., 1] = lg - np.log(top_gray + 1.0)[None, :]
    X[..., 2] = np.log(cv2.blur(g, (15, 15)) + 1.0) - math.log(med + 1.0)
    if rgb_s is not None:
        rgb = np.asarray(rgb_s, np.float32)
        s = rgb.sum(axis=2) + 3.0
        for j, ch in enumerate((0, 2)):
            cr = (rgb[..., ch] + 1.0) / s
            X[..., 3 + j] = cr - (median(cr[valid_s]) if anyv else float(np.median(cr)))
    else:
        X[..., 3:5] = 0.0
    X[..., 8] = cv2.blur(gy, (9, 3)) / mmed
    X[..., 9] = above
    return np.nan_to_num(X, copy=False, nan=0.0, posinf=0.0, neginf=0.0)


@njit(cache=True, inline="always")
def _walk_block(X, feat, thr, child, value, roots, depth, out, i0, m):
    """Add the forest's raw score of rows ``i0 .. i0 + m - 1`` of X to ``out``.

    Node k's children are ``child[2 k]`` (x <= thr) and ``child[2 k + 1]`` (else, NaN too);
    leaves point to themselves with an infinite threshold, so every tree is walked a fixed
    ``depth[t]`` steps. The walk is level by level over the block: each step of one pixel
    depends on its previous step (four loads in a chain), so the block's pixels, independent of
    each other, are what keeps the CPU busy (2x over walking each pixel to its leaf in turn).
    """
    ks = np.empty(m, np.int32)
    for t in range(roots.size):
        for j in range(m):
            ks[j] = roots[t]
        for _ in range(depth[t]):
            for j in range(m):
                k = ks[j]
                ks[j] = child[2 * k + np.int32(not X[i0 + j, feat[k]] <= thr[k])]
        for j in range(m):
            out[i0 + j] += value[ks[j]]


_BLOCK = 1024


@njit(cache=True)
def _ensemble_serial(X, feat, thr, child, value, roots, depth, baseline):
    """Raw (log-odds) score of each row of X under a forest stored as arrays, on one thread."""
    n = X.shape[0]
    out = np.full(n, baseline)
    for b in range((n + _BLOCK - 1) // _BLOCK):
        i0 = b * _BLOCK
        _walk_block(X, feat, thr, child, value, roots, depth, out, i0, min(n, i0 + _BLOCK) - i0)
    return out


@njit(cache=True, parallel=True)
def _ensemble_parallel(X, feat, thr, child, value, roots, depth, baseline):
    """:func:`_ensemble_serial` with the blocks shared among numba's threads."""
    n = X.shape[0]
    out = np.full(n, baseline)
    for b in prange((n + _BLOCK - 1) // _BLOCK):
        i0 = b * _BLOCK
        _walk_block(X, feat, thr, child, value, roots, depth, out, i0, min(n, i0 + _BLOCK) - i0)
    return out


def _walk_tables(feat, thr, left, right, leaf, roots):
    """(feat, float32 thresholds, interleaved children, roots, per-tree depths) for :func:`_walk_block`
    (thresholds as :func:`~skyfix.detect.forest.float32_thresholds` rounds them)."""
    idx = np.arange(feat.size)
    t32 = float32_thresholds(thr, leaf)
    child = np.empty(2 * feat.size, np.int32)
    child[0::2] = np.where(leaf, idx, left)
    child[1::2] = np.where(leaf, idx, right)
    depth = np.zeros(roots.size, np.int32)
    for t, r in enumerate(roots):
        level, d = [int(r)], 0
        while True:
            nxt = [c for k in level if not leaf[k] for c in (left[k], right[k])]
            if not nxt:
                break
            level, d = nxt, d + 1
        depth[t] = d
    return np.where(leaf, 0, feat).astype(np.int32), t32, child, roots.astype(np.int32), depth


@dataclass(frozen=True)
class SkyModel:
    """A tree ensemble giving the log-odds that a pixel is terrain rather than sky.

    Arrays are concatenated node tables; ``roots`` holds each tree's first node. ``left`` and
    ``right`` are absolute node indices. ``feature_names`` guards against a model trained on
    another feature set.
    """

    feat: np.ndarray
    thr: np.ndarray
    left: np.ndarray
    right: np.ndarray
    leaf: np.ndarray
    value: np.ndarray
    roots: np.ndarray
    baseline: float
    feature_names: tuple

    def log_odds_sky(self, X):
        """log P(sky) / P(terrain) per row of X (n, N_FEATURES)."""
        X = np.ascontiguousarray(X, dtype=np.float32).reshape(-1, N_FEATURES)
        # a parallel loop on one thread costs 25 % (the board's single core)
        parallel = num_threads() > 1
        elim = self._elimination()
        if elim is not None:
            return forest_scores(X, elim, self.baseline, parallel=parallel)
        return self.walk_log_odds_sky(X, parallel=parallel)

    def walk_log_odds_sky(self, X, *, parallel=False):
        """:meth:`log_odds_sky` by walking each tree to its leaf: the reference for the leaf
        elimination that :meth:`log_odds_sky` uses, and the way for trees of over 32 leaves."""
        X = np.ascontiguousarray(X, dtype=np.float32).reshape(-1, N_FEATURES)
        f, t, child, roots, depth = self._tables()
        kernel = _ensemble_parallel if parallel else _ensemble_serial
        return kernel(X, f, t, child, self.value, roots, depth, self.baseline)

    # caches, not state (the dataclass is frozen otherwise)
    def _tables(self):
        tab = self.__dict__.get("_tab")
        if tab is None:
            tab = _walk_tables(self.feat, self.thr, self.left, self.right, self.leaf, self.roots)
            object.__setattr__(self, "_tab", tab)
        return tab

    def _elimination(self):
        if "_elim" not in self.__dict__:
            object.__setattr__(self, "_elim", elimination_tables(
                self.feat, self.thr, self.left, self.right, self.leaf, self.value, self.roots,
                N_FEATURES))
        return self.__dict__["_elim"]

    def save(self, path):
        from .._io import atomic_path

        with atomic_path(path) as tmp:
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, feat=self.feat, thr=self.thr, left=self.left,
                                    right=self.right, leaf=self.leaf, value=self.value,
                                    roots=self.roots, baseline=np.float64(self.baseline),
                                    feature_names=np.array(self.feature_names))


def from_sklearn(clf) -> SkyModel:
    """Export a fitted binary ``HistGradientBoostingClassifier`` (classes False/True = sky) to
    arrays. Its leaf values already include the learning rate."""
    if list(clf.classes_) != [False, True]:
        raise ParameterError(f"expected classes [False, True] (True = sky), got {clf.classes_}")
    feats, thrs, lefts, rights, leaves, values, roots = [], [], [], [], [], [], []
    off = 0
    for it in clf._predictors:
        nodes = it[0].nodes
        if np.any(nodes["is_categorical"]):
            raise ParameterError("categorical splits are not supported")
        n = len(nodes)
        roots.append(off)
        feats.append(nodes["feature_idx"].astype(np.int64))
        thrs.append(nodes["num_threshold"].astype(np.float64))
        lefts.append(nodes["left"].astype(np.int64) + off)
        rights.append(nodes["right"].astype(np.int64) + off)
        leaves.append(nodes["is_leaf"].astype(np.bool_))
        values.append(nodes["value"].astype(np.float64))
        off += n
    base = float(np.ravel(clf._baseline_prediction)[0])
    return SkyModel(np.concatenate(feats), np.concatenate(thrs), np.concatenate(lefts),
                    np.concatenate(rights), np.concatenate(leaves), np.concatenate(values),
                    np.array(roots, np.int64), base, tuple(FEATURE_NAMES))


def load_sky_model(path=None, *, grey: bool = False) -> SkyModel:
    """Load a model written by :meth:`SkyModel.save` (default: the shipped one, for colour
    images, or with ``grey`` the one trained on grey copies)."""
    default = DEFAULT_GREY_MODEL if grey else DEFAULT_MODEL
    return _load_cached(str(Path(path) if path is not None else default))


@lru_cache(maxsize=4)
def _load_cached(path: str) -> SkyModel:
    p = Path(path)
    if not p.is_file():
        raise ParameterError(
            f"sky model {p} not found: train one with scripts/train_sky_model.py")
    with np.load(p, allow_pickle=False) as z:
        names = tuple(str(s) for s in z["feature_names"])
        if names != FEATURE_NAMES:
            raise ParameterError(
                f"sky model {p} was trained on features {names}, this code computes "
                f"{FEATURE_NAMES}: retrain with scripts/train_sky_model.py")
        return SkyModel(z["feat"].astype(np.int64), z["thr"].astype(np.float64),
                        z["left"].astype(np.int64), z["right"].astype(np.int64),
                        z["leaf"].astype(np.bool_), z["value"].astype(np.float64),
                        z["roots"].astype(np.int64), float(z["baseline"]), names)


def sky_label_mask(label_rgb):
    """True where a MarsScapes label image (H, W, 3 RGB) marks sky."""
    lab = np.asarray(label_rgb)
    return np.all(lab[..., :3] == np.array(SKY_RGB, lab.dtype), axis=-1)


# --- training (scikit-learn needed only here) -----------------------------------------------------

def training_pixels(image, sky_mask, *, model_pixels=250_000, no_data_black=True):
    """Features and labels of one labelled image on the classifier's scale.

    image : H x W x 3 RGB or H x W grey; sky_mask : H x W bool, True = sky (labels).
    Returns (X (n, N_FEATURES) float32, y (n,) bool, True = sky): the valid model-scale pixels
    whose label is pure (a mixed pixel on the boundary says nothing clean).
    """
    import cv2

    img, _, _ = as_gray_rgb(image)
    sky_mask = np.asarray(sky_mask, bool)
    if sky_mask.shape != img.shape[:2]:
        raise ParameterError(f"label shape {sky_mask.shape} does not match image {img.shape[:2]}")
    # the 2 px margin the shipped model was trained with (detection trusts 3 px in since; the
    # training pixels are sampled well inside the sky and the ground, where it makes no odds)
    valid = trusted(valid_mask(img, None, no_data_black), margin=2)
    gray = fill_invalid(to_float_gray(img), valid)
    X, v_m, fm = sky_inputs(img, valid, gray, model_pixels)
    frac = downscale(sky_mask.astype(np.float32), fm)
    if frac.shape != v_m.shape:  # cv2 rounding; both are floor(H / fm)
        frac = cv2.resize(frac, (v_m.shape[1], v_m.shape[0]), interpolation=cv2.INTER_AREA)
    keep = v_m & ((frac <= 0.1) | (frac >= 0.9))
    return X[keep], frac[keep] >= 0.9


def sky_classifier(*, seed=0, max_iter=60, max_leaf_nodes=16, max_depth=4, learning_rate=0.15):
    """The sky model's estimator, unfitted: scikit-learn's ``HistGradientBoostingClassifier`` with
    the shipped recipe (what :func:`fit_sky_model` fits; benchmarks that refit it on other
    features take it from here)."""
    HistGradientBoostingClassifier = require(
        "sklearn.ensemble", "training the sky model").HistGradientBoostingClassifier
    return HistGradientBoostingClassifier(max_iter=max_iter, max_leaf_nodes=max_leaf_nodes,
                                          max_depth=max_depth, learning_rate=learning_rate,
                                          l2_regularization=1.0, min_samples_leaf=100,
                                          early_stopping=False, random_state=seed)


def fit_sky_model(parts, *, per_image=20_000, seed=0, max_iter=60, max_leaf_nodes=16,
                  max_depth=4, learning_rate=0.15, balance=True):
    """Train the classifier on several images' :func:`training_pixels` (X, y) pairs.

    Each image contributes at most ``per_image`` pixels, drawn at random, and equal total weight,
    so a large mosaic does not outvote a small one; with ``balance`` sky and terrain get equal
    total weight (prior odds 1). Returns (:class:`SkyModel`, the fitted scikit-learn estimator).
    """
    clf = sky_classifier(seed=seed, max_iter=max_iter, max_leaf_nodes=max_leaf_nodes,
                         max_depth=max_depth, learning_rate=learning_rate)
    rng = np.random.default_rng(seed)
    Xs, ys, ws = [], [], []
    for X, y in parts:
        if len(y) == 0:
            continue
        idx = rng.choice(len(y), size=min(per_image, len(y)), replace=False)
        Xs.append(X[idx])
        ys.append(y[idx])
        ws.append(np.full(idx.size, 1.0 / idx.size))
    if not Xs:
        raise ParameterError("no labelled pixels to train the sky model on")
    X = np.concatenate(Xs)
    y = np.concatenate(ys)
    if y.all() or not y.any():
        raise ParameterError("training pixels hold only one class (need both sky and terrain)")
    w = np.concatenate(ws)
    if balance:
        # equal total weight to sky and terrain: the region term should carry the evidence of the
        # pixels, not the dev set's share of sky (which an unseen panorama need not share)
        w = np.where(y, w / w[y].sum(), w / w[~y].sum())
    w *= len(y) / w.sum()
    clf.fit(X, y, sample_weight=w)
    return from_sklearn(clf), clf


def sky_inputs(img, valid, gray, model_pixels):
    """Classifier features on a copy downscaled to at most ``model_pixels`` [px].

    img : the input image; valid : trusted valid pixels; gray : filled float grey.
    Returns (X (hm, wm, k) float32, valid_m (hm, wm) bool, fm the integer downscale factor).
    """
    H, W = gray.shape
    fm = downscale_factor(H, W, model_pixels)
    g_m = downscale(gray, fm)
    v_m = downscale_valid(valid, fm)
    # chroma needs no filling: it is per pixel, and invalid pixels never enter the region term
    rgb_m = downscale_rgb(img, fm) if img.ndim == 3 else None
    return sky_features(g_m, rgb_m, v_m), v_m, fm


def sky_log_odds(img, valid, gray, model, model_pixels):
    """log P(sky)/P(terrain) per pixel of the model-scale copy: (lo (hm, wm), valid_m, fm)."""
    X, v_m, fm = sky_inputs(img, valid, gray, model_pixels)
    hm, wm = v_m.shape
    lo = model.log_odds_sky(X.reshape(hm * wm, -1)).reshape(hm, wm)
    return lo, v_m, fm


def resolve_model(model, grey=False) -> "SkyModel":
    """A :class:`SkyModel` from a model, a path to one, or None (the shipped colour model, or the
    grey one when ``grey``)."""
    if isinstance(model, SkyModel):
        return model
    return load_sky_model(model, grey=grey)
