"""Sigmas that allow for a wrong basin: a fit's own sigma knows its basin only, the calibrated
confidence how likely that basin is; together they give the half-width (an angle) or radius (a
position) that holds the error as often as a normal 1-sigma does.
"""

from __future__ import annotations

import math

import numpy as np

from ..north import wrap_deg


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
    (seeds 0, 2), this one 91 % and 88 %: the basins' sigmas over-cover (86-91 % of all errors
    within them), so a low confidence mostly means another basin."""
    if not (math.isfinite(sigma) and sigma >= 0.0):
        return float(sigma)
    c = _weight(confidence)
    w = float(half_width)
    d = abs(float(offset))

    def wrong(r):  # P(|error| <= r) when the truth is uniform over the window
        if w >= 180.0:
            return min(2.0 * r, 360.0) / 360.0
        if w <= 0.0 or r >= 180.0:
            return 1.0
        # the truths within r of the answer, the way round the circle that is shorter: past
        # 90 deg a window's far side lies near its other end
        inside = sum(max(0.0, min(d + r + k, w) - max(d - r + k, -w)) for k in (-360.0, 0.0, 360.0))
        return min(inside, 2.0 * w) / (2.0 * w)

    def share(r):
        right = math.erf(r / (sigma * math.sqrt(2.0))) if sigma > 0 else 1.0
        return c * right + (1.0 - c) * wrong(r)

    return max(_reach(share, ONE_SIGMA_SHARE, sigma), float(sigma))


def rival_heading_sigma(sigma: float, confidence: float, rival_offsets_deg) -> float:
    """The 1-sigma [deg] of a heading that is, with probability ``confidence``, the answer's with
    a normal error of ``sigma`` [deg], and otherwise the heading of one of the rival basins,
    ``rival_offsets_deg`` [deg] from the answer, each as likely (a normal of ``sigma`` about it):
    the half-width that holds the error with the probability a normal 1-sigma holds it
    (:data:`ONE_SIGMA_SHARE`).

    For ``locate``, whose answer is a position and a heading together: a rival position over a
    full turn mostly keeps the answer's heading (map errors moved the fix metres but not the
    heading), and the sigma then hardly widens; a narrow arc's rivals can face anywhere (a
    7.5 deg arc's fix 103 deg off came with 0.81 deg at confidence 0.03, its rivals at +3 and
    -103 deg). Without rivals, ``sigma``: nothing else was found in what was searched."""
    offs = [abs(float(wrap_deg(o))) for o in rival_offsets_deg]
    offs = [o for o in offs if math.isfinite(o)]
    if not (math.isfinite(sigma) and sigma >= 0.0) or not offs:
        return float(sigma)
    c = _weight(confidence)
    sd = max(float(sigma), 1e-9) * math.sqrt(2.0)

    def within(r, o):  # P(|e| <= r) for e normal about o (the circle's wrap is beyond 1-sigma)
        return 0.5 * (math.erf((r - o) / sd) + math.erf((r + o) / sd))

    def share(r):
        return c * within(r, 0.0) + (1.0 - c) * sum(within(r, o) for o in offs) / len(offs)

    return max(min(_reach(share, ONE_SIGMA_SHARE, sigma), 180.0), float(sigma))


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
    c = _weight(confidence)

    def share(r):
        right = 1.0 - math.exp(-(r / sigma_m) ** 2) if sigma_m > 0 else 1.0
        return c * right + (1.0 - c) * wrong_share(r)

    return max(_reach(share, RADIAL_SIGMA_SHARE, sigma_m), float(sigma_m))


def _weight(confidence: float) -> float:
    """The right basin's weight: the confidence within [0, 1], 0 where it is not a number."""
    return min(max(float(confidence), 0.0), 1.0) if math.isfinite(confidence) else 0.0


def _reach(share, level: float, start: float) -> float:
    """The least ``r`` with ``share(r) >= level`` (``share`` rising in ``r``): doubled from
    ``start`` until it holds (at most 1e9), then bisected to a part in 1e18."""
    hi = max(start, 1.0)
    while share(hi) < level and hi < 1e9:
        hi *= 2.0
    lo = 0.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if share(mid) < level else (lo, mid)
    return float(hi)


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
        a3 = 0.5 * math.sqrt(max(0.0, (-d + r + big) * (d + r - big) * (d - r + big)
                                 * (d + r + big)))
        return (a1 + a2 - a3) / (math.pi * big * big)

    return share


def rect_share(x0: float, x1: float, y0: float, y1: float, x: float, y: float, strips: int = 256,
               disc: tuple | None = None):
    """``r -> `` the share of the rectangle [x0, x1] x [y0, y1] [m] (within the disc ``(cx, cy,
    radius)`` [m] too, when given: a database searched inside a prior disc) within ``r`` [m] of
    (x, y), by the midpoint rule over ``strips`` strips (to about 0.1 %). An empty region gives
    1 at every ``r``: nothing to spread over."""
    if disc is not None:
        cx, cy, big = (float(v) for v in disc)
        x0, x1 = max(x0, cx - big), min(x1, cx + big)

    def bounds(u):  # the region's extent in y at abscissae u
        lo, hi = np.full(u.shape, float(y0)), np.full(u.shape, float(y1))
        if disc is not None:
            h = np.sqrt(np.maximum(big * big - (u - cx) ** 2, 0.0))
            lo, hi = np.maximum(lo, cy - h), np.minimum(hi, cy + h)
        return lo, hi

    area = 0.0
    if x1 > x0:
        u = x0 + (np.arange(4 * strips) + 0.5) * (x1 - x0) / (4 * strips)
        lo, hi = bounds(u)
        area = float(np.clip(hi - lo, 0.0, None).sum() * (x1 - x0) / (4 * strips))
    if area <= 1e-9:
        return lambda r: 1.0

    def share(r):
        a, b = max(x0, x - r), min(x1, x + r)
        if b <= a:
            return 0.0
        xs = a + (np.arange(strips) + 0.5) * (b - a) / strips
        half = np.sqrt(np.maximum(r * r - (xs - x) ** 2, 0.0))
        lo, hi = bounds(xs)
        length = np.clip(np.minimum(hi, y + half) - np.maximum(lo, y - half), 0.0, None)
        return float(min(1.0, length.sum() * (b - a) / strips / area))

    return share
