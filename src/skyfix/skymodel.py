"""Kept so that ``from skyfix.skymodel import ...`` still works: the sky classifier now lives in
:mod:`skyfix.detect.skymodel`, beside the detector that uses it."""

from .detect.skymodel import (DEFAULT_GREY_MODEL, DEFAULT_MODEL, FEATURE_NAMES, N_FEATURES,  # noqa: F401
                              SKY_RGB, SkyModel, fit_sky_model, from_sklearn, load_sky_model,
                              sky_features, sky_label_mask, training_pixels)
