"""What the pose search returns: a position fix (:class:`Fix`) or a heading (:class:`HeadingFix`),
with the CRS and longitude/latitude of the point.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np


@dataclass(frozen=True)
class Fix:
    """The answer of :func:`locate` (``conventions.md``): position [m] in ``crs``, lon/lat [deg],
    heading [deg] from true north with the grid heading (the yaw, from the CRS's +y axis) and the
    meridian convergence (``heading_deg - grid_heading_deg``; NaN, and ``heading_deg`` the grid
    heading, where the CRS does not say where true north is), pitch/roll [deg], 1-sigma position
    [m] and heading [deg], calibrated ``confidence``, ``score`` (mean squared residual [deg^2],
    clipped per bin at max(3 noise, 0.5 deg) after refinement), the top candidates (their
    headings from true north too) and ``notes``: what the user must know to read it (a
    confidence capped by a degenerate search, a forced DEM, a camera-height mismatch, quantities
    echoed rather than estimated)."""

    x: float
    y: float
    crs: str
    lon: float
    lat: float
    heading_deg: float
    grid_heading_deg: float
    meridian_convergence_deg: float
    pitch_deg: float
    roll_deg: float
    position_sigma_m: float
    heading_sigma_deg: float
    confidence: float
    score: float
    candidates: tuple = ()
    features: dict = field(default_factory=dict, compare=False)
    notes: tuple = ()

    def to_dict(self) -> dict:
        d = asdict(self)
        d["candidates"] = [dict(c) for c in self.candidates]
        d["notes"] = list(self.notes)
        d.pop("features")
        return d

    def to_geojson(self) -> dict:
        props = self.to_dict()
        return {"type": "Feature", "geometry": {"type": "Point", "coordinates": [self.lon, self.lat]},
                "properties": props}


@dataclass(frozen=True)
class HeadingFix:
    """Scenario 3's answer at a given rough position (x, y) [m] in ``crs`` (lon/lat [deg]): heading
    [deg] from true north, the grid heading and the meridian convergence as in :class:`Fix`, its
    1-sigma [deg], pitch/roll [deg], calibrated ``confidence``, ``score`` [deg^2] and ``notes``, as
    :class:`Fix`'s: what the user must know to read it (a heading on the window's edge, a prior
    taken from grid north, a confidence capped because two solves disagree)."""

    heading_deg: float
    heading_sigma_deg: float
    pitch_deg: float
    roll_deg: float
    confidence: float
    score: float
    x: float
    y: float
    grid_heading_deg: float = float("nan")
    meridian_convergence_deg: float = float("nan")
    crs: str = ""
    lon: float = float("nan")
    lat: float = float("nan")
    pitch_sigma_deg: float = float("nan")
    roll_sigma_deg: float = float("nan")
    #: which of heading, pitch and roll the view pins down: 1-sigma within DETERMINED_SIGMA_DEG,
    #: and the answer at least DETERMINED_MIN_CONFIDENCE likely right (a pitch and roll fitted
    #: at a heading in the wrong basin have small sigmas and are wrong all the same)
    determined: dict = field(default_factory=dict)
    features: dict = field(default_factory=dict, compare=False)
    notes: tuple = ()

    def to_dict(self) -> dict:
        d = asdict(self)
        d["notes"] = list(self.notes)
        d.pop("features")
        return d


#: [deg] the largest 1-sigma at which an angle counts as determined by the view
DETERMINED_SIGMA_DEG = 0.5
#: the least confidence at which any angle counts as determined
DETERMINED_MIN_CONFIDENCE = 0.5
#: the share of a normal error within its 1-sigma: what a reported sigma claims
ONE_SIGMA_SHARE = math.erf(1.0 / math.sqrt(2.0))
#: [deg] the 1-sigma of a pitch or roll known not at all, uniform over the fits' +-30 deg bound:
#: the half-width that holds 68 % of it, as every sigma claims (the uniform's standard deviation,
#: 17.3, held 58 %); no reported pitch or roll sigma exceeds it (a view that cannot see the tilt
#: gave 290-900)
UNKNOWN_TILT_SIGMA_DEG = ONE_SIGMA_SHARE * 30.0
#: [deg] the 1-sigma of a heading known not at all, uniform on the circle: the half-width holding
#: 68 % of it (122.9; 360 / sqrt(12) = 103.9 held 58 %); no reported heading sigma exceeds it
UNKNOWN_HEADING_SIGMA_DEG = ONE_SIGMA_SHARE * 180.0


def crs_and_lonlat(crs_wkt: str, x: float, y: float):
    """(CRS, lon [deg], lat [deg]) of (x, y) [m] in ``crs_wkt``; NaNs without a CRS. The CRS is
    its authority code (``EPSG:32611``) where it has one, else its WKT: a name alone (a Mars
    DEM's local transverse Mercator) is nothing another tool, or ``--geojson``, can read back.
    On Earth lon/lat are WGS 84 (what GeoJSON means); on another body, its own geodetic CRS."""
    if not crs_wkt:
        return "", float("nan"), float("nan")
    from pyproj import CRS, Transformer

    from ..planets import EARTH, planet_from_crs

    crs = CRS.from_user_input(crs_wkt)
    auth = crs.to_authority()
    name = f"{auth[0]}:{auth[1]}" if auth else crs.to_wkt()
    try:
        geo = "EPSG:4326" if planet_from_crs(crs) in (EARTH, None) else crs.geodetic_crs
        t = Transformer.from_crs(crs, geo, always_xy=True)
        lon, lat = t.transform(x, y)
    except Exception:  # noqa: BLE001 - a CRS without a geographic link gives no lon/lat
        lon = lat = float("nan")
    return name, float(lon), float(lat)


#: [deg] how far the attitude found may lie from the inclinometer's before a fix says so: the
#: acquisition convention allows a prior wrong by up to this much
PRIOR_TRUST_DEG = 10.0


def prior_disagreement(pitch_deg, roll_deg, prior_pitch_deg, prior_roll_deg) -> tuple:
    """A note (a 1-tuple) when the attitude found [deg] tilts more than :data:`PRIOR_TRUST_DEG`
    from the inclinometer's prior, else (): a mast tilt left out of an acquisition, or given
    with the wrong sign, comes out as that much pitch or roll, and the skyline fits it as well."""
    off = math.hypot(pitch_deg - prior_pitch_deg, roll_deg - prior_roll_deg)
    if not off > PRIOR_TRUST_DEG:
        return ()
    return (f"the attitude found (pitch {pitch_deg:.1f}, roll {roll_deg:.1f} deg) tilts {off:.1f} "
            f"deg from the inclinometer's prior (pitch {prior_pitch_deg:.1f}, roll "
            f"{prior_roll_deg:.1f}): more than the {PRIOR_TRUST_DEG:g} deg a prior may be off; "
            "check the frames' tilt_deg and the prior",)


#: [deg] the pitch and roll bar a frame's skyline should be held to (issue 25's 0.5 deg): a
#: skyline nearer than ``dem_sigma / tan`` of it moves by more under the map's height error alone
NEAR_SKYLINE_BAR_DEG = 0.5


def near_skyline(skyline_distance_m, dem_sigma_m, narrow: bool = True) -> tuple:
    """A note (a 1-tuple) when the skyline in view lies, in the median observed bin, nearer than
    ``dem_sigma_m / tan(NEAR_SKYLINE_BAR_DEG)`` [m] (229 m for 2 m), else (): the map's height
    error alone then moves it by more than that bar, and a frame looking up a slope a DEM cell or
    two away sees the DEM's own cell, not a landmark (single frames with map errors: 20 % of such
    frames within 1 deg of heading, against 93-94 % of those with a farther skyline).
    ``narrow``: the view was solved in the image plane, whose sigmas take ``dem_sigma_m``; a view
    solved on its profile has sigmas calibrated on cases with map errors instead, and the note
    says so (it named the option's degrees beside sigmas the option left unchanged)."""
    d = np.asarray(skyline_distance_m, float)
    d = d[np.isfinite(d)]
    if not (dem_sigma_m and dem_sigma_m > 0 and d.size):
        return ()
    med = float(np.median(d))
    limit = dem_sigma_m / math.tan(math.radians(NEAR_SKYLINE_BAR_DEG))
    if med >= limit:
        return ()
    sigmas = ("the sigmas allow for it" if narrow else
              "a view solved on its profile has sigmas calibrated on cases with map errors, not "
              "taken from --dem-sigma-m")
    return (f"the skyline in view lies {med:.0f} m away (median of the observed bins): the DEM's "
            f"height error ({dem_sigma_m:g} m, --dem-sigma-m) alone moves it by "
            f"{math.degrees(math.atan(dem_sigma_m / max(med, 1e-3))):.1f} deg in elevation there, "
            f"so the attitude is only as good as the map so near ({sigmas}); a view of a skyline "
            f"beyond {limit:.0f} m, or a finer DEM, holds it better",)
