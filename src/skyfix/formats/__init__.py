"""The interface formats of ``conventions.md``: acquisitions, skylines and angular profiles.

Outside tools read and write these, so parsing is strict and every error names the field
(:mod:`.values`). The localiser reads an acquisition with :func:`load_acquisition`
(:mod:`.acquisition`), which never exposes ``truth``; evaluation tools call :func:`load_truth`.
Skylines per image column are :mod:`.skyline`, angular profiles :mod:`.profile`.
"""

from .acquisition import (ACQUISITION_FILE, MAX_TANGENTIAL, RADIAL_SCALE_RANGE, Acquisition, Frame,
                          PanoramaSpec, Truth, acquisition_from_dict, load_acquisition, load_truth,
                          save_acquisition)
from .profile import Profile, read_profile_json, write_profile_json
from .skyline import Skyline, read_skyline_json, write_skyline_json
from .values import MAX_CAMERA_HEIGHT_M, MAX_PRIOR_TILT_DEG

__all__ = ["ACQUISITION_FILE", "MAX_CAMERA_HEIGHT_M", "MAX_PRIOR_TILT_DEG", "MAX_TANGENTIAL",
           "RADIAL_SCALE_RANGE", "Acquisition", "Frame", "PanoramaSpec", "Profile", "Skyline",
           "Truth", "acquisition_from_dict", "load_acquisition", "load_truth", "read_profile_json",
           "read_skyline_json", "save_acquisition", "write_profile_json", "write_skyline_json"]
