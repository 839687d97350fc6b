"""Options of the detectors (frozen dataclasses, presets by method) and their checks.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from ..errors import ParameterError


METHODS = ("dp", "bayes", "net", "fuse")
#: the method every caller uses unless told otherwise
DEFAULT_METHOD = "dp"


#: smallest image searched, width x height [px]
MIN_WIDTH_PX, MIN_HEIGHT_PX = 2, 8


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
    w_net, net_sky_clip, net_member : weight of the sky network's log-odds (:mod:`.net`) added to
        the region term, clipped to [-``llr_clip``, ``net_sky_clip``] [nats] (a smaller
        ``net_sky_clip`` lets the network veto sky more than claim it), and which of its members
        runs (-1: the ensemble's mean; see :class:`NetOptions`); 0 (default) leaves the network
        out, 1 is the ``fuse`` method. The region term then sees the network's wide context
        beside the pixel classifier and the texture, and the path keeps ``dp``'s edges, its
        confidence and its refinement. Cross-validated (``benchmarks/bench_detect.py --cv``: the
        sky classifier per fold, the network member that held the fold out; the network as
        retrained 2026-11-27), ``dp`` -> ``fuse``: Mars dev set 1.08 -> 1.13 px, false skyline
        12.9 -> 5.2 %, missed 4.2 -> 9.3 %, no-sky mosaics 34.8 -> 12.8 % claimed; Earth photos
        8.36 -> 0.82 px, 87.9 -> 96.6 % within 3 px, missed 23.5 -> 1.0 %. Weights 0, 0.5, 1 and
        2 tried (``benchmarks/choose_fuse_options.py``): every fold's training folds chose 1 (least
        share of wrong columns, Mars and Earth averaged), as with the earlier network; a
        ``net_sky_clip`` of 0.4 or 0.75 lost most of the Earth gain. The price is on simulated
        Mars frames, whose smooth rendered ground the network calls sky: COND 2.5 -> 6.3 px
        (14.2 % missed; 9.6 px with the earlier network), and on simulated wide-camera frames
        (0.17 -> 0.53 px), so ``dp`` stays the default. Tried, not
        taken: ignoring the network's sky evidence where the pixel classifier is sure of terrain
        (log-odds below -1 or -2 nats; on the dev images the network never calls such pixels
        sky, on simulated Mars frames 13-17 % of them) won back part of COND (9.6 -> 6.3-6.8 px)
        and lost part of the Earth gain (1.04 -> 1.7-2.5 px)
    net_flip : (``w_net`` > 0) the network also runs on the mirror image and the two are averaged
        (:attr:`NetOptions.flip`). False halves the network's time: a 1-MP navcam frame 0.83 ->
        0.51 s, a 4-MP mosaic 1.00 -> 0.71 s (dp alone 0.16 and 0.37 s; load 2.7), with the dev
        sets cross-validated as good (Mars 1.13 -> 1.16 px, false and missed unchanged; Earth
        1.04 px, 36/38 photos either way) and simulated COND worse (9.6 -> 13.3 px): the choice
        for a slow processor
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
    w_net: float = 0.0
    net_sky_clip: float = 1.5
    net_member: int = -1
    net_flip: bool = True
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


@dataclass(frozen=True)
class NetOptions:
    """Options of the ``net`` detector (:mod:`skyfix.detect.net`; costs in nats).

    net_pixels : the image is downscaled by an integer factor to at most this many pixels for the
        network and the path [px]
    flip : average the network's log-odds with its run on the mirrored image (halves the
        variance of a small network's mistakes for twice the network time, ~20-60 ms)
    llr_clip : per-pixel log-odds clipped to +-``llr_clip`` [nats], so a few confident mistakes
        cannot dominate a column
    none_cost : extra cost of the no-skyline state per column [nats]
    switch_cost : cost of switching between skyline and no-skyline between columns [nats]
    jump_cost : cost per row of change between neighbouring columns [nats]
    vertical_cost : cost per pixel of a move within a column (steep sections) [nats]
    min_sky_rows : a skyline needs at least this many valid working rows above it [working px]
    refine_band : half-height of the full-resolution refinement band [working px]
    conf_rows : working rows above and below the path whose probabilities make the confidence
    min_confidence : a column whose calibrated confidence is below this is reported unknown
    min_run, anchor_conf, anchor_gap, anchor_len : run hysteresis as in :class:`DpOptions`
    member : -1 (default): the mean of every member of an ensemble network; k: member k alone
        (each was trained with some images held out: see the model's ``held_out_by_member``)
    """

    net_pixels: int = 300_000
    flip: bool = True
    llr_clip: float = 8.0
    none_cost: float = 2.0
    switch_cost: float = 4.0
    jump_cost: float = 0.3
    vertical_cost: float = 0.5
    min_sky_rows: int = 2
    refine_band: float = 1.5
    conf_rows: int = 6
    min_confidence: float = 0.3  # cross-validated (bench_detect.py --cv-net): false + missed least
    min_run: int = 0
    anchor_conf: float = 0.0
    anchor_gap: float = 0.02
    anchor_len: float = 0.15
    member: int = -1
    no_data_black: bool = True


#: ``fuse`` is ``dp`` with the sky network in its region term (:attr:`DpOptions.w_net`)
PRESETS = {"dp": DpOptions(), "bayes": BayesOptions(), "net": NetOptions(),
           "fuse": DpOptions(w_net=1.0)}


# Ranges the options must lie in. The kernels do not check them, and most wrong values would give
# a quiet nonsense answer rather than a crash (a negative weight rewards an edge-free skyline, a
# gap of -0.1 links nothing), so they are refused up front, naming the option.
_AT_LEAST_ONE = {"work_pixels", "model_pixels", "window", "max_iter", "n_train", "net_pixels",
                 "conf_rows"}


_FRACTIONS = {"min_confidence", "anchor_conf", "anchor_gap", "anchor_len", "cloud_sure_share",
              "sure_sky_share"}


_PERCENTS = {"sure_sky_q"}  # both detectors' option


_CHOICES = {"region": ("both", "model", "texture"), "init": ("prior", "model")}


def check_options(opt) -> None:
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
            low = 1 if name in _AT_LEAST_ONE else (-1 if name in ("member", "net_member") else 0)
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
