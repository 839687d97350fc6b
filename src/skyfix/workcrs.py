"""The work CRS (``conventions.md``, "World frame"): a metric projected CRS on the DEM's own body in
which distances are true to within 0.1 % over the work area; and, for a DEM reprojected into it,
the crop to where the source raster lies (:func:`source_footprint`, :func:`crop_to_footprint`).

A horizon is made of distances, heights and directions: a projection that stretches distances
tilts every line of sight (an equirectangular Mars map with its standard parallel at the equator
stretches east-west distances by 5 % at Jezero's 18.4 deg N), and one that is not conformal also
turns directions, which no meridian convergence undoes (the Sierra DEM's USA Albers: 0.98 % and
up to 0.56 deg; a full turn's heading came out 0.3-0.4 deg off true north in it). Where the DEM's
own CRS is geographic or projected with more than 0.1 % scale error, the DEM is reprojected to a
transverse Mercator on its body: on Earth its UTM zone where that is within 0.1 % over the DEM
(:func:`earth_work_crs`), else one centred on the DEM (scale 1 on its central meridian: well under
0.1 % within ~90 km of it).

A DEM's labels are checked against its numbers here too: a geographic CRS on coordinates that
cannot be degrees (:func:`check_lonlat_extent`), a CRS in feet (:func:`units_in_metres`,
:func:`metric_twin`), and degrees typed where metres are expected (:func:`lonlat_hint`).
"""

from __future__ import annotations

import math
from contextlib import contextmanager

import numpy as np

#: the largest scale error [fraction] a work CRS may have over the work area
MAX_SCALE_ERROR = 0.001


def mid_longitude(west: float, east: float) -> float:
    """[deg] the longitude halfway from ``west`` to ``east``, eastwards: across the 180th meridian
    (west > east) the middle lies near 180, not on the far side of the body (a DEM there was read
    into a projection centred 180 deg away, and half of it was lost)."""
    if west > east:
        east += 360.0
    mid = (west + east) / 2.0
    return (mid + 180.0) % 360.0 - 180.0 if mid > 180.0 else mid


def local_tm_crs(crs, lon0: float, lat0: float):
    """A transverse Mercator (scale 1, no false origin) on the geodetic datum of ``crs`` (any
    body), centred on (lon0, lat0) [deg] of that body: a ``pyproj.CRS``."""
    from pyproj import CRS
    from pyproj.crs import ProjectedCRS
    from pyproj.crs.coordinate_operation import TransverseMercatorConversion

    geo = CRS.from_user_input(crs).geodetic_crs
    conv = TransverseMercatorConversion(latitude_natural_origin=round(lat0, 6),
                                        longitude_natural_origin=round(lon0, 6),
                                        false_easting=0.0, false_northing=0.0,
                                        scale_factor_natural_origin=1.0)
    name = f"skyfix local transverse Mercator at {lat0:.4f}, {lon0:.4f} on {geo.name}"
    return ProjectedCRS(conversion=conv, geodetic_crs=geo, name=name)


def utm_crs_for(lon: float, lat: float):
    """The WGS 84 UTM zone CRS containing (lon, lat) [deg]."""
    from pyproj import CRS

    zone = int((lon + 180.0) // 6.0) % 60 + 1
    return CRS.from_epsg((32600 if lat >= 0 else 32700) + zone)


def earth_work_crs(src_crs, src_bounds):
    """The work CRS of an Earth DEM in ``src_crs`` over ``src_bounds`` (xmin, ymin, xmax, ymax in
    that CRS): the UTM zone of its centre where that stretches distances by at most 0.1 % over
    it (a coordinate system users know), else a transverse Mercator centred on it (a DEM across
    a zone's edge)."""
    from pyproj import CRS, Transformer

    src = CRS.from_user_input(src_crs)
    w, s, e, n = (src_bounds if src.is_geographic else geographic_bounds(src, src_bounds))
    lon0 = mid_longitude(w, e)
    utm = utm_crs_for(lon0, (s + n) / 2)
    try:
        b = Transformer.from_crs(src, utm, always_xy=True).transform_bounds(*src_bounds)
    except Exception:  # noqa: BLE001 - pyproj raises several types for bounds it cannot carry
        b = None
    if b is not None and scale_error(utm, b) <= MAX_SCALE_ERROR:
        return utm
    return local_tm_crs(src, lon0, (s + n) / 2)


def _worst_factor(crs, bounds, n: int, of) -> float:
    """The largest of the values ``of(factors)`` gives (a tuple) over ``bounds`` (xmin, ymin, xmax,
    ymax) [m] of a projected ``crs``: PROJ's factors on an n x n grid of points, on the CRS's own
    body, from 0. NaN where PROJ cannot say."""
    from pyproj import CRS, Proj, Transformer

    c = CRS.from_user_input(crs)
    try:
        to_geo = Transformer.from_crs(c, c.geodetic_crs, always_xy=True)
        proj = Proj(c)
        xs = [bounds[0] + (bounds[2] - bounds[0]) * i / (n - 1) for i in range(n)]
        ys = [bounds[1] + (bounds[3] - bounds[1]) * i / (n - 1) for i in range(n)]
        worst = 0.0
        for x in xs:
            for y in ys:
                worst = max(worst, *of(proj.get_factors(*to_geo.transform(x, y))))
        return worst
    except Exception:  # noqa: BLE001 - pyproj raises several types for a CRS it cannot use
        return float("nan")


def scale_error(crs, bounds, n: int = 5) -> float:
    """The largest |scale - 1| [fraction] of a projected ``crs`` over ``bounds`` (xmin, ymin, xmax,
    ymax) [m], in any direction: the Tissot indicatrix's two semi-axes on an n x n grid of
    points, on the CRS's own body (PROJ's factors). Not the meridional and parallel scales
    alone: where meridians and parallels are not perpendicular (sinusoidal, a common Mars DEM
    projection) those stay near 1 while the shear stretches other directions (a Mars DEM over
    lon 77.5-79, lat 17.5-19 in a sinusoidal projection centred on 77.5 E: 0.004 % against
    0.43 %). NaN where PROJ cannot say."""
    return _worst_factor(crs, bounds, n, lambda f: (abs(f.tissot_semimajor - 1.0),
                                                    abs(f.tissot_semiminor - 1.0)))


def direction_error_deg(crs, bounds, n: int = 5) -> float:
    """The largest angle [deg] by which a projected ``crs`` turns a direction over ``bounds``
    (xmin, ymin, xmax, ymax) [m], beyond its meridian convergence: half PROJ's maximum angular
    distortion, on an n x n grid of points. 0 for a conformal CRS (UTM, transverse Mercator);
    an equal-area one turns directions where its two scales differ (USA Albers over the Sierra
    Nevada: 0.55 deg). A narrow view's heading is off by up to as much. NaN where PROJ cannot
    say."""
    return _worst_factor(crs, bounds, n, lambda f: (0.5 * f.angular_distortion,))


def geographic_bounds(crs, bounds):
    """(west, south, east, north) [deg on the CRS's body] of projected ``bounds`` [m]."""
    from pyproj import CRS, Transformer

    c = CRS.from_user_input(crs)
    t = Transformer.from_crs(c, c.geodetic_crs, always_xy=True)
    return t.transform_bounds(*bounds)


def lonlat_to_xy(crs, lon: float, lat: float):
    """(x, y) [m] in the work CRS ``crs`` of a longitude/latitude [deg] on its body."""
    from pyproj import CRS, Transformer

    c = CRS.from_user_input(crs)
    x, y = Transformer.from_crs(c.geodetic_crs, c, always_xy=True).transform(lon, lat)
    if not (math.isfinite(x) and math.isfinite(y)):
        from .errors import ParameterError

        raise ParameterError(f"lon {lon}, lat {lat} cannot be placed in {c.name}")
    return float(x), float(y)


#: [m] the international foot and the US survey foot
FOOT_M = 0.3048
US_SURVEY_FOOT_M = 1200.0 / 3937.0
#: names a band (GDAL's unit type) or a CRS axis gives its unit -> [m] per unit: heights and
#: coordinates in feet are read in metres; any other unit is refused (a guess would be a wrong DEM)
LENGTH_UNITS_M = {
    **dict.fromkeys(("m", "metre", "meter", "metres", "meters"), 1.0),
    **dict.fromkeys(("ft", "foot", "feet", "international foot", "ft_intl"), FOOT_M),
    **dict.fromkeys(("us-ft", "us_ft", "ftus", "us survey foot", "us survey feet", "survey foot",
                     "foot_us", "us_survey_foot"), US_SURVEY_FOOT_M),
}


def horizontal_crs(crs):
    """The horizontal part of ``crs`` (a compound CRS's first member), a ``pyproj.CRS``."""
    from pyproj import CRS

    c = CRS.from_user_input(crs)
    return c.sub_crs_list[0] if c.is_compound and c.sub_crs_list else c


def metric_twin(crs):
    """The projection of the projected ``crs`` on its datum with its axes in metres, named by its
    EPSG code where PROJ finds one (UTM zone 7N in feet -> EPSG:32607). Its coordinates are the
    feet ones times the foot: the same grid, no resampling."""
    from pyproj import CRS
    from pyproj.crs import ProjectedCRS

    h = horizontal_crs(crs)
    twin = ProjectedCRS(conversion=h.coordinate_operation, geodetic_crs=h.geodetic_crs,
                        name=f"{h.name} (metres)")
    auth = twin.to_authority(min_confidence=90)
    return CRS.from_authority(*auth) if auth else twin


def units_in_metres(band_unit: str | None, crs, name: str) -> tuple[float, float]:
    """[m] per unit of a DEM's heights and of its ``crs``'s coordinates (1.0, 1.0 for a metric
    DEM). The heights' unit is the band's (``band_unit``), else a compound CRS's vertical axis';
    unsaid it is metres, except in a CRS whose coordinates are not: a DEM in feet holds heights
    in feet as often as in metres, 3.3 x apart, so there it must be said, never guessed. The
    coordinates' unit is PROJ's, exact whatever its name."""
    from pyproj import CRS

    from .errors import DemError

    c = CRS.from_user_input(crs)
    vertical = next((s for s in c.sub_crs_list if s.is_vertical), None) if c.is_compound else None
    zunit = (band_unit or "").strip() or (vertical.axis_info[0].unit_name if vertical else None)
    zf = LENGTH_UNITS_M.get(zunit.lower()) if zunit else 1.0
    if zf is None:
        raise DemError(f"{name}'s heights are in {zunit!r}, not metres or feet: convert them to metres "
                       f"(e.g. `gdal_calc.py -A {name} --calc 'A*1000' --outfile OUT.tif` for km) "
                       "and retry")
    h = horizontal_crs(c)
    hf = float(h.axis_info[0].unit_conversion_factor) if h.is_projected else 1.0
    if abs(hf - 1.0) <= 1e-12:
        return zf, 1.0
    if not zunit:
        raise DemError(f"{name}: its CRS {crs_label(c)} is in {h.axis_info[0].unit_name} and the file "
                       f"does not say the unit of its heights: say it (gdal_edit.py -units ft {name} "
                       f"for feet, -units us-ft for US survey feet, -units m for metres) and skyfix "
                       f"reads it in metres, in "
                       f"{crs_label(metric_twin(c))}")
    return zf, hf


def crs_label(crs) -> str:
    """A short name of ``crs`` for a message: its authority code (``EPSG:32607``), else its name,
    else its PROJ string (a CRS built from one is named "unknown", which says nothing)."""
    from pyproj import CRS

    c = CRS.from_user_input(crs)
    auth = c.to_authority(min_confidence=70)
    if auth:
        return f"{auth[0]}:{auth[1]}"
    if c.name and c.name.lower() != "unknown":
        return c.name
    import warnings

    with warnings.catch_warnings():  # "you will likely lose information": it is only a label
        warnings.simplefilter("ignore")
        return c.to_proj4() or c.name or "an unnamed CRS"


def fits_lonlat(xs, ys) -> bool:
    """Whether every x could be a longitude (|x| <= 360: east longitudes up to 360 pass, as
    Mars's are often given) and every y a latitude (|y| <= 90) [deg]."""
    return bool(np.all(np.abs(np.asarray(xs, float)) <= 360.0)
                and np.all(np.abs(np.asarray(ys, float)) <= 90.0))


def check_lonlat_extent(crs, bounds, name: str) -> None:
    """Refuse a raster whose CRS is geographic while its coordinates (``bounds``: xmin, ymin,
    xmax, ymax) cannot be longitudes and latitudes: beyond +-360 and +-90 deg they are metres
    (or feet) under a wrong label, and reprojecting them fails deep inside GDAL ("Too many
    points failed to transform") with no word on the cause. East longitudes up to 360 pass
    (Mars's are often given so)."""
    from pyproj import CRS

    from .errors import DemError

    if not CRS.from_user_input(crs).is_geographic:
        return
    w, s, e, n = bounds
    if fits_lonlat((w, e), (s, n)):
        return
    raise DemError(f"{name}: its CRS {crs_label(crs)} is geographic but its coordinates x {w:.10g}..{e:.10g}, "
                   f"y {s:.10g}..{n:.10g} are not longitudes and latitudes: the file's CRS is wrong; set the "
                   f"right one (gdal_edit.py -a_srs EPSG:XXXX {name}, with the code of the projection "
                   "its coordinates are in)")


def check_projected_extent(crs, bounds, cell, name: str) -> None:
    """Refuse a raster whose CRS is projected while its coordinates (``bounds``) fit longitudes
    and latitudes and its cells (``cell``, in the CRS's unit) are under a millimetre: degrees
    under a projected label (a 3-arcsecond tile read as a 100 m wide DEM of 0.8 mm cells),
    which no real DEM is."""
    from pyproj import CRS

    from .errors import DemError

    if not CRS.from_user_input(crs).is_projected:
        return
    w, s, e, n = bounds
    if not (fits_lonlat((w, e), (s, n)) and abs(cell) < 1e-3):
        return
    raise DemError(f"{name}: its CRS {crs_label(crs)} is projected but its coordinates x {w:.10g}..{e:.10g}, "
                   f"y {s:.10g}..{n:.10g} with cells of {abs(cell):.3g} look like longitudes and "
                   "latitudes: the file's CRS is wrong; set the right one (gdal_edit.py -a_srs "
                   f"EPSG:4326 {name} for WGS 84 degrees, or the geographic CRS of its body)")


@contextmanager
def reprojection_errors(name: str, src_crs, dst_crs, *, chosen: bool = False):
    """Turn GDAL's refusal to carry a raster from ``src_crs`` to ``dst_crs`` ("Too many points
    (441 out of 441) failed to transform") into a :class:`~skyfix.errors.DemError` that names
    the file, both CRSs and the likely cause: a ``dst_crs`` the user ``chosen`` that does not
    cover the DEM, else coordinates that are not in the CRS the file says. Only GDAL's own
    errors (rasterio's ``CPLE_*``, which rasterio does not export) are turned."""
    from .errors import DemError

    try:
        yield
    except Exception as e:  # noqa: BLE001 - narrowed below to GDAL's errors
        if not (type(e).__name__.startswith("CPLE_") and type(e).__module__.startswith("rasterio")):
            raise
        why = str(e).splitlines()[0].rstrip(".") if str(e) else type(e).__name__
        todo = ("give a --crs that covers where the DEM lies (e.g. its UTM zone)" if chosen else
                f"its coordinates are likely not in the CRS it says: check them with gdalinfo {name} "
                f"and set the right CRS (gdal_edit.py -a_srs EPSG:XXXX {name})")
        raise DemError(f"{name}: cannot reproject it from {crs_label(src_crs)} to {crs_label(dst_crs)} "
                       f"(GDAL: {why}): {todo}") from None


def as_typed(v) -> str:
    """A coordinate in a message as the user would have typed it: -139.15, 601000, 60.81938 (12
    significant digits: rounding to 0.1 hid that -139.15 was a longitude)."""
    return f"{float(v):.12g}"


def lonlat_hint(xs, ys, bounds, dem: str = "DEM", lonlat_options: str = "") -> str:
    """A hint for a point refused as outside a DEM: where every (x, y) could be a longitude and a
    latitude (|x| <= 360, |y| <= 90) while the DEM's extent ``bounds`` (xmin, ymin, xmax, ymax)
    [m] lies wholly beyond that range, degrees were typed where metres are expected; ''
    otherwise (a DEM in a local CRS near its origin cannot tell the two apart). ``lonlat_options``
    names the command's own options for degrees, if it has them."""
    xs = np.atleast_1d(np.asarray(xs, float))
    ys = np.atleast_1d(np.asarray(ys, float))
    if not fits_lonlat(xs, ys):
        return ""
    if not (np.any(xs) or np.any(ys)):  # (0, 0) is a placeholder or an origin, not a place
        return ""
    xmin, ymin, xmax, ymax = bounds
    if xmax >= -360.0 and xmin <= 360.0 and ymax >= -90.0 and ymin <= 90.0:
        return ""
    return ("; these look like longitude/latitude: give metres in the work CRS (`skyfix info "
            f"{dem}` shows its extent)" + (f", or give them with {lonlat_options}" if lonlat_options
                                            else ""))


def source_footprint(src_crs, src_transform, src_shape, dst_crs, dst_transform, dst_shape):
    """Boolean (ny, nx) mask of the destination cells whose centre falls on the source raster,
    whatever the source holds there (its no-data included)."""
    from rasterio.warp import Resampling, reproject

    ones = np.ones(src_shape, np.uint8)
    fp = np.zeros(dst_shape, np.uint8)
    # Nearest on an all-ones raster with no source nodata: a cell is 1 exactly where the warper
    # found a source pixel under it, i.e. inside the source extent; 0 is the warp's own wedge.
    reproject(ones, fp, src_transform=src_transform, src_crs=src_crs, src_nodata=None,
              dst_transform=dst_transform, dst_crs=dst_crs, dst_nodata=0,
              resampling=Resampling.nearest)
    return fp.astype(bool)


def crop_to_footprint(z: np.ndarray, footprint: np.ndarray, transform, name: str = "DEM"):
    """Crop a reprojected grid to the north-up rectangle that bounds the source footprint, every
    cell outside the footprint set to NaN: no terrain there, never a void to fill.

    A reprojection turns the source's rectangle into a rotated or curved shape inside a larger
    grid. Only the rows and columns that hold no source cell go; the wedges in the corners stay,
    marked, so that rays still reach every bit of the source's terrain (the largest rectangle
    inside the footprint kept 70 % of the Sierra DEM read into UTM, and its skylines ended 12.7-13.7
    km out where the terrain goes on to 16.5 km). Only ``footprint`` decides, never NaN in ``z``:
    voids inside the footprint stay, to be filled. Returns the cropped copy of ``z``, the cropped
    footprint and the grid's transform.
    """
    from rasterio.transform import Affine

    from .errors import DemError

    rows = np.flatnonzero(footprint.any(axis=1))
    cols = np.flatnonzero(footprint.any(axis=0))
    if rows.size < 2 or cols.size < 2:
        raise DemError(f"{name}: once reprojected, it covers less than 2 x 2 cells: pass --crs with a "
                       "metric CRS in which the DEM keeps its extent (e.g. its UTM zone)")
    r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    fp = footprint[r0:r1, c0:c1].copy()
    out = np.where(fp, z[r0:r1, c0:c1], np.nan)
    return out, fp, transform @ Affine.translation(c0, r0)
