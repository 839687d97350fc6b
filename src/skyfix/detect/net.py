"""The ``net`` detector: a small fully-convolutional sky/terrain segmentation network feeding the
exact path solver.

Per-pixel colour and texture cannot tell a hazy distant mountain from the sky, nor a cumulus
cloud from a ridge: a smooth band is sky only where nothing lies behind it. The network sees the
whole working copy at once (a U-Net with dilated convolutions at 1/16 scale; its receptive field
spans a working image's height), and its per-pixel log-odds of sky are the only evidence the path
uses:

1. :func:`net_input`: the image downscaled by an integer factor to at most ``net_pixels``, as five
   channels: colour normalised per image (median luminance 0, 5-95 % spread 1), the validity mask,
   and the log of the full-resolution high-pass magnitude averaged onto the working grid (the faint
   texture of hazy relief that downscaling would average away), minus its image median. No-data
   pixels are filled from their valid neighbours so they make no edges.
2. :meth:`SkyNet.log_odds`: the network (ONNX, run by OpenCV's ``dnn`` module: no dependency
   beyond OpenCV), averaged with its run on the mirrored image.
3. The path: entering column c at row r costs the sum of ``-log p(sky)`` above r and of
   ``-log p(terrain)`` from r down (prefix sums), each clipped at ``llr_clip`` nats; the
   no-skyline state costs that of calling the whole column terrain or sky, plus ``none_cost``;
   smoothness and switching as in :mod:`.path`. The exact optimum on the working copy is refined at
   full resolution by the intensity step (:func:`.refine.refine_full`).
4. Per-column confidence: the mean sky probability of the ``conf_rows`` working rows above the
   path times the mean terrain probability of those below, mapped through the calibration stored
   with the model (isotonic, fitted on cross-validated runs: see ``scripts/train_sky_net.py``);
   columns under ``min_confidence`` are reported unknown, then the run hysteresis of :mod:`.runs`.

The model (``skyfix/models/sky_net.onnx``, with ``sky_net.json``: channels, calibration, training
recipe) is trained by ``scripts/train_sky_net.py``; training needs PyTorch (``pip install
-e ".[train]"``), running does not.
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..errors import ParameterError
from ..formats.images import full_scale
from .image import downscale_factor, fill_invalid, to_float_gray, trusted
from .options import NetOptions
from .path import BIG, column_prefix, solve_path
from .refine import refine_full, skyline_allowed
from .runs import drop_short_runs, drop_unanchored_runs

DEFAULT_NET = Path(__file__).resolve().parents[1] / "models" / "sky_net.onnx"
#: input channels: R, G, B (normalised), validity, log texture
CHANNELS = 5
#: the network's total stride: inputs are padded to a multiple of it [px]
STRIDE = 16


def _float_rgb_small(img, size):
    """The colour image (grey replicated) resized to ``size`` (w, h) with area averaging, as
    float32 in [0, 1] (uint8 / 255, uint16 over its own bit depth's full scale
    (:func:`~skyfix.formats.images.full_scale`), float taken as [0, 1] unless above 1, then / 255,
    as :func:`.image.to_float_gray`)."""
    import cv2

    if img.dtype == np.uint8:
        small = cv2.resize(img, size, interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0
    else:
        x = img.astype(np.float32)
        if img.dtype == np.uint16:  # at its own bit depth, as detect_skyline reads it (to_8bit)
            x /= full_scale(img)
        elif x.size and np.nanmax(x) > 1.0:
            x /= 255.0
        small = cv2.resize(x, size, interpolation=cv2.INTER_AREA)
    if small.ndim == 2:
        small = np.repeat(small[..., None], 3, axis=2)
    return small


def log_texture(img, valid, size):
    """(h, w) float32: log of the mean high-pass magnitude [grey levels] of the full-resolution
    image over each working pixel of ``size`` (w, h), valid pixels only, minus its median over
    the working pixels that are wholly valid. The high-pass is |g - G_1px * g| on the 0-255 grey."""
    import cv2

    g = to_float_gray(img)
    hp = np.abs(g - cv2.GaussianBlur(g, (0, 0), 1.0))
    del g
    hp[~valid] = 0.0
    s = cv2.resize(hp, size, interpolation=cv2.INTER_AREA)
    del hp
    v = cv2.resize(valid.astype(np.float32), size, interpolation=cv2.INTER_AREA)
    t = np.log(s / np.maximum(v, 1e-3) + 0.25).astype(np.float32)
    whole = v > 0.999
    return t - (float(np.median(t[whole])) if whole.any() else 0.0)


def net_input(img, valid, size):
    """The network's input for an image and its trusted valid mask (H x W bool), at working size
    ``size`` = (w, h) [px]: (x (CHANNELS, h, w) float32, valid_w (h, w) bool, a working pixel being
    valid when every full-resolution pixel it covers is). Training uses this same function."""
    import cv2

    img = np.asarray(img)
    x = _float_rgb_small(img, size)
    v = cv2.resize(valid.astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0.999
    t = log_texture(img, valid, size)
    if v.any() and not v.all():
        x = fill_invalid(x, v)
        t = fill_invalid(t, v)
    lum = x.mean(axis=2)
    vals = lum[v] if v.any() else lum.ravel()
    lo, med, hi = np.percentile(vals, (5, 50, 95))
    x = (x - med) / (hi - lo + 0.05)
    out = np.empty((CHANNELS,) + v.shape, np.float32)
    out[:3] = x.transpose(2, 0, 1)
    out[3] = v
    out[4] = t
    return out, v


class SkyNet:
    """The segmentation network (one, or an ensemble whose members' log-odds are output channels
    and averaged) and what was stored with it (``meta``: channels, members, calibration)."""

    def __init__(self, path):
        path = Path(path)
        self.path = path
        self.net = self._read()
        meta_path = path.with_suffix(".json")
        self.meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
        if int(self.meta.get("channels", CHANNELS)) != CHANNELS:
            raise ParameterError(f"{path} takes {self.meta['channels']} input channels, this skyfix "
                                 f"makes {CHANNELS}: retrain it with scripts/train_sky_net.py")
        cal = self.meta.get("calibration") or {}
        self.cal_x = np.asarray(cal.get("raw", []), float)
        self.cal_y = np.asarray(cal.get("p_within_3px", []), float)

    def held_out_members(self) -> dict:
        """{image name: index of the ensemble member that never saw it in training} (the
        ``held_out_by_member`` lists in the metadata; members in name order, as the output
        channels are); empty for a network without them."""
        by_member = self.meta.get("held_out_by_member") or {}
        return {n: k for k, (_, names) in enumerate(sorted(by_member.items())) for n in names}

    def _read(self):
        import cv2

        try:
            return cv2.dnn.readNetFromONNX(str(self.path))
        except cv2.error as e:
            raise ParameterError(f"cannot read the sky network {self.path}: {str(e).strip()[-200:]}") from None

    def _run(self, x, member=-1):
        c, h, w = x.shape
        hp, wp = -(-h // STRIDE) * STRIDE, -(-w // STRIDE) * STRIDE
        t = np.zeros((1, c, hp, wp), np.float32)
        t[0, :, :h, :w] = x
        if hp > h:  # replicate the last row / column; the validity channel stays 0 there
            t[0, :, h:, :w] = t[0, :, h - 1:h, :w]
            t[0, 3, h:, :] = 0.0
        if wp > w:
            t[0, :, :, w:] = t[0, :, :, w - 1:w]
            t[0, 3, :, w:] = 0.0
        if self.net is None:
            self.net = self._read()
        self.net.setInput(t)
        # an ensemble stacks its members' log-odds as channels: their mean is the answer
        out = self.net.forward()[0, :, :h, :w]
        if member >= 0:
            if member >= out.shape[0]:
                raise ParameterError(f"member {member}: this network has {out.shape[0]} member(s)")
            return out[member]
        return out.mean(axis=0)

    def log_odds(self, x, flip=True, member=-1):
        """log p(sky) / p(terrain) [nats] per working pixel of a :func:`net_input` array, the mean
        of the network on the image and on its mirror image when ``flip``."""
        lo = self._run(x, member)
        if flip:
            lo = 0.5 * (lo + self._run(np.ascontiguousarray(x[:, :, ::-1]), member)[:, ::-1])
        # OpenCV keeps every layer's buffers while the net lives (~80 MB at 0.3 MP), and the
        # path and the refinement come after: dropped here, read again (~10 ms) for the next image
        self.net = None
        if not np.isfinite(lo).all():
            raise ParameterError("the sky network gave non-finite output: its model file is damaged")
        return lo.astype(np.float64)

    def calibrate(self, raw):
        """Calibrated per-column confidence (share within 3 px of the truth) from the raw one."""
        if self.cal_x.size < 2:
            return raw
        return np.interp(raw, self.cal_x, self.cal_y)


@lru_cache(maxsize=4)
def _load_cached(path: str) -> SkyNet:
    return SkyNet(path)


def load_sky_net(path=None) -> SkyNet:
    """The network at ``path`` (default: the shipped ``skyfix/models/sky_net.onnx``), loaded once
    per process."""
    p = Path(path) if path is not None else DEFAULT_NET
    if not p.is_file():
        raise ParameterError(f"no sky network at {p}: train one with scripts/train_sky_net.py")
    return _load_cached(str(p.resolve()))


def sky_net_log_odds(img, valid, opt: NetOptions, model=None):
    """(log-odds of sky (h, w) [nats], working validity (h, w), integer downscale factor f)."""
    net = model if isinstance(model, SkyNet) else load_sky_net(model)
    H, W = img.shape[:2]
    f = downscale_factor(H, W, opt.net_pixels)
    size = (max(1, W // f), max(1, H // f))
    x, v = net_input(img, valid, size)
    return net.log_odds(x, flip=opt.flip, member=opt.member), v, f, net


def column_confidence(p, top, bottom, v, k):
    """Raw confidence per working column: for a skyline (rows ``top``..``bottom``, -1 = none) the
    mean sky probability ``p`` of the ``k`` valid rows above times the mean terrain probability of
    the ``k`` below; for no skyline, how sure the column is all one thing."""
    h, w = p.shape
    conf = np.zeros(w)
    for c in range(w):
        vv = v[:, c]
        if top[c] >= 0:
            r0, r1 = int(top[c]), int(bottom[c])
            a = p[max(0, r0 - k):r0, c][vv[max(0, r0 - k):r0]]
            b = p[r1:r1 + k, c][vv[r1:r1 + k]]
            conf[c] = (a.mean() if a.size else 0.0) * (1.0 - b.mean() if b.size else 0.5)
        else:
            pc = p[vv, c]
            conf[c] = max(1.0 - pc.max(), pc.min()) if pc.size else 0.0
    return conf


def net_columns(img, valid, opt: NetOptions, model=None):
    """The path before any confidence cut: (rows (W,) [px, NaN = none], raw confidence (W,) in
    [0, 1] (uncalibrated), column validity (W,), the network, the downscale factor f)."""
    H, W = img.shape[:2]
    col_valid = valid.any(axis=0)
    valid = trusted(valid)
    lo, v, f, net = sky_net_log_odds(img, valid, opt, model)
    h, w = v.shape
    lc = np.clip(lo, -opt.llr_clip, opt.llr_clip)
    Ps = column_prefix(np.logaddexp(0.0, -lc), v)  # cost of calling a pixel sky
    Pt = column_prefix(np.logaddexp(0.0, lc), v)  # ... terrain
    enter = Ps[:-1] + (Pt[-1][None, :] - Pt[:-1])
    ok = skyline_allowed(v, opt.min_sky_rows)
    enter = np.where(ok, enter, BIG)
    none = np.minimum(Pt[-1], Ps[-1]) + opt.none_cost
    vert = np.where(ok, opt.vertical_cost, BIG)
    top, bottom = solve_path(enter, vert, np.zeros_like(enter), none, 1, opt.jump_cost, 0.0,
                             opt.switch_cost)
    gray = fill_invalid(to_float_gray(img), valid)
    full_cols = np.minimum(np.arange(W) // f, w - 1)
    top_f = np.where(top >= 0, top * float(f), np.nan)[full_cols]
    bot_f = np.where(top >= 0, bottom * float(f), np.nan)[full_cols]
    rows = refine_full(gray, valid, top_f, bot_f, f, opt.refine_band)
    raw = column_confidence(1.0 / (1.0 + np.exp(-lc)), top, bottom, v, opt.conf_rows)
    return rows, raw[full_cols], col_valid, net, f


def finish_columns(rows, conf, col_valid, opt: NetOptions, f: int):
    """In place, after calibration: columns under ``min_confidence`` and runs the hysteresis
    drops (:mod:`.runs`) become unknown (NaN, confidence 0), as do columns without data."""
    W = rows.size
    unsure = np.isfinite(rows) & (conf < opt.min_confidence)
    rows[unsure] = np.nan
    conf[unsure] = 0.0
    if opt.min_run > 1:
        drop_short_runs(rows, conf, opt.min_run * f)
    if opt.anchor_conf > 0:
        drop_unanchored_runs(rows, conf, opt.anchor_conf, opt.anchor_gap * W, opt.anchor_len * W)
    rows[~col_valid] = np.nan
    conf[~col_valid] = 0.0


def detect_net(img, valid, opt: NetOptions, model=None):
    """The ``net`` detector on a prepared image.

    img : H x W (grey) or H x W x 3 image; valid : H x W bool, pixels holding data;
    opt : :class:`NetOptions`; model : a :class:`SkyNet`, a path to an ONNX file, or None (the
    shipped one). Returns (rows (W,) [px, NaN = no skyline], confidence (W,) in [0, 1], column
    validity (W,)).
    """
    rows, raw, col_valid, net, f = net_columns(img, valid, opt, model)
    conf = net.calibrate(raw)
    finish_columns(rows, conf, col_valid, opt, f)
    return rows, conf, col_valid
