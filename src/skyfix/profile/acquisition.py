"""The entry point: :func:`acquisition_profile` reads an acquisition's images, detects their skylines
and builds the body-frame profile by the ``project`` or the ``stitch`` method."""

from __future__ import annotations

import logging
from typing import Sequence

import numpy as np

from ..camera import direction_to_az_el, r_world_cam
from ..errors import DetectionError, ParameterError
from ..formats import Acquisition, Profile, Skyline
from .frames import Detector, detect_frames, get_detector, read_rgb
from .geometry import check_bins, sample_polyline
from .pans import DEFAULT_REFINEMENT, PanRefinement
from .project import panorama_profile, profile_from_skylines


log = logging.getLogger(__package__)  # messages name the stage, as before the split


METHODS = ("project", "stitch")

#: azimuth bins of a profile made for no database (conventions.md: 360 bins of 1 deg)
DEFAULT_AZIMUTH_BINS = 360


def profile_bins(db=None) -> int:
    """The azimuth bins to make an acquisition's profile in: the database's when there is one
    (its search takes no other bin count), else :data:`DEFAULT_AZIMUTH_BINS` (a search on the
    DEM alone, or a heading, takes any)."""
    return int(db.azimuth_bins) if db is not None else DEFAULT_AZIMUTH_BINS


#: [deg] margin on each side of a frame's azimuths in :func:`observable_bins`: the pan
#: refinement may move a frame by up to its search bound, and the rows are sampled
OBSERVABLE_MARGIN_DEG = DEFAULT_REFINEMENT.search_deg + 1.0


def observable_bins(acq: Acquisition, azimuth_bins: int = DEFAULT_AZIMUTH_BINS) -> int:
    """The most azimuth bins a profile of ``acq`` can observe, from its description alone (no
    image read): the bins whose centres some pixel of some frame (any row, through the mast
    pointing and the attitude prior), or the panorama's azimuth range, reaches, widened by
    :data:`OBSERVABLE_MARGIN_DEG`. An upper bound: whatever the detector finds, the profile holds
    no more, so a view too narrow for a search is refused before detection (minutes on a board).
    """
    check_bins(azimuth_bins)
    step = 360.0 / azimuth_bins
    centres = np.arange(azimuth_bins) * step
    if acq.panorama is not None:
        spec = acq.panorama
        if spec.hfov_deg + 2 * OBSERVABLE_MARGIN_DEG >= 360.0:
            return azimuth_bins
        off = (centres - spec.azimuth_left_deg + OBSERVABLE_MARGIN_DEG) % 360.0
        return int(np.count_nonzero(off <= spec.hfov_deg + 2 * OBSERVABLE_MARGIN_DEG))
    cam = acq.camera
    seen = np.zeros(azimuth_bins, bool)
    # The image's border, walked round once: azimuth has no extreme inside a frame (the lens maps
    # it smoothly onto the sky, where azimuth's only critical points are the poles), so the
    # border reaches every azimuth the frame does; a border round a pole sweeps the whole
    # circle. Its edges, not its outer pixel centres, bound what it sees. (33 whole rows a
    # frame took 0.34 s for 12 frames of a distorted lens, at the start of every locate.)
    w, h = cam.width - 0.5, cam.height - 0.5
    top = np.linspace(-0.5, w, cam.width + 1)
    side = np.linspace(-0.5, h, cam.height + 1)
    u = np.concatenate([top, np.full(side.size, w), top[::-1], np.full(side.size, -0.5), [-0.5]])
    v = np.concatenate([np.full(top.size, -0.5), side, np.full(top.size, h), side[::-1], [-0.5]])
    for fr in acq.frames:
        # camera axes -> the levelled body frame the profile is in (yaw 0)
        rot = r_world_cam(0.0, acq.prior_pitch_deg, acq.prior_roll_deg, fr.pan_deg, fr.tilt_deg)
        az, _ = direction_to_az_el(cam.pixel_to_ray(u, v) @ rot.T)
        # only which bin centres the border's azimuths cover counts; points a bin apart at most
        # join (a wide lens)
        got, _ = sample_polyline(az, np.zeros_like(az), azimuth_bins,
                                 max_step_deg=max(2.0, 2 * step))
        seen |= np.isfinite(got)
    # widen every observed run by the margin, round the circle
    k = int(np.ceil(OBSERVABLE_MARGIN_DEG / step))
    wide = seen.copy()
    for s in range(1, k + 1):
        wide |= np.roll(seen, s) | np.roll(seen, -s)
    return int(wide.sum())


def acquisition_profile(acq: Acquisition, *, method: str = "project",
                        azimuth_bins: int = DEFAULT_AZIMUTH_BINS,
                        detector: str | Detector | None = None, skylines: Sequence[Skyline | None] | None = None,
                        refine: PanRefinement = DEFAULT_REFINEMENT) -> Profile:
    """The body-frame angular profile of an acquisition.

    method : ``project`` (per-frame projection, needs known pointing) or ``stitch`` (OpenCV
        panorama, then one detection); a panorama acquisition is read directly whatever the method
    azimuth_bins : bins over 360 deg (bin k centred on ``k * 360 / n`` deg)
    detector : a :func:`skyfix.detect.detect_skyline` method name or a callable
        ``(rgb_uint8, mask=None) -> Skyline``
    skylines : per-frame skylines already known (skips detection; ``project`` only)
    """
    if method not in METHODS:
        raise ParameterError(f"unknown profile method {method!r}: choose one of {', '.join(METHODS)}")
    check_bins(azimuth_bins)
    if acq.panorama is not None:
        spec = acq.panorama
        img = read_rgb(acq.image_path(spec.image))
        mask = np.any(img > 0, axis=2)
        if skylines is not None:
            sky = skylines[0]
        else:
            try:
                sky = get_detector(detector)(img, mask=mask)
            except DetectionError as e:
                raise DetectionError(f"no skyline in panorama {spec.image}: {e}") from None
        prof = panorama_profile(spec, sky, azimuth_bins=azimuth_bins,
                                pitch_deg=acq.prior_pitch_deg, roll_deg=acq.prior_roll_deg)
    elif method == "stitch":
        from .stitch import stitched_profile

        prof = stitched_profile(acq, azimuth_bins=azimuth_bins, detector=detector)
    else:
        if skylines is None:
            skylines = detect_frames(acq, detector)
        prof = profile_from_skylines(acq, skylines, azimuth_bins=azimuth_bins, refine=refine)
    # the height the skyline was seen from: a profile saved and located later must carry it
    # (without it, locate --profile took 1.5 m for a camera 5 m up: 3.7 m off at 0.96)
    prof.meta["camera_height_m"] = float(acq.camera_height_m)
    return prof
