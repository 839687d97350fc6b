"""Stage 6: from an acquisition to an angular skyline profile in the rover's body frame.

Two ways to get there:

* ``project`` (pointing known): detect the skyline in every frame, map each skyline pixel through
  the intrinsics (undistorted), the mast pan/tilt and the attitude prior to (azimuth, elevation),
  refine the pan angles by aligning the frames' overlaps, and merge the frames bin by bin.
* ``stitch`` (pointing unknown or poor): OpenCV's detailed stitching pipeline with a spherical
  warper builds one panorama; each panorama pixel keeps its ray, so the skyline detected once on
  the panorama maps back to (azimuth, elevation) with the zero-yaw direction fixed by the nominal
  pans (see :mod:`.stitch`).

A ``panorama`` acquisition (one equirectangular image) is read directly.

The output azimuth is clockwise from the rover's forward axis, elevation above the plane that the
attitude prior says is level: a body direction ``d`` is levelled as ``r_world_body(0, pitch, roll) @ d``.
Bin k is centred on ``k * 360 / n`` deg and holds the skyline elevation *at* that azimuth
(linear interpolation along the skyline polyline), as the horizon renderer computes it.

Files: :mod:`.acquisition` (:func:`acquisition_profile`, the entry point), :mod:`.frames` (images
and detection), :mod:`.geometry`, :mod:`.pans` (pan refinement), :mod:`.merge`, :mod:`.project`,
:mod:`.stitch`.
"""

from .acquisition import (DEFAULT_AZIMUTH_BINS, METHODS, acquisition_profile, observable_bins,
                          profile_bins)
from .frames import Detector, detect_frames, get_detector, read_rgb
from .geometry import horizon_rows, levelling_rotation, sample_polyline, skyline_az_el
from .merge import merge_samples
from .pans import DEFAULT_REFINEMENT, PanRefinement, refine_pans
from .project import panorama_profile, profile_from_skylines

__all__ = ["DEFAULT_AZIMUTH_BINS", "DEFAULT_REFINEMENT", "METHODS", "Detector", "PanRefinement",
           "acquisition_profile", "detect_frames", "get_detector", "horizon_rows",
           "levelling_rotation", "merge_samples", "observable_bins", "panorama_profile",
           "profile_bins", "profile_from_skylines", "read_rgb", "refine_pans", "sample_polyline", "skyline_az_el"]
