"""The input a board command reads its skyline from: an acquisition folder (its images detected
and profiled) or a ``--profile`` JSON, for ``skyfix locate``, ``heading`` and ``attitude``.

Imports stay light at module level (the board process must fit in 256 MB).
"""

from __future__ import annotations

from ..errors import ParameterError
from ..progress import stage


def check_source(acq_dir, profile_path):
    """Exactly one of ACQ_DIR and --profile (checked before any work)."""
    if acq_dir is not None and profile_path is not None:
        raise ParameterError(f"give an acquisition folder ({acq_dir}) or --profile ({profile_path}), "
                             "not both: the profile would be used and the folder ignored")
    if acq_dir is None and profile_path is None:
        raise ParameterError("give an acquisition folder or --profile PROFILE.json")


def check_detector(profile_path, detector):
    if profile_path is not None and detector is not None:
        raise ParameterError(f"--detector {detector} says how an acquisition's images are detected, "
                             f"and the profile {profile_path} holds none: give the acquisition "
                             "folder instead, or drop --detector")


def detector_used(profile_path, detector):
    """The detection method a result's skylines came from (None: from a --profile)."""
    from ..detect.options import DEFAULT_METHOD

    return None if profile_path is not None else (detector or DEFAULT_METHOD)


def read_acquisition(acq_dir):
    """The acquisition's description (no image read), once per run; None with a --profile."""
    if acq_dir is None:
        return None
    from ..formats import load_acquisition

    return load_acquisition(acq_dir)


def check_view_width(acq, db, min_bins: int, what: str) -> None:
    """Refuse, before any image is read, an acquisition whose frames (or panorama) cannot cover
    ``min_bins`` of the profile's azimuth bins (the database's, else 360) whatever the detector
    finds: detection takes minutes on a board and its profile would be refused after it."""
    if acq is None:
        return
    from ..profile import observable_bins, profile_bins

    n = profile_bins(db)
    most = observable_bins(acq, n)
    if most < min_bins:
        step = 360.0 / n
        raise ParameterError(
            f"the acquisition's {_view_words(acq)} can observe at most {most} of the profile's "
            f"{n} azimuth bins ({most * step:.0f} deg); {what} needs at least {min_bins} "
            f"({min_bins * step:.0f} deg of skyline): add frames at other pans or use a wider lens")


def _view_words(acq) -> str:
    if acq.panorama is not None:
        return f"panorama ({acq.panorama.hfov_deg:g} deg wide)"
    n = len(acq.frames)
    return (f"{n} frame{'s' * (n != 1)} (camera {acq.camera.hfov_deg:.1f} deg wide, pans "
            + ", ".join(f"{f.pan_deg:g}" for f in acq.frames[:6]) + (", ..." if n > 6 else "")
            + " deg)")


def input_files(acq, profile_path, dem_paths) -> list:
    """The files a locate or heading run reads (the acquisition's own, the profile, the DEMs): no
    output may replace one of them."""
    return [profile_path, *(dem_paths or ()), *(acq.files() if acq is not None else ())]


def read_profile(acq, profile_path, frames=None, detector=None, db=None):
    """Profile from ``--profile`` JSON, else from the acquisition ``acq`` (:func:`read_acquisition`;
    one of the two, as :func:`check_source` made sure), its images detected with
    ``detector`` (a method name; None: the default) into the database ``db``'s azimuth bins
    (:func:`~skyfix.profile.profile_bins`); with the attitude prior (pitch, roll) [deg]
    and the camera height [m] (None when the profile does not say). ``frames``, a list, receives
    each frame's detected rows (:class:`~skyfix.pose.image_plane.FrameRows`) when the profile
    comes from frames."""
    from ..formats import read_profile_json

    if profile_path is not None:
        # the reader validates frame, attitude_prior and camera_height_m, naming the field
        prof = read_profile_json(profile_path, frame="body")
        prior = prof.meta.get("attitude_prior") or {}
        return prof, prior.get("pitch_deg", 0.0), prior.get("roll_deg", 0.0), \
            prof.meta.get("camera_height_m")
    import numpy as np

    from ..profile import acquisition_profile, profile_bins

    azimuth_bins = profile_bins(db)
    n = len(acq.frames) or 1
    with stage(f"skyline detected and profiled ({n} image{'s' * (n > 1)})") as st:
        if frames is not None and acq.frames and acq.panorama is None:
            from ..pose.image_plane import frames_from_acquisition
            from ..profile import detect_frames

            skylines = detect_frames(acq, detector)
            frames.extend(frames_from_acquisition(acq, skylines))
            prof = acquisition_profile(acq, skylines=skylines, azimuth_bins=azimuth_bins)
        else:
            prof = acquisition_profile(acq, detector=detector, azimuth_bins=azimuth_bins)
        used = prof.meta.get("frames_used")
        obs = int(np.isfinite(prof.elevation_deg).sum())
        st.result = (f"{used} of {n} images with a skyline, " if used is not None else "") + \
            f"{obs} of {prof.elevation_deg.size} azimuth bins observed"
    return prof, acq.prior_pitch_deg, acq.prior_roll_deg, acq.camera_height_m
