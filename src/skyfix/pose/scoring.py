"""Scoring candidate positions against the query profile on skylines rendered from the DEM, made
robust to gross bins (a near rock, a false fragment): outlier masking and a per-bin clipped
cost.
"""

from __future__ import annotations

import numpy as np

from ..match import prepare_query, score_profiles


def profile_arrays(profile):
    """(elevation [deg] as float64 with NaN = unobserved, the profile's typical noise [deg]: the
    median sigma, 0.2 when it has none)."""
    el = np.asarray(profile.elevation_deg, np.float64)
    sig = profile.sigma_deg
    noise = float(np.nanmedian(sig)) if sig is not None and np.isfinite(sig).any() else 0.2
    return el, noise


class Renders:
    """Skylines rendered from one DEM at exact points, kept for reuse within one candidate's
    refinement: its grid levels re-centre on points already rendered and its polish's rings
    overlap (a quarter of a fix's renders were repeats). A point's skyline does not depend on
    the others rendered with it, so a kept one is the one a new render would give."""

    def __init__(self, dem, *, camera_height_m, planet):
        self._dem, self._h, self._planet = dem, camera_height_m, planet
        self._kept = {}

    @property
    def dem(self):
        """The DEM the skylines are rendered from."""
        return self._dem

    def horizons(self, xs, ys, bins):
        """(elevation [deg], distance of the skyline's terrain [m]): float32 (N, bins) each."""
        from ..horizon import render_horizons

        keys = [(float(x), float(y), int(bins)) for x, y in zip(np.ravel(xs), np.ravel(ys))]
        new = list(dict.fromkeys(k for k in keys if k not in self._kept))
        if new:
            hb = render_horizons(self._dem, [k[0] for k in new], [k[1] for k in new],
                                 camera_height_m=self._h, planet=self._planet, azimuth_bins=bins)
            for j, k in enumerate(new):
                self._kept[k] = (hb.elevation_deg[j].copy(), hb.skyline_distance_m[j].copy())
        el = np.stack([self._kept[k][0] for k in keys]) if keys else np.zeros((0, bins), np.float32)
        dist = np.stack([self._kept[k][1] for k in keys]) if keys else np.zeros((0, bins), np.float32)
        return el, dist


def render_points(dem, xs, ys, *, camera_height_m, planet, n_bins, renders=None):
    """(N, n_bins) float32 world-frame skylines [deg] at (xs, ys) [m], bin-averaged
    (``renders``: a :class:`Renders` of this DEM and camera height to take them from)."""
    from ..horizon import render_horizons

    # A measured bin averages the skyline over its width: render 5 sub-bins per bin and average,
    # or sharp ridges bias the fine position (point samples vs bin means).
    k = 5
    if renders is not None:
        el = renders.horizons(xs, ys, n_bins * k)[0]
    else:
        el = render_horizons(dem, xs, ys, camera_height_m=camera_height_m, planet=planet,
                             azimuth_bins=n_bins * k).elevation_deg
    p = np.nan_to_num(el, nan=0.0)
    return np.roll(p, k // 2, axis=1).reshape(p.shape[0], n_bins, k).mean(axis=2).astype(np.float32)


def outlier_bins(q, p_world, shift_bins, remove_tilt=True, floor_deg=0.5, k_sigma=3.5,
                 above_floor_deg=0.15, above_k_sigma=2.5):
    """Observed bins of the query [deg] that a prediction cannot explain (a near rock, a glint).

    p_world : (n,) [deg] world skyline; shift_bins : best shift [bins] (``q[j] ~ p[j + shift]``).
    The residual, after removing the offset (and tilt harmonic), is compared with
    ``max(k_sigma * 1.4826 MAD, floor_deg)``: Gaussian detection noise stays in, gross errors
    (>= 1 deg) go out. Bins *above* the prediction go out sooner, beyond
    ``max(above_k_sigma * 1.4826 MAD, above_floor_deg)``: something near the camera (a rock,
    the rover's own hardware) can only raise the skyline, and small rocks a few tenths of a
    degree high otherwise stayed in and pulled the position metres off.
    Returns a bool (n,) mask, True = outlier.
    """
    from ..match import harmonic_basis

    q = np.asarray(q, np.float64)
    n = q.size
    obs = np.isfinite(q)
    j = np.arange(n, dtype=np.float64)
    pred = np.interp((j + float(shift_bins)) % n, np.arange(n + 1),
                     np.append(np.asarray(p_world, np.float64), float(p_world[0])))
    u = harmonic_basis(n, remove_tilt)[obs]
    r = q[obs] - pred[obs]
    coef, *_ = np.linalg.lstsq(u, r, rcond=None)
    r = r - u @ coef
    mad = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    thr = max(k_sigma * mad, floor_deg)
    thr_above = min(max(above_k_sigma * mad, above_floor_deg), thr)
    out = np.zeros(n, bool)
    out[np.flatnonzero(obs)[(r > thr_above) | (r < -thr)]] = True
    return out


def clipped_costs(p, q, shift_bins, remove_tilt=True, clip_deg=0.5):
    """Per point, the mean of ``min(r^2, clip_deg^2)`` [deg^2] over the query's observed bins,
    r the residual at the point's shift after removing the offset (and tilt harmonic) fitted by
    least squares to the bins within ``clip_deg`` of the median residual.

    p : (N, n) [deg] world skylines; q : (n,) [deg] query (NaN unobserved); shift_bins : (N,)
    (``q[j] ~ p[j + shift]``)."""
    from ..match import harmonic_basis

    p = np.asarray(p, np.float64)
    q = np.asarray(q, np.float64)
    N, n = p.shape
    obs = np.flatnonzero(np.isfinite(q))
    grid = np.arange(n + 1, dtype=np.float64)
    pred = np.empty((N, obs.size))
    for k in range(N):
        pred[k] = np.interp((obs + float(shift_bins[k])) % n, grid, np.append(p[k], p[k, 0]))
    r = q[obs][None, :] - pred
    r -= np.median(r, axis=1, keepdims=True)
    u = harmonic_basis(n, remove_tilt)[obs]
    w = (np.abs(r) < clip_deg).astype(np.float64)
    for k in range(N):  # one weighted refit on the inliers: offset and tilt harmonic
        uw = u * w[k][:, None]
        coef, *_ = np.linalg.lstsq(uw.T @ u, uw.T @ r[k], rcond=None)
        r[k] -= u @ coef
    return np.mean(np.minimum(r * r, clip_deg * clip_deg), axis=1)


def robust_scores(p, q, *, remove_tilt=True, rounds=2):
    """Shift search scores of skylines ``p`` (N, n) [deg] against ``q`` with outlier bins dropped.

    Plain sums of squares let a few gross bins (a 5 deg outlier weighs as much as 600 bins of
    0.2 deg noise) choose the position. The best point's residuals flag outlier bins
    (:func:`outlier_bins`); all points are re-scored with those bins masked (the same mask for
    every point, so scores stay comparable), ``rounds`` times. Rendering is not repeated.
    Returns (score [deg^2] (N,), shift [bins] (N,), the masked query (n,) [deg]).
    """
    q = np.asarray(q, np.float64)
    n_obs = int(np.isfinite(q).sum())
    qm = q
    sc, sh = score_profiles(p, prepare_query(qm, remove_tilt, min_observed=8))
    for _ in range(rounds):
        # The reference point whose residuals name the outliers: the lowest clipped cost, not
        # the lowest sum of squares -- near rocks covering 10 % of the view pull the plain
        # optimum tens of metres off, and its residuals then flag the wrong bins.
        i = int(np.argmin(clipped_costs(p, q, sh, remove_tilt)))
        bad = outlier_bins(q, p[i], sh[i], remove_tilt)
        # Never drop so many bins that the position information goes with them.
        if not bad.any() or n_obs - bad.sum() < max(20, n_obs // 2):
            break
        q_new = np.where(bad, np.nan, q)
        if np.array_equal(np.isfinite(q_new), np.isfinite(qm)):
            break
        qm = q_new
        sc, sh = score_profiles(p, prepare_query(qm, remove_tilt, min_observed=8))
    return sc, sh, qm


def score_points(dem, xs, ys, q, *, camera_height_m, planet, n_bins, remove_tilt=True,
                 renders=None):
    """(scores [deg^2], shifts [bins]) of skylines rendered at (xs, ys) [m] against the query
    ``q`` [deg], by :func:`robust_scores` (``renders``: see :func:`render_points`)."""
    p = render_points(dem, xs, ys, camera_height_m=camera_height_m, planet=planet, n_bins=n_bins,
                      renders=renders)
    sc, sh, _ = robust_scores(p, q, remove_tilt=remove_tilt)
    return sc, sh


def clip_bound_deg(noise_deg):
    """[deg] the residual beyond which :func:`robust_cost` counts a bin no further (and a fit
    takes it for an outlier): three times the noise [deg], at least 0.5 deg."""
    return max(3.0 * noise_deg, 0.5)


def robust_cost(resid, noise_deg, dist_m=None, dem_sigma_m=None):
    """Clipped mean squared residual [deg^2] of a :func:`residual_profile`, offset removed:
    each bin counts at most ``(max(3 noise, 0.5 deg))^2``, so a few gross bins (a near rock)
    cannot out-vote the rest when candidates are ranked.

    With ``dist_m`` (per bin [m]: how far the terrain making the predicted skyline lies) and
    ``dem_sigma_m`` [m] (the DEM's height error), bins are weighted by how much the DEM can be
    trusted there, ``noise^2 / (noise^2 + atan(dem_sigma_m / d)^2)``, and the offset is fitted as
    ``a + b / d``: a height error of the DEM under the camera raises every bin by ``atan(dh / d)``.
    """
    ok = np.isfinite(resid)
    r = resid[ok]
    c = clip_bound_deg(noise_deg)
    if dist_m is None or dem_sigma_m is None:
        r = r - np.median(r)
        return float(np.mean(np.minimum(r * r, c * c)))
    d = np.asarray(dist_m, float)[ok]
    d = np.where(np.isfinite(d) & (d > 0), d, np.inf)
    sig = np.degrees(np.arctan(dem_sigma_m / d))
    w = noise_deg ** 2 / (noise_deg ** 2 + sig ** 2)
    u = np.stack([np.ones_like(d), np.degrees(1.0 / d)], axis=1)  # dh [m] -> dh / d [deg]
    r = r - np.median(r)
    inl = (np.abs(r) < c).astype(float) * w
    for _ in range(2):  # weighted least squares on the inliers, then re-centred
        uw = u * inl[:, None]
        coef, *_ = np.linalg.lstsq(uw.T @ u + 1e-9 * np.eye(2), uw.T @ r, rcond=None)
        r = r - u @ coef
        inl = (np.abs(r) < c).astype(float) * w
    return float(np.sum(w * np.minimum(r * r, c * c)) / max(np.sum(w), 1e-12))


def body_distances(world_dist_m, yaw_deg, n_bins):
    """The skyline distances [m] of a world-frame profile (any bin count) at the body-frame bins
    of a rover with yaw ``yaw_deg`` [deg] (``world[az] = body[az - yaw]``; tilt ignored: the
    distances change slowly with azimuth)."""
    w = np.asarray(world_dist_m, float)
    m = w.size
    az = (np.arange(n_bins) * 360.0 / n_bins + yaw_deg) % 360.0
    grid = np.arange(m + 1) * 360.0 / m
    return np.interp(az, grid, np.append(w, w[0]))
