"""Stage 6: from an acquisition to an angular skyline profile in the rover's body frame.

Two ways to get there:

* ``project`` (pointing known): detect the skyline in every frame, map each skyline pixel through
  the intrinsics (undistorted), the mast pan/tilt and the attitude prior to (azimuth, elevation),
  refine the pan angles by aligning the frames' overlaps, and merge the frames bin by bin.
* ``stitch`` (pointing unknown or poor): OpenCV's detailed stitching pipeline with a spherical
  warper builds one panorama; each panorama pixel keeps its ray, so the skyline detected once on
  the panorama maps back to (azimuth, elevation) with the zero-yaw direction fixed by the nominal
  pans (see :mod:`skyfix.stitch`).

A ``panorama`` acquisition (one equirectangular image) is read directly.

The output azimuth is clockwise from the rover's forward axis, elevation above the plane that the
attitude prior says is level: a body direction ``d`` is levelled as ``r_world_body(0, pitch, roll) @ d``.
Bin k is centred on ``k * 360 / n`` deg and holds the skyline elevation *at* that azimuth
(linear interpolation along the skyline polyline), as the horizon renderer computes it.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from .camera import C_CAM_TO_BODY, Camera, direction_to_az_el, r_body_mast, r_world_body
from .errors import AcquisitionError, DetectionError, ParameterError
from .formats import Acquisition, PanoramaSpec, Profile, Skyline

log = logging.getLogger(__name__)

METHODS = ("project", "stitch")

#: A detector: RGB uint8 image (H, W, 3) and a validity mask (or None) -> Skyline.
Detector = Callable[..., Skyline]


@dataclass(frozen=True)
class PanRefinement:
    """How ``project`` refines the mast pan angles from the frames' overlaps.

    enabled : refine at all
    prior_sigma_deg : [deg] 1-sigma accuracy of the nominal pans (a real mast: about 1 deg); it
        fixes the gauge (a common pan offset is a yaw, invisible in the overlaps) and keeps frames
        without a usable overlap at their nominal pan
    search_deg : [deg] largest pan correction searched
    step_deg : [deg] azimuth sampling of the overlap comparison
    min_overlap_deg : [deg] pairs overlapping less than this are not used
    iterations : passes; the second, with the corrected pans, refines on the full overlaps
    """

    enabled: bool = True
    prior_sigma_deg: float = 1.0
    search_deg: float = 3.0
    step_deg: float = 0.02
    min_overlap_deg: float = 2.0
    iterations: int = 2


DEFAULT_REFINEMENT = PanRefinement()


# --- geometry ------------------------------------------------------------------------------------

def levelling_rotation(pitch_deg: float, roll_deg: float) -> np.ndarray:
    """Body -> levelled body (yaw 0) for an attitude prior [deg]."""
    return r_world_body(0.0, pitch_deg, roll_deg)


def skyline_az_el(camera: Camera, rows: np.ndarray, pan_deg: float, tilt_deg: float = 0.0,
                  pitch_deg: float = 0.0, roll_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame (levelled) azimuth and elevation [deg] of a frame's skyline, one per column.

    rows : (W,) skyline row per column [px, 0-based pixel-centre coordinates], NaN where none
    pan_deg, tilt_deg : [deg] mast pointing; pitch_deg, roll_deg : [deg] attitude prior
    Returns two (W,) arrays, NaN where ``rows`` is NaN.
    """
    rows = np.asarray(rows, dtype=float)
    u = np.arange(rows.size, dtype=float)
    ok = np.isfinite(rows)
    az = np.full(rows.size, np.nan)
    el = np.full(rows.size, np.nan)
    if not ok.any():
        return az, el
    ray = camera.pixel_to_ray(u[ok], rows[ok])
    rot = levelling_rotation(pitch_deg, roll_deg) @ r_body_mast(pan_deg, tilt_deg) @ C_CAM_TO_BODY
    az[ok], el[ok] = direction_to_az_el(ray @ rot.T)
    return az, el


def sample_polyline(az: np.ndarray, el: np.ndarray, bins: int, *, weight: np.ndarray | None = None,
                    max_step_deg: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Skyline elevation [deg] at the bin centres ``k * 360 / bins`` covered by a polyline.

    az, el : (M,) vertices in order along the skyline [deg]; NaN breaks the line
    weight : (M,) per-vertex weight (e.g. detection confidence), interpolated the same way
    max_step_deg : [deg] consecutive vertices further apart in azimuth are not joined (a fold or a
        jump, not a skyline segment)
    Returns ``(elevation, weight)``, each (bins,), NaN where no segment covers the bin centre. Where
    several segments cover a centre, the highest wins (a skyline is the highest terrain).
    """
    az = np.asarray(az, float)
    el = np.asarray(el, float)
    w = np.ones_like(el) if weight is None else np.where(np.isfinite(weight), weight, 0.0)
    out = np.full(bins, -np.inf)
    out_w = np.zeros(bins)
    step = 360.0 / bins
    a0, a1 = az[:-1], az[1:]
    e0, e1 = el[:-1], el[1:]
    seg = np.isfinite(a0) & np.isfinite(a1) & np.isfinite(e0) & np.isfinite(e1)
    da = (a1 - a0 + 180.0) % 360.0 - 180.0  # shortest way round: a segment never spans 180 deg
    seg &= np.abs(da) <= max_step_deg
    idx = np.flatnonzero(seg)
    if idx.size == 0:
        return np.full(bins, np.nan), np.full(bins, np.nan)
    a0, da, e0, e1 = a0[idx], da[idx], e0[idx], e1[idx]
    w0, w1 = w[idx], w[idx + 1]
    lo = np.minimum(a0, a0 + da)
    hi = np.maximum(a0, a0 + da)
    k_lo = np.ceil(lo / step - 1e-9).astype(np.int64)
    k_hi = np.floor(hi / step + 1e-9).astype(np.int64)
    n = np.maximum(k_hi - k_lo + 1, 0)
    rep = np.repeat(np.arange(idx.size), n)
    k = k_lo[rep] + (np.arange(rep.size) - np.repeat(np.cumsum(n) - n, n))
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where(da[rep] != 0, (k * step - a0[rep]) / da[rep], 0.0)
    t = np.clip(t, 0.0, 1.0)
    val = e0[rep] + t * (e1[rep] - e0[rep])
    wv = w0[rep] + t * (w1[rep] - w0[rep])
    kb = np.mod(k, bins)
    np.maximum.at(out, kb, val)
    np.maximum.at(out_w, kb, wv)
    out[~np.isfinite(out)] = np.nan
    out_w[np.isnan(out)] = np.nan
    return out, out_w


def horizon_rows(camera: Camera, az_deg: np.ndarray, el_deg: np.ndarray, r_world_cam: np.ndarray) -> np.ndarray:
    """Forward model: the skyline row [px] per image column of a horizon seen by a camera.

    az_deg, el_deg : (M,) a densely sampled closed horizon [deg] in the frame ``r_world_cam`` maps to
        (world for a rendered horizon, levelled body for a profile)
    r_world_cam : camera axes -> that frame (e.g. :func:`skyfix.camera.r_world_cam`)
    Each horizon vertex is projected (with distortion) and the row is interpolated linearly in
    column; NaN where the skyline is outside the image. Used to draw a predicted skyline over an
    image and, in tests, as the independent forward path that :func:`skyline_az_el` inverts.
    """
    from .camera import az_el_to_direction

    az = np.asarray(az_deg, float)
    el = np.asarray(el_deg, float)
    d = az_el_to_direction(az, el) @ np.asarray(r_world_cam)  # rows: R^T d
    u, v, front = camera.ray_to_pixel(d)
    # keep a margin so columns at the image edge are interpolated, not extrapolated
    half = max(camera.width, camera.height)
    ok = front & np.isfinite(el) & (u > -half) & (u < camera.width + half)
    rows = np.full(camera.width, np.nan)
    if ok.sum() < 2:
        return rows
    # walk the closed horizon from a vertex outside the view, so the visible part is one run
    start = int(np.flatnonzero(~ok)[0]) if (~ok).any() else 0
    order = np.roll(np.arange(az.size), -start)
    uu, vv, kk = u[order], v[order], ok[order]
    cols = np.arange(camera.width, dtype=float)
    # a run of consecutive in-front vertices is one visible piece of the skyline
    breaks = np.flatnonzero(np.diff(kk.astype(np.int8)) != 0) + 1
    for piece in np.split(np.arange(az.size), breaks):
        if not kk[piece[0]] or piece.size < 2:
            continue
        pu, pv = uu[piece], vv[piece]
        if np.any(np.diff(pu) <= 0):
            srt = np.argsort(pu)
            pu, pv = pu[srt], pv[srt]
        inside = (cols >= pu[0]) & (cols <= pu[-1])
        rows[inside] = np.interp(cols[inside], pu, pv)
    rows[(rows < 0) | (rows > camera.height - 1)] = np.nan
    return rows


# --- merging -------------------------------------------------------------------------------------

def _weighted_median(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Per row of (bins, F) arrays (NaN = missing): the weighted median; NaN where a row is empty."""
    v = np.where(np.isfinite(values), values, np.inf)
    w = np.where(np.isfinite(values), np.maximum(weights, 1e-6), 0.0)
    order = np.argsort(v, axis=1)
    vs = np.take_along_axis(v, order, axis=1)
    ws = np.take_along_axis(w, order, axis=1)
    cw = np.cumsum(ws, axis=1)
    tot = cw[:, -1:]
    # lower and upper weighted medians, averaged (the plain median for equal weights)
    lo = np.argmax(cw >= 0.5 * tot - 1e-12, axis=1)
    hi = np.argmax(cw > 0.5 * tot + 1e-12, axis=1)
    r = np.arange(v.shape[0])
    med = 0.5 * (vs[r, lo] + vs[r, np.minimum(hi, v.shape[1] - 1)])
    med[tot[:, 0] <= 0] = np.nan
    return med


def merge_samples(values: np.ndarray, sigmas: np.ndarray, weights: np.ndarray):
    """Merge per-frame bin samples (bins, F) into one profile.

    values : [deg] elevation samples, NaN where a frame does not cover the bin
    sigmas : [deg] per-sample 1-sigma; weights : detection confidence in [0, 1]
    Returns ``(elevation, sigma, count)``: the confidence-weighted median; its sigma is the larger of
    the samples' combined sigma and the robust spread between frames (1.4826 MAD / sqrt(n)), so a
    bin where frames disagree says so.
    """
    med = _weighted_median(values, weights)
    have = np.isfinite(values)
    count = have.sum(axis=1)
    inv = np.where(have, 1.0 / np.square(np.where(have, sigmas, 1.0)), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        sig_comb = 1.0 / np.sqrt(inv.sum(axis=1))
        dev = np.abs(values - med[:, None])
        with warnings.catch_warnings():  # empty bins: NaN is the answer
            warnings.simplefilter("ignore", RuntimeWarning)
            mad = np.nanmedian(np.where(have, dev, np.nan), axis=1)
        spread = np.where(count >= 2, 1.4826 * mad / np.sqrt(np.maximum(count, 1)), 0.0)
    sigma = np.where(count > 0, np.maximum(sig_comb, np.nan_to_num(spread)), np.nan)
    return med, sigma, count


# --- pan refinement ------------------------------------------------------------------------------

def _frame_fine(camera, sky: Skyline, pan, tilt, pitch, roll, bins):
    az, el = skyline_az_el(camera, sky.rows, pan, tilt, pitch, roll)
    return sample_polyline(az, el, bins)[0]


def _pair_shift(fi: np.ndarray, fj: np.ndarray, step: float, search: float, min_overlap: int,
                clip: float = np.inf):
    """Azimuth shift s [deg] with ``fj(az - s) ~ fi(az)`` over the overlap, and its weight.

    Both are fine-sampled profiles on the same circular grid (NaN = not covered). Each sample's
    squared difference counts at most ``clip``^2 [deg^2]: a stretch that one frame's detector got
    wrong then cannot pull the shift (measured: a 3-5 px detection error on a steep overlap gave
    a 0.35 deg pan error and a 7 m position error). The weight is the Fisher information of the
    shift (sum of squared slopes over the overlap samples that agree within ``clip``): a flat
    overlap pins nothing down and then the pan prior wins.
    """
    n = fi.size
    max_k = int(round(search / step))
    best = (np.inf, 0)
    ks = np.arange(-max_k, max_k + 1)
    costs = np.full(ks.size, np.inf)
    for m, k in enumerate(ks):
        g = np.roll(fj, k)
        ok = np.isfinite(fi) & np.isfinite(g)
        if ok.sum() < min_overlap:
            continue
        d = fi[ok] - g[ok]
        # no free vertical offset: on a sloping skyline an offset and a shift look alike
        costs[m] = np.mean(np.minimum(np.square(d), clip * clip))
        if costs[m] < best[0]:
            best = (costs[m], m)
    if not np.isfinite(best[0]):
        return None
    m = best[1]
    s = float(ks[m])
    if 0 < m < ks.size - 1 and np.isfinite(costs[m - 1]) and np.isfinite(costs[m + 1]):
        denom = costs[m - 1] - 2 * costs[m] + costs[m + 1]
        if denom > 0:
            s += 0.5 * (costs[m - 1] - costs[m + 1]) / denom
    g = np.roll(fj, int(ks[m]))
    ok = np.isfinite(fi) & np.isfinite(g)
    ok &= np.abs(np.where(ok, fi - g, 0.0)) <= clip
    slope = np.gradient(np.where(np.isfinite(fi), fi, np.nan)) / step
    info = float(np.nansum(np.square(slope[ok])))
    resid = float(np.sqrt(best[0]))
    return s * step, info, resid, int(ok.sum())


def refine_pans(camera: Camera, skylines: Sequence[Skyline], pans: Sequence[float],
                tilts: Sequence[float],
                options: PanRefinement = DEFAULT_REFINEMENT) -> tuple[np.ndarray, list[dict]]:
    """Pan corrections [deg] that make overlapping frames agree.

    The frames are compared in the *unlevelled* body frame: a pan is a rotation about the body z
    axis, so there a pan error is exactly an azimuth shift (after levelling it is not, and the
    small elevation change it brings biases the shift on gently sloping overlaps).

    Every overlapping pair (i, j) gives a relative shift ``s_ij ~ d_j - d_i`` (search over
    ``+-search_deg`` of the median-removed squared difference, sub-sample by a parabola), weighted by
    its Fisher information. The corrections solve the weighted least squares
    ``sum w_ij (d_j - d_i - s_ij)^2 / sig_el^2 + sum d_i^2 / prior_sigma^2``. This is repeated after
    re-projecting with the corrected pans. Returns ``(corrections, pair_records)``.
    """
    nf = len(skylines)
    delta = np.zeros(nf)
    if nf < 2 or not options.enabled:
        return delta, []
    bins = int(round(360.0 / options.step_deg))
    step = 360.0 / bins
    pix_deg = float(np.degrees(1.0 / camera.fx))
    sig_el = max(pix_deg, 1e-3)
    min_overlap = int(options.min_overlap_deg / step)
    pairs: list[dict] = []
    search = options.search_deg
    for it in range(max(options.iterations, 1)):
        if it:  # later passes only mop up what the re-projection changed
            search = min(options.search_deg, max(0.3, 10 * step))
        fine = [_frame_fine(camera, s, p + d, t, 0.0, 0.0, bins)
                for s, p, d, t in zip(skylines, pans, delta, tilts)]
        pairs = []
        a = np.eye(nf) / options.prior_sigma_deg ** 2
        b = -delta / options.prior_sigma_deg ** 2  # prior on the *total* correction
        for i in range(nf):
            for j in range(i + 1, nf):
                ov = np.isfinite(fine[i]) & np.isfinite(fine[j])
                if ov.sum() < min_overlap:
                    continue
                r = _pair_shift(fine[i], fine[j], step, search, min_overlap, clip=3 * sig_el)
                if r is None:
                    continue
                s, info, resid, nov = r
                # a residual well above the pixel level means the frames do not see the same skyline
                w = info / (sig_el ** 2 + resid ** 2)
                pairs.append({"i": i, "j": j, "shift_deg": s, "overlap_deg": nov * step,
                              "residual_deg": resid, "weight": w})
                # unknowns: increments e = new delta - delta; s is the residual shift e_j - e_i
                a[i, i] += w
                a[j, j] += w
                a[i, j] -= w
                a[j, i] -= w
                b[i] -= w * s
                b[j] += w * s
        inc = np.linalg.solve(a, b)
        delta = delta + inc
        if np.max(np.abs(inc)) < 1e-3:
            break
    return np.clip(delta, -options.search_deg, options.search_deg), pairs


# --- profiles ------------------------------------------------------------------------------------

def profile_from_skylines(acq: Acquisition, skylines: Sequence[Skyline | None], *,
                          azimuth_bins: int = 360, refine: PanRefinement = DEFAULT_REFINEMENT,
                          method: str = "project") -> Profile:
    """Project per-frame skylines (one per ``acq.frames``, None = failed) into a body-frame profile.

    Frames without a skyline are dropped and recorded in ``meta["frames"]``. Raises
    :class:`DetectionError` when no frame has a skyline.
    """
    _check_bins(azimuth_bins)
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
    contributors = [[used[m] for m in np.flatnonzero(np.isfinite(vals[k]))] for k in range(azimuth_bins)]
    for m, i in enumerate(used):
        records[i].update(pan_deg=float(pans[m] + delta[m]), pan_correction_deg=float(delta[m]),
                          bins=int(np.isfinite(vals[:, m]).sum()))
    meta = {
        "method": method, "attitude_prior": {"pitch_deg": pitch, "roll_deg": roll},
        "frames": records, "frames_used": len(used), "frames_dropped": len(acq.frames) - len(used),
        "pan_refinement": {"enabled": refine.enabled and len(used) > 1, "pairs": pairs},
        "contributors": contributors, "coverage_deg": float(np.isfinite(el).sum() * 360.0 / azimuth_bins),
    }
    return Profile(el, sigma, frame="body", meta=meta)


def panorama_profile(spec: PanoramaSpec, skyline: Skyline, *, azimuth_bins: int = 360,
                     pitch_deg: float = 0.0, roll_deg: float = 0.0) -> Profile:
    """Profile from the skyline of an equirectangular body-frame panorama.

    Pixel (i, j) centre is at azimuth ``left + (j + 0.5) hfov / W`` and elevation
    ``top - (i + 0.5) vfov / H`` [deg]; the directions are then levelled with the attitude prior.
    """
    _check_bins(azimuth_bins)
    w, h = skyline.width, skyline.height
    rows = np.asarray(skyline.rows, float)
    j = np.arange(rows.size)
    az = spec.azimuth_left_deg + (j + 0.5) * spec.hfov_deg / w
    el = spec.elevation_top_deg - (rows + 0.5) * spec.vfov_deg / h
    if pitch_deg or roll_deg:
        from .camera import az_el_to_direction
        d = az_el_to_direction(az, np.nan_to_num(el)) @ levelling_rotation(pitch_deg, roll_deg).T
        az2, el2 = direction_to_az_el(d)
        az, el = np.where(np.isfinite(el), az2, np.nan), np.where(np.isfinite(el), el2, np.nan)
    az = np.mod(az, 360.0)
    conf = skyline.confidence if skyline.confidence is not None else np.ones(rows.size)
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


def _check_bins(bins):
    if int(bins) != bins or bins < 4:
        raise ParameterError(f"azimuth bins must be a whole number >= 4, got {bins}")


# --- images and detection -------------------------------------------------------------------------

def read_rgb(path) -> np.ndarray:
    """An image as RGB uint8 (H, W, 3); 16-bit images are scaled down."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise AcquisitionError(f"cannot read image {path}: not an image OpenCV can decode")
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    else:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return np.ascontiguousarray(img)


def get_detector(detector: str | Detector) -> Detector:
    """A detector callable ``(rgb, mask=None) -> Skyline`` from a method name or a callable."""
    if callable(detector):
        return detector
    from .detect import detect_skyline  # the sibling stage; imported only when detecting

    def run(image, mask=None):
        return detect_skyline(image, mask=mask, method=detector)

    return run


def detect_frames(acq: Acquisition, detector: str | Detector = "dp") -> list[Skyline | None]:
    """Detect the skyline in every frame; a frame whose detection raises DetectionError is None."""
    det = get_detector(detector)
    out: list[Skyline | None] = []
    for f in acq.frames:
        img = read_rgb(acq.image_path(f.image))
        h, w = img.shape[:2]
        if (w, h) != (acq.camera.width, acq.camera.height):
            raise AcquisitionError(
                f"image {f.image} is {w} x {h} px but camera is {acq.camera.width} x {acq.camera.height}")
        try:
            s = det(img, mask=None)
            s.image = s.image or f.image
            out.append(s)
        except DetectionError as e:
            log.warning("frame %s: %s", f.image, e)
            out.append(None)
    return out


def acquisition_profile(acq: Acquisition, *, method: str = "project", azimuth_bins: int = 360,
                        detector: str | Detector = "dp", skylines: Sequence[Skyline | None] | None = None,
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
    _check_bins(azimuth_bins)
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
        return panorama_profile(spec, sky, azimuth_bins=azimuth_bins,
                                pitch_deg=acq.prior_pitch_deg, roll_deg=acq.prior_roll_deg)
    if method == "stitch":
        from .stitch import stitched_profile

        return stitched_profile(acq, azimuth_bins=azimuth_bins, detector=detector)
    if skylines is None:
        skylines = detect_frames(acq, detector)
    return profile_from_skylines(acq, skylines, azimuth_bins=azimuth_bins, refine=refine)
