"""True north against grid north (``conventions.md``, "Units and angles").

Inside skyfix every azimuth is from grid north, the +y axis of the work CRS. A heading in an
output is from true north, with the grid heading and the meridian convergence beside it:
``heading_deg = grid_heading_deg + meridian_convergence_deg``. The convergence is read off the CRS
itself: the grid azimuth of a short step due north along the meridian, on the CRS's own body (so
a Mars CRS gives Mars's meridians). Grid north is 1.3 deg from true north over the Sierra DEM
(read into UTM 11N; 14 deg in its own Albers), 1.6 deg on the glacier DEM's UTM zone: beyond the
1 deg a heading must meet. The sum is exact only in a conformal CRS, which is why
:mod:`skyfix.workcrs` reads a DEM in any other (beyond 0.1 % of stretch) into one.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np


def wrap_deg(a):
    """An angle or a difference of angles [deg] into [-180, 180), the short way round (scalars
    or arrays): ``wrap_deg(h1 - h2)`` is how far heading h1 lies clockwise of h2."""
    return (np.asarray(a, float) + 180.0) % 360.0 - 180.0


def arc_span_deg(angles_deg, width_deg: float) -> float:
    """[deg] the smallest arc of the circle that holds every one of ``angles_deg`` [deg], each
    reaching ``width_deg`` [deg] on: the circle less its largest gap between neighbours, at most
    360; 0 without angles. A frame set's pans with the field of view, a profile's observed bins
    with the bin's width."""
    a = np.sort(np.mod(np.asarray(angles_deg, float).ravel(), 360.0))
    if a.size == 0:
        return 0.0
    gaps = np.diff(np.r_[a, a[0] + 360.0])
    return float(min(360.0, 360.0 - gaps.max() + width_deg))


@lru_cache(maxsize=16)
def _transformers(crs_wkt: str):
    from pyproj import CRS, Transformer

    crs = CRS.from_user_input(crs_wkt)
    geo = crs.geodetic_crs
    if geo is None:
        return None
    return (Transformer.from_crs(crs, geo, always_xy=True),
            Transformer.from_crs(geo, crs, always_xy=True))


def meridian_convergence_deg(crs_wkt: str, x: float, y: float) -> float:
    """``heading_deg - grid_heading_deg`` [deg] at (x, y) [m] of the CRS ``crs_wkt``: minus the
    grid azimuth (clockwise from +y) of true north. NaN without a CRS or where the CRS has no
    geodetic link (a local engineering grid): true north is then unknown."""
    if not crs_wkt:
        return float("nan")
    try:
        t = _transformers(crs_wkt)
        if t is None:
            return float("nan")
        to_geo, from_geo = t
        lon, lat = to_geo.transform(x, y)
        d = 1e-5  # deg of latitude: ~1 m on Earth, well inside any projection's smooth range
        lat0, lat1 = max(lat - d, -90.0), min(lat + d, 90.0)
        xs, ys = from_geo.transform([lon, lon], [lat0, lat1])
    except Exception:  # noqa: BLE001 - pyproj raises several types for a CRS it cannot use
        return float("nan")
    if not all(math.isfinite(v) for v in (*xs, *ys)):
        return float("nan")
    return -math.degrees(math.atan2(xs[1] - xs[0], ys[1] - ys[0]))


def heading_360(a: float) -> float:
    """A heading [deg] into [0, 360): a tiny negative angle % 360 rounds to 360.0 in floating
    point (-1e-17 % 360.0 == 360.0), which [0, 360) means as 0."""
    r = float(a) % 360.0
    return 0.0 if r >= 360.0 else r


def true_heading_deg(grid_heading_deg: float, convergence_deg: float) -> float:
    """Heading from true north [deg, 0..360) from the grid heading [deg] and the convergence [deg]
    (the grid heading itself when the convergence is unknown)."""
    if not math.isfinite(convergence_deg):
        return heading_360(grid_heading_deg)
    return heading_360(grid_heading_deg + convergence_deg)


def grid_heading_from_true(true_heading_deg: float, convergence_deg: float) -> float:
    """The inverse of :func:`true_heading_deg` [deg, 0..360)."""
    if not math.isfinite(convergence_deg):
        return heading_360(true_heading_deg)
    return heading_360(true_heading_deg - convergence_deg)
