"""Yaw, pitch and roll solved in the image plane: the rendered horizon projected through each
frame's camera model against the skyline rows detected in it (the NASA Ames study's solve).

Why beside the profile fit (:mod:`.attitude`): a profile bins the skyline into 1-deg azimuth
bins and removes a free elevation offset (camera height, DEM bias), so over a narrow arc pitch
and roll are left to the curve's second-order shape. In the image every column is a
measurement (0.04 deg per pixel for a 45-deg navcam) and nothing absorbs the horizon's height in
the frame: pitch comes from where the skyline sits, roll from its slope, yaw from its place
across the frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import Camera, az_el_to_direction, r_world_cam
from ..north import arc_span_deg, wrap_deg
from .confidence import residual_correlation_bins
from .lm import levenberg_marquardt
from .map_error import MAP_CORRELATION_M, MAP_DEM_SIGMA_M, error_covariance, sandwich


@dataclass(frozen=True)
class FrameRows:
    """One frame's detected skyline: rows [px] per column (NaN = none), its camera and pointing
    (pan, tilt [deg] of the mast)."""

    camera: Camera
    pan_deg: float
    tilt_deg: float
    rows: np.ndarray


@dataclass(frozen=True)
class ImageAttitude:
    """An image-plane fit: yaw, pitch, roll [deg] with 1-sigma [deg] (inflated for correlated
    residuals), the robust residual level [px] and the number of skyline columns used."""

    yaw_deg: float
    pitch_deg: float
    roll_deg: float
    yaw_sigma_deg: float
    pitch_sigma_deg: float
    roll_sigma_deg: float
    robust_rms_px: float
    n_columns: int
    #: (yaw, pitch, roll) 1-sigma [deg] of the map's share alone (None: no map error modelled)
    map_sigma_deg: tuple | None = None


#: every this many detected columns is a residual (neighbouring columns are not independent)
COLUMN_STEP = 4
#: [px] a column the prediction does not reach counts as this far off (the loss keeps it small)
MISS_PX = 40.0
#: the Cauchy loss's scale in robust sigmas (1.4826 MAD): 95 % efficiency on Gaussian residuals.
#: A loss that redescends, not Huber's, because over a real map whole stretches of columns are
#: wrong by tens of pixels (a near slope the DEM's error tilts): Huber still pays for each of them
#: in proportion and trades the many columns that fit for them (single frames with map errors,
#: seed 1: heading within 1 deg 70 -> 76 %; held out, seeds 0 and 2: see docs/results.md)
CAUCHY_SCALE = 2.385
#: [px] the fixed scale of the Cauchy cost that ranks the starts (one detection pixel, twice)
RANK_SCALE_PX = 2.0
#: a restart wins only below this share of the first start's residual cost
RESTART_GAIN = 0.9
#: [deg] frames spanning at most this much are also solved in the image plane
IMAGE_PLANE_MAX_SPAN_DEG = 120.0
#: confidence at most, when the image-plane yaw lies more than 1 deg from the profile fit's
SOLVES_DISAGREE_CONFIDENCE = 0.5
#: [m] the DEM's height error (rms) the image-plane sigmas allow for, unless told otherwise
#: (``skyfix heading --dem-sigma-m``): :data:`skyfix.pose.map_error.MAP_DEM_SIGMA_M`
IMAGE_PLANE_DEM_SIGMA_M = MAP_DEM_SIGMA_M
#: azimuth bins of the horizon rendered for the image-plane solve (0.05 deg: ~1 px of a navcam)
IMAGE_PLANE_RENDER_BINS = 7200


class _Projector:
    """Predicted skyline rows at the detected columns of each frame, for an attitude."""

    def __init__(self, frames, world_el_deg, world_dist_m=None):
        w = np.asarray(world_el_deg, np.float64)
        az = np.arange(w.size) * 360.0 / w.size
        ok = np.isfinite(w)
        # directions, not angles: a frame across north needs no unrolling
        self._dirs = az_el_to_direction(az[ok], w[ok])
        # (east, north) [m] of each bin's skyline point from the camera
        self._points = None
        if world_dist_m is not None:
            d, a = np.asarray(world_dist_m, np.float64)[ok], np.radians(az[ok])
            self._points = np.stack([d * np.sin(a), d * np.cos(a)], axis=1)
        self._frames = []
        for f in frames:
            r = np.asarray(f.rows, np.float64)
            cols = np.flatnonzero(np.isfinite(r))[::COLUMN_STEP]
            if cols.size:
                self._frames.append((f, cols.astype(np.float64), r[cols]))
        self.n = sum(c.size for _, c, _ in self._frames)

    def observed(self):
        return np.concatenate([o for _, _, o in self._frames]) if self._frames else np.zeros(0)

    def focal_px(self):
        """Each detected column's focal length [px] (rows per radian of elevation)."""
        return np.concatenate([np.full(c.size, f.camera.fy) for f, c, _ in self._frames]
                              or [np.zeros(0)])

    def predict(self, yaw, pitch, roll, points=False):
        """Rows [px] at the detected columns (NaN where the horizon does not reach); with
        ``points``, also the (east, north) [m] of each column's skyline point, (n, 2)."""
        out, pts = [], []
        for f, cols, _ in self._frames:
            cam = f.camera
            d = self._dirs @ r_world_cam(yaw, pitch, roll, f.pan_deg, f.tilt_deg)
            u, v, front = cam.ray_to_pixel(d)
            keep = front & (u > -0.5 * cam.width) & (u < 1.5 * cam.width)
            pred = np.full(cols.size, np.nan)
            pt = np.full((cols.size, 2), np.nan)
            if keep.sum() >= 2:
                uu, vv = u[keep], v[keep]
                # the visible piece: vertices in front, in order of azimuth; a column between two
                # vertices gets the row interpolated between them
                order = np.argsort(uu, kind="stable")
                uu, vv = uu[order], vv[order]
                inside = (cols >= uu[0]) & (cols <= uu[-1])
                pred[inside] = np.interp(cols[inside], uu, vv)
                if points:
                    pk = self._points[keep][order]
                    for i in range(2):
                        pt[inside, i] = np.interp(cols[inside], uu, pk[:, i])
            out.append(pred)
            pts.append(pt)
        pred = np.concatenate(out) if out else np.zeros(0)
        if points:
            return pred, (np.concatenate(pts) if pts else np.zeros((0, 2)))
        return pred


def fit_attitude_image(frames, world_el_deg, yaw0_deg, pitch0_deg, roll0_deg, *,
                       yaw_window_deg=None, yaw_center_deg=None, iterations=20,
                       min_columns=12, starts=(), world_dist_m=None, dem_sigma_m=None):
    """Yaw, pitch, roll [deg] that put the world horizon (``world_el_deg``, bin k at
    ``k * 360 / m`` deg from grid north, rendered at the camera) on the detected rows.

    frames : :class:`FrameRows`; starts from (yaw0, pitch0, roll0) [deg], the profile fit's answer,
    and from each of ``starts`` ((yaw, pitch, roll) [deg], the restarts over the prior's
    uncertainty); a restart's answer replaces the first one only when its residual (Cauchy
    cost at a fixed RANK_SCALE_PX scale) is below RESTART_GAIN times the first one's.
    Levenberg-Marquardt with a numerical Jacobian and Cauchy weights (scale CAUCHY_SCALE x
    1.4826 MAD, at least 1 px): columns on a false fragment, a rock or terrain the map has wrong
    weigh little. Yaw stays within ``yaw_window_deg`` of ``yaw_center_deg`` when given.

    The sigmas [deg] are the detection noise's (the residuals' spread, inflated for their
    correlation) plus, with ``world_dist_m`` (each bin's skyline distance [m]) and
    ``dem_sigma_m`` (the DEM's height error [m]), the spread the map's error gives the answer
    (:func:`_map_covariance`): over a near skyline the map, not the detector, is the limit, and
    the residuals cannot show it (the fit absorbs a tilted near ridge into pitch and roll).
    Returns an :class:`ImageAttitude`, or None when fewer than ``min_columns`` columns are
    usable.
    """
    map_model = world_dist_m is not None and bool(dem_sigma_m)
    # the skyline points are only needed for the map's share of the sigmas
    proj = _Projector(frames, world_el_deg, world_dist_m if map_model else None)
    if proj.n < min_columns:
        return None
    obs = proj.observed()
    center = yaw0_deg if yaw_center_deg is None else yaw_center_deg

    def clamp(th):
        th = th.copy()
        if yaw_window_deg is not None:
            d = wrap_deg(th[0] - center)
            th[0] = center + float(np.clip(d, -yaw_window_deg, yaw_window_deg))
        th[1:] = np.clip(th[1:], -30.0, 30.0)
        return th

    def resid(th):
        r = obs - proj.predict(*th)
        return np.where(np.isfinite(r), r, MISS_PX)

    def weights(r):
        c = CAUCHY_SCALE * max(1.4826 * float(np.median(np.abs(r))), 1.0)
        q = (r / c) ** 2
        return 1.0 / (1.0 + q), float(np.sum(0.5 * c * c * np.log1p(q)))

    def jacobian(th, h=0.01):
        jac = np.empty((obs.size, 3))
        for i in range(3):
            e = np.zeros(3)
            e[i] = h
            jac[:, i] = (resid(th + e) - resid(th - e)) / (2 * h)
        return jac

    def normal(th, r, w):
        jac = jacobian(th)
        jw = jac * w[:, None]
        return jac.T @ jw, jw.T @ r

    def solve(th):
        th, r, w, _ = levenberg_marquardt(clamp(np.asarray(th, float)), resid, weights, normal,
                                          clamp, iterations)
        return th, r, w

    th, r, w = solve([yaw0_deg, pitch0_deg, roll0_deg])
    c0 = _rank_cost(r)
    best = (c0, th, r, w)
    for st in starts:
        th_s, r_s, w_s = solve(st)
        c = _rank_cost(r_s)
        if c < RESTART_GAIN * c0 and c < best[0]:
            best = (c, th_s, r_s, w_s)
    _, th, r, w = best
    jac = jacobian(th)
    good = w >= 0.5  # within the Cauchy scale: the columns the fit follows
    sig2 = float(np.sum(w * r * r) / max(1, r.size - 3))
    # neighbouring residuals share a detection error (a bias over a ridge): inflate by the
    # integrated autocorrelation length of the residuals, in samples
    inflate = residual_correlation_bins(np.where(good, r, np.nan), max_lag=30, circular=False)
    try:
        info_inv = np.linalg.inv(jac.T @ (jac * w[:, None]))
        cov = info_inv * sig2 * inflate
        map_sd = None
        if map_model:
            cov_map = _map_covariance(proj, th, jac, w, info_inv, dem_sigma_m)
            cov = cov + cov_map
            map_sd = tuple(float(v) for v in np.sqrt(np.clip(np.diag(cov_map), 0, None)))
        sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    except np.linalg.LinAlgError:
        sd, map_sd = np.full(3, np.inf), None
    mad = float(1.4826 * np.median(np.abs(r - np.median(r))))
    return ImageAttitude(float(th[0] % 360.0), float(th[1]), float(th[2]), *map(float, sd), mad,
                         int(obs.size), map_sd)


def _rank_cost(r) -> float:
    """The Cauchy cost at the fixed RANK_SCALE_PX scale of residuals ``r`` [px]."""
    return float(np.sum(0.5 * RANK_SCALE_PX ** 2 * np.log1p((r / RANK_SCALE_PX) ** 2)))


def attitude_cost(frames, world_el_deg, yaw_deg, pitch_deg, roll_deg):
    """How well an attitude [deg] puts the world horizon (``world_el_deg``, as
    :func:`fit_attitude_image` takes it) on the detected rows: (the cost that ranks the solve's
    starts, the median absolute residual [px]). Used to tell a search that missed the truth (the
    truth costs less than the answer) from a map that cannot hold it (the truth costs more)."""
    proj = _Projector(frames, world_el_deg)
    r = proj.observed() - proj.predict(yaw_deg, pitch_deg, roll_deg)
    r = np.where(np.isfinite(r), r, MISS_PX)
    return _rank_cost(r), float(np.median(np.abs(r))) if r.size else float("nan")


def _map_covariance(proj, th, jac, w, info_inv, dem_sigma_m):
    """The covariance [deg^2] the map's height error (``dem_sigma_m`` [m] rms, the model of
    :mod:`skyfix.pose.map_error`) gives a fitted (yaw, pitch, roll): a column whose skyline point
    lies ``d`` away moves by ``f (e_sky - e_cam) / d`` px (``f`` the focal length [px])."""
    pred, pts = proj.predict(*th, points=True)
    ok = np.isfinite(pred) & np.isfinite(pts).all(axis=1)
    if not ok.any():
        return np.zeros((th.size, th.size))
    p = pts[ok]
    d = np.hypot(p[:, 0], p[:, 1])
    s = error_covariance(p, proj.focal_px()[ok] / np.maximum(d, 1.0), dem_sigma_m)
    return sandwich(jac[ok], w[ok], s, info_inv)


def image_plane_attitude(frames, dem, x, y, yaw_deg, pitch_deg, roll_deg, *, camera_height_m,
                         planet=None, prior=None, window_deg=None, dem_sigma_m=None):
    """:func:`fit_attitude_image` at (x, y) [m] on ``dem`` from the profile fit's yaw, pitch and
    roll [deg], the horizon rendered there at IMAGE_PLANE_RENDER_BINS. With ``prior`` (yaw,
    pitch, roll [deg]) and ``window_deg`` [deg], also from restarts over the prior's
    uncertainty, as the NASA Ames study did (27 there): over a narrow view the profile's answer
    can sit in a wrong basin; yaw stays within the window. ``dem_sigma_m`` [m]: the DEM's height
    error the sigmas allow for (None: IMAGE_PLANE_DEM_SIGMA_M; 0: the DEM is the world)."""
    from ..horizon import render_horizons

    hb = render_horizons(dem, [x], [y], camera_height_m=camera_height_m, planet=planet,
                         azimuth_bins=IMAGE_PLANE_RENDER_BINS)
    fine, dist = hb.elevation_deg[0], hb.skyline_distance_m[0]
    starts = ()
    if prior is not None:
        h0, p0, r0 = prior
        half = min(window_deg if window_deg is not None else 10.0, 10.0)
        starts = [(h0 + dy, p0 + dp, r0 + dr) for dy in np.linspace(-0.75, 0.75, 4) * half
                  for dp in (-3.0, 0.0, 3.0) for dr in (-3.0, 0.0, 3.0)]
    return fit_attitude_image(frames, fine, yaw_deg, pitch_deg, roll_deg,
                              yaw_window_deg=window_deg,
                              yaw_center_deg=prior[0] if prior is not None else None,
                              starts=starts, world_dist_m=dist,
                              dem_sigma_m=(IMAGE_PLANE_DEM_SIGMA_M if dem_sigma_m is None
                                           else dem_sigma_m))


def frames_from_acquisition(acq, skylines):
    """:class:`FrameRows` of an acquisition's frames with a detected skyline."""
    out = []
    for fr, sky in zip(acq.frames, skylines):
        if sky is None:
            continue
        rows = np.asarray(sky.rows, np.float64)
        if np.isfinite(rows).any():
            out.append(FrameRows(acq.camera, float(fr.pan_deg), float(fr.tilt_deg), rows))
    return out


def view_span_deg(frames) -> float:
    """Horizontal span [deg] the frames cover together: the smallest arc holding every pan, plus
    the widest field of view (an upper bound, used to decide whether the view is narrow)."""
    if not frames:
        return 0.0
    return arc_span_deg([f.pan_deg for f in frames], max(f.camera.hfov_deg for f in frames))


__all__ = ["IMAGE_PLANE_DEM_SIGMA_M", "IMAGE_PLANE_MAX_SPAN_DEG", "MAP_CORRELATION_M",
           "IMAGE_PLANE_RENDER_BINS", "SOLVES_DISAGREE_CONFIDENCE", "attitude_cost",
           "FrameRows", "ImageAttitude", "fit_attitude_image", "frames_from_acquisition",
           "image_plane_attitude", "view_span_deg"]
