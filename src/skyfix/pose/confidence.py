"""How sure a fix is: the calibrated confidence (a logistic model on features of the score
landscape, fitted by ``scripts/calibrate_confidence.py`` into ``skyfix/models/confidence.json``)
and the position sigma from the local score surface, with the residuals' correlation along
azimuth.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np



MODEL_PATH = Path(__file__).resolve().parents[1] / "models" / "confidence.json"


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


def load_confidence_model(path=MODEL_PATH):
    """The fitted confidence model (a dict per scenario key), or None when the file is missing or
    unreadable (the confidence then falls back to the unfitted formula)."""
    try:
        return json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError):
        return None


def confidence_from_features(feat: dict, model: dict | None = None, key: str = "locate") -> float:
    """Calibrated probability that the fix is right, from :func:`confidence_features`.

    Uses the logistic model in ``skyfix/models/confidence.json``; without it, a conservative
    uncalibrated fallback (ratio only) that never exceeds 0.5.
    """
    model = model if model is not None else load_confidence_model()
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


def calibrated_sigma(raw_sigma: float, feat: dict, model: dict | None = None,
                     key: str = "locate") -> float:
    """The 1-sigma a fix reports [m for a position (sqrt of the covariance's trace), deg for a
    heading]: ``raw_sigma`` (the score surface's curvature, or the grid) widened to the model
    fitted by ``scripts/calibrate_confidence.py`` so that it covers the error as often as it
    claims: ``log s = intercept + coef . features`` (``sqrt(2) s`` for a position), never below
    ``raw_sigma``. The curvature alone covered 28-53 % of errors within 1 sigma on held-out
    sites (63-68 % claimed): it does not see residuals above the noise, a map that is not the
    world or a detection off by pixels. Without a fitted model, ``raw_sigma``."""
    model = model if model is not None else load_confidence_model()
    entry = (model or {}).get(key)
    m = entry.get("sigma") if isinstance(entry, dict) else None
    if not m:
        return float(raw_sigma)
    z = m["intercept"] + sum(c * feat[f] for c, f in zip(m["coef"], m["features"]))
    s = math.exp(max(min(z, 20.0), -20.0)) * (math.sqrt(2.0) if m.get("radial") else 1.0)
    return float(max(raw_sigma, s)) if math.isfinite(raw_sigma) else float(raw_sigma)


#: the share of a normal error within its 1-sigma: what a reported 1-sigma claims
ONE_SIGMA_SHARE = math.erf(1.0 / math.sqrt(2.0))


def wrong_basin_sigma(sigma: float, confidence: float, half_width: float,
                      offset: float = 0.0) -> float:
    """The 1-sigma [deg] of an angle that is, with probability ``confidence``, in its right basin
    with a normal error of ``sigma`` [deg], and otherwise anywhere in the prior's window
    ``+-half_width`` [deg] (uniform; the answer ``offset`` [deg] from the prior; 180 or more:
    anywhere on the circle): the half-width that holds the error with the probability a normal
    1-sigma holds it (:data:`ONE_SIGMA_SHARE`, 68.3 %).

    A fit's own sigma knows its basin only: a heading 7.3 deg off in a rival basin came with 1.37
    deg at confidence 0.55. The confidence says how likely the basin is; this puts the two
    together so that the sigma covers the error as often as it claims whenever the confidence is
    calibrated. Equal to ``sigma`` at confidence 1 and hardly wider above about 0.9 (1.06x at
    0.95); at confidence 0 the window's own spread (0.683 ``half_width`` about the prior).

    The confidence is taken as the basin's weight whole, though it counts right only the errors
    within a tolerance (1 deg), so a basin as wide as that could account for part of a low one
    (weight ``confidence / erf(tol / (sigma sqrt 2))``). Measured on single frames with map
    errors, that split covered 55 % and 76 % of the heading errors beyond 1 deg within 1 sigma
    (seeds 0, 2), this one 91 % and 94 %: the basins' sigmas over-cover (86-91 % of all errors
    within them), so a low confidence mostly means another basin."""
    if not (math.isfinite(sigma) and sigma >= 0.0):
        return float(sigma)
    c = min(max(float(confidence), 0.0), 1.0) if math.isfinite(confidence) else 0.0
    w = float(half_width)
    d = abs(float(offset))

    def wrong(r):  # P(|error| <= r) when the truth is uniform over the window
        if w >= 180.0:
            return min(2.0 * r, 360.0) / 360.0
        return max(0.0, min(d + r, w) - max(d - r, -w)) / (2.0 * w)

    def share(r):
        right = math.erf(r / (sigma * math.sqrt(2.0))) if sigma > 0 else 1.0
        return c * right + (1.0 - c) * wrong(r)

    lo, hi = 0.0, sigma * 10.0 + w + d + 360.0
    for _ in range(100):  # share() rises with r: bisection to well below 1e-9 deg
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if share(mid) < ONE_SIGMA_SHARE else (lo, mid)
    return float(max(hi, sigma))


#: the share of a round normal's errors within its radial 1-sigma (the root of the trace)
RADIAL_SIGMA_SHARE = 1.0 - math.exp(-1.0)


def wrong_basin_radius(sigma_m: float, confidence: float, wrong_share) -> float:
    """The radial 1-sigma [m] of a position that is, with probability ``confidence``, in its right
    basin with a round normal error of radial sigma ``sigma_m`` [m], and otherwise anywhere in the
    searched area: the radius that holds the error with the probability a radial sigma holds it
    (:data:`RADIAL_SIGMA_SHARE`, 63.2 %). ``wrong_share(r)``: the share of the searched area
    within ``r`` [m] of the answer (:func:`disc_share`, :func:`rect_share`). As
    :func:`wrong_basin_sigma` for an angle: ``sigma_m`` at confidence 1, hardly wider above 0.9,
    the confidence taken as the basin's weight whole."""
    if not (math.isfinite(sigma_m) and sigma_m >= 0.0):
        return float(sigma_m)
    c = min(max(float(confidence), 0.0), 1.0) if math.isfinite(confidence) else 0.0

    def share(r):
        right = 1.0 - math.exp(-(r / sigma_m) ** 2) if sigma_m > 0 else 1.0
        return c * right + (1.0 - c) * wrong_share(r)

    hi = max(sigma_m, 1.0)
    while share(hi) < RADIAL_SIGMA_SHARE and hi < 1e9:
        hi *= 2.0
    lo = 0.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if share(mid) < RADIAL_SIGMA_SHARE else (lo, mid)
    return float(max(hi, sigma_m))


def disc_share(cx: float, cy: float, radius_m: float, x: float, y: float):
    """``r -> `` the share of the disc of ``radius_m`` [m] about (cx, cy) within ``r`` [m] of
    (x, y): the area of the two circles' lens over the disc's."""
    d = math.hypot(x - cx, y - cy)
    big = float(radius_m)

    def share(r):
        if r <= 0.0:
            return 0.0
        if d + r <= big:
            return r * r / (big * big)
        if d + big <= r:
            return 1.0
        if d >= r + big:
            return 0.0
        a1 = r * r * math.acos(min(1.0, max(-1.0, (d * d + r * r - big * big) / (2 * d * r))))
        a2 = big * big * math.acos(min(1.0, max(-1.0, (d * d + big * big - r * r) / (2 * d * big))))
        a3 = 0.5 * math.sqrt(max(0.0, (-d + r + big) * (d + r - big) * (d - r + big) * (d + r + big)))
        return (a1 + a2 - a3) / (math.pi * big * big)

    return share


def rect_share(x0: float, x1: float, y0: float, y1: float, x: float, y: float, strips: int = 256):
    """``r -> `` the share of the rectangle [x0, x1] x [y0, y1] [m] within ``r`` [m] of (x, y),
    by the midpoint rule over ``strips`` strips of the disc (to about 0.1 %)."""
    area = max((x1 - x0) * (y1 - y0), 1e-9)

    def share(r):
        a, b = max(x0, x - r), min(x1, x + r)
        if b <= a:
            return 0.0
        xs = a + (np.arange(strips) + 0.5) * (b - a) / strips
        half = np.sqrt(np.maximum(r * r - (xs - x) ** 2, 0.0))
        length = np.clip(np.minimum(y1, y + half) - np.maximum(y0, y - half), 0.0, None)
        return float(min(1.0, length.sum() * (b - a) / strips / area))

    return share


def structureless_cap(conf: float, relief_deg: float, noise_deg: float) -> float:
    """At most 0.05 when the query's relief (std [deg]) is within twice its noise [deg]: such a
    horizon fits anywhere, and no calibration case is that flat, so the fitted model would be
    extrapolating (it gave 0.32 on a flat plain)."""
    return min(conf, 0.05) if relief_deg <= 2.0 * noise_deg else conf


def residual_correlation_bins(resid, max_lag=60, floor=0.05, circular=True):
    """Integrated autocorrelation length [bins] of a residual profile (NaN = unobserved):
    ``1 + 2 sum_k rho_k`` over lags until ``rho_k`` drops below ``floor``, at least 1.
    ``circular``: the series closes on itself (a 360-deg profile), else it is open (a frame's
    columns).

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
        if circular:
            both = ok & np.roll(ok, -k)
            prod = r * np.roll(r, -k)
        else:
            both = ok[:-k] & ok[k:]
            prod = r[:-k] * r[k:]
        if both.sum() < 10:
            break
        rho = float(np.mean(prod[both])) / var
        if rho < floor:
            break
        tau += 2.0 * rho
    return tau


def position_sigma(local, best_score, m_obs, noise_deg, corr_bins=1.0):
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
