"""Stage 5: the skyline in an image, or the statement that there is none.

Output (:class:`skyfix.formats.Skyline`): per column the row [px, 0-based, sub-pixel] of the
first terrain pixel below the sky, NaN where no skyline is visible (the column is all terrain,
all sky, or holds no data), and a confidence in [0, 1].

Every detector turns an image into per-pixel evidence of sky and terrain, then finds the skyline
as one exact minimum-cost path over the columns with a per-column *no-skyline* state
(:mod:`.path`), and refines it at full resolution (:mod:`.refine`):

``dp`` (:mod:`.dp`)
    The source study's dense multi-stage graph (gradient, Canny, height, gradient difference)
    plus a region term: texture (:mod:`.texture`) and a small learned pixel classifier
    (:mod:`.skymodel`), with a cloud rule and run hysteresis (:mod:`.runs`).
``net`` (:mod:`.net`)
    A small fully-convolutional sky/terrain network (ONNX through OpenCV's dnn; trained by
    ``scripts/train_sky_net.py``) feeding the same exact path, with a calibrated confidence.
``fuse`` (``dp`` with :attr:`DpOptions.w_net`)
    ``dp`` whose region term also holds the network's log-odds: the network's wide context
    against clouds, lakes and haze, ``dp``'s edges for the row. Best on real photographs.
``bayes`` (:mod:`.bayes`)
    The NASA Ames sky/ground segmentation by column transitions, re-learned iteratively.

Files: :mod:`.skyline` (:func:`detect_skyline`, the entry point), :mod:`.options` (options,
presets, checks), :mod:`.image` (validity, filling, downscaling shared by all), :mod:`.path`,
:mod:`.refine`, :mod:`.runs`, :mod:`.texture`, :mod:`.skymodel`, :mod:`.dp`, :mod:`.net`, :mod:`.bayes`,
:mod:`.score` (:func:`score_skyline` against a truth, with the metrics of
``shared/data/README.md``).
"""

from .options import (DEFAULT_METHOD, METHODS, MIN_HEIGHT_PX, MIN_WIDTH_PX, PRESETS, BayesOptions, DpOptions,
                      NetOptions)
from .score import combine_scores, score_skyline, scored_columns
from .skyline import detect_skyline
from .skymodel import sky_log_odds

__all__ = ["DEFAULT_METHOD", "METHODS", "MIN_HEIGHT_PX", "MIN_WIDTH_PX", "PRESETS", "BayesOptions", "DpOptions",
           "NetOptions",
           "combine_scores", "detect_skyline", "score_skyline", "scored_columns", "sky_log_odds"]
