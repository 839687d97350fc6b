"""Stage 1: read a DEM, bring it to a metric CRS, fill small voids, build a max pyramid.

Grid convention: ``z[i, j]`` is the height [m] at the centre of pixel (row i, column j), at
``x = x0 + j * dx`` and ``y = y0 - i * dy`` (row 0 is north). Heights between pixel centres are
bilinear; the usable area is the hull of pixel centres, :attr:`Dem.bounds`, where heights are
known. NaN is no height: a void left unfilled, or a cell around the data (a reprojection's wedges,
a raster's no-data collar): rays see no terrain there, and no position stands there.
"""

from __future__ import annotations

import hashlib
import logging
import math
import shlex
from functools import cached_property
from pathlib import Path

import numpy as np

from .errors import DemError, OutsideDemError, ParameterError
from .heights import check_heights, pds3_unit
from .planets import EARTH, planet_from_crs
from .voids import VoidReport, collar_cells, fill_voids
from .workcrs import (MAX_SCALE_ERROR, as_typed, check_lonlat_extent, check_projected_extent,
                      crop_to_footprint, crs_label, direction_error_deg, earth_work_crs,
                      geographic_bounds, horizontal_crs, local_tm_crs, lonlat_hint, metric_twin,
                      mid_longitude,
                      reprojection_errors, scale_error, source_footprint, units_in_metres)

log = logging.getLogger(__name__)

#: [fraction] the largest scale error of the work CRS skyfix picks for a DEM: beyond it the DEM
#: spans too much of its body for any one metric CRS (a UTM zone keeps 5 % within ~2000 km of its
#: central meridian)
MAX_WORK_SCALE_ERROR = 0.05


class Dem:
    """A north-up DEM in a metric CRS.

    z : float32 (ny, nx) heights [m], NaN where unknown
    x0, y0 : [m] coordinates of the centre of pixel (0, 0)
    dx, dy : [m] pixel size along x (east) and y (south), both > 0
    crs_wkt : the projected CRS as WKT; crs_name a short name (``EPSG:32611``) where one exists
    body : the :class:`skyfix.planets.Planet` the CRS lives on (None when unknown: Earth is assumed)
    scale_error : largest |scale - 1| [fraction] of the CRS over the DEM (NaN when not measured)
    """

    def __init__(self, z, x0, y0, dx, dy, crs_wkt="", crs_name="", *, source="", checksum="",
                 voids: VoidReport | None = None, body=None, scale_error: float = float("nan")):
        z = np.ascontiguousarray(z, dtype=np.float32)
        if z.ndim != 2 or min(z.shape) < 2:
            raise DemError(f"a DEM must be a 2-D grid of at least 2 x 2 cells, got shape {z.shape}")
        if not (dx > 0 and dy > 0):
            raise DemError(f"DEM pixel size must be positive, got dx={dx}, dy={dy}")
        self.z = z
        self.x0, self.y0, self.dx, self.dy = float(x0), float(y0), float(dx), float(dy)
        self.crs_wkt = crs_wkt
        self.crs_name = crs_name
        self.source = str(source)
        self.checksum = checksum or hashlib.sha256(z.tobytes()).hexdigest()
        self.voids = voids or VoidReport()
        self.body = body
        self.scale_error = float(scale_error)

    # --- geometry ------------------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int]:
        return self.z.shape

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) [m] of the pixel-centre hull, where heights are defined."""
        ny, nx = self.z.shape
        return (self.x0, self.y0 - (ny - 1) * self.dy, self.x0 + (nx - 1) * self.dx, self.y0)

    @property
    def cell_m(self) -> float:
        """Nominal cell size [m] (the larger of dx, dy)."""
        return max(self.dx, self.dy)

    def xy_to_colrow(self, x, y):
        """Fractional (column, row) of world coordinates [m]."""
        return (np.asarray(x, float) - self.x0) / self.dx, (self.y0 - np.asarray(y, float)) / self.dy

    def colrow_to_xy(self, col, row):
        return self.x0 + np.asarray(col, float) * self.dx, self.y0 - np.asarray(row, float) * self.dy

    def contains(self, x, y, margin_m: float = 0.0):
        """True where (x, y) [m] lies inside :attr:`bounds` shrunk by ``margin_m``."""
        xmin, ymin, xmax, ymax = self.bounds
        x = np.asarray(x, float)
        y = np.asarray(y, float)
        return (x >= xmin + margin_m) & (x <= xmax - margin_m) & (y >= ymin + margin_m) & (y <= ymax - margin_m)

    def height_at(self, x, y):
        """Bilinear height [m] at (x, y) [m]; NaN outside the DEM or next to a void."""
        col, row = self.xy_to_colrow(x, y)
        col, row = np.broadcast_arrays(col, row)
        ny, nx = self.z.shape
        out = np.full(col.shape, np.nan)
        ok = (col >= 0) & (col <= nx - 1) & (row >= 0) & (row <= ny - 1)
        c, r = col[ok], row[ok]
        j = np.minimum(np.floor(c).astype(np.int64), nx - 2)
        i = np.minimum(np.floor(r).astype(np.int64), ny - 2)
        fu, fv = c - j, r - i
        z = self.z
        # a corner of weight 0 is left out: on a grid line beside a void the height is the
        # line's own, as it is beside a void on the line's other side
        out[ok] = sum(np.where(w == 0.0, 0.0, z[a, b] * w) for a, b, w in (
            (i, j, (1 - fu) * (1 - fv)), (i, j + 1, fu * (1 - fv)), (i + 1, j, (1 - fu) * fv),
            (i + 1, j + 1, fu * fv)))
        return out if out.ndim else float(out)

    def require_inside(self, x, y, what: str = "point", lonlat_options: str = "") -> None:
        """Raise :class:`OutsideDemError` unless every (x, y) lies inside with a known height; where
        the values look like degrees, say so (``lonlat_options``: the command's own options for
        degrees, :func:`~skyfix.workcrs.lonlat_hint`)."""
        x = np.atleast_1d(np.asarray(x, float))
        y = np.atleast_1d(np.asarray(y, float))
        inside = self.contains(x, y)
        if not inside.all():
            k = int(np.flatnonzero(~inside)[0])
            xmin, ymin, xmax, ymax = self.bounds
            raise OutsideDemError(
                f"{what} ({as_typed(x[k])}, {as_typed(y[k])}) is outside the DEM: valid x "
                f"{xmin:.1f}..{xmax:.1f}, y {ymin:.1f}..{ymax:.1f} in {self.crs_name or 'the DEM CRS'}"
                + lonlat_hint(x, y, self.bounds, self.source or "DEM", lonlat_options))
        h = self.height_at(x, y)
        if not np.all(np.isfinite(h)):
            k = int(np.flatnonzero(~np.isfinite(h))[0])
            raise OutsideDemError(f"{what} ({as_typed(x[k])}, {as_typed(y[k])}) has no height on the "
                                  "DEM: it falls in a void or outside the DEM's data")

    # --- far-field acceleration ------------------------------------------------------------------
    @cached_property
    def pyramid(self) -> list[np.ndarray]:
        """Max pyramid over bilinear cells: level 0 ``(ny-1, nx-1)`` holds the maximum of each cell's
        four corner heights, level L+1 the maximum of 2 x 2 blocks of level L. Voids are ignored
        (-inf where a block has no height). Because bilinear heights never exceed their corners, a
        block's value bounds every height inside it: a far ridge is never lost."""
        return build_max_pyramid(self.z)

    def packed_pyramid(self):
        """The pyramid flattened for numba: (data, offsets, rows, cols)."""
        levels = self.pyramid
        offs = np.cumsum([0] + [lv.size for lv in levels[:-1]]).astype(np.int64)
        data = np.concatenate([lv.ravel() for lv in levels]).astype(np.float32)
        rows = np.array([lv.shape[0] for lv in levels], np.int64)
        cols = np.array([lv.shape[1] for lv in levels], np.int64)
        return data, offs, rows, cols

    def describe(self) -> str:
        ny, nx = self.z.shape
        zmin, zmax = np.nanmin(self.z), np.nanmax(self.z)
        return (f"{Path(self.source).name or 'DEM'}: {nx} x {ny} cells of {self.dx:g} x {self.dy:g} m, "
                f"{self.crs_name or 'custom CRS'}, heights {zmin:.0f}..{zmax:.0f} m, {self.voids}")

    # --- constructors ----------------------------------------------------------------------------
    @classmethod
    def from_array(cls, z, spacing_m: float, x0: float = 0.0, y0: float | None = None,
                   crs: str | None = None) -> "Dem":
        """A DEM from an array (row 0 north) with square cells; handy for tests and demos.

        ``y0`` defaults to ``(ny - 1) * spacing_m`` so that the south-west pixel centre is at (x0, 0).
        ``crs`` defaults to a transverse Mercator on WGS 84 whose origin is (0, 0) (at 0 N,
        117 W): true to scale near there, as a work CRS must be (a UTM zone's (0, 0) lies 500 km
        off its meridian, 0.27 % stretched, and would be reprojected on reading).
        """
        from pyproj import CRS

        z = np.asarray(z, np.float32)
        if y0 is None:
            y0 = (z.shape[0] - 1) * spacing_m
        c = CRS.from_user_input(crs) if crs is not None else local_tm_crs("EPSG:4326", -117.0, 0.0)
        return cls(z, x0, y0, spacing_m, spacing_m, c.to_wkt(), crs_label(c), body=planet_from_crs(c))


def build_max_pyramid(z: np.ndarray) -> list[np.ndarray]:
    """See :attr:`Dem.pyramid`."""
    zz = np.where(np.isfinite(z), z, -np.inf).astype(np.float32)
    cell = np.maximum(np.maximum(zz[:-1, :-1], zz[:-1, 1:]), np.maximum(zz[1:, :-1], zz[1:, 1:]))
    levels = [cell]
    while max(levels[-1].shape) > 1:
        a = levels[-1]
        ny, nx = a.shape
        pad = np.full((ny + ny % 2, nx + nx % 2), -np.inf, np.float32)
        pad[:ny, :nx] = a
        levels.append(np.maximum(np.maximum(pad[0::2, 0::2], pad[0::2, 1::2]),
                                 np.maximum(pad[1::2, 0::2], pad[1::2, 1::2])))
    return levels


def file_checksum(path, chunk: int = 1 << 20) -> str:
    """SHA-256 of a file's bytes (hex)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while b := f.read(chunk):
            h.update(b)
    return h.hexdigest()


def load_dem(path, *, crs: str | None = None, resolution_m: float | None = None,
             fill_max_cells: int = 100) -> Dem:
    """Read a GeoTIFF (any raster rasterio reads) as a north-up metric :class:`Dem`.

    path : DEM file
    crs : target CRS (``EPSG:…``, WKT, PROJ); default (:mod:`skyfix.workcrs`): the DEM's own when
        projected in metres with a scale error within 0.1 % over the DEM; else a transverse
        Mercator on the DEM's body centred on it (on Earth: the UTM zone of the DEM's centre where
        that is within 0.1 % over it, :func:`~skyfix.workcrs.earth_work_crs`; a projected Earth
        DEM so read is said with a warning, its coordinates being the user's). A given ``crs``
        is used as is, with a warning if it stretches distances by more than 0.1 % over the DEM.
        The body (:attr:`Dem.body`) comes from the CRS's datum. A CRS in feet is read in the
        same projection in metres (said with a warning: coordinates are given in it). Heights are
        metres: a band scale and offset are applied; heights in feet (the band's unit or a
        compound CRS's vertical unit) are converted; any other unit is refused, and so are
        heights of no said unit in a CRS in feet (:func:`~skyfix.workcrs.units_in_metres`)
    resolution_m : [m] pixel size when reprojecting; default about the native size. A reprojected
        grid keeps the north-up rectangle around the source raster's footprint, the cells outside
        it no-data (NaN, no terrain: :attr:`Dem.voids` counts them ``n_outside``)
    fill_max_cells : [cells] voids are filled by inverse-distance interpolation when a valid height
        lies within this many cells; larger voids stay masked (NaN) and are reported, as does a
        raster's no-data collar (the voids outside the convex hull of its heights)
    """
    import rasterio
    from pyproj import CRS
    from rasterio.errors import RasterioIOError
    from rasterio.transform import Affine

    path = Path(path)
    if not path.exists():
        raise DemError(f"DEM file {path} does not exist")
    if fill_max_cells < 0:
        raise ParameterError("fill_max_cells must be >= 0")
    import warnings

    try:
        with warnings.catch_warnings():
            # an image without georeferencing makes rasterio warn, with its source line, before the
            # clear refusal below says the same
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            src = rasterio.open(path)
    except RasterioIOError as e:
        raise DemError(f"cannot read {path} as a raster ({e}); give a GeoTIFF DEM") from None
    with src:
        if src.crs is None:
            raise DemError(
                f"{path} has no CRS: assign one (e.g. `gdal_edit.py -a_srs EPSG:32611 {path.name}`) "
                "so positions mean something"
            )
        src_crs = CRS.from_user_input(src.crs.to_wkt())
        check_lonlat_extent(src_crs, src.bounds, path.name)  # before a transform trips on it
        check_projected_extent(src_crs, src.bounds, src.res[0], path.name)
        advise = False  # a projected Earth DEM read into its UTM zone: say how to write it once
        zfactor, xyfactor = units_in_metres((src.units or (None,))[0] or pds3_unit(src),
                                            src_crs, path.name)
        transform, bounds = src.transform, tuple(src.bounds)
        # (xmin, ymin, xmax, ymax) whichever way the raster runs: one running east to west gave
        # left > right, and a traceback
        bounds = (min(bounds[0], bounds[2]), min(bounds[1], bounds[3]),
                  max(bounds[0], bounds[2]), max(bounds[1], bounds[3]))
        if xyfactor != 1.0:
            # A CRS in feet is read in the same projection in metres: its coordinates times the
            # foot, the very grid (no resampling). The user's coordinates change: said each time.
            metric = metric_twin(src_crs)
            log.warning("%s: its CRS %s is in %s: read in %s, the same projection in metres, in "
                        "which coordinates are given (the file's x and y times %.10g)%s", path.name,
                        crs_label(src_crs), horizontal_crs(src_crs).axis_info[0].unit_name,
                        crs_label(metric), xyfactor,
                        f"; heights times {zfactor:.10g}" if zfactor != 1.0 else "")
            src_crs, transform = metric, Affine.scale(xyfactor) @ transform
            bounds = tuple(v * xyfactor for v in bounds)
        elif zfactor != 1.0:
            log.info("%s: heights in feet, read in metres (times %.10g)", path.name, zfactor)
        if np.dtype(src.dtypes[0]).kind == "c":
            raise DemError(f"{path} holds complex numbers, not heights: give a DEM of real heights")
        if src.count > 1:
            log.warning("%s has %d bands: its heights are taken from band 1", path.name, src.count)
        try:
            band = src.read(1, masked=True).astype(np.float64)
        except RasterioIOError as e:  # "Read failed", naming neither the file nor the cause
            raise DemError(f"cannot read the heights of {path} ({e.__cause__ or e}): the file is "
                           "truncated or damaged; give a whole copy") from None
        z = band.filled(np.nan)
        z[~np.isfinite(z)] = np.nan
        scale, offset = (src.scales or (1.0,))[0], (src.offsets or (0.0,))[0]
        if scale not in (None, 1.0) or offset not in (None, 0.0):
            z = z * (scale if scale is not None else 1.0) + (offset or 0.0)
            log.info("%s: band scale %s and offset %s applied to the heights", path.name, scale, offset)
        z = z * zfactor if zfactor != 1.0 else z
        body = planet_from_crs(src_crs)
        check_heights(z, path, body)
        if crs is not None:
            try:
                dst_crs = CRS.from_user_input(crs)
            except Exception as e:  # pyproj raises CRSError, a plain Exception subclass
                raise ParameterError(f"cannot understand CRS {crs!r}: {e}") from None
        elif src_crs.is_geographic:
            if body is EARTH:
                dst_crs = earth_work_crs(src_crs, bounds)
            else:
                west, south, east, north = bounds
                dst_crs = local_tm_crs(src_crs, (west + east) / 2, (south + north) / 2)
        else:
            dst_crs = src_crs
            err = scale_error(src_crs, bounds)
            if err > MAX_SCALE_ERROR:
                if body is not EARTH:
                    w, s, e, n = geographic_bounds(src_crs, bounds)
                    dst_crs = local_tm_crs(src_crs, mid_longitude(w, e), (s + n) / 2)
                    log.info("%s: %s stretches distances by up to %.2f %% over the DEM: "
                             "reprojected to %s", path.name, crs_label(src_crs),
                             100 * err, dst_crs.name)
                else:
                    # Not kept: a 1 % stretch bends horizons, and a CRS that is not conformal
                    # turns directions no meridian convergence undoes (the Sierra's USA Albers put
                    # a full turn's true-north heading 0.3-0.4 deg off). Coordinates are the
                    # user's, so this is said every time.
                    dst_crs = earth_work_crs(src_crs, bounds)
                    turn = direction_error_deg(src_crs, bounds)
                    log.warning("%s: %s stretches distances by up to %.2f %% over the DEM (more than "
                                "%.1f %%)%s: reprojected to %s, in which coordinates are given",
                                path.name, crs_label(src_crs), 100 * err,
                                100 * MAX_SCALE_ERROR,
                                f" and turns directions by up to {turn:.2f} deg" if turn >= 0.01
                                else "", crs_label(dst_crs))
                    advise = True
        if not dst_crs.is_projected or abs(dst_crs.axis_info[0].unit_conversion_factor - 1.0) > 1e-9:
            # only a CRS asked for can be so: skyfix's own choices are metric
            raise ParameterError(f"the CRS asked for, {crs_label(dst_crs)}, is not projected in metres "
                                 f"(its unit: {dst_crs.axis_info[0].unit_name}): give a metric "
                                 "projected CRS (e.g. the DEM's UTM zone)")
        north_up = transform.b == 0 and transform.d == 0 and transform.a > 0 and transform.e < 0
        if dst_crs != src_crs or not north_up or (resolution_m and resolution_m != abs(transform.a)):
            with reprojection_errors(path.name, src_crs, dst_crs, chosen=crs is not None):
                z, transform, outside = _reproject(z, transform, src_crs, bounds, dst_crs,
                                                   resolution_m, path.name, check_spread=crs is None)
            log.info("reprojected %s from %s to %s", path.name, crs_label(src_crs), crs_label(dst_crs))
            if advise and zfactor == 1.0:  # (gdalwarp would keep heights in feet: no advice)
                # the very grid read here, its wedges no-data (not 0, gdalwarp's default fill for a
                # source without nodata); read back, they are no terrain again (:func:`~skyfix.voids.collar_cells`)
                xmin, ymax = transform.c, transform.f
                xmax, ymin = xmin + z.shape[1] * transform.a, ymax + z.shape[0] * transform.e
                log.warning("%s: to read this grid without reprojecting it each time, write it once: "
                            "gdalwarp -t_srs %s -te %.3f %.3f %.3f %.3f -tr %.6f %.6f -r bilinear "
                            "-ot Float32 -dstnodata -99999 %s OUT.tif", path.name,
                            shlex.quote(crs_label(dst_crs)),
                            xmin, ymin, xmax, ymax, transform.a, -transform.e, path.name)
        else:
            outside = None
    voids = fill_voids(z, fill_max_cells, outside)
    dx, dy = transform.a, -transform.e
    dem = Dem(z, transform.c + dx / 2, transform.f - dy / 2, dx, dy, dst_crs.to_wkt(),
              crs_label(dst_crs), source=str(path), checksum=file_checksum(path), voids=voids,
              body=body)
    xmin, ymin, xmax, ymax = dem.bounds
    dem.scale_error = scale_error(dst_crs, (xmin, ymin, xmax, ymax))
    if crs is not None and dem.scale_error > MAX_SCALE_ERROR:
        # The user's choice is kept, but not silently: it bends every horizon by this much.
        log.warning("%s: the requested CRS %s stretches distances by up to %.2f %% over the DEM (more "
                    "than %.1f %%): horizons are distorted by as much", path.name,
                    dem.crs_name or dst_crs.name, 100 * dem.scale_error, 100 * MAX_SCALE_ERROR)
    return dem


def _reproject(z, transform, src_crs, bounds, dst_crs, resolution_m, name, *, check_spread):
    """Heights ``z`` on ``transform`` in ``src_crs`` (over ``bounds``) reprojected into ``dst_crs``
    (bilinear; square cells of ``resolution_m``, default GDAL's, which keeps the source's pixel
    diagonal: coarser than its finer side where the cells are not square, e.g. 79.6 m for a
    3-arcsecond tile at 46 deg N whose cells are 64 x 93 m, and sqrt(2) coarser for a grid turned
    45 deg; not changed, for it would change every reprojected DEM's grid): (heights, their
    transform, the mask of cells outside the source's footprint). With ``check_spread`` a grid
    that spans too much of its body for one metric CRS is refused."""
    from rasterio.warp import Resampling, calculate_default_transform, reproject

    src_wkt, dst_wkt = src_crs.to_wkt(), dst_crs.to_wkt()
    ny, nx = z.shape
    dst_transform, w, h = calculate_default_transform(src_wkt, dst_wkt, nx, ny, *bounds,
                                                      resolution=resolution_m)
    if resolution_m is None:  # square pixels (GDAL's default already is: this keeps its size)
        res = min(abs(dst_transform.a), abs(dst_transform.e))
        dst_transform, w, h = calculate_default_transform(src_wkt, dst_wkt, nx, ny, *bounds,
                                                          resolution=res)
    if check_spread:
        x0, y0 = dst_transform.c, dst_transform.f
        x1, y1 = x0 + w * dst_transform.a, y0 + h * dst_transform.e
        spread = scale_error(dst_crs, (min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1)))
        if spread > MAX_WORK_SCALE_ERROR:
            # no one metric CRS holds a continent: every horizon would be stretched
            raise DemError(
                f"{name} spans too much of its body for one metric CRS: in "
                f"{crs_label(dst_crs)} distances stretch "
                + (f"by up to {100 * spread:.0f} %" if math.isfinite(spread) else
                   "without bound") + " over it; clip it to the area you need (e.g. "
                "gdalwarp -te XMIN YMIN XMAX YMAX, a few hundred km at most)")
    out = np.full((h, w), np.nan, np.float64)
    reproject(np.where(np.isfinite(z), z, np.nan), out, src_transform=transform,
              src_crs=src_wkt, dst_transform=dst_transform, dst_crs=dst_wkt,
              resampling=Resampling.bilinear, src_nodata=np.nan, dst_nodata=np.nan)
    # Crop by where the source raster lies, not by where heights are: the DEM's own voids
    # (7 % of an SRTM tile, some along its edges) are holes to fill, not border to cut.
    footprint = source_footprint(src_wkt, transform, z.shape, dst_wkt, dst_transform, (h, w))
    collar = collar_cells(~np.isfinite(z))
    if collar.any():  # the source's own no-data collar is no more terrain than the wedges
        moved = np.zeros((h, w), np.uint8)
        reproject(collar.astype(np.uint8), moved, src_transform=transform, src_crs=src_wkt,
                  dst_transform=dst_transform, dst_crs=dst_wkt, src_nodata=None,
                  dst_nodata=0, resampling=Resampling.nearest)
        footprint &= moved == 0
    z, footprint, dst_transform = crop_to_footprint(out, footprint, dst_transform, name)
    log.info("%s: reprojected into %d x %d cells, %.1f %% of them around the source's "
             "data (no terrain there)", name, z.shape[1], z.shape[0], 100 * (1 - footprint.mean()))
    return z, dst_transform, ~footprint


def write_dem(path, dem: Dem) -> Path:
    """Write a :class:`Dem` as a float32 GeoTIFF (NaN nodata), atomically."""
    import rasterio
    from rasterio.transform import from_origin

    from ._io import atomic_path

    path = Path(path)
    ny, nx = dem.z.shape
    transform = from_origin(dem.x0 - dem.dx / 2, dem.y0 + dem.dy / 2, dem.dx, dem.dy)
    with atomic_path(path, suffix=".tif") as tmp:
        with rasterio.open(tmp, "w", driver="GTiff", width=nx, height=ny, count=1, dtype="float32",
                           crs=dem.crs_wkt or None, transform=transform, nodata=np.nan,
                           compress="deflate") as dst:
            dst.write(dem.z, 1)
    return path


def fractal_dem(size_cells: int = 512, spacing_m: float = 30.0, *, relief_m: float = 1500.0,
                beta: float = 3.6, seed: int = 0, x0: float = 500_000.0, y0: float = 4_200_000.0,
                crs: str = "EPSG:32611") -> Dem:
    """Mountain-like terrain by spectral synthesis (power spectrum ~ f**-beta), for demos and tests
    when no real DEM is at hand.

    size_cells : grid size (square); spacing_m : [m] cell size; relief_m : [m] peak-to-trough range
    beta : spectral slope (3.4 to 3.8 looks like eroded mountains); seed : reproducible terrain
    x0, y0 : [m] coordinates of the north-west pixel centre in ``crs``
    """
    rng = np.random.default_rng(seed)
    n = int(size_cells)
    fy = np.fft.fftfreq(n)[:, None]
    fx = np.fft.rfftfreq(n)[None, :]
    f = np.hypot(fx, fy)
    f[0, 0] = 1.0
    amp = f ** (-beta / 2.0)
    amp[0, 0] = 0.0
    phase = rng.uniform(0, 2 * np.pi, amp.shape)
    z = np.fft.irfft2(amp * np.exp(1j * phase), s=(n, n))
    # Sharpen crests a little (eroded ranges have sharp ridges and rounded valleys).
    z = (z - z.min()) / (z.max() - z.min())
    z = z ** 1.5
    z = (z - z.min()) / (z.max() - z.min()) * relief_m + 1000.0
    return Dem.from_array(z.astype(np.float32), spacing_m, x0=x0, y0=y0, crs=crs)
