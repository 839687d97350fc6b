"""Yaw, pitch and roll by Gauss-Newton against a rendered horizon, with restarts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..north import wrap_deg
from .forward import BodyProfiler
from .lm import levenberg_marquardt, median


@dataclass(frozen=True)
class Attitude:
    """An attitude fit: yaw, pitch, roll [deg] with their 1-sigma [deg], and the residual rms
    [deg] (plain and robust)."""

    yaw_deg: float
    pitch_deg: float
    roll_deg: float
    rms_deg: float
    yaw_sigma_deg: float
    pitch_sigma_deg: float
    roll_sigma_deg: float
    robust_rms_deg: float = float("nan")  # 1.4826 * MAD: the noise level, outlier bins ignored


def fit_attitude(query_deg, world_el_deg, yaw0_deg, pitch0_deg=0.0, roll0_deg=0.0, *,
                 restarts_deg=(-2.5, 0.0, 2.5), prior_pitch_deg=0.0, prior_roll_deg=0.0,
                 yaw_window_deg=None, yaw_center_deg=None, iterations=12,
                 accept_deg=None, world_weights=None) -> Attitude:
    """Yaw, pitch, roll [deg] (and a height offset) that best map the world horizon onto the query.

    Gauss-Newton with a numerical Jacobian and Huber weights (outlier bins), restarted from
    every combination of ``restarts_deg`` offsets on the three axes; the lowest robust cost wins.
    ``yaw_window_deg`` [deg] keeps yaw within that distance of ``yaw_center_deg`` [deg] (default
    ``yaw0_deg``), restarts included. With ``accept_deg`` [deg],
    the fit from the first guess alone is kept when its robust residual level (1.4826 MAD) is
    below it: the restarts are there to escape false minima, which do not fit at the noise level.
    ``world_weights`` (m,): how far each world-horizon bin can be trusted, in [0, 1] (a skyline
    near a camera whose position is uncertain: :func:`~skyfix.pose.heading.position_weights`);
    carried to the body frame at ``yaw0_deg`` and multiplied into the Huber weights.
    """
    q = np.asarray(query_deg, np.float64)
    obs = np.isfinite(q)
    qo = q[obs]
    n = q.size
    profile = BodyProfiler(world_el_deg, n_bins=n, prior_pitch_deg=prior_pitch_deg,
                           prior_roll_deg=prior_roll_deg)

    def resid(th):
        r = qo - profile(th[0], th[1], th[2])[obs]
        return r - median(r)

    prior_w = None
    if world_weights is not None:
        ww = np.asarray(world_weights, float)
        az_w = np.arange(ww.size) * 360.0 / ww.size
        az_b = (np.arange(n) * 360.0 / n + yaw0_deg) % 360.0
        prior_w = np.interp(az_b, az_w, ww, period=360.0)[obs]

    def robust(r):
        s = max(1.4826 * median(np.abs(r)), 0.02)
        k = 2.5 * s
        a = np.abs(r)
        w = np.where(a <= k, 1.0, k / np.maximum(a, 1e-12))
        c = np.where(a <= k, 0.5 * a * a, k * a - 0.5 * k * k)
        if prior_w is not None:
            return w * prior_w, np.sum(c * prior_w)
        return w, np.sum(c)

    center = yaw0_deg if yaw_center_deg is None else yaw_center_deg

    def in_window(yaw):
        # The window is about the prior, not the start: a start at the window's edge plus a
        # restart and a step returned the truth 20 deg from a +-10 deg prior.
        if yaw_window_deg is None:
            return yaw
        d = wrap_deg(yaw - center)
        return center + float(np.clip(d, -yaw_window_deg, yaw_window_deg))

    def normal(th, r, w):
        jac = np.empty((r.size, 4))
        for i in range(3):
            e = np.zeros(3)
            e[i] = h
            jac[:, i] = (resid(th + e) - resid(th - e)) / (2 * h)  # dr/dtheta
        jac[:, 3] = -1.0  # dr/d(offset): a nuisance, the median is removed anyway
        jw = jac * w[:, None]
        return jac.T @ jw, jw.T @ r

    def clamp(th):
        th = th.copy()
        th[0] = in_window(th[0])
        th[1:] = np.clip(th[1:], -30.0, 30.0)
        return th

    best = None
    h = 0.02
    offsets = [(0.0, 0.0, 0.0)] + [(dy, dp, dr) for dy in restarts_deg for dp in restarts_deg
                                   for dr in restarts_deg if (dy, dp, dr) != (0.0, 0.0, 0.0)]
    for k_start, (dy, dp, dr) in enumerate(offsets):
        if k_start == 1 and accept_deg is not None:
            rb = best[2]
            if 1.4826 * median(np.abs(rb - median(rb))) <= accept_deg:
                break
        th = np.array([in_window(yaw0_deg + dy), pitch0_deg + dp, roll0_deg + dr], float)
        th, r, w, cost = levenberg_marquardt(th, resid, robust, normal, clamp, iterations)
        if best is None or cost < best[0]:
            best = (cost, th.copy(), r.copy(), w.copy())
    cost, th, r, w = best
    jac = np.empty((r.size, 4))
    for i in range(3):
        e = np.zeros(3)
        e[i] = h
        jac[:, i] = (resid(th + e) - resid(th - e)) / (2 * h)
    jac[:, 3] = -1.0
    sig2 = float(np.sum(w * r * r) / max(1, r.size - 4))
    try:
        cov = np.linalg.inv(jac.T @ (jac * w[:, None])) * sig2
        sd = np.sqrt(np.clip(np.diag(cov)[:3], 0, None))
    except np.linalg.LinAlgError:
        sd = np.full(3, np.inf)
    rms = float(np.sqrt(np.mean(r * r)))
    mad = float(1.4826 * np.median(np.abs(r - np.median(r))))
    return Attitude(float(th[0] % 360.0), float(th[1]), float(th[2]), rms, *map(float, sd), mad)
