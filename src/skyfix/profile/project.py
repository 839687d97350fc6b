"""The ``project`` method: each frame's detected skyline projected through its known pointing onto
azimuth bins and merged; a panorama's skyline read off its angular grid.
"""

from __future__ import annotations

import logging
from typing import Sequence

import numpy as np

from ..camera import direction_to_az_el
from ..errors import AcquisitionError, DetectionError, ParameterError
from ..formats import Acquisition, PanoramaSpec, Profile, Skyline
from .geometry import check_bins, levelling_rotation, sample_polyline, skyline_az_el
from .merge import merge_samples
from .pans import DEFAULT_REFINEMENT, PanRefinement, refine_pans

log = logging.getLogger(__package__)  # messages name the stage, as before the split



#: [deg] the median elevation difference over their shared bins beyond which two overlapping
#: frames are said to disagree: after pan refinement they agree to a pixel or two (0.01-0.1 deg
#: on simulated navcam frames), and a mast's pans are good to about 1 deg
DISAGREE_DEG = 1.0
#: fewest shared bins for two frames' disagreement to be judged
DISAGREE_MIN_BINS = 3


def disagreeing_frames(vals: np.ndarray, frames) -> list[dict]:
    """Pairs of frames whose samples (``vals``: (bins, F) [deg], NaN where a frame does not
    cover a bin; ``frames``: each column's frame index) differ by more than
    :data:`DISAGREE_DEG` in the median over at least :data:`DISAGREE_MIN_BINS` shared bins: a
    wrong pan or tilt in the acquisition, which the merge's median would otherwise split the
    difference of without a word."""
    out = []
    have = np.isfinite(vals)
    for a in range(vals.shape[1]):
        for b in range(a + 1, vals.shape[1]):
            both = have[:, a] & have[:, b]
            n = int(both.sum())
            if n < DISAGREE_MIN_BINS:
                continue
            med = float(np.median(np.abs(vals[both, a] - vals[both, b])))
            if med > DISAGREE_DEG:
                out.append({"i": int(frames[a]), "j": int(frames[b]), "median_deg": med, "bins": n})
    return out


def profile_from_skylines(acq: Acquisition, skylines: Sequence[Skyline | None], *,
                          azimuth_bins: int = 360, refine: PanRefinement = DEFAULT_REFINEMENT,
                          method: str = "project") -> Profile:
    """Project per-frame skylines (one per ``acq.frames``, None = failed) into a body-frame profile.

    Frames without a skyline are dropped and recorded in ``meta["frames"]``. Raises
    :class:`DetectionError` when no frame has a skyline.
    """
    check_bins(azimuth_bins)
    if not acq.frames:
        raise AcquisitionError("profile_from_skylines needs a frame acquisition (it has a panorama)")
    if len(skylines) != len(acq.frames):
        raise ParameterError(f"{len(skylines)} skylines for {len(acq.frames)} frames")
    cam = acq.camera
    pitch, roll = acq.prior_pitch_deg, acq.prior_roll_deg
    records = []
    used = []
    for i, (f, s) in enumerate(zip(acq.frames, skylines)):
        rec = {"index": i, "image": f.image, "pan_nominal_deg": f.pan_deg, "tilt_deg": f.tilt_deg}
        reason = None
        if s is None:
            reason = "detection failed"
        elif s.rows.size != cam.width:
            reason = f"skyline has {s.rows.size} columns, the camera {cam.width}"
        elif not np.isfinite(s.rows).any():
            reason = "no skyline visible"
        if reason:
            log.warning("frame %d (%s) dropped: %s", i, f.image, reason)
            rec.update(status="dropped", reason=reason)
        else:
            rec["status"] = "used"
            rec["skyline_columns"] = int(np.isfinite(s.rows).sum())
            used.append(i)
        records.append(rec)
    if not used:
        raise DetectionError(
            f"no skyline in any of the {len(acq.frames)} frames of {acq.root}: check the images "
            "(sky visible? exposure?) or the detector")
    sk = [skylines[i] for i in used]
    pans = np.array([acq.frames[i].pan_deg for i in used])
    tilts = np.array([acq.frames[i].tilt_deg for i in used])
    delta, pairs = refine_pans(cam, sk, pans, tilts, refine)
    pix_deg = float(np.degrees(1.0 / cam.fx))
    vals = np.full((azimuth_bins, len(used)), np.nan)
    wts = np.zeros((azimuth_bins, len(used)))
    sigs = np.full((azimuth_bins, len(used)), np.nan)
    for m, (s, p, d, t) in enumerate(zip(sk, pans, delta, tilts)):
        az, el = skyline_az_el(cam, s.rows, p + d, t, pitch, roll)
        conf = s.confidence if s.confidence is not None else np.ones(s.rows.size)
        v, w = sample_polyline(az, el, azimuth_bins, weight=np.clip(conf, 0.0, 1.0))
        vals[:, m] = v
        wts[:, m] = np.nan_to_num(w)
        # one pixel at full confidence, more where the detector is unsure
        sigs[:, m] = pix_deg / np.maximum(np.nan_to_num(w), 0.05)
    el, sigma, count = merge_samples(vals, sigs, wts)
    disagree = disagreeing_frames(vals, used)
    for d in disagree:
        log.warning("frames %d and %d disagree by %.1f deg (median over %d shared bins) where "
                    "they overlap: a wrong pan_deg or tilt_deg in acquisition.json, or a skyline "
                    "detected wrong in one of them (the merged profile's sigma there says so)",
                    d["i"], d["j"], d["median_deg"], d["bins"])
    contributors = [[used[m] for m in np.flatnonzero(np.isfinite(vals[k]))] for k in range(azimuth_bins)]
    for m, i in enumerate(used):
        records[i].update(pan_deg=float(pans[m] + delta[m]), pan_correction_deg=float(delta[m]),
                          bins=int(np.isfinite(vals[:, m]).sum()))
        log.debug("frame %d (%s): pan %.2f deg %+.2f refined, %d skyline columns -> %d bins", i,
                  acq.frames[i].image, pans[m], delta[m], records[i]["skyline_columns"],
                  records[i]["bins"])
    # -v: a pan refinement that moved a frame by degrees says the mast's pans (or the overlaps'
    # skylines) are suspect
    log.info("profile: %d of %d frames used, pans refined by %+.2f to %+.2f deg (%d overlaps), "
             "%.0f deg of azimuth observed", len(used), len(acq.frames), float(np.min(delta)),
             float(np.max(delta)), len(pairs), np.isfinite(el).sum() * 360.0 / azimuth_bins)
    meta = {
        "method": method, "attitude_prior": {"pitch_deg": pitch, "roll_deg": roll},
        "frames": records, "frames_used": len(used), "frames_dropped": len(acq.frames) - len(used),
        "pan_refinement": {"enabled": refine.enabled and len(used) > 1, "pairs": pairs},
        "contributors": contributors, "coverage_deg": float(np.isfinite(el).sum() * 360.0 / azimuth_bins),
        "frames_disagree": disagree,
    }
    return Profile(el, sigma, frame="body", meta=meta)


def panorama_profile(spec: PanoramaSpec, skyline: Skyline, *, azimuth_bins: int = 360,
                     pitch_deg: float = 0.0, roll_deg: float = 0.0) -> Profile:
    """Profile from the skyline of an equirectangular body-frame panorama.

    Pixel (i, j) centre is at azimuth ``left + (j + 0.5) hfov / W`` and elevation
    ``top - (i + 0.5) vfov / H`` [deg]; the directions are then levelled with the attitude prior.
    """
    check_bins(azimuth_bins)
    w, h = skyline.width, skyline.height
    rows = np.asarray(skyline.rows, float)
    j = np.arange(rows.size)
    az = spec.azimuth_left_deg + (j + 0.5) * spec.hfov_deg / w
    el = spec.elevation_top_deg - (rows + 0.5) * spec.vfov_deg / h
    if pitch_deg or roll_deg:
        from ..camera import az_el_to_direction
        d = az_el_to_direction(az, np.nan_to_num(el)) @ levelling_rotation(pitch_deg, roll_deg).T
        az2, el2 = direction_to_az_el(d)
        az, el = np.where(np.isfinite(el), az2, np.nan), np.where(np.isfinite(el), el2, np.nan)
    az = np.mod(az, 360.0)
    conf = skyline.confidence if skyline.confidence is not None else np.ones(rows.size)
    if spec.hfov_deg >= 360.0 - 1e-9:
        # a full turn: its last column joins its first across the seam (the bin between them was
        # left empty, wherever the seam lay)
        az, el, conf = np.append(az, az[0]), np.append(el, el[0]), np.append(conf, conf[0])
    max_step = 2.0 * max(spec.hfov_deg / w, 360.0 / azimuth_bins)
    v, wgt = sample_polyline(az, el, azimuth_bins, weight=np.clip(conf, 0, 1), max_step_deg=max_step)
    pix_deg = spec.vfov_deg / h
    sigma = np.where(np.isfinite(v), pix_deg / np.maximum(np.nan_to_num(wgt), 0.05), np.nan)
    if not np.isfinite(v).any():
        raise DetectionError(f"no skyline in panorama {spec.image}")
    meta = {"method": "panorama", "image": spec.image,
            "attitude_prior": {"pitch_deg": pitch_deg, "roll_deg": roll_deg},
            "coverage_deg": float(np.isfinite(v).sum() * 360.0 / azimuth_bins)}
    return Profile(v, sigma, frame="body", meta=meta)
