"""Stage 8: position, heading and attitude from a body-frame skyline profile.

Pipeline of :func:`locate`:

1. candidates: the database matcher (:mod:`skyfix.match`) keeps the best K positions in distinct
   basins; without a database (small prior area) a grid is rendered from the DEM over the prior.
2. refinement of every kept candidate (the source study's single-candidate pyramid fell into
   false minima): fresh skylines rendered from the DEM on finer and finer local grids (each level
   4x finer, 9 x 9 points), scored with the same shift search (tilt harmonic removed), made
   robust to gross bins (a near rock) by masking the best point's outlier bins and re-scoring
   (:func:`robust_scores`); a level whose best point is on its edge is re-centred. Candidates
   are ranked by a per-bin clipped cost (:func:`robust_cost`), not the plain rms.
3. attitude: yaw, pitch and roll by Gauss-Newton against the rendered horizon, with restarts at
   -2.5/0/+2.5 deg per axis around the first guess; the query is then re-levelled with the
   estimated attitude and the finest position levels are redone.
4. confidence: a logistic model on features of the score landscape (best vs best of another basin,
   residual vs expected noise, relief of the skyline), fitted on simulated cases by
   ``scripts/calibrate_confidence.py`` (``skyfix/models/confidence.json``).
5. retry (database only): a fix with low confidence or a residual far above the noise is searched
   again with each quarter of the observed skyline left out in turn; the new candidates go
   through 2-3 and the best on the whole profile wins. A false fragment of skyline can outweigh
   the rest of the view in the database's sum of squares; one of the partial searches leaves it
   out.

The forward model (world horizon -> body-frame profile for an attitude) is :func:`body_profile`.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .camera import r_world_body
from .errors import ParameterError, SkyfixError
from .match import MatchConfig, brute_force_scores, match_database, prepare_query, score_profiles  # noqa: F401

MODEL_PATH = Path(__file__).resolve().parent / "models" / "confidence.json"


@dataclass(frozen=True)
class PoseConfig:
    """Pose estimation settings.

    refine_candidates : how many of the matcher's candidates are refined from the DEM
    levels : refinement levels (each 4x finer, 9 x 9 grid)
    grid_step_m : [m] first grid step without a database (scenario 2)
    render_bins : azimuth bins of the horizons rendered for the attitude fit
    restarts_deg : [deg] offsets of the Gauss-Newton restarts per axis
    tolerance_m : [m] what "correct" means for the confidence (scenario 1: 5 m)
    polish : finish every refined candidate by a search on the attitude-refitted
        cost (:func:`_polish_position`)
    retry_below, retry_rms_ratio : with a database, a fix whose confidence is below
        ``retry_below``, or whose robust residual rms exceeds ``retry_rms_ratio`` times the
        profile's noise, is searched again with each of ``retry_segments`` contiguous parts of
        the observed skyline left out in turn (:func:`_segment_candidates`); the new candidates
        are refined and ranked with the others on the whole profile. A false skyline fragment a
        few degrees wide (a shade boundary seen in two frames) can outweigh the rest of the view
        in the database's sum of squares and keep the true basin out of the candidates. In the
        whole-pipeline scenario-1 cases (59 correct, 6 wrong) either trigger catches all the
        wrong fixes; the rms one also fires on 3 correct ones (time only). 0 / inf = never
    retry_segments, retry_per_segment : how many parts, and candidates kept from each search
    """

    match: MatchConfig = MatchConfig()
    refine_candidates: int = 4
    levels: int = 3
    grid_step_m: float = 2.0
    render_bins: int = 1440
    restarts_deg: tuple = (-2.5, 0.0, 2.5)
    tolerance_m: float = 5.0
    polish: bool = True
    retry_below: float = 0.5
    retry_rms_ratio: float = 3.0
    retry_segments: int = 4
    retry_per_segment: int = 2


# --- forward model ------------------------------------------------------------------------------

def body_profile(world_el_deg, yaw_deg, pitch_deg=0.0, roll_deg=0.0, *, n_bins=360,
                 prior_pitch_deg=0.0, prior_roll_deg=0.0) -> np.ndarray:
    """The body-frame profile [deg] a camera with this attitude measures, levelled with the prior.

    world_el_deg : (m,) [deg] world-frame horizon, bin k at ``k * 360 / m`` from grid north
    A world direction ``d`` appears at ``R(0, prior) R(yaw, pitch, roll)^T d`` in the levelled body
    frame (azimuth from the forward axis); the rotated curve is re-binned by periodic linear
    interpolation at the ``n_bins`` body bin centres.
    """
    w = np.asarray(world_el_deg, np.float64)
    m = w.size
    az = np.radians(np.arange(m) * 360.0 / m)
    el = np.radians(np.nan_to_num(w))
    ce = np.cos(el)
    d = np.stack([ce * np.sin(az), ce * np.cos(az), np.sin(el)], axis=1)
    rot = r_world_body(0.0, prior_pitch_deg, prior_roll_deg) @ r_world_body(yaw_deg, pitch_deg, roll_deg).T
    b = d @ rot.T
    azb = np.degrees(np.arctan2(b[:, 0], b[:, 1])) % 360.0
    elb = np.degrees(np.arctan2(b[:, 2], np.hypot(b[:, 0], b[:, 1])))
    order = np.argsort(azb)
    return np.interp(np.arange(n_bins) * 360.0 / n_bins, azb[order], elb[order], period=360.0)


def relevel(profile_deg, pitch_deg, roll_deg, *, prior_pitch_deg=0.0, prior_roll_deg=0.0):
    """Undo an estimated attitude: the profile a level camera (same heading) would measure [deg]."""
    q = np.asarray(profile_deg, np.float64)
    n = q.size
    obs = np.isfinite(q)
    az = np.radians(np.arange(n) * 360.0 / n)
    el = np.radians(np.nan_to_num(q))
    ce = np.cos(el)
    d = np.stack([ce * np.sin(az), ce * np.cos(az), np.sin(el)], axis=1)
    rot = r_world_body(0.0, pitch_deg, roll_deg) @ r_world_body(0.0, prior_pitch_deg, prior_roll_deg).T
    b = d @ rot.T
    azl = np.degrees(np.arctan2(b[:, 0], b[:, 1])) % 360.0
    ell = np.degrees(np.arctan2(b[:, 2], np.hypot(b[:, 0], b[:, 1])))
    order = np.argsort(azl)
    out = np.interp(np.arange(n) * 360.0 / n, azl[order], ell[order], period=360.0)
    # A level bin is observed when both neighbours it was interpolated from were.
    obs_l = np.interp(np.arange(n) * 360.0 / n, azl[order], obs[order].astype(float), period=360.0)
    return np.where(obs_l > 0.999, out, np.nan)


# --- attitude by Gauss-Newton ---------------------------------------------------------------------

@dataclass(frozen=True)
class Attitude:
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
                 accept_deg=None) -> Attitude:
    """Yaw, pitch, roll [deg] (and a height offset) that best map the world horizon onto the query.

    Gauss-Newton with a numerical Jacobian and Huber weights (outlier bins), restarted from
    every combination of ``restarts_deg`` offsets on the three axes; the lowest robust cost wins.
    ``yaw_window_deg`` [deg] keeps yaw within that distance of ``yaw_center_deg`` [deg] (default
    ``yaw0_deg``), restarts included. With ``accept_deg`` [deg],
    the fit from the first guess alone is kept when its robust residual level (1.4826 MAD) is
    below it: the restarts are there to escape false minima, which do not fit at the noise level.
    """
    q = np.asarray(query_deg, np.float64)
    obs = np.isfinite(q)
    qo = q[obs]
    n = q.size
    kw = dict(n_bins=n, prior_pitch_deg=prior_pitch_deg, prior_roll_deg=prior_roll_deg)

    def resid(th):
        r = qo - body_profile(world_el_deg, th[0], th[1], th[2], **kw)[obs]
        return r - np.median(r)

    def robust(r):
        s = max(1.4826 * np.median(np.abs(r)), 0.02)
        k = 2.5 * s
        a = np.abs(r)
        return np.where(a <= k, 1.0, k / np.maximum(a, 1e-12)), np.sum(np.where(a <= k, 0.5 * a * a, k * a - 0.5 * k * k))

    center = yaw0_deg if yaw_center_deg is None else yaw_center_deg

    def in_window(yaw):
        # The window is about the prior, not the start: a start at the window's edge plus a
        # restart and a step returned the truth 20 deg from a +-10 deg prior.
        if yaw_window_deg is None:
            return yaw
        d = (yaw - center + 180.0) % 360.0 - 180.0
        return center + float(np.clip(d, -yaw_window_deg, yaw_window_deg))

    best = None
    h = 0.02
    offsets = [(0.0, 0.0, 0.0)] + [(dy, dp, dr) for dy in restarts_deg for dp in restarts_deg
                                   for dr in restarts_deg if (dy, dp, dr) != (0.0, 0.0, 0.0)]
    for k_start, (dy, dp, dr) in enumerate(offsets):
        if k_start == 1 and accept_deg is not None:
            rb = best[2]
            if 1.4826 * np.median(np.abs(rb - np.median(rb))) <= accept_deg:
                break
        th = np.array([in_window(yaw0_deg + dy), pitch0_deg + dp, roll0_deg + dr], float)
        lam = 1e-3
        r = resid(th)
        w, cost = robust(r)
        for _ in range(iterations):
            jac = np.empty((r.size, 4))
            for i in range(3):
                e = np.zeros(3)
                e[i] = h
                jac[:, i] = (resid(th + e) - resid(th - e)) / (2 * h)  # dr/dtheta
            jac[:, 3] = -1.0  # dr/d(offset): a nuisance, the median is removed anyway
            jw = jac * w[:, None]
            a = jac.T @ jw
            g = jw.T @ r
            step = np.linalg.solve(a + lam * np.diag(np.diag(a) + 1e-9), -g)[:3]
            th_new = th + step
            th_new[0] = in_window(th_new[0])
            th_new[1:] = np.clip(th_new[1:], -30.0, 30.0)
            r_new = resid(th_new)
            w_new, cost_new = robust(r_new)
            if cost_new < cost:
                th, r, w, cost = th_new, r_new, w_new, cost_new
                lam = max(lam / 4, 1e-6)
                if np.max(np.abs(step)) < 1e-4:
                    break
            else:
                lam *= 8
                if lam > 1e4:
                    break
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


# --- the fix ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Fix:
    """The answer of :func:`locate` (``conventions.md``): position [m] in ``crs``, lon/lat [deg],
    heading/pitch/roll [deg], 1-sigma position [m] and heading [deg], calibrated ``confidence``,
    ``score`` (mean squared residual [deg^2], clipped per bin at max(3 noise, 0.5 deg) after
    refinement) and the top candidates."""

    x: float
    y: float
    crs: str
    lon: float
    lat: float
    heading_deg: float
    pitch_deg: float
    roll_deg: float
    position_sigma_m: float
    heading_sigma_deg: float
    confidence: float
    score: float
    candidates: tuple = ()
    features: dict = field(default_factory=dict, compare=False)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["candidates"] = [dict(c) for c in self.candidates]
        d.pop("features")
        return d

    def to_geojson(self) -> dict:
        props = self.to_dict()
        return {"type": "Feature", "geometry": {"type": "Point", "coordinates": [self.lon, self.lat]},
                "properties": props}


@dataclass(frozen=True)
class HeadingFix:
    """Scenario 3's answer: heading [deg] (and pitch/roll [deg]) at a given rough position."""

    heading_deg: float
    heading_sigma_deg: float
    pitch_deg: float
    roll_deg: float
    confidence: float
    score: float
    x: float
    y: float
    features: dict = field(default_factory=dict, compare=False)

    def to_dict(self) -> dict:
        d = asdict(self)
        d.pop("features")
        return d


def _crs_and_lonlat(crs_wkt: str, x: float, y: float):
    if not crs_wkt:
        return "", float("nan"), float("nan")
    from pyproj import CRS, Transformer

    crs = CRS.from_user_input(crs_wkt)
    auth = crs.to_authority()
    name = f"{auth[0]}:{auth[1]}" if auth else crs.name
    try:
        t = Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
        lon, lat = t.transform(x, y)
    except Exception:  # noqa: BLE001 - a CRS without a geographic link gives no lon/lat
        lon = lat = float("nan")
    return name, float(lon), float(lat)


# --- confidence ------------------------------------------------------------------------------------

FEATURES = ("log_ratio", "log_rms_over_noise", "log_relief", "observed_fraction", "log_sigma",
            "tilt_deg")

#: The confidence model per scenario key, and what "correct" means there.
SCENARIOS = {"locate": "scenario 1: database search, correct within 5 m",
             "locate_prior": "scenario 2: DEM only over a prior area, correct within 1 m",
             "heading": "scenario 3: heading from a rough position, correct within 1 deg"}


def confidence_features(best_score, other_score, rms_deg, noise_deg, relief_deg, observed_fraction,
                        sigma=1.0, tilt_deg=0.0):
    """Features of the score landscape for the confidence model (see ``FEATURES``).

    best_score, other_score : [deg^2] mean squared residual of the fix and of the best answer in
        another basin (inf when there is none)
    rms_deg : [deg] robust residual level of the fix (outlier bins excluded)
    noise_deg : [deg] expected detection noise; relief_deg : [deg] std of the query profile
    sigma : the fix's own 1-sigma (position [m] or heading [deg]); tilt_deg : [deg] estimated
        pitch/roll away from the prior
    """
    eps = 1e-4
    ratio = (other_score + eps) / (best_score + eps) if np.isfinite(other_score) else 1e4
    return {
        "log_ratio": float(np.log(min(max(ratio, 1.0), 1e4))),
        "log_rms_over_noise": float(np.log((rms_deg + 1e-3) / max(noise_deg, 0.02))),
        "log_relief": float(np.log(relief_deg + 1e-3)),
        "observed_fraction": float(observed_fraction),
        "log_sigma": float(np.log(min(max(sigma, 1e-3), 1e4))) if np.isfinite(sigma) else float(np.log(1e4)),
        "tilt_deg": float(tilt_deg),
    }


def _load_model(path=MODEL_PATH):
    try:
        return json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError):
        return None


def confidence_from_features(feat: dict, model: dict | None = None, key: str = "locate") -> float:
    """Calibrated probability that the fix is right, from :func:`confidence_features`.

    Uses the logistic model in ``skyfix/models/confidence.json``; without it, a conservative
    uncalibrated fallback (ratio only) that never exceeds 0.5.
    """
    model = model if model is not None else _load_model()
    if not model or key not in model:
        return float(0.5 * (1 - math.exp(-feat["log_ratio"])))
    m = model[key]
    names = m["features"]
    mean = m.get("mean", [0.0] * len(names))
    scale = m.get("scale", [1.0] * len(names))
    z = m["intercept"] + sum(c * (feat[name] - mu) / sd
                             for c, name, mu, sd in zip(m["coef"], names, mean, scale))
    z -= m.get("logit_offset", 0.0)  # a conservative shift set where the 0.9 bin fell short
    p = 1.0 / (1.0 + math.exp(-max(min(z, 50.0), -50.0)))
    # Platt-scaled probabilities are binned in the isotonic table when present.
    table = m.get("isotonic")
    if table:
        p = float(np.interp(p, table["x"], table["y"]))
    return float(p)


def _structureless_cap(conf: float, relief_deg: float, noise_deg: float) -> float:
    """At most 0.05 when the query's relief (std [deg]) is within twice its noise [deg]: such a
    horizon fits anywhere, and no calibration case is that flat, so the fitted model would be
    extrapolating (it gave 0.32 on a flat plain)."""
    return min(conf, 0.05) if relief_deg <= 2.0 * noise_deg else conf


# --- locate -----------------------------------------------------------------------------------------

def _profile_arrays(profile):
    el = np.asarray(profile.elevation_deg, np.float64)
    sig = profile.sigma_deg
    noise = float(np.nanmedian(sig)) if sig is not None and np.isfinite(sig).any() else 0.2
    return el, noise


def _render_points(dem, xs, ys, *, camera_height_m, planet, n_bins):
    """(N, n_bins) float32 world-frame skylines [deg] at (xs, ys) [m], bin-averaged."""
    from .horizon import render_horizons

    # A measured bin averages the skyline over its width: render 5 sub-bins per bin and average,
    # or sharp ridges bias the fine position (point samples vs bin means).
    k = 5
    hb = render_horizons(dem, xs, ys, camera_height_m=camera_height_m, planet=planet,
                         azimuth_bins=n_bins * k)
    p = np.nan_to_num(hb.elevation_deg, nan=0.0)
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
    from .match import _basis

    q = np.asarray(q, np.float64)
    n = q.size
    obs = np.isfinite(q)
    j = np.arange(n, dtype=np.float64)
    pred = np.interp((j + float(shift_bins)) % n, np.arange(n + 1),
                     np.append(np.asarray(p_world, np.float64), float(p_world[0])))
    u = _basis(n, remove_tilt)[obs]
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
    from .match import _basis

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
    u = _basis(n, remove_tilt)[obs]
    w = (np.abs(r) < clip_deg).astype(np.float64)
    for k in range(N):  # one weighted refit on the inliers: offset and tilt harmonic
        uw = u * w[k][:, None]
        coef, *_ = np.linalg.lstsq(uw.T @ u, uw.T @ r[k], rcond=None)
        r[k] -= u @ coef
    return np.mean(np.minimum(r * r, clip_deg * clip_deg), axis=1)


def robust_scores(p, q, *, remove_tilt=True, workers=2, rounds=2):
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
    sc, sh = score_profiles(p, prepare_query(qm, remove_tilt, min_observed=8), workers)
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
        sc, sh = score_profiles(p, prepare_query(qm, remove_tilt, min_observed=8), workers)
    return sc, sh, qm


def _score_points(dem, xs, ys, q, *, camera_height_m, planet, n_bins, remove_tilt=True, workers=2):
    p = _render_points(dem, xs, ys, camera_height_m=camera_height_m, planet=planet, n_bins=n_bins)
    sc, sh, _ = robust_scores(p, q, remove_tilt=remove_tilt, workers=workers)
    return sc, sh


#: Most grid points a search without a database renders: each costs ~3 ms and ~30 kB, so this
#: (a 100 m radius at the 2 m step) is about a minute and 300 MB more; a radius of 1e7 m asked
#: for 728 TiB. Larger areas are what the database is for.
MAX_PRIOR_GRID_POINTS = 101 * 101


def _prior_grid(dem, prior_xy, radius_m, step_m):
    """Grid points [m] at ``step_m`` over the prior square (centre ``prior_xy``, half-side
    ``radius_m``), only the part on the DEM: a radius reaching past the DEM costs nothing.
    Raises ParameterError when the area lies off the DEM or needs more than
    MAX_PRIOR_GRID_POINTS renders."""
    xmin, ymin, xmax, ymax = dem.bounds
    px, py = float(prior_xy[0]), float(prior_xy[1])
    k = math.ceil(radius_m / step_m)
    i0, i1 = max(-k, math.ceil((xmin - px) / step_m)), min(k, math.floor((xmax - px) / step_m))
    j0, j1 = max(-k, math.ceil((ymin - py) / step_m)), min(k, math.floor((ymax - py) / step_m))
    if i0 > i1 or j0 > j1:
        raise ParameterError("the prior area lies outside the DEM")
    n = (i1 - i0 + 1) * (j1 - j0 + 1)
    if n > MAX_PRIOR_GRID_POINTS:
        r_max = (math.isqrt(MAX_PRIOR_GRID_POINTS) // 2) * step_m
        raise ParameterError(
            f"without a database the search renders a skyline every {step_m:g} m over the prior "
            f"area: a {radius_m:g} m radius is {n:,} points on the DEM (at most "
            f"{MAX_PRIOR_GRID_POINTS:,}, a radius of about {r_max:g} m); give a smaller "
            "--prior-radius-m, or build a database over the area (skyfix build-db) and pass --db")
    gx, gy = np.meshgrid(px + np.arange(i0, i1 + 1) * step_m, py + np.arange(j0, j1 + 1) * step_m)
    return gx.ravel(), gy.ravel()


def _inside(dem, xs, ys, margin):
    return np.asarray(dem.contains(xs, ys, margin), bool) & np.isfinite(dem.height_at(xs, ys))


def _refine(dem, q, x, y, step, levels, *, camera_height_m, planet, remove_tilt, workers,
            max_moves=3):
    """Local grid search (9 x 9 per level, 4x finer each level) around (x, y) [m].

    When the best point lies on the grid's edge the level is re-centred there and redone (at most
    ``max_moves`` times in all): with 10 deg pitch/roll the database's candidate can sit 10-15 m
    from the true basin, beyond the first level's +/- 4 steps.
    Returns (x, y, score, heading_deg, local) with ``local`` the finest level's grid and scores
    (for the position sigma)."""
    n = q.size
    best = None
    local = None
    moves = 0
    for _ in range(levels):
        while True:
            off = np.arange(-4, 5) * step
            gx, gy = np.meshgrid(x + off, y + off)
            gx, gy = gx.ravel(), gy.ravel()
            ok = _inside(dem, gx, gy, 0.0)
            if not ok.any():
                break
            gx, gy = gx[ok], gy[ok]
            sc, sh = _score_points(dem, gx, gy, q, camera_height_m=camera_height_m, planet=planet,
                                   n_bins=n, remove_tilt=remove_tilt, workers=workers)
            i = int(np.argmin(sc))
            on_edge = max(abs(gx[i] - x), abs(gy[i] - y)) > 3.5 * step
            x, y = float(gx[i]), float(gy[i])
            best = (x, y, float(sc[i]), float(sh[i]) * 360.0 / n)
            local = (gx, gy, sc, step)
            if not on_edge or moves >= max_moves:
                break
            moves += 1
        if best is None:
            break
        step /= 4.0
    if best is None:
        raise SkyfixError(f"no refinement point near ({x:.1f}, {y:.1f}) lies inside the DEM")
    return (*best, local)


def residual_correlation_bins(resid, max_lag=60, floor=0.05):
    """Integrated autocorrelation length [bins] of a residual profile (NaN = unobserved):
    ``1 + 2 sum_k rho_k`` over lags until ``rho_k`` drops below ``floor``, at least 1.

    Detection errors are smooth along the skyline (a sub-pixel bias over a ridge, a frame's
    pan error), so neighbouring bins do not bring independent information; the number of
    independent bins is the observed count divided by this length."""
    r = np.asarray(resid, np.float64)
    ok = np.isfinite(r)
    if ok.sum() < 10:
        return 1.0
    r = np.where(ok, r - np.mean(r[ok]), 0.0)
    var = float(np.mean(r[ok] ** 2))
    if var <= 0:
        return 1.0
    tau = 1.0
    n = r.size
    for k in range(1, min(max_lag, n // 2) + 1):
        both = ok & np.roll(ok, -k)  # profiles are circular
        if both.sum() < 10:
            break
        rho = float(np.mean((r * np.roll(r, -k))[both])) / var
        if rho < floor:
            break
        tau += 2.0 * rho
    return tau


def _position_sigma(local, best_score, m_obs, noise_deg, corr_bins=1.0):
    """1-sigma position [m] from a quadratic fit of the score surface on the finest grid, with
    ``m_obs / corr_bins`` independent bins (:func:`residual_correlation_bins`)."""
    gx, gy, sc, step = local
    if gx.size < 6:
        return float(step)
    i = int(np.argmin(sc))
    dx, dy = gx - gx[i], gy - gy[i]
    near = (np.abs(dx) <= 2.01 * step) & (np.abs(dy) <= 2.01 * step)
    a = np.stack([np.ones(near.sum()), dx[near], dy[near], dx[near] ** 2, dx[near] * dy[near],
                  dy[near] ** 2], axis=1)
    try:
        c, *_ = np.linalg.lstsq(a, sc[near].astype(float), rcond=None)
        hess = np.array([[2 * c[3], c[4]], [c[4], 2 * c[5]]])
        # score = mean sq residual; NLL = m * score / (2 s^2) -> cov = 2 s^2 / m * H^-1.
        s2 = max(best_score, noise_deg ** 2)
        cov = 2 * s2 * max(corr_bins, 1.0) / m_obs * np.linalg.inv(hess)
        ev = np.linalg.eigvalsh(cov)
        if np.any(ev <= 0) or not np.all(np.isfinite(ev)):
            return float(4 * step)
        return float(max(math.sqrt(ev.sum()), step / math.sqrt(6)))
    except np.linalg.LinAlgError:
        return float(4 * step)


def _harmonic_tilt(q, world_shifted):
    """First guess of (pitch, roll) [deg] from the first harmonic of query - prediction."""
    n = q.size
    obs = np.isfinite(q)
    az = np.radians(np.arange(n) * 360.0 / n)
    u = np.stack([np.ones(n), np.cos(az), np.sin(az)], axis=1)[obs]
    c, *_ = np.linalg.lstsq(u, (q - world_shifted)[obs], rcond=None)
    # Small pitch p lowers what is ahead: -p cos(az); small roll r raises the right side: +r sin(az).
    return float(-c[1]), float(c[2])


def _refine_candidate(dem, q, cx, cy, ch, step0, config, *, camera_height_m, planet,
                      prior_pitch_deg, prior_roll_deg, noise):
    """Attitude, then position, then attitude again around one candidate (x, y [m], heading [deg]).

    The attitude comes first: with 10 deg of pitch/roll the tilt-harmonic removal of the shift
    search is only approximate and biased the fine position by 5-15 m; levelling the query with
    the attitude fitted at the candidate (far horizon: insensitive to metres) removes that bias.
    Returns (x, y, score, local, attitude, clipped cost, residual profile [deg])."""
    from .horizon import render_horizons

    n = q.size

    def world_at(x, y):
        return render_horizons(dem, [x], [y], camera_height_m=camera_height_m, planet=planet,
                               azimuth_bins=config.render_bins).elevation_deg[0]

    def fit(world, yaw0, p0, r0, restarts):
        return fit_attitude(q, world, yaw0, p0, r0, restarts_deg=restarts,
                            prior_pitch_deg=prior_pitch_deg, prior_roll_deg=prior_roll_deg,
                            accept_deg=2.0 * max(noise, 0.05))

    def level(att):
        if max(abs(att.pitch_deg - prior_pitch_deg), abs(att.roll_deg - prior_roll_deg)) < 0.3:
            return q
        ql = relevel(q, att.pitch_deg, att.roll_deg, prior_pitch_deg=prior_pitch_deg,
                     prior_roll_deg=prior_roll_deg)
        return ql if np.isfinite(ql).sum() >= 20 else q

    kw = dict(camera_height_m=camera_height_m, planet=planet,
              remove_tilt=config.match.remove_tilt, workers=config.match.workers)
    world = world_at(cx, cy)
    p0, r0 = _harmonic_tilt(q, body_profile(world, ch, n_bins=n))
    att = fit(world, ch, prior_pitch_deg + p0, prior_roll_deg + r0, config.restarts_deg)
    x, y, s, hd, local = _refine(dem, level(att), cx, cy, step0, config.levels, **kw)
    world = world_at(x, y)
    att = fit(world, att.yaw_deg, att.pitch_deg, att.roll_deg, (0.0,))
    ql = level(att)
    if ql is not q and config.levels > 1:
        # The attitude moved with the position: redo the finest level with the new levelling.
        fine = step0 / 4.0 ** (config.levels - 1)
        x, y, s, hd, local = _refine(dem, ql, x, y, fine, 1, **kw)
        world = world_at(x, y)
        att = fit(world, att.yaw_deg, att.pitch_deg, att.roll_deg, (0.0,))
    resid = residual_profile(q, world, att, prior_pitch_deg=prior_pitch_deg,
                             prior_roll_deg=prior_roll_deg)
    return x, y, s, local, att, robust_cost(resid, noise), resid


def _polish_position(dem, q, x, y, att, *, camera_height_m, planet, render_bins, prior_pitch_deg,
                     prior_roll_deg, noise, step_m=0.5, min_step_m=0.03, max_evals=120):
    """Compass search of the position [m] on the attitude-refitted cost (:func:`robust_cost`).

    The grid refinement (:func:`_refine`) ranks points by the shift search's score: whole-bin
    azimuth shifts of a query levelled with an attitude fitted elsewhere. With 10 deg of tilt its
    noise floor (~0.03 deg rms) hides metre-scale position information (a fix 1.3 m off whose
    own cost was three times the truth's). Here every trial point gets its own yaw, pitch and
    roll (Gauss-Newton from the current attitude, ~10 ms), so the cost is the model's own.
    The 8 neighbours at the current step (``step_m`` at first) are tried; the best improvement
    is taken and the step doubles (up to 8 ``step_m``), else it halves, down to ``min_step_m``.
    Returns (x, y, attitude, cost, residual profile [deg]).
    """
    from .horizon import render_horizons

    kw = dict(prior_pitch_deg=prior_pitch_deg, prior_roll_deg=prior_roll_deg)

    def evaluate(xs, ys, a0):
        xs, ys = np.asarray(xs, float), np.asarray(ys, float)
        ok = _inside(dem, xs, ys, 0.0)
        out = [(np.inf, None, None)] * xs.size
        if ok.any():
            w = render_horizons(dem, xs[ok], ys[ok], camera_height_m=camera_height_m, planet=planet,
                                azimuth_bins=render_bins).elevation_deg
            for i, wi in zip(np.flatnonzero(ok), w):
                a = fit_attitude(q, wi, a0.yaw_deg, a0.pitch_deg, a0.roll_deg, restarts_deg=(0.0,), **kw)
                r = residual_profile(q, wi, a, **kw)
                out[i] = (robust_cost(r, noise), a, r)
        return out

    (cost, att, resid), = evaluate([x], [y], att)
    if att is None:
        raise SkyfixError(f"the position ({x:.1f}, {y:.1f}) lies outside the DEM")
    ring = np.array([(i, j) for i in (-1, 0, 1) for j in (-1, 0, 1) if (i, j) != (0, 0)], float)
    step, evals = float(step_m), 1
    while step >= min_step_m and evals < max_evals:
        trials = evaluate(x + step * ring[:, 0], y + step * ring[:, 1], att)
        evals += len(ring)
        k = int(np.argmin([t[0] for t in trials]))
        if trials[k][0] < cost:
            x, y = x + step * ring[k, 0], y + step * ring[k, 1]
            cost, att, resid = trials[k]
            step = min(2.0 * step, 8.0 * step_m)  # a long way to go: stride out
        else:
            step /= 2.0
    return float(x), float(y), att, float(cost), resid


def residual_profile(q, world_el_deg, att, *, prior_pitch_deg=0.0, prior_roll_deg=0.0):
    """Query minus the world horizon seen with attitude ``att`` [deg] (NaN where unobserved)."""
    pred = body_profile(world_el_deg, att.yaw_deg, att.pitch_deg, att.roll_deg,
                        n_bins=np.size(q), prior_pitch_deg=prior_pitch_deg,
                        prior_roll_deg=prior_roll_deg)
    return np.asarray(q, np.float64) - pred


def robust_cost(resid, noise_deg):
    """Clipped mean squared residual [deg^2] of a :func:`residual_profile`, offset removed:
    each bin counts at most ``(max(3 noise, 0.5 deg))^2``, so a few gross bins (a near rock)
    cannot out-vote the rest when candidates are ranked."""
    r = resid[np.isfinite(resid)]
    r = r - np.median(r)
    c = max(3.0 * noise_deg, 0.5)
    return float(np.mean(np.minimum(r * r, c * c)))



def _refined(dem, q, cands, step0, config, *, camera_height_m, planet, prior_pitch_deg,
             prior_roll_deg, noise):
    """Refine (:func:`_refine_candidate`) and polish (:func:`_polish_position`) each candidate
    (x [m], y [m], score, heading [deg]); result dicts sorted by the clipped cost."""
    results = []
    for cx, cy, cs, ch in cands:
        x, y, s, local, att, cost, resid = _refine_candidate(
            dem, q, cx, cy, ch, step0, config, camera_height_m=camera_height_m, planet=planet,
            prior_pitch_deg=prior_pitch_deg, prior_roll_deg=prior_roll_deg, noise=noise)
        results.append(dict(x=x, y=y, score=s, heading=att.yaw_deg, att=att, local=local,
                            db_score=cs, cost=cost, resid=resid))
    if config.polish:
        # Every refined candidate gets the same final polish: the grid's score can leave the
        # true basin's candidate behind a worse one (rocks over a quarter of the view), and the
        # confidence's best-vs-other ratio then compares like with like.
        for d in results:
            x, y, att_p, cost_p, resid_p = _polish_position(
                dem, q, d["x"], d["y"], d["att"], camera_height_m=camera_height_m, planet=planet,
                render_bins=config.render_bins, prior_pitch_deg=prior_pitch_deg,
                prior_roll_deg=prior_roll_deg, noise=noise)
            d.update(x=x, y=y, att=att_p, heading=att_p.yaw_deg, cost=cost_p, resid=resid_p)
    # Ranked by the clipped cost: plain rms let outlier bins pick the wrong basin.
    results.sort(key=lambda d: d["cost"])
    return results


def _decide(results, rest, q, noise, relief, sep, prior_pitch_deg, prior_roll_deg, model, key):
    """The best refined result, its uncertainties and confidence. results: refined dicts sorted
    by cost; rest: unrefined candidates (x, y, score, heading); sep [m]: how far another answer
    must be to count as a rival."""
    best = results[0]
    far = lambda x, y: math.hypot(x - best["x"], y - best["y"]) > sep  # noqa: E731
    other = min([d["cost"] for d in results[1:] if far(d["x"], d["y"])] +
                [c[2] for c in rest if far(c[0], c[1])] or [np.inf])
    att = best["att"]
    obs = np.isfinite(q)
    psig = _position_sigma(best["local"], best["score"], int(obs.sum()), noise,
                           corr_bins=residual_correlation_bins(best["resid"]))
    tilt = math.hypot(att.pitch_deg - prior_pitch_deg, att.roll_deg - prior_roll_deg)
    feat = confidence_features(best["cost"], other, att.robust_rms_deg, noise, relief,
                               float(obs.mean()), psig, tilt)
    conf = _structureless_cap(confidence_from_features(feat, model, key), relief, noise)
    return dict(x=best["x"], y=best["y"], heading=att.yaw_deg, pitch=att.pitch_deg,
                roll=att.roll_deg, cost=best["cost"], psig=psig, hsig=att.yaw_sigma_deg,
                feat=feat, conf=conf)


def _segment_candidates(db, q, config, known, *, prior_xy=None, prior_radius_m=None):
    """Database candidates (x, y, score, heading) found with each of ``config.retry_segments``
    contiguous parts of the observed skyline left out in turn, farther than the tolerance from
    every position in ``known`` and from each other (the first ``retry_per_segment`` of each
    search)."""
    obs = np.flatnonzero(np.isfinite(q))
    out = []
    for part in np.array_split(obs, max(1, config.retry_segments)):
        if part.size == 0 or obs.size - part.size < config.match.min_observed:
            continue
        qk = q.copy()
        qk[part] = np.nan
        m = match_database(db, qk, config.match, prior_xy=prior_xy, prior_radius_m=prior_radius_m)
        for c in m.candidates[: config.retry_per_segment]:
            if all(math.hypot(c.x - x, c.y - y) > config.tolerance_m for x, y in known):
                out.append((c.x, c.y, c.score, c.heading_deg))
                known = known + [(c.x, c.y)]
    return out


def locate(profile, *, db=None, dem=None, prior_xy=None, prior_radius_m=None,
           prior_pitch_deg: float = 0.0, prior_roll_deg: float = 0.0,
           camera_height_m: float | None = None, planet=None, config: PoseConfig = PoseConfig(),
           model: dict | None = None, return_match: bool = False):
    """Position, heading and attitude from a body-frame profile.

    profile : :class:`skyfix.formats.Profile` (frame ``body``, levelled with the attitude prior)
    db : an opened skyline database (or anything with its read API); None for a small prior area
    dem : the DEM the database was built from; needed to refine (and without a database)
    prior_xy, prior_radius_m : [m] search disc (required without a database)
    prior_pitch_deg, prior_roll_deg : [deg] the attitude prior the profile was levelled with
    Returns a :class:`Fix` (and the :class:`skyfix.match.MatchResult` with ``return_match``).
    """
    if getattr(profile, "frame", "body") not in ("body", None):
        raise ParameterError(f"locate needs a body-frame profile, got frame '{profile.frame}'")
    q, noise = _profile_arrays(profile)
    n = q.size
    if db is None and dem is None:
        raise ParameterError("locate needs a skyline database (--db) or a DEM with a prior area")
    if db is None and (prior_xy is None or prior_radius_m is None):
        raise ParameterError("without a database, give a prior position and radius "
                             "(--prior-x, --prior-y, --prior-radius-m) and a DEM")
    if prior_xy is not None and not all(math.isfinite(float(v)) for v in prior_xy):
        raise ParameterError(f"prior position must be finite [m], got {tuple(prior_xy)}")
    if prior_radius_m is not None and not (math.isfinite(prior_radius_m) and prior_radius_m > 0):
        raise ParameterError(f"prior radius must be a finite number of metres > 0, got {prior_radius_m}")
    if camera_height_m is None:
        camera_height_m = float(getattr(db, "camera_height_m", None) or
                                profile.meta.get("camera_height_m", 1.5))
    if planet is None:
        planet = getattr(db, "planet", None) or "earth"
        if isinstance(planet, dict):
            planet = planet.get("name") or planet.get("radius_m") or "earth"
    workers = config.match.workers
    mres = None
    if db is not None:
        mres = match_database(db, q, config.match, prior_xy=prior_xy, prior_radius_m=prior_radius_m)
        cands = [(c.x, c.y, c.score, c.heading_deg) for c in mres.candidates]
        step0 = float(db.spacing_m) / 4.0
        crs_wkt = getattr(db, "crs_wkt", "") or (dem.crs_wkt if dem is not None else "")
    else:
        step = config.grid_step_m
        gx, gy = _prior_grid(dem, prior_xy, float(prior_radius_m), step)
        ok = _inside(dem, gx, gy, 0.0)
        if not ok.any():
            raise ParameterError("the prior area lies outside the DEM")
        gx, gy = gx[ok], gy[ok]
        prepare_query(q, config.match.remove_tilt, config.match.min_observed)  # validates the view
        pts = _render_points(dem, gx, gy, camera_height_m=camera_height_m, planet=planet, n_bins=n)
        _, sh, _ = robust_scores(pts, q, remove_tilt=config.match.remove_tilt, workers=workers)
        # Candidates by the clipped cost: rocks covering a quarter of the view (OCCL) named the
        # wrong outlier bins at the sum-of-squares optimum and kept the true basin out of the
        # refined few; clipped, each rock bin costs the same everywhere.
        sc = clipped_costs(pts, q, sh, config.match.remove_tilt)
        order = np.argsort(sc)
        cands = []
        for i in order:
            if all(math.hypot(gx[i] - c[0], gy[i] - c[1]) > 2.5 * step for c in cands):
                cands.append((float(gx[i]), float(gy[i]), float(sc[i]), float(sh[i]) * 360.0 / n))
            if len(cands) >= config.match.top_k:
                break
        step0 = step / 4.0
        crs_wkt = dem.crs_wkt
    if not cands:
        raise SkyfixError("no candidate position found: the database holds no usable skyline")
    relief = float(np.nanstd(q))
    if dem is not None:
        kw = dict(camera_height_m=camera_height_m, planet=planet, prior_pitch_deg=prior_pitch_deg,
                  prior_roll_deg=prior_roll_deg, noise=noise)
        results = _refined(dem, q, cands[: config.refine_candidates], step0, config, **kw)
        rest = list(cands[config.refine_candidates:])
        # "Another basin" is another answer beyond the tolerance: refined candidates often
        # converge onto the best one, and comparing with a copy of itself said nothing.
        sep = config.tolerance_m if db is not None else 1.0
        # Without a database the answer is judged at scenario 2's tolerance (1 m), not 5 m.
        out = _decide(results, rest, q, noise, relief, sep, prior_pitch_deg, prior_roll_deg,
                      model, "locate" if db is not None else "locate_prior")
        if db is not None and (out["conf"] < config.retry_below or
                               out["feat"]["log_rms_over_noise"] > math.log(config.retry_rms_ratio)):
            known = [(d["x"], d["y"]) for d in results] + [(c[0], c[1]) for c in rest]
            extra = _segment_candidates(db, q, config, known, prior_xy=prior_xy,
                                        prior_radius_m=prior_radius_m)
            if extra:
                results = sorted(results + _refined(dem, q, extra, step0, config, **kw),
                                 key=lambda d: d["cost"])
                out = _decide(results, rest, q, noise, relief, sep, prior_pitch_deg,
                              prior_roll_deg, model, "locate")
        fx, fy, heading, pitch, roll = out["x"], out["y"], out["heading"], out["pitch"], out["roll"]
        best_s, psig, hsig, feat, conf = out["cost"], out["psig"], out["hsig"], out["feat"], out["conf"]
        cand_out = [{"x": d["x"], "y": d["y"], "heading_deg": d["heading"],
                     "score": d["cost"]} for d in results]
        cand_out += [{"x": c[0], "y": c[1], "heading_deg": c[3], "score": c[2]} for c in rest]
    else:
        cx, cy, cs, ch = cands[0]
        other = cands[1][2] if len(cands) > 1 else np.inf
        best_s = cs
        fx, fy, heading, pitch, roll = cx, cy, ch, prior_pitch_deg, prior_roll_deg
        psig = float(db.spacing_m) / math.sqrt(6)
        hsig, rms = 360.0 / n, math.sqrt(cs)
        tilt = 0.0
        cand_out = [{"x": c[0], "y": c[1], "heading_deg": c[3], "score": c[2]} for c in cands]
        feat = confidence_features(best_s, other, rms, noise, relief, float(np.isfinite(q).mean()),
                                   psig, tilt)
        conf = _structureless_cap(confidence_from_features(feat, model, "locate"), relief, noise)
    crs, lon, lat = _crs_and_lonlat(crs_wkt, fx, fy)
    fix = Fix(float(fx), float(fy), crs, lon, lat, float(heading) % 360.0, float(pitch),
              float(roll), float(psig), float(hsig), conf, float(best_s), tuple(cand_out), feat)
    return (fix, mres) if return_match else fix


#: Confidence at most, of a heading pinned to the edge of its search window.
PINNED_HEADING_CONFIDENCE = 0.05


def at_window_edge(heading_deg, prior_deg, window_deg, tol_deg=1e-6) -> bool:
    """Whether ``heading_deg`` [deg] sits on the edge of ``prior_deg +/- window_deg`` [deg]."""
    d = abs((heading_deg - prior_deg + 180.0) % 360.0 - 180.0)
    return d >= window_deg - tol_deg


def estimate_heading(profile, dem, x, y, heading_prior_deg, window_deg=10.0, *,
                     camera_height_m=1.5, planet="earth", prior_pitch_deg=0.0, prior_roll_deg=0.0,
                     render_bins=1440, model=None) -> HeadingFix:
    """Scenario 3: heading [deg] from a rough position (x, y) [m] and a heading prior [deg].

    The shift search is restricted to ``heading_prior_deg +/- window_deg``; the attitude is then
    refined by Gauss-Newton with restarts, yaw kept within the window. A heading on the window's
    edge (the best lies beyond it) gets confidence at most PINNED_HEADING_CONFIDENCE.
    """
    from .horizon import render_horizons

    if not 0 < window_deg <= 180:
        raise ParameterError(f"window must be in (0, 180] deg, got {window_deg}")
    if not math.isfinite(heading_prior_deg):
        raise ParameterError(f"heading prior must be a finite angle [deg], got {heading_prior_deg}")
    if not (math.isfinite(x) and math.isfinite(y)):
        raise ParameterError(f"rough position must be finite [m], got ({x}, {y})")
    q, noise = _profile_arrays(profile)
    n = q.size
    dem.require_inside(np.array([x]), np.array([y]), "rough position")
    world = render_horizons(dem, [x], [y], camera_height_m=camera_height_m, planet=planet,
                            azimuth_bins=render_bins).elevation_deg[0]
    world_n = np.nan_to_num(body_profile(world, 0.0, n_bins=n))
    query = prepare_query(q, True, min_observed=8)
    s = score_profiles(world_n[None].astype(np.float32), query, all_shifts=True)[0]
    shifts = np.arange(n) * 360.0 / n
    dist = np.abs((shifts - heading_prior_deg + 180.0) % 360.0 - 180.0)
    # A window narrower than half a bin holds no bin centre: take the nearest one as the start.
    inwin = dist <= max(window_deg, float(dist.min()))
    k = int(np.flatnonzero(inwin)[np.argmin(s[inwin])])
    h0 = shifts[k]
    p0, r0 = _harmonic_tilt(q, body_profile(world, h0, n_bins=n))
    att = fit_attitude(q, world, h0, prior_pitch_deg + p0, prior_roll_deg + r0,
                       prior_pitch_deg=prior_pitch_deg, prior_roll_deg=prior_roll_deg,
                       yaw_window_deg=window_deg, yaw_center_deg=heading_prior_deg,
                       restarts_deg=(-2.5, 0.0, 2.5),
                       accept_deg=2.0 * max(noise, 0.05))
    # Landscape inside the window: best vs best shift more than 3 deg away.
    far = inwin & (np.abs((shifts - att.yaw_deg + 180.0) % 360.0 - 180.0) > 3.0)
    other = float(s[far].min()) if far.any() else np.inf
    relief = float(np.nanstd(q))
    feat = confidence_features(float(s[inwin].min()), other, att.robust_rms_deg, noise,
                               relief, float(np.isfinite(q).mean()),
                               att.yaw_sigma_deg,
                               math.hypot(att.pitch_deg - prior_pitch_deg, att.roll_deg - prior_roll_deg))
    conf = _structureless_cap(confidence_from_features(feat, model, "heading"), relief, noise)
    if window_deg < 180.0 and at_window_edge(att.yaw_deg, heading_prior_deg, window_deg):
        # Pinned to the window's edge: the fit still improves beyond it, so this is no minimum
        # and the true heading most likely lies outside the window (truth 20 deg from the prior
        # with a +-10 deg window gave the edge at confidence 0.9).
        conf = min(conf, PINNED_HEADING_CONFIDENCE)
    return HeadingFix(att.yaw_deg % 360.0, att.yaw_sigma_deg, att.pitch_deg, att.roll_deg, conf,
                      att.rms_deg ** 2, float(x), float(y), feat)


# --- simulation helpers (tests, benchmarks, calibration) ---------------------------------------------

def synthetic_profile(dem, x, y, heading_deg, pitch_deg=0.0, roll_deg=0.0, *, camera_height_m=1.5,
                      planet="earth", n_bins=360, noise_deg=0.0, outlier_fraction=0.0,
                      coverage_deg=360.0, rng=None, render_bins=3600, prior_pitch_deg=0.0,
                      prior_roll_deg=0.0):
    """A body-frame :class:`~skyfix.formats.Profile` as a rover at (x, y) [m] with this attitude
    [deg] would measure it: a dense rendered horizon rotated exactly into the body frame, then
    Gaussian noise [deg], outlier bins (+/- 1..5 deg) and a view of ``coverage_deg`` centred on a
    random azimuth."""
    from .formats import Profile
    from .horizon import render_horizons

    rng = np.random.default_rng(rng)
    world = render_horizons(dem, [x], [y], camera_height_m=camera_height_m, planet=planet,
                            azimuth_bins=render_bins).elevation_deg[0]
    # Average the dense world horizon onto sub-bins before rotating: a measured bin is an average.
    q = body_profile(world, heading_deg, pitch_deg, roll_deg, n_bins=n_bins * 10,
                     prior_pitch_deg=prior_pitch_deg, prior_roll_deg=prior_roll_deg)
    if n_bins * 10 == q.size:
        # bin j spans j - 0.5 .. j + 0.5 bins: 11 sub-bin samples, the two ends half-weighted
        # (a plain mean of 10 is centred 0.05 bin off, a heading bias of 0.05 deg at 360 bins)
        idx = (10 * np.arange(n_bins)[:, None] + np.arange(-5, 6)[None, :]) % q.size
        w = np.r_[0.5, np.ones(9), 0.5] / 10.0
        q = q[idx] @ w
    q = q + rng.normal(0.0, noise_deg, n_bins) if noise_deg > 0 else q
    if outlier_fraction > 0:
        k = rng.random(n_bins) < outlier_fraction
        q[k] += rng.choice([-1, 1], k.sum()) * rng.uniform(1, 5, k.sum())
    if coverage_deg < 360.0:
        c = rng.uniform(0, 360)
        az = np.arange(n_bins) * 360.0 / n_bins
        d = np.abs((az - c + 180.0) % 360.0 - 180.0)
        q[d > coverage_deg / 2] = np.nan
    sig = np.where(np.isfinite(q), max(noise_deg, 0.05), np.nan)
    return Profile(q, sig, "body", {"camera_height_m": camera_height_m})
