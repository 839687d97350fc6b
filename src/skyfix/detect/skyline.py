"""The one entry point: :func:`detect_skyline` checks the image and options and runs a method.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace

import numpy as np

from ..errors import ParameterError
from ..formats import Skyline
from ..formats.images import to_8bit
from .bayes import detect_bayes
from .dp import detect_dp
from .image import as_gray_rgb, is_grey_rgb, non_finite_as_no_data, valid_mask
from .net import detect_net
from .options import DEFAULT_METHOD, METHODS, PRESETS, check_options

#: method name -> detector(img, valid, options, model) -> (rows, confidence, column validity);
#: a new detector enters here and in :data:`skyfix.detect.options.PRESETS`
DETECTORS = {"dp": detect_dp, "bayes": detect_bayes, "net": detect_net, "fuse": detect_dp}

log = logging.getLogger(__name__)


def detect_skyline(image, *, mask=None, method: str = DEFAULT_METHOD, name: str = "", model=None,
                   **options) -> Skyline:
    """The skyline of one image.

    image : H x W x 3 RGB (uint8, uint16 or float in [0, 1]; NaN = no data) or H x W grey
    mask : optional bool H x W, True where the image holds valid data
    method : one of :data:`METHODS` (default :data:`DEFAULT_METHOD`)
    name : image name written into the result
    model : the method's learned model or a path to one (``dp``, ``fuse``, ``bayes``: the sky classifier
        :class:`skyfix.detect.skymodel.SkyModel`; ``net``: :class:`skyfix.detect.net.SkyNet`);
        None = the shipped one
    options : fields of :class:`DpOptions` / :class:`BayesOptions` / :class:`NetOptions` to override

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
    check_options(opt)
    try:
        img, _, _ = as_gray_rgb(to_8bit(image))
    except ParameterError as e:
        if not name:
            raise
        # one image of many (evaluate-detect, an acquisition's frames): say which
        raise ParameterError(f"{name}: {e}") from None
    img, mask = non_finite_as_no_data(img, mask)
    if img.ndim == 3 and is_grey_rgb(img):
        img = img[..., 0]  # a grey image stored as RGB: treated as the grey image it is
    valid = valid_mask(img, mask, opt.no_data_black)
    H, W = img.shape[:2]
    t0 = time.perf_counter()
    rows, conf, col_valid = DETECTORS[method](img, valid, opt, model)
    if log.isEnabledFor(logging.INFO):
        # -v: what was detected and how sure, per image (an acquisition logs each frame)
        found = np.isfinite(rows)
        log.info("%s%s, %d x %d px %s, %.0f %% of pixels valid: skyline in %d of %d columns, "
                 "median confidence %.2f (%.2f s)", f"{name}: " if name else "", method, W, H,
                 "grey" if img.ndim == 2 else "colour", 100.0 * float(np.mean(valid)),
                 int(found.sum()), W,
                 float(np.median(conf[found])) if conf is not None and found.any() else float("nan"),
                 time.perf_counter() - t0)
    return Skyline(rows=rows, width=W, height=H, image=name, confidence=conf, valid=col_valid)
