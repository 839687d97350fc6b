"""The texture evidence of sky: the sky is smooth, terrain is not. A local texture measure, the
sensor noise's texture, and the per-pixel likelihood ratio that the ``dp`` region term and the
``bayes`` prior use.
"""

from __future__ import annotations

import numpy as np

from .options import DpOptions
from .quantile import median, percentile


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
    return percentile(loc[valid_s], 5)


def texture_region(gray_s, valid_s, opt: DpOptions, sure_sky=None):
    """Texture region term per working pixel: log of the local texture over the sky threshold,
    clipped to [-1, 1]; < 0 looks like sky, > 0 like terrain. ``sure_sky`` (bool, optional): the
    pixels the sky classifier is sure of (``DpOptions.sure_sky_*``)."""
    import cv2

    # sky-likeness from texture of the un-equalised grey (CLAHE would lift the sky's noise)
    tex = _texture(cv2.GaussianBlur(gray_s, (3, 3), 0.8), valid_s, 3).astype(np.float64)
    tv = tex[valid_s] if valid_s.any() else np.ones(1)
    # the median alone collapses to ~0 when over half the image is smooth (a big clean sky,
    # smooth rendered terrain), and then nothing looks like sky: floor it by the textured part
    med = max(median(tv), 0.25 * percentile(tv, 90))
    # a pixel whose texture is no more than the sensor noise's is sky-like whatever the rest
    # of the image does: in a noisy frame over smooth ground 0.35 median is below the noise
    thr = max(opt.texture_ratio * med, opt.noise_ratio * _noise_level(gray_s, valid_s))
    # ... and the typical texture of the sky the classifier is sure of counts as sky: a wide
    # camera's sky darkens steeply towards the horizon, and that gradient is texture to Sobel. In
    # a raw frame the noise floor above happens to cover it; JPEG, a slight blur or the resampling
    # of a stitched panorama remove the noise, and the sky then looked textured (see DpOptions)
    n_sure = np.count_nonzero(sure_sky) if sure_sky is not None and opt.sure_sky_q > 0 else 0
    if n_sure >= 100 and n_sure >= opt.sure_sky_share * np.count_nonzero(valid_s):
        thr = max(thr, percentile(tex[sure_sky], opt.sure_sky_q))
    # log ratio to the sky threshold: < 0 looks like sky, > 0 like terrain; clipped so a few
    # wild pixels cannot dominate a column
    return np.clip(np.log((tex + 0.05 * med + 1e-6) / (thr + 1e-6)), -1.0, 1.0)
