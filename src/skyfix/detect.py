"""Stage 5: the skyline in an image, or the statement that there is none.

Output (:class:`skyfix.formats.Skyline`): per column the row [px, 0-based, sub-pixel] of the
first terrain pixel below the sky, NaN where no skyline is visible (the column is all terrain,
all sky, or holds no data), and a confidence in [0, 1].

Two detectors share one exact dynamic-programming kernel (:func:`_dp_solve`, numba):

``dp`` (default)
    A dense multi-stage graph over the pixels of a downscaled working copy. A path visits one or
    more pixels per column; it moves to the next column at -1/0/+1 row, or up/down within a
    column (steep or vertical skyline sections). A pixel costs
    ``w_grad (1 - |grad|) + w_edge (1 - canny) + w_height row/H``, a step between columns adds
    ``w_diff | |grad|(r, c) - |grad|(r', c-1) |`` (the source study's four terms, on CLAHE'd,
    smoothed grey with Canny thresholds from Otsu), and entering a column at row ``r`` adds a
    region term: ``w_region`` times the sum, over the pixels above ``r``, of how unlike sky
    they look: a texture likelihood ratio (the sky is smooth, terrain is not) plus ``w_model``
    times the log-odds of a small learned sky-vs-terrain classifier (:mod:`skyfix.skymodel`,
    trained by ``scripts/train_sky_model.py`` on the dev mosaics; prefix sums make the cost of
    every row O(1)). A textured pixel that the classifier calls sky and that is brighter than the
    clear sky in every colour channel is taken for cloud, and its texture counts for neither
    (``cloud_llr``). Each column also
    has an explicit *no-skyline* state whose cost is that of calling the whole column terrain (or
    the whole column sky) plus ``none_cost``; switching between it and the skyline costs
    ``switch_cost``. The exact optimum is found on the working copy, then each column is refined
    at full resolution by a narrow band DP on the vertical intensity step.

``bayes``
    The NASA Ames formulation (sky/ground segmentation by column transitions): per-pixel
    observations (intensity, local edge density at two scales, chroma); sky and ground
    likelihoods start from priors (the sky is smooth and high in the image) and are re-learned
    by a random forest from the current segmentation; the column log-likelihood of a transition
    at each row comes from prefix sums, plus a boundary term (a transition where the grey level
    does not step costs up to ``w_boundary``); a Viterbi pass with a smoothness window and a
    no-skyline state gives the segmentation; iterate until the total likelihood stops improving.

Pixels outside ``mask`` and, by default, pure black (0, 0, 0) pixels are no data: they are filled
from their nearest valid neighbour before filtering (so the mosaic border makes no edge) and a
skyline may only lie where the pixel and the one above it are valid.

:func:`score_skyline` scores a detection against a truth skyline with the metrics of
``shared/data/README.md``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, fields, replace

import numba
import numpy as np

from .errors import ParameterError
from .formats import Skyline

METHODS = ("dp", "bayes")

#: smallest image searched, width x height [px]
MIN_WIDTH_PX, MIN_HEIGHT_PX = 2, 8

_BIG = 1e18


# --- configuration -------------------------------------------------------------------------------

@dataclass(frozen=True)
class DpOptions:
    """Options of the ``dp`` detector (weights are dimensionless).

    work_pixels : the image is downscaled by an integer factor to at most this many pixels for
        the global search [px]
    w_grad, w_edge, w_height, w_diff : the source study's terms (gradient magnitude, Canny
        edge-ness, height in the image, gradient difference between neighbours)
    w_region : weight of the sky-likeness of the pixels above the skyline, per pixel of height
        (summed over the column, so it is in units of "rows")
    region : ``"both"`` (default): the hand-set texture term plus ``w_model`` times the learned
        sky classifier's log-odds (:mod:`skyfix.skymodel`); ``"model"``: the classifier alone;
        ``"texture"``: the texture term alone (no model needed). Leave-one-image-out on the dev
        set, ``both`` beat each alone; the classifier alone also fails on synthetic skies whose
        colour equals the terrain's (it learnt Mars's colours), which the texture term keeps
        honest. Grey images (or RGB with R = G = B) use the classifier trained on grey copies
        (``skyfix/models/sky_hgb_grey.npz``) and no cloud rule. Dev set held out, in grey: 1.41
        -> 1.34 px, missed 11.8 -> 8.3 %, false 2.07 -> 2.15 % (404_1) against ``texture``; the
        15 wide-camera frames in grey 83 -> 1.3 % missed, as JPEG 100 -> 0 %. The price is under
        clouds: simulated CLUT in grey finds more but worse columns (within 3 px 93 -> 76 %,
        missed 69 -> 47 %; a grey cloud rule misfired on clear skies, REF 0.3 -> 1.8 px)
    w_model : weight of the classifier's log-odds [nats] in the ``both`` region term
    model_pixels : the classifier runs on a copy downscaled to at most this many pixels [px]
    llr_clip : the classifier's per-pixel log-odds are clipped to +-``llr_clip`` [nats], so a
        few confident mistakes cannot dominate a column
    texture_ratio : (``region="texture"``) a pixel whose local texture is below
        ``texture_ratio`` times the image's median texture looks like sky
    noise_ratio : ... or below ``noise_ratio`` times the sensor noise's texture (estimated from
        the image's smoothest blocks): over smooth ground a noisy sky's texture exceeds
        ``texture_ratio`` times the median, and would otherwise look like terrain
    none_cost : extra cost of the no-skyline state per column (what a missing edge costs)
    switch_cost : cost of switching between skyline and no-skyline between columns
    vertical_cost : extra cost per pixel of a move within a column
    jump_cost : cost of a one-row change between columns
    min_sky_rows : a skyline needs at least this many valid working-scale rows above it in its
        column: a sliver under the mosaic's top edge is too thin to tell sky from hazy terrain,
        and calling it sky is the commonest false skyline [working px]
    refine_band : half-height of the full-resolution refinement band, in working-scale rows
    min_confidence : a column whose skyline confidence is below this is reported as unknown
        (no row, confidence 0) rather than guessed. Measured per column at 0.15: of the rows
        within 3 px of the truth 1.8 % (Curiosity dev set) / 0.3 % (simulated sets) are dropped,
        of the false skylines 55 % / 86 %, of the rows more than 10 px off 60 % / 67 %
    min_run : a run of skyline columns narrower than this many working columns, with no
        skyline (or no data) on both sides, is reported unknown: what survives the
        ``min_confidence`` cut in isolated slivers is mostly a haze band's edge or a cloud's.
        Dev set, leave-one-image-out: 1.37 -> 1.33 px, false skyline 3.24 -> 3.19 %, missed
        8.08 -> 8.17 %; simulated CLUT 45 -> 40 px; REF, OCCL unchanged [working px]
    anchor_conf, anchor_gap, anchor_len : (0 disables) hysteresis over runs of skyline columns,
        as Canny's over edge pixels: weak evidence is accepted as the continuation of a skyline,
        not on its own. A run is an anchor when its mean confidence is >= ``anchor_conf`` or it
        spans >= ``anchor_len`` of the image's width; runs separated by gaps of <= ``anchor_gap``
        of the width are linked; runs with no anchor among their links are reported unknown.
        What it removes are the slivers left along a hazy mountain's foot or on dark ground
        below a mosaic's top edge. Dev set, leave-one-image-out: false skyline 3.19 -> 2.16 %
        (all of 431_1's and 432_2's), no column within 3 px lost, missed unchanged; shipped
        model 2.19 -> 2.16 %. Simulated REF, CLUT, OCCL, COND, wide-camera frames: no change.
        Same on any ``anchor_conf`` from 0.35 to 0.5 (431_1's slivers average 0.25-0.31); a
        gap of 0.1 cut weak but true skylines in two COND frames (113 columns); without
        ``anchor_len`` the wide frames lost 2,500 correct columns of weak but whole skylines.
        Scenario-2/-3 calibration frames (Alps, Sierra, 5 cases per set): of 994 columns
        removed, 789 were > 3 px off, 204 within 3 px [fractions of the image width]
    cloud_llr : (``region="both"``; 0 disables) a pixel the texture term calls terrain but the
        classifier calls sky with log-odds above this [nats], and which is brighter than the
        clear sky in every colour channel (:func:`_cloud_like`), is taken for a cloud: its
        texture term is set to 0. Clouds are textured, so otherwise a column whose sky holds one
        costs more as a skyline than as "no skyline", or the cloud's lower edge is taken. A
        sunlit cloud scatters every band more than the clear sky; sunlit grey ground under a
        blue sky is brighter in grey level but not in blue (the classifier, trained on Mars,
        calls it sky): a grey-level test misfired there (a glacier frame set 0.63 -> 8.6 px, its
        scenario-1 fix 0.2 -> 6.1 m at confidence 0.98), the per-channel one does not (0.64 px).
        Simulated CLUT (Earth clouds) 39.5 -> 13.4 px, missed 45 -> 13 %; REF, OCCL unchanged;
        dev set held out: missed 8.2 -> 6.9 %, error and false skyline unchanged
    cloud_sure_share : the cloud rule stands down in an image where the unmistakable sky (smooth,
        log-odds > 2) is less than this share of what the classifier calls sky (log-odds >
        ``cloud_llr``): the texture term then calls the bulk of the sky itself textured (a
        steep zenith-to-horizon gradient over a wide field, vignetting, noise), the smooth
        remnant is the darkest corner of the sky, and sunlit terrain below the horizon is
        "brighter than the sky" in every channel. Measured share: wide-camera Earth frames of
        ``benchmarks/bench_profile.py`` 0.10-0.55, the five where the rule moved the skyline
        down to a nearer ridge 0.14-0.33 (15 frames: 0.17 -> 4.7 px; profile p95 0.06 -> 3.9
        deg); simulated navcam frames with clouds 0.44-0.91, without 0.65-0.97. So a sky more
        than about 60 % clouded (textured) gets no cloud rule
    sure_sky_q, sure_sky_llr, sure_sky_share : (``region="both"``; ``sure_sky_q`` 0 disables) the
        texture term's sky threshold is raised to the ``sure_sky_q`` percentile of the texture of
        the pixels the classifier calls sky with log-odds above ``sure_sky_llr`` [nats], when
        they are at least ``sure_sky_share`` of the valid pixels. A wide camera's sky darkens
        steeply towards the horizon and Sobel reads that gradient as texture; in the simulator's
        raw frames the noise floor (``noise_ratio``) happened to cover it, but JPEG, a slight
        blur or the resampling of a stitched panorama remove the noise and the sky then looked
        textured. 15 wide-camera Earth frames, missed skyline: JPEG quality 70 56 -> 0.1 %,
        Gaussian blur 1 px 45 -> 0.3 %, bilateral denoising 45 -> 0.3 %; stitched frame sets
        (``stitch``, 3 partial + 3 full circle + 1 small) 20.7 -> 3.9 %. Unchanged: the dev set
        (shipped model and leave-one-image-out; there the classifier's sure sky is far smoother
        than the threshold), simulated REF / CLUT / OCCL / COND, the raw wide-camera and glacier
        frames. Same on the dev set for any percentile from 25 to 50; the share keeps out the
        no-sky mosaics, where a few confident mistakes on rough ground (1.7 % of 389_2, 0.1 % of
        431_2) would raise the threshold to the terrain's texture [percent, nats, fraction]
    no_data_black : treat (0, 0, 0) pixels as no data
    """

    work_pixels: int = 600_000
    w_grad: float = 0.3
    w_edge: float = 0.3
    w_height: float = 0.1
    w_diff: float = 0.05
    w_region: float = 0.08
    region: str = "both"
    model_pixels: int = 250_000
    llr_clip: float = 1.5
    texture_ratio: float = 0.35
    noise_ratio: float = 1.0
    sure_sky_q: float = 50.0
    sure_sky_llr: float = 3.0
    sure_sky_share: float = 0.05
    w_model: float = 0.25
    none_cost: float = 0.2
    switch_cost: float = 8.0
    vertical_cost: float = 0.15
    jump_cost: float = 0.05
    min_sky_rows: int = 3
    refine_band: float = 1.5
    min_confidence: float = 0.15
    min_run: int = 4
    anchor_conf: float = 0.5
    anchor_gap: float = 0.15
    anchor_len: float = 0.1
    cloud_llr: float = 1.0
    cloud_sure_share: float = 0.4
    no_data_black: bool = True


@dataclass(frozen=True)
class BayesOptions:
    """Options of the ``bayes`` detector.

    work_pixels : working-copy size for the whole method [px]
    window : smoothness window, the largest row change between neighbouring columns [working px]
    jump_cost : log-likelihood cost per row of change between columns
    switch_cost : cost of switching between skyline and no-skyline between columns
    none_cost : extra cost of the no-skyline state per column
    w_boundary : cost [nats] of a transition where the grey level does not step between rows
        (scaled down linearly to 0 at the image's 99th-percentile step). Region likelihoods
        alone put the transition where the sky's haze gradient or a blurred feature flips, rows
        above the edge; dev set: 40 -> 1.8 px mean error, 91 % within 3 px (0 -> 10.2 px, 48 %);
        20 -> 5.5 px, 88 %; 80 -> 1.8 px, 93 % but 21 % of the skyline missed (15 % at 40)
    init : ``"model"``: the first likelihoods are the texture/position prior plus ``w_model``
        times the learned sky classifier's log-odds (colour images); ``"prior"`` (default): the
        prior alone. On the dev set (the classifier trained on it, so flattering ``model``)
        ``prior`` is better: 1.8 vs 2.8 px, false skyline 3.8 % vs 5.4 %
    max_iter : most re-learning rounds
    n_train : pixels sampled to train each random forest
    seed : random seed (the forest and the sample)
    min_sky_rows : a skyline needs at least this many valid working-scale rows above it (as
        :class:`DpOptions`)
    sure_sky_q : (colour images; 0, the default, disables) the prior's texture threshold is
        raised to this percentile of the texture of the pixels the sky classifier is sure of
        (:class:`DpOptions` ``sure_sky_*``). For wide-angle frames: the prior reads a wide sky's
        steep gradient as texture and calls no column a skyline. 15 wide-camera Earth frames:
        99.4 % of the skyline missed without, 0 % at 90 (0.22 px, 99.1 % within 3 px; 7 % missed
        at 75; all missed at 99, where smooth terrain passes for sky too). Off by default: on the
        Curiosity dev set it finds more columns but worse ones (missed 14.9 -> 11.6 %, within
        3 px 91.3 -> 88.2 %) [percent]
    """

    work_pixels: int = 300_000
    window: int = 4
    jump_cost: float = 0.3
    switch_cost: float = 10.0
    none_cost: float = 2.0
    init: str = "prior"
    w_model: float = 1.0
    max_iter: int = 5
    n_train: int = 20_000
    seed: int = 0
    min_sky_rows: int = 3
    w_boundary: float = 40.0
    sure_sky_q: float = 0.0
    no_data_black: bool = True


PRESETS = {"dp": DpOptions(), "bayes": BayesOptions()}

# Ranges the options must lie in. The kernels do not check them, and most wrong values would give
# a quiet nonsense answer rather than a crash (a negative weight rewards an edge-free skyline, a
# gap of -0.1 links nothing), so they are refused up front, naming the option.
_AT_LEAST_ONE = {"work_pixels", "model_pixels", "window", "max_iter", "n_train"}
_FRACTIONS = {"min_confidence", "anchor_conf", "anchor_gap", "anchor_len", "cloud_sure_share",
              "sure_sky_share"}
_PERCENTS = {"sure_sky_q"}  # both detectors' option
_CHOICES = {"region": ("both", "model", "texture"), "init": ("prior", "model")}


def _check_options(opt) -> None:
    """Raise :class:`ParameterError` naming the first option of ``opt`` out of its range."""
    for f in fields(opt):
        name, v = f.name, getattr(opt, f.name)
        if name in _CHOICES:
            if v not in _CHOICES[name]:
                raise ParameterError(f"option {name}={v!r}: choose one of {', '.join(_CHOICES[name])}")
        elif f.type in ("bool", bool):
            if not isinstance(v, (bool, np.bool_)):
                raise ParameterError(f"option {name}={v!r}: give True or False")
        elif f.type in ("int", int):
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
                raise ParameterError(f"option {name}={v!r}: give a whole number")
            low = 1 if name in _AT_LEAST_ONE else 0
            if v < low:
                raise ParameterError(f"option {name}={v}: must be >= {low}")
        else:
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)):
                raise ParameterError(f"option {name}={v!r}: give a number")
            if not np.isfinite(v) or v < 0:
                raise ParameterError(f"option {name}={v}: must be a finite number >= 0")
            if name in _FRACTIONS and v > 1:
                raise ParameterError(f"option {name}={v}: must be a fraction in [0, 1]")
            if name in _PERCENTS and v > 100:
                raise ParameterError(f"option {name}={v}: must be a percentile in [0, 100]")


# --- the DP kernel --------------------------------------------------------------------------------

@numba.njit(cache=True)
def _dp_solve(enter_cost, vert_cost, grad, none_cost, window, jump_cost, w_diff, switch_cost):
    """Exact minimum-cost path over a column-staged graph with a no-skyline state.

    enter_cost (H, W): cost of the path entering column c at row r (inf = forbidden)
    vert_cost (H, W): cost of moving onto pixel (r, c) from (r -+ 1, c) (inf = no vertical moves)
    grad (H, W): normalised gradient magnitude, for the neighbour-difference term
    none_cost (W,): cost of the no-skyline state in column c
    window: largest row change between columns; jump_cost: cost per row of change
    Returns (path_top (W,), path_bottom (W,)): the rows the path covers in each column, -1 for
    the no-skyline state.
    """
    H, W = enter_cost.shape
    D = np.empty((H, W))
    DN = np.empty(W)
    # back pointers: 0..2w = from (r + k - w, c - 1); 2w+1 = from N; 2w+2 = from above (r-1, c);
    # 2w+3 = from below (r+1, c)
    bp = np.empty((H, W), dtype=np.int16)
    bpn = np.empty(W, dtype=np.int8)  # 0: from N, 1: from the best skyline row
    best_prev_row = np.empty(W, dtype=np.int64)
    FROM_N = 2 * window + 1
    FROM_UP = 2 * window + 2
    FROM_DOWN = 2 * window + 3
    for r in range(H):
        D[r, 0] = enter_cost[r, 0]
        bp[r, 0] = FROM_N
    DN[0] = none_cost[0]
    bpn[0] = 0
    for c in range(W):
        if c > 0:
            # best skyline state of the previous column, for switches into N
            bi = 0
            bv = D[0, c - 1]
            for r in range(1, H):
                if D[r, c - 1] < bv:
                    bv = D[r, c - 1]
                    bi = r
            best_prev_row[c] = bi
            if DN[c - 1] <= bv + switch_cost:
                DN[c] = DN[c - 1] + none_cost[c]
                bpn[c] = 0
            else:
                DN[c] = bv + switch_cost + none_cost[c]
                bpn[c] = 1
            for r in range(H):
                ec = enter_cost[r, c]
                if ec >= _BIG:
                    D[r, c] = _BIG
                    bp[r, c] = FROM_N
                    continue
                best = DN[c - 1] + switch_cost
                arg = FROM_N
                g = grad[r, c]
                for k in range(-window, window + 1):
                    rp = r + k
                    if rp < 0 or rp >= H:
                        continue
                    v = D[rp, c - 1]
                    if v >= _BIG:
                        continue
                    v += jump_cost * abs(k) + w_diff * abs(g - grad[rp, c - 1])
                    if v < best:
                        best = v
                        arg = k + window
                D[r, c] = best + ec
                bp[r, c] = arg
        # moves within the column: one sweep down, one up (costs are non-negative, so a path
        # never needs to reverse direction inside a column)
        for r in range(1, H):
            vc = vert_cost[r, c]
            if vc < _BIG and D[r - 1, c] + vc < D[r, c]:
                D[r, c] = D[r - 1, c] + vc
                bp[r, c] = FROM_UP
        for r in range(H - 2, -1, -1):
            vc = vert_cost[r, c]
            if vc < _BIG and D[r + 1, c] + vc < D[r, c]:
                D[r, c] = D[r + 1, c] + vc
                bp[r, c] = FROM_DOWN
    top = np.full(W, -1, dtype=np.int64)
    bottom = np.full(W, -1, dtype=np.int64)
    # end state
    bi = 0
    bv = D[0, W - 1]
    for r in range(1, H):
        if D[r, W - 1] < bv:
            bv = D[r, W - 1]
            bi = r
    in_none = DN[W - 1] <= bv
    r = bi
    c = W - 1
    while c >= 0:
        if in_none:
            if bpn[c] == 1 and c > 0:
                in_none = False
                r = best_prev_row[c]
            c -= 1
            continue
        if top[c] < 0 or r < top[c]:
            top[c] = r
        if bottom[c] < 0 or r > bottom[c]:
            bottom[c] = r
        a = bp[r, c]
        if a == FROM_UP:
            r -= 1
        elif a == FROM_DOWN:
            r += 1
        elif a == FROM_N:
            in_none = True
            c -= 1
        else:
            r = r + a - window
            c -= 1
    return top, bottom


@numba.njit(cache=True)
def _column_prefix(d, valid):
    """P[r, c] = sum of d[0:r, c] over valid pixels; shape (H + 1, W)."""
    H, W = d.shape
    P = np.zeros((H + 1, W))
    for c in range(W):
        s = 0.0
        for r in range(H):
            if valid[r, c]:
                s += d[r, c]
            P[r + 1, c] = s
    return P


# --- shared preprocessing ------------------------------------------------------------------------

def _as_gray_rgb(image):
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[..., :3]
    if img.ndim == 2:
        rgb = None
        gray = img
    elif img.ndim == 3 and img.shape[2] == 3:
        rgb = img
        gray = None
    else:
        raise ParameterError(
            f"image must be H x W (grey) or H x W x 3 (RGB), got shape {img.shape}")
    h, w = img.shape[:2]
    if w < MIN_WIDTH_PX or h < MIN_HEIGHT_PX:
        raise ParameterError(f"image of {w} x {h} px (width x height) is too small to search: "
                             f"at least {MIN_WIDTH_PX} x {MIN_HEIGHT_PX} px")
    return img, gray, rgb


def _is_grey_rgb(img) -> bool:
    """True when every pixel of an H x W x 3 image has R = G = B (a grey image stored as RGB)."""
    return bool(np.array_equal(img[..., 0], img[..., 1]) and np.array_equal(img[..., 1], img[..., 2]))


def _valid_mask(img, mask, no_data_black):
    H, W = img.shape[:2]
    if mask is None:
        valid = np.ones((H, W), dtype=bool)
    else:
        mask = np.asarray(mask)
        if mask.shape != (H, W):
            raise ParameterError(f"mask shape {mask.shape} does not match the image ({H}, {W})")
        valid = mask.astype(bool)
    if no_data_black:
        black = (img == 0) if img.ndim == 2 else np.all(img == 0, axis=2)
        valid &= ~black
    return valid


def _trusted(valid, margin=3):
    """Valid pixels at least ``margin`` px from no-data: mosaic borders carry a dark seam and a
    resampling overshoot that would otherwise read as a strong edge. 3 px, not 2: a mosaic
    resampled once (down by 2 and back) smears its black border into a grey ramp 2-3 px wide.
    Dev set held out (``bench_detect.py --cv``), so resampled (``--degrade resample:2``): missed
    skyline 11.9 % at 2 px, 8.4 % at 3 (7.8 % at 4); as delivered: 1.32 -> 1.31 px, 94.6 -> 94.8 %
    within 3 px, false unchanged, missed 6.92 -> 6.96 % at 3 px (7.19 % at 4: slivers under the
    mosaic's top edge)."""
    import cv2

    if valid.all() or margin <= 0:
        return valid
    k = np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)
    return cv2.erode(valid.astype(np.uint8), k, borderType=cv2.BORDER_REPLICATE).astype(bool)


def _to_float_gray(img):
    if img.ndim == 2:
        g = img.astype(np.float32)
    else:
        g = img[..., :3].astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
    if img.dtype == np.uint16:
        g *= 255.0 / 65535.0
    elif img.dtype.kind == "f" and g.size and np.nanmax(g) <= 1.0:
        g *= 255.0
    return g


@numba.njit(cache=True)
def _mirror_fill_columns(arr, valid, out, done):
    """Above the first and below the last valid pixel of a column, mirror the column about that
    pixel (at most 4 rows deep, then repeat, so no-data is not filled with distant content): a mirrored edge has the same gradient as the data, so the first valid row does not look
    smoother (more sky-like) than the rows below it, as it would with replicated values."""
    H, W = valid.shape
    for c in range(W):
        t0 = -1
        t1 = -1
        for r in range(H):
            if valid[r, c]:
                if t0 < 0:
                    t0 = r
                t1 = r
        if t0 < 0:
            continue
        for r in range(0, t0):
            src = min(t0 + min(t0 - r, 4), t1)
            if not valid[src, c]:
                src = t0
            out[r, c] = arr[src, c]
            done[r, c] = True
        for r in range(t1 + 1, H):
            src = max(t1 - min(r - t1, 4), t0)
            if not valid[src, c]:
                src = t1
            out[r, c] = arr[src, c]
            done[r, c] = True


def _fill_invalid(arr, valid):
    """Replace invalid pixels from valid ones (so no-data makes no edges): mirrored along the
    column above and below the data, nearest valid pixel elsewhere."""
    if valid.all() or not valid.any():
        return arr
    from scipy import ndimage

    if arr.ndim == 2:
        out = arr.copy()
        done = valid.copy()
        _mirror_fill_columns(arr, valid, out, done)
        if done.all():
            return out
        arr, valid = out, done

    # strongly anisotropic distance: take the nearest valid pixel of the same column when there is
    # one (replicating the edge row vertically makes no horizontal seam, which isotropic nearest
    # filling does where two mosaic tiles meet)
    idx = ndimage.distance_transform_edt(~valid, sampling=(1.0, 64.0), return_distances=False,
                                         return_indices=True)
    return arr[tuple(idx)]


def _downscale_factor(H, W, work_pixels):
    return max(1, int(math.ceil(math.sqrt(H * W / float(work_pixels)))))


def _downscale(arr, f):
    import cv2

    if f == 1:
        return arr
    H, W = arr.shape[:2]
    return cv2.resize(arr, (max(1, W // f), max(1, H // f)), interpolation=cv2.INTER_AREA)


def _downscale_valid(valid, f):
    """A working pixel is valid when all the full-resolution pixels it covers are."""
    if f == 1:
        return valid
    H, W = valid.shape
    h, w = H // f, W // f
    v = valid[: h * f, : w * f].reshape(h, f, w, f)
    return v.all(axis=(1, 3))


def _texture(gray_s, valid_s, radius):
    """Local mean of the Sobel magnitude [grey levels / px] over a (2 radius + 1)^2 box."""
    import cv2

    gx = cv2.Sobel(gray_s, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(gray_s, cv2.CV_32F, 0, 1, ksize=3)
    mag = np.sqrt(gx * gx + gy * gy)
    # averaged mostly along the row: a tall blur would smear the sky/terrain boundary over
    # several rows (the region term sums rows exactly); a wide one tames the sky's noise
    k = 2 * radius + 1
    return cv2.blur(mag, (2 * k + 1, 3))


def _noise_level(gray_s, valid_s, block=15):
    """Sensor noise level [grey levels]: the mean absolute response to the second-difference mask
    of Immerkaer (1996), which is blind to linear gradients such as the sky's, over blocks, in the
    smoothest 5 % of the valid blocks (the sky, when there is one). White noise of std s gives
    about 4 s here and a texture (:func:`_texture`) of about 2 s, so ``noise_ratio`` 1 puts the
    sky threshold near twice the noise's own texture."""
    import cv2

    if not valid_s.any():
        return 0.0
    n = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    lap = np.abs(cv2.filter2D(np.asarray(gray_s, np.float32), -1, n))
    loc = cv2.blur(lap, (block, block))
    return float(np.percentile(loc[valid_s], 5))


# --- the dp detector -----------------------------------------------------------------------------

def _texture_region(gray_s, valid_s, opt: DpOptions, sure_sky=None):
    """Texture region term per working pixel: log of the local texture over the sky threshold,
    clipped to [-1, 1]; < 0 looks like sky, > 0 like terrain. ``sure_sky`` (bool, optional): the
    pixels the sky classifier is sure of (``DpOptions.sure_sky_*``)."""
    import cv2

    # sky-likeness from texture of the un-equalised grey (CLAHE would lift the sky's noise)
    tex = _texture(cv2.GaussianBlur(gray_s, (3, 3), 0.8), valid_s, 3).astype(np.float64)
    tv = tex[valid_s] if valid_s.any() else np.ones(1)
    # the median alone collapses to ~0 when over half the image is smooth (a big clean sky,
    # smooth rendered terrain), and then nothing looks like sky: floor it by the textured part
    med = max(float(np.median(tv)), 0.25 * float(np.percentile(tv, 90)))
    # a pixel whose texture is no more than the sensor noise's is sky-like whatever the rest
    # of the image does: in a noisy frame over smooth ground 0.35 median is below the noise
    thr = max(opt.texture_ratio * med, opt.noise_ratio * _noise_level(gray_s, valid_s))
    # ... and the typical texture of the sky the classifier is sure of counts as sky: a wide
    # camera's sky darkens steeply towards the horizon, and that gradient is texture to Sobel. In
    # a raw frame the noise floor above happens to cover it; JPEG, a slight blur or the resampling
    # of a stitched panorama remove the noise, and the sky then looked textured (see DpOptions)
    n_sure = np.count_nonzero(sure_sky) if sure_sky is not None and opt.sure_sky_q > 0 else 0
    if n_sure >= 100 and n_sure >= opt.sure_sky_share * np.count_nonzero(valid_s):
        thr = max(thr, float(np.percentile(tex[sure_sky], opt.sure_sky_q)))
    # log ratio to the sky threshold: < 0 looks like sky, > 0 like terrain; clipped so a few
    # wild pixels cannot dominate a column
    return np.clip(np.log((tex + 0.05 * med + 1e-6) / (thr + 1e-6)), -1.0, 1.0)


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
    scale = np.percentile(mag[valid_s], 99) if valid_s.any() else 1.0
    G = np.clip(mag / max(scale, 1e-6), 0, 1).astype(np.float64)
    # edge-ness falls off over a couple of pixels from a Canny edge
    dist = cv2.distanceTransform((~edges).astype(np.uint8), cv2.DIST_L2, 3)
    E = np.exp(-dist / 1.5).astype(np.float64)

    if d is None:
        d = _texture_region(gray_s, valid_s, opt)
    P = _column_prefix(d, valid_s)  # (h + 1, w)

    rows = np.arange(h, dtype=np.float64)[:, None]
    pix = opt.w_grad * (1 - G) + opt.w_edge * (1 - E) + opt.w_height * rows / h
    ok = _skyline_allowed(valid_s, opt.min_sky_rows)
    enter = pix + opt.w_region * P[:-1]
    enter = np.where(ok, enter, _BIG)
    vert = np.where(ok, pix + opt.vertical_cost, _BIG)
    # no skyline: the whole column terrain (region 0) or the whole column sky (P[h])
    none = opt.none_cost + opt.w_region * np.minimum(0.0, P[h])
    return enter, vert, G, none, d


def _skyline_allowed(valid, min_sky_rows=1):
    """Where a skyline row may lie (bool, shape of ``valid``): the pixel and the one above it are
    valid (sky above, terrain at r) and at least ``min_sky_rows`` valid rows lie above it."""
    ok = valid.copy()
    ok[1:] &= valid[:-1]
    ok[0] = False
    if min_sky_rows > 1:
        ok &= (np.cumsum(valid, axis=0) - valid) >= min_sky_rows
    return ok


def _vertical_step(gray):
    """|grey(r) - grey(r - 1)| [grey levels] on the grey smoothed with sigma 1 px; row 0 is 0."""
    import cv2

    sm = cv2.GaussianBlur(np.asarray(gray, np.float32), (0, 0), 1.0)
    step = np.zeros_like(sm)
    step[1:] = np.abs(sm[1:] - sm[:-1])
    return step


def _refine_full(gray, valid, top_full, bottom_full, f, opt: DpOptions):
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
    step = _vertical_step(gray)  # the skyline is at r when the step into r is large
    ok = _skyline_allowed(valid)
    m = int(math.ceil(opt.refine_band * f)) + 1
    a = np.where(have, np.floor(np.nan_to_num(top_full)) - m, 0).astype(np.int64)
    b = np.where(have, np.ceil(np.nan_to_num(bottom_full)) + f - 1 + m, -1).astype(np.int64)
    a = np.clip(a, 0, H - 1)
    b = np.clip(b, -1, H - 1)
    lo = int(a[have].min())
    hi = int(b[have].max()) + 1
    rows = np.arange(lo, hi)[:, None]
    inband = (rows >= a[None, :]) & (rows <= b[None, :])
    sub_ok = ok[lo:hi] & inband
    scale = np.percentile(step[ok], 99.5) if ok.any() else 1.0
    # prefer the coarse span (its centre) a little, so texture steps nearby do not pull the row
    mid = 0.5 * (np.nan_to_num(top_full) + np.nan_to_num(bottom_full) + f - 1)
    span = 0.5 * (np.nan_to_num(bottom_full) - np.nan_to_num(top_full) + f) + 1.0
    off_c = np.clip(np.abs(rows - mid[None, :]) - span[None, :], 0, None) / max(m, 1)
    cost = np.where(sub_ok, 1.0 - np.clip(step[lo:hi] / max(scale, 1e-6), 0, 1) + 0.3 * off_c, _BIG)
    # columns the coarse pass called no-skyline stay so; the others follow the band optimum
    none = np.where(have, _BIG, 0.0)
    vert = np.full_like(cost, _BIG)
    win = int(min(hi - lo, 2 * m + 2 * f))
    top, _ = _dp_solve(cost, vert, np.zeros_like(cost), none, win, 0.1, 0.0, 0.0)
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
    g_row = cv2.GaussianBlur(np.asarray(gray, np.float32), (0, 0), sigmaX=1.0, sigmaY=0.01)
    _edge_crossing(g_row, valid, out)
    return out


@numba.njit(cache=True)
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


def _sky_inputs(img, valid, gray, model_pixels):
    """Classifier features on a copy downscaled to at most ``model_pixels`` [px].

    img : the input image; valid : trusted valid pixels; gray : filled float grey.
    Returns (X (hm, wm, k) float32, valid_m (hm, wm) bool, fm the integer downscale factor).
    """
    from .skymodel import sky_features

    H, W = gray.shape
    fm = _downscale_factor(H, W, model_pixels)
    g_m = _downscale(gray, fm)
    v_m = _downscale_valid(valid, fm)
    # chroma needs no filling: it is per pixel, and invalid pixels never enter the region term
    rgb_m = _downscale(np.asarray(img[..., :3], np.float32), fm) if img.ndim == 3 else None
    return sky_features(g_m, rgb_m, v_m), v_m, fm


def _resample_to(arr_m, fm, f, shape):
    """Bilinear resampling of a map on the fm-downscaled grid onto the f-downscaled grid (pixel
    centres aligned in full-resolution coordinates)."""
    import cv2

    h, w = shape
    ys = ((np.arange(h) + 0.5) * f / fm - 0.5).astype(np.float32)
    xs = ((np.arange(w) + 0.5) * f / fm - 0.5).astype(np.float32)
    mx, my = np.meshgrid(xs, ys)
    return cv2.remap(np.asarray(arr_m, np.float32), mx, my, cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


def sky_log_odds(img, valid, gray, model, model_pixels):
    """log P(sky)/P(terrain) per pixel of the model-scale copy: (lo (hm, wm), valid_m, fm)."""
    X, v_m, fm = _sky_inputs(img, valid, gray, model_pixels)
    hm, wm = v_m.shape
    lo = model.log_odds_sky(X.reshape(hm * wm, -1)).reshape(hm, wm)
    return lo, v_m, fm


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


def _resolve_model(model, grey=False):
    from .skymodel import SkyModel, load_sky_model

    if isinstance(model, SkyModel):
        return model
    return load_sky_model(model, grey=grey)


def _detect_dp(img, valid, opt: DpOptions, model=None):
    H, W = img.shape[:2]
    col_valid = valid.any(axis=0)
    valid = _trusted(valid)
    gray = _fill_invalid(_to_float_gray(img), valid)
    f = _downscale_factor(H, W, opt.work_pixels)
    gray_s = _downscale(gray, f)
    valid_s = _downscale_valid(valid, f)
    d = None
    region = opt.region
    grey = img.ndim == 2
    if region in ("model", "both"):
        # a grey image gets the model trained on grey copies: without chroma the colour model's
        # input is off its training distribution (it called a smooth grey sky terrain)
        lo, _, fm = sky_log_odds(img, valid, gray, _resolve_model(model, grey=grey), opt.model_pixels)
        # d > 0: terrain more likely; the region cost of a skyline at r is the sum of d above r
        lo_s = _resample_to(lo, fm, f, gray_s.shape)
        d = -np.clip(lo_s, -opt.llr_clip, opt.llr_clip)
        d = d.astype(np.float64)
        if region == "both":
            tex = _texture_region(gray_s, valid_s, opt,
                                   sure_sky=valid_s & (lo_s > opt.sure_sky_llr))
            # the cloud rule needs colour: a grey-level "brighter than the sky" took sunlit
            # ground for cloud (see DpOptions.cloud_llr)
            if opt.cloud_llr > 0 and not grey:
                rgb_s = _downscale(np.asarray(img[..., :3], np.float32), f)
                cloud = _cloud_like(tex, lo_s, rgb_s, valid_s, opt.cloud_llr,
                                    min_share=opt.cloud_sure_share)
                tex = np.where(cloud, 0.0, tex)
            d = opt.w_model * d + tex
    enter, vert, G, none, d = _dp_costs(gray_s, valid_s, opt, d)
    top, bottom = _dp_solve(enter, vert, G, none, 1, opt.jump_cost, opt.w_diff, opt.switch_cost)
    h, w = gray_s.shape
    # working column j covers full-res columns j f .. j f + f - 1; rows scale by f
    full_cols = np.minimum(np.arange(W) // f, w - 1)
    top_f = np.where(top >= 0, top * float(f), np.nan)[full_cols]
    bot_f = np.where(top >= 0, bottom * float(f), np.nan)[full_cols]
    rows = _refine_full(gray, valid, top_f, bot_f, f, opt)
    # confidence: edge strength at the chosen pixel times how sky-like the pixels above are
    conf_s = np.zeros(w)
    have = top >= 0
    cs = np.flatnonzero(have)
    if cs.size:
        r = top[cs]
        edge = G[r, cs]
        # the median over 30 rows: the texture term is blurred 7 columns wide, so on a steep
        # flank the rows just above the skyline look like the terrain beside them
        above = np.array([np.median(d[max(0, rr - 30):rr, c][valid_s[max(0, rr - 30):rr, c]])
                          if rr > 0 and valid_s[max(0, rr - 30):rr, c].any() else 0.0
                          for rr, c in zip(r, cs)])
        conf_s[cs] = np.clip(edge, 0, 1) * np.clip(0.5 - 0.5 * above, 0, 1)
    no = ~have
    # no-skyline: confident when the column clearly lacks sky (mean d well above 0)
    col_mean = np.array([d[valid_s[:, c], c].mean() if valid_s[:, c].any() else 0.0
                         for c in range(w)])
    conf_s[no] = np.clip(0.5 + 0.5 * np.abs(col_mean[no]), 0, 1)
    conf = conf_s[full_cols]
    unsure = np.isfinite(rows) & (conf < opt.min_confidence)
    rows[unsure] = np.nan
    conf[unsure] = 0.0
    if opt.min_run > 1:
        _drop_short_runs(rows, conf, opt.min_run * f)
    if opt.anchor_conf > 0:
        # the widths are fractions of the image's, not working columns: a mosaic and a single
        # frame differ in width far more than in working scale
        _drop_unanchored_runs(rows, conf, opt.anchor_conf, opt.anchor_gap * W,
                              opt.anchor_len * W)
    rows[~col_valid] = np.nan
    conf[~col_valid] = 0.0
    return rows, conf, col_valid


def _finite_runs(rows):
    """[(start, stop)] of each run of finite ``rows``, stop exclusive [columns]."""
    have = np.isfinite(rows).astype(np.int8)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], have, [0]])))
    return list(zip(edges[::2], edges[1::2]))


def _drop_short_runs(rows, conf, min_len):
    """Set runs of finite ``rows`` shorter than ``min_len`` columns to NaN (confidence 0), in
    place."""
    for a, b in _finite_runs(rows):
        if b - a < min_len:
            rows[a:b] = np.nan
            conf[a:b] = 0.0


def _drop_unanchored_runs(rows, conf, min_conf, max_gap, self_len):
    """Hysteresis on runs of finite ``rows``, in place: a run is kept when it is an anchor (mean
    ``conf`` >= ``min_conf``, or at least ``self_len`` columns long) or is linked to one through
    runs separated by gaps of at most ``max_gap`` columns; the rest become NaN (confidence 0)."""
    runs = _finite_runs(rows)
    chain = np.cumsum([0] + [b0 - a1 > max_gap for (_, a1), (b0, _) in zip(runs, runs[1:])])
    anchored = {c for c, (a, b) in zip(chain, runs)
                if b - a >= self_len or conf[a:b].mean() >= min_conf}
    for c, (a, b) in zip(chain, runs):
        if c not in anchored:
            rows[a:b] = np.nan
            conf[a:b] = 0.0


# --- the bayes detector --------------------------------------------------------------------------

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
    """:func:`_vertical_step` over its 99th percentile, clipped to [0, 1]."""
    step = _vertical_step(gray_s)
    scale = np.percentile(step[valid_s], 99) if valid_s.any() else 1.0
    return np.clip(step / max(scale, 1e-6), 0, 1).astype(np.float64)


def _detect_bayes(img, valid, opt: BayesOptions, model=None):
    from sklearn.ensemble import RandomForestClassifier

    H, W = img.shape[:2]
    col_valid = valid.any(axis=0)
    valid = _trusted(valid)
    gray = _fill_invalid(_to_float_gray(img), valid)
    f = _downscale_factor(H, W, opt.work_pixels)
    gray_s = _downscale(gray, f)
    valid_s = _downscale_valid(valid, f)
    rgb_s = None
    if img.ndim == 3:
        rgb_s = _downscale(_fill_invalid(img[..., :3].astype(np.float32), valid), f)
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
        lo, _, fm = sky_log_odds(img, valid, gray, _resolve_model(model), DpOptions().model_pixels)
        lo_s = _resample_to(lo, fm, f, (h, w))
    # the prior has no classifier term to outweigh a sky that reads as textured, so the sure
    # sky's threshold must sit high in its texture (see BayesOptions.sure_sky_q)
    dpo = replace(DpOptions(), sure_sky_q=opt.sure_sky_q)
    sure = valid_s & (lo_s > dpo.sure_sky_llr) if lo_s is not None and opt.sure_sky_q > 0 else None
    llr = 2.0 * _texture_region(gray_s, valid_s, dpo, sure_sky=sure) + 0.5 * (rows / h - 0.5)
    if opt.init == "model" and lo_s is not None:
        # start from the learned sky classifier's log-odds (terrain positive) added to the prior
        llr = llr - opt.w_model * np.clip(lo_s, -3.0, 3.0)
    ok = _skyline_allowed(valid_s, opt.min_sky_rows)
    B = _boundary_strength(gray_s, valid_s)
    rng = np.random.default_rng(opt.seed)
    prev_ll = -np.inf
    best = None
    for it in range(opt.max_iter):
        # llr > 0: terrain more likely. Cost of transition at r = sum of llr above r (sky there)
        # minus the sum below (terrain there) = 2 P[r] - P[h] up to the constant P[h].
        P = _column_prefix(llr, valid_s)
        enter = np.where(ok, P[:-1] + opt.w_boundary * (1.0 - B), _BIG)
        none = opt.none_cost + np.minimum(0.0, P[h])
        vert = np.full_like(enter, _BIG)
        top, _ = _dp_solve(enter, vert, np.zeros_like(enter), none, opt.window, opt.jump_cost,
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
    rows = _refine_full(gray, valid, lo_f[full_cols], hi_f[full_cols], f, DpOptions())
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
        else:
            conf_s[c] = float(np.clip(1 - p_sky[v, c].max() + 0.0, 0, 1))
    conf = conf_s[full_cols]
    rows[~col_valid] = np.nan
    conf[~col_valid] = 0.0
    return rows, conf, col_valid


# --- public API ----------------------------------------------------------------------------------

def detect_skyline(image, *, mask=None, method: str = "dp", name: str = "", model=None,
                   **options) -> Skyline:
    """The skyline of one image.

    image : H x W x 3 RGB (uint8, uint16 or float in [0, 1]) or H x W grey
    mask : optional bool H x W, True where the image holds valid data
    method : ``"dp"`` (default) or ``"bayes"``
    name : image name written into the result
    model : the sky classifier (:class:`skyfix.skymodel.SkyModel` or a path to one); None = the
        shipped model ``skyfix/models/sky_hgb.npz``
    options : fields of :class:`DpOptions` / :class:`BayesOptions` to override

    Returns a :class:`Skyline`: ``rows`` [px, 0-based, first terrain row below the sky] with NaN
    where no skyline is visible, ``confidence`` in [0, 1], ``valid`` = columns with any valid
    pixel. Raises :class:`ParameterError` on a bad image, mask, method or option.
    """
    if method not in PRESETS:
        raise ParameterError(f"unknown detection method {method!r}: choose one of {', '.join(METHODS)}")
    base = PRESETS[method]
    try:
        opt = replace(base, **options)
    except TypeError as e:
        raise ParameterError(f"bad option for method {method!r}: {e}") from None
    _check_options(opt)
    img, _, _ = _as_gray_rgb(image)
    if img.ndim == 3 and _is_grey_rgb(img):
        img = img[..., 0]  # a grey image stored as RGB: treated as the grey image it is
    valid = _valid_mask(img, mask, opt.no_data_black)
    H, W = img.shape[:2]
    if method == "dp":
        rows, conf, col_valid = _detect_dp(img, valid, opt, model)
    else:
        rows, conf, col_valid = _detect_bayes(img, valid, opt, model)
    return Skyline(rows=rows, width=W, height=H, image=name, confidence=conf, valid=col_valid)


# --- scoring -------------------------------------------------------------------------------------

def scored_columns(pred: Skyline, truth: Skyline) -> np.ndarray:
    """The columns a detection is scored on (bool): ``truth.valid``, else ``pred.valid``, else
    all. Raises :class:`ParameterError` when the two skylines differ in width."""
    if pred.rows.shape != truth.rows.shape:
        raise ParameterError(
            f"detected skyline has {pred.rows.size} columns, the truth {truth.rows.size}: "
            "score the same image")
    if truth.valid is not None:
        return np.asarray(truth.valid, bool)
    if pred.valid is not None:
        return np.asarray(pred.valid, bool)
    return np.ones(truth.rows.size, bool)


def score_skyline(pred: Skyline, truth: Skyline, *, tol_px: tuple[float, float] = (3.0, 10.0)) -> dict:
    """Score a detected skyline against the truth (``shared/data/README.md``).

    Over valid columns (``truth.valid``, else ``pred.valid``, else all): ``mean_abs_err_px``
    over columns where both have a skyline, ``within_3px`` / ``within_10px`` (shares of those
    columns), ``false_rate`` (share of valid columns where a skyline is claimed but none is
    there), ``missed_rate`` (a skyline is there but none claimed), and the column counts.
    """
    valid = scored_columns(pred, truth)
    pt = np.isfinite(pred.rows) & valid
    tt = np.isfinite(truth.rows) & valid
    both = pt & tt
    err = np.abs(pred.rows[both] - truth.rows[both])
    nv = int(valid.sum())
    nb = int(both.sum())
    lo, hi = tol_px
    return {
        "n_valid": nv,
        "n_both": nb,
        "n_truth": int(tt.sum()),
        "n_false": int((pt & ~tt).sum()),
        "n_missed": int((tt & ~pt).sum()),
        "n_within_3px": int((err <= lo).sum()),
        "n_within_10px": int((err <= hi).sum()),
        "sum_abs_err_px": float(err.sum()),
        "mean_abs_err_px": float(err.mean()) if nb else float("nan"),
        "within_3px": float((err <= lo).mean()) if nb else float("nan"),
        "within_10px": float((err <= hi).mean()) if nb else float("nan"),
        "false_rate": float((pt & ~tt).sum() / nv) if nv else 0.0,
        "missed_rate": float((tt & ~pt).sum() / nv) if nv else 0.0,
    }


def combine_scores(scores) -> dict:
    """Pool per-image :func:`score_skyline` results (column-weighted)."""
    keys = ("n_valid", "n_both", "n_truth", "n_false", "n_missed", "n_within_3px",
            "n_within_10px", "sum_abs_err_px")
    tot = {k: sum(s[k] for s in scores) for k in keys}
    nb, nv = tot["n_both"], tot["n_valid"]
    tot.update({
        "mean_abs_err_px": tot["sum_abs_err_px"] / nb if nb else float("nan"),
        "within_3px": tot["n_within_3px"] / nb if nb else float("nan"),
        "within_10px": tot["n_within_10px"] / nb if nb else float("nan"),
        "false_rate": tot["n_false"] / nv if nv else 0.0,
        "missed_rate": tot["n_missed"] / nv if nv else 0.0,
    })
    return tot
