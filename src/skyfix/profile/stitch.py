"""Stage 6, ``stitch``: OpenCV panorama of a frame set, then one skyline detection.

For acquisitions whose pointing is unknown or poor. OpenCV's detailed stitching pipeline finds the
frames' relative rotations from image features alone: SIFT features, matching restricted to
neighbouring frames (the frames stay in order; a pair that does not match is dropped and the
biggest connected set of frames kept), a homography-based first guess and a ray bundle adjustment
with the focal length fixed to the known intrinsics.

The rotations live in an arbitrary frame. It is tied to the rover's body frame by the rotation that
best maps them onto the nominal mast pointing (chordal mean over the stitched frames: individual
pan errors average out), and levelled with the attitude prior. The frames are then warped with a
spherical warper whose sphere *is* the levelled body frame, so the panorama is equirectangular in
(azimuth, elevation): column ``j`` is azimuth ``az0 + (roi_x + j) / scale`` and row ``i`` is
elevation ``90 deg - (roi_y + i) / scale`` (scale in px/rad). Field of view and the zero-yaw column
follow from that; the panorama profile code does the rest.
"""

from __future__ import annotations

import logging

import numpy as np

from ..camera import C_CAM_TO_BODY, r_body_mast
from ..errors import DetectionError
from ..formats import Acquisition, PanoramaSpec, Profile
from ..north import arc_span_deg
from .frames import Detector, get_detector, read_rgb
from .geometry import levelling_rotation
from .project import panorama_profile

log = logging.getLogger("skyfix.stitch")  # the name its messages always had

#: feature images are resized to about this many megapixels (speed; rotations do not care)
WORK_MEGAPIX = 0.6
#: a pair of frames whose match confidence is below this is dropped
MATCH_CONF_THRESH = 0.6


def _undistorted(acq: Acquisition, img: np.ndarray) -> np.ndarray:
    import cv2

    cam = acq.camera
    if cam.distortion.is_zero:
        return img
    return cv2.undistort(img, cam.matrix(), cam.distortion.as_array())


def _chordal_mean_rotation(mats: list[np.ndarray]) -> np.ndarray:
    """The rotation closest (Frobenius) to the sum of ``mats``."""
    u, _, vt = np.linalg.svd(np.sum(mats, axis=0))
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def stitch_rotations(images: list[np.ndarray], focal_px: float, cx: float, cy: float, *,
                     range_width: int = 2, wrap: bool = False, initial: list[np.ndarray] | None = None):
    """Relative camera rotations of a frame sequence from image features.

    images : RGB uint8 frames, in pan order; focal_px, cx, cy : [px] pinhole intrinsics
    range_width : only frames this close in the sequence are matched (keeps the order)
    wrap : also match the last frame with the first (a full turn)
    initial : nominal camera -> body rotations, the bundle adjustment's first start (a poor
        pointing is close enough); without them, or if that fails, the homography estimator's
    Returns ``(kept_indices, rotations (list of 3x3 cam -> stitch frame), pair_report)``; raises
    :class:`DetectionError` when fewer than two frames can be stitched.
    """
    import cv2

    n = len(images)
    h, w = images[0].shape[:2]
    work = min(1.0, np.sqrt(WORK_MEGAPIX * 1e6 / (w * h)))
    # low contrast threshold: dusty, low-contrast terrain has few strong corners
    finder = cv2.SIFT_create(nfeatures=4000, contrastThreshold=0.01)
    feats = []
    for i, img in enumerate(images):
        small = cv2.resize(img, None, fx=work, fy=work, interpolation=cv2.INTER_AREA) if work < 1 else img
        f = cv2.detail.computeImageFeatures2(finder, small)
        f.img_idx = i
        feats.append(f)
    pairs = _match(feats, list(range(n)), range_width, n, wrap)
    report = []
    for p in pairs:
        if p.src_img_idx >= 0 and p.dst_img_idx > p.src_img_idx and p.confidence > 0:
            report.append({"i": int(p.src_img_idx), "j": int(p.dst_img_idx), "used": p.confidence >= MATCH_CONF_THRESH,
                           "confidence": float(p.confidence), "inliers": int(p.num_inliers)})
    kept = cv2.detail.leaveBiggestComponent(feats, pairs, MATCH_CONF_THRESH)
    kept = [int(k) for k in np.asarray(kept).ravel()]
    if len(kept) < 2:
        raise DetectionError(
            f"stitching failed: no two of the {n} frames match well enough (confidence >= "
            f"{MATCH_CONF_THRESH}); use --method project if the pointing is known")
    feats_k = [feats[k] for k in kept]
    pairs_k = _match(feats_k, kept, range_width, n, wrap)
    last = "no estimate"
    for init in ("nominal", "homography"):
        if init == "nominal":
            if initial is None:
                continue
            cams = []
            for k in kept:
                c = cv2.detail_CameraParams()
                c.R = np.asarray(initial[k], np.float32)
                c.t = np.zeros((3, 1), np.float64)
                cams.append(c)
        else:
            ok, cams = cv2.detail_HomographyBasedEstimator().apply(feats_k, pairs_k, None)
            if not ok:
                last = "the homography estimator found no rotations"
                continue
        for c in cams:
            c.R = np.asarray(c.R, np.float32)
            c.focal = focal_px * work
            c.ppx, c.ppy = cx * work, cy * work
            c.aspect = 1.0
        adjuster = cv2.detail_BundleAdjusterRay()
        adjuster.setConfThresh(MATCH_CONF_THRESH)
        adjuster.setRefinementMask(np.zeros((3, 3), np.uint8))  # focal known: refine rotations only
        ok, cams = adjuster.apply(feats_k, pairs_k, cams)
        if ok:
            log.info("stitch: rotations from the %s start", init)
            break
        last = f"bundle adjustment from the {init} start did not converge"
    else:
        raise DetectionError(f"stitching failed: {last}")
    return kept, [np.asarray(c.R, float) for c in cams], report


def _match(feats, seq, range_width, n, wrap):
    """Pairwise matches of ``feats`` (frame ``seq[a]`` of ``n`` for position ``a``), keeping only
    neighbours in the sequence (``range_width`` apart, across the ends for a full turn ``wrap``).

    The full matcher is run and the other pairs get confidence 0: the Python binding of the
    pair-mask variant did not match the right pairs (OpenCV 4.14).
    """
    import cv2

    matcher = cv2.detail_BestOf2NearestMatcher(False, 0.3)
    pairs = matcher.apply2(feats)
    matcher.collectGarbage()
    m = len(feats)
    for p in pairs:
        a, b = p.src_img_idx, p.dst_img_idx
        if a < 0 or b < 0 or a == b:
            continue
        d = abs(seq[b] - seq[a])
        if not (d <= range_width or (wrap and n - d <= range_width)):
            p.confidence = 0.0
    assert len(pairs) == m * m
    return pairs


def pan_order(pans_deg) -> np.ndarray:
    """The frames' indices in pan order [deg], starting after the widest gap between pans round
    the circle: a sequence whose neighbours overlap, however the acquisition lists them."""
    p = np.mod(np.asarray(pans_deg, float), 360.0)
    o = np.argsort(p, kind="stable")
    gaps = np.diff(np.r_[p[o], p[o][0] + 360.0])
    return np.roll(o, -((int(np.argmax(gaps)) + 1) % o.size))


def stitch_panorama(acq: Acquisition, images: list[np.ndarray] | None = None, *, use_nominal: bool = True,
                    overlays: list[np.ndarray] | None = None):
    """Equirectangular panorama of a frame set in the levelled body frame.

    Returns ``(rgb, valid_mask, spec, info)``: ``spec`` is the :class:`PanoramaSpec` of the result
    (azimuth of the left edge, fields of view, top elevation, all [deg]) and ``info`` records the
    stitched and dropped frames, the pairs and the estimated pans (frame indices as the
    acquisition lists them); ``info["overlay"]`` holds ``overlays`` (per-frame RGB images) warped
    and cropped the same way, when given.
    use_nominal : start the bundle adjustment from the nominal pointing (else features alone)

    The frames are stitched in pan order (:func:`pan_order`): only neighbours in the sequence
    are matched, and frames listed out of order were dropped as matching none.
    """
    from dataclasses import replace

    order = pan_order([f.pan_deg for f in acq.frames])
    if images is None:
        images = [read_rgb(acq.image_path(f.image)) for f in acq.frames]
    pano, valid, spec, info = _stitch_in_order(
        replace(acq, frames=tuple(acq.frames[i] for i in order)), [images[i] for i in order],
        use_nominal, None if overlays is None else [overlays[i] for i in order])
    back = [int(i) for i in order]  # sequence index -> the acquisition's
    info["frames_stitched"] = [back[k] for k in info["frames_stitched"]]
    info["frames_dropped"] = sorted(back[k] for k in info["frames_dropped"])
    info["pan_estimated_deg"] = {str(back[int(k)]): v for k, v in info["pan_estimated_deg"].items()}
    for pair in info["pairs"]:
        pair["i"], pair["j"] = back[pair["i"]], back[pair["j"]]
    return pano, valid, spec, info


def _stitch_in_order(acq: Acquisition, images: list[np.ndarray], use_nominal: bool, overlays):
    """:func:`stitch_panorama` of frames listed in pan order."""
    import cv2

    cam = acq.camera
    images = [_undistorted(acq, im) for im in images]
    n = len(images)
    pans = np.array([f.pan_deg for f in acq.frames])
    # the smallest arc holding the frames: pans of 300, 330, 0 and 30 deg are a 135 deg arc across
    # north, not a full turn (max - min took them for one, and matched the loop's "ends")
    wrap = arc_span_deg(pans, cam.hfov_deg) >= 360.0
    if n == 1:
        kept, rots, report = [0], [np.eye(3)], []
    else:
        nominal_all = [r_body_mast(f.pan_deg, f.tilt_deg) @ C_CAM_TO_BODY for f in acq.frames]
        kept, rots, report = stitch_rotations(images, cam.fx, cam.cx, cam.cy, wrap=wrap,
                                              initial=nominal_all if use_nominal else None)
    # stitch frame -> unlevelled body: best fit to the nominal pointing of the stitched frames
    nominal = [r_body_mast(acq.frames[k].pan_deg, acq.frames[k].tilt_deg) @ C_CAM_TO_BODY for k in kept]
    align = _chordal_mean_rotation([nm @ r.T for nm, r in zip(nominal, rots)])
    level = levelling_rotation(acq.prior_pitch_deg, acq.prior_roll_deg)
    # the warper's sphere: OpenCV camera axes (x right, y down, z forward) of a camera looking along
    # azimuth az0, level; the seam sits at the left edge of the first frame
    az0 = float(pans[kept[0]] - cam.hfov_deg / 2 - 1.0)
    sphere_to_body = r_body_mast(az0, 0.0) @ C_CAM_TO_BODY
    body_to_sphere = sphere_to_body.T
    scale = float(cam.fx)  # px/rad: native resolution at the image centre
    warper = cv2.PyRotationWarper("spherical", scale)
    K = cam.matrix().astype(np.float32)
    est_pans = {}
    r_spheres = {}
    for k, r in zip(kept, rots):
        r_spheres[k] = (body_to_sphere @ level @ align @ r).astype(np.float32)
        fwd = align @ r @ np.array([0.0, 0.0, 1.0])  # optical axis in the unlevelled body frame
        est_pans[k] = float(np.degrees(np.arctan2(fwd[0], fwd[1])))
    pano, valid, (x0, y0) = _composite(warper, K, [images[k] for k in kept], [r_spheres[k] for k in kept])
    # crop to the valid area
    rows = np.flatnonzero(valid.any(axis=1))
    cols = np.flatnonzero(valid.any(axis=0))
    r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    pano, valid = pano[r0:r1, c0:c1], valid[r0:r1, c0:c1]
    overlay = None
    if overlays is not None:
        # the same warp and crop for other images of the frames (e.g. truth masks, for evaluation)
        ov, _, (ox, oy) = _composite(warper, K, [overlays[k] for k in kept], [r_spheres[k] for k in kept])
        overlay = ov[r0 + y0 - oy:r1 + y0 - oy, c0 + x0 - ox:c1 + x0 - ox]
    ux, vy = x0 + c0, y0 + r0  # sphere coordinates [px] of the crop's pixel (0, 0) centre
    spec = PanoramaSpec(
        "stitched",
        azimuth_left_deg=az0 + float(np.degrees((ux - 0.5) / scale)),
        hfov_deg=float(np.degrees(pano.shape[1] / scale)),
        elevation_top_deg=90.0 - float(np.degrees((vy - 0.5) / scale)),
        vfov_deg=float(np.degrees(pano.shape[0] / scale)),
    )
    # the column whose centre looks along the rover's forward axis (azimuth 0), if in the panorama
    zero_col = (-spec.azimuth_left_deg) % 360.0 * pano.shape[1] / spec.hfov_deg - 0.5
    zero_col = float(zero_col) if -0.5 <= zero_col <= pano.shape[1] - 0.5 else None
    info = {
        "frames_stitched": kept, "frames_dropped": [i for i in range(n) if i not in kept],
        "pairs": report, "pan_estimated_deg": {str(k): v for k, v in est_pans.items()},
        "panorama": {"width": int(pano.shape[1]), "height": int(pano.shape[0]),
                     "azimuth_left_deg": spec.azimuth_left_deg, "hfov_deg": spec.hfov_deg,
                     "elevation_top_deg": spec.elevation_top_deg, "vfov_deg": spec.vfov_deg,
                     "zero_yaw_column": zero_col},
    }
    info["overlay"] = overlay
    return pano, valid, spec, info


def _composite(warper, K, images, rotations):
    """Warp ``images`` with ``rotations`` (camera -> sphere) and feather them together.

    Returns ``(rgb uint8, valid mask, (x0, y0))`` with (x0, y0) the sphere pixel of the canvas's
    pixel (0, 0).
    """
    import cv2

    warped, masks, corners = [], [], []
    for img, r in zip(images, rotations):
        corner, img_w = warper.warp(img, K, r, cv2.INTER_LINEAR, cv2.BORDER_CONSTANT)
        _, m_w = warper.warp(np.full(img.shape[:2], 255, np.uint8), K, r, cv2.INTER_NEAREST,
                             cv2.BORDER_CONSTANT)
        warped.append(img_w)
        masks.append(m_w > 0)
        corners.append(corner)
    x0 = min(c[0] for c in corners)
    y0 = min(c[1] for c in corners)
    x1 = max(c[0] + im.shape[1] for c, im in zip(corners, warped))
    y1 = max(c[1] + im.shape[0] for c, im in zip(corners, warped))
    acc = np.zeros((y1 - y0, x1 - x0, 3))
    wsum = np.zeros((y1 - y0, x1 - x0))
    for c, im, m in zip(corners, warped, masks):
        # feather: weight by distance to the frame's edge, so seams blend and borders fade out
        wgt = cv2.distanceTransform(m.astype(np.uint8), cv2.DIST_L2, 3)
        wgt[wgt < 1.5] = 0  # drop the interpolated border ring (half black)
        ys, xs = c[1] - y0, c[0] - x0
        acc[ys:ys + im.shape[0], xs:xs + im.shape[1]] += im * wgt[..., None]
        wsum[ys:ys + im.shape[0], xs:xs + im.shape[1]] += wgt
    valid = wsum > 0
    pano = np.zeros(acc.shape, np.uint8)
    pano[valid] = np.clip(acc[valid] / wsum[valid, None] + 0.5, 0, 255).astype(np.uint8)
    return pano, valid, (x0, y0)


def stitched_profile(acq: Acquisition, *, azimuth_bins: int = 360, detector: str | Detector | None = None,
                     images: list[np.ndarray] | None = None) -> Profile:
    """Profile of a frame set by stitching, then detecting once on the panorama."""
    pano, valid, spec, info = stitch_panorama(acq, images)
    info.pop("overlay")
    det = get_detector(detector)
    sky = det(pano, mask=valid)
    if not np.isfinite(sky.rows).any():
        raise DetectionError(f"no skyline in the stitched panorama of {acq.root}")
    prof = panorama_profile(spec, sky, azimuth_bins=azimuth_bins)  # already levelled by the warp
    for k in info["frames_dropped"]:
        log.warning("stitch: frame %d (%s) dropped: no good match with its neighbours", k, acq.frames[k].image)
    prof.meta.update(method="stitch", stitch=info,
                     attitude_prior={"pitch_deg": acq.prior_pitch_deg, "roll_deg": acq.prior_roll_deg},
                     frames_used=len(info["frames_stitched"]), frames_dropped=len(info["frames_dropped"]))
    return prof
