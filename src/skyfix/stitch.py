"""Kept so that ``from skyfix.stitch import ...`` still works: stitching now lives in
:mod:`skyfix.profile.stitch`, beside the other way to an angular profile."""

from .profile.stitch import (MATCH_CONF_THRESH, WORK_MEGAPIX, stitch_panorama,  # noqa: F401
                             stitch_rotations, stitched_profile)
