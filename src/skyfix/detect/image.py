"""Image preparation shared by the detectors and the sky classifier: grey and RGB views, the
validity mask (no-data black pixels, a user mask) and its trusted core, filling no-data so it
makes no edges, integer downscaling and resampling between working grids.

Pixels outside ``mask`` and, by default, pure black (0, 0, 0) pixels are no data: they are filled
from their nearest valid neighbour before filtering (so the mosaic border makes no edge) and a
skyline may only lie where the pixel and the one above it are valid.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import ParameterError
from ..formats.images import full_scale
from ..jit import njit
from .options import MIN_HEIGHT_PX, MIN_WIDTH_PX


def as_gray_rgb(image):
    """(image, grey, rgb): the image as H x W or H x W x 3 (an alpha channel dropped), with
    ``grey`` or ``rgb`` set to it and the other None. Raises :class:`ParameterError` on another
    shape or an image under :data:`MIN_WIDTH_PX` x :data:`MIN_HEIGHT_PX` [px]."""
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


def is_grey_rgb(img) -> bool:
    """True when every pixel of an H x W x 3 image has R = G = B (a grey image stored as RGB)."""
    return bool(np.array_equal(img[..., 0], img[..., 1]) and np.array_equal(img[..., 1], img[..., 2]))


def non_finite_as_no_data(img, mask):
    """(image, mask) with a float image's NaN (or infinite) pixels as no data: left out of
    ``mask`` (None = all valid) and set to 0, so that none reaches a filter, the classifier or the
    network (one NaN pixel made every column's region cost NaN: no skyline at all, silently). An
    image without such pixels comes back as it is."""
    if img.dtype.kind != "f":
        return img, mask
    finite = np.isfinite(img) if img.ndim == 2 else np.isfinite(img).all(axis=2)
    if finite.all():
        return img, mask
    img = np.where(finite[..., None] if img.ndim == 3 else finite, img, 0.0)
    if mask is None:
        return img, finite
    mask = np.asarray(mask)
    # a mask of the wrong shape is left to valid_mask, which names the problem
    return img, (mask.astype(bool) & finite) if mask.shape == finite.shape else mask


def valid_mask(img, mask, no_data_black):
    """H x W bool: the pixels holding data: ``mask`` (bool-like, H x W; None = all) and, with
    ``no_data_black``, not pure black (0 in every channel)."""
    H, W = img.shape[:2]
    if mask is None:
        valid = np.ones((H, W), dtype=bool)
    else:
        mask = np.asarray(mask)
        if mask.shape != (H, W):
            raise ParameterError(f"mask shape {mask.shape} does not match the image ({H}, {W})")
        valid = mask.astype(bool)
    if no_data_black:
        if img.ndim == 2:
            valid &= img != 0
        else:
            # channel by channel: np.all over the interleaved channel axis took 13 ms a 1-MP frame
            black = img[..., 0] == 0
            for c in range(1, img.shape[2]):
                black &= img[..., c] == 0
            valid &= ~black
    return valid


def trusted(valid, margin=3):
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


#: rows converted at a time where a whole-image float copy is not needed
ROW_BAND = 256


def to_float_gray(img):
    """The grey level as float32 on the 0-255 scale (uint16 rescaled from its own bit depth, float
    in [0, 1] stretched), luma weights 0.299, 0.587, 0.114 for RGB."""
    if img.ndim == 2:
        g = img.astype(np.float32)
    else:
        # a band of rows at a time: the whole image as float32 RGB was 48 MB at 4 MP, three times
        # the grey it makes (same values: each pixel's dot product is computed alike)
        w = np.array([0.299, 0.587, 0.114], np.float32)
        g = np.empty(img.shape[:2], np.float32)
        for r in range(0, img.shape[0], ROW_BAND):
            g[r:r + ROW_BAND] = img[r:r + ROW_BAND, :, :3].astype(np.float32) @ w
    if img.dtype == np.uint16:  # at its own bit depth, as detect_skyline reads it (to_8bit)
        g *= 255.0 / full_scale(img)
    elif img.dtype.kind == "f" and g.size and np.nanmax(g) <= 1.0:
        g *= 255.0
    return g


@njit(cache=True)
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


#: [columns] how far beside a run of columns with holes their filling looks at first
FILL_REACH_COLUMNS = 4


def fill_invalid(arr, valid):
    """Replace invalid pixels from valid ones (so no-data makes no edges): mirrored along the
    column above and below the data, nearest valid pixel elsewhere."""
    if valid.all() or not valid.any():
        return arr
    from ..nearest import nearest_valid

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
    # Only around the columns still holding a hole: the whole image's transform was 5 arrays of
    # its size (a 3.9-MP mosaic with 131 hole pixels peaked at 384 MB, the board's budget 256).
    # The same answer: the columns beside a run hold no hole, so none beyond them is nearer.
    out = arr.copy()
    holes = ~valid
    need = np.flatnonzero(holes.any(axis=0))
    starts = need[np.r_[True, np.diff(need) > 1]]
    ends = need[np.r_[np.diff(need) > 1, True]] + 1
    W = arr.shape[1]
    for a, b in zip(starts, ends):
        reach = FILL_REACH_COLUMNS
        while True:
            lo, hi = max(0, a - reach), min(W, b + reach)
            _, rows, cols = nearest_valid(valid[:, lo:hi], row_spacing=1.0, col_spacing=64.0)
            if (rows[:, a - lo:b - lo] >= 0).all() or (lo == 0 and hi == W):
                break
            reach *= 4  # a band of empty columns wider than the window: look farther
        sub = holes[:, a:b]
        r, c = rows[:, a - lo:b - lo][sub], cols[:, a - lo:b - lo][sub] + lo
        out[:, a:b][sub] = arr[r, c]
    return out


def downscale_factor(H, W, work_pixels):
    """The smallest integer factor that brings an H x W image [px] to at most ``work_pixels`` [px]."""
    return max(1, int(math.ceil(math.sqrt(H * W / float(work_pixels)))))


def downscale(arr, f):
    """``arr`` (H x W or H x W x C) shrunk by the integer factor ``f`` with area averaging, to
    (H // f) x (W // f) [px]; returned unchanged for f = 1."""
    import cv2

    if f == 1:
        return arr
    H, W = arr.shape[:2]
    return cv2.resize(arr, (max(1, W // f), max(1, H // f)), interpolation=cv2.INTER_AREA)


def downscale_rgb(img, f):
    """The first three channels of ``img`` as float32, shrunk by ``f`` as :func:`downscale` does,
    one channel at a time (the same values; a full-resolution float32 RGB copy is not made)."""
    if f == 1:
        return np.asarray(img[..., :3], np.float32)
    return np.stack([downscale(np.ascontiguousarray(img[..., c], dtype=np.float32), f)
                     for c in range(3)], axis=-1)


def downscale_valid(valid, f):
    """A working pixel is valid when all the full-resolution pixels it covers are."""
    if f == 1:
        return valid
    H, W = valid.shape
    h, w = H // f, W // f
    # AND of row slices, then of column slices: a strided all() over (f, f) cells is 20x slower
    v = valid[: h * f, : w * f].reshape(h, f, w * f)
    rows = v[:, 0, :].copy()
    for k in range(1, f):
        rows &= v[:, k, :]
    cells = rows.reshape(h, w, f)
    out = cells[..., 0].copy()
    for k in range(1, f):
        out &= cells[..., k]
    return out


def resample_to(arr_m, fm, f, shape):
    """Bilinear resampling of a map on the fm-downscaled grid onto the f-downscaled grid (pixel
    centres aligned in full-resolution coordinates)."""
    import cv2

    h, w = shape
    ys = ((np.arange(h) + 0.5) * f / fm - 0.5).astype(np.float32)
    xs = ((np.arange(w) + 0.5) * f / fm - 0.5).astype(np.float32)
    mx, my = np.meshgrid(xs, ys)
    return cv2.remap(np.asarray(arr_m, np.float32), mx, my, cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)
