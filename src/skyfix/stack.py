"""Several DEMs of one place (``conventions.md``: at every point the finest DEM that covers it is
the terrain): a HiRISE-like 1 m model inside a CTX-like 20 m one inside a MOLA-like global one.

:func:`load_dems` reads them into the finest's work CRS (each coarser one reprojected there at its
own resolution) and masks in every coarser member what a finer one covers, so a ridge is taken
from the finest DEM that holds it and a ridge beyond the fine DEM's edge still comes from a
coarse one. A skyline is rendered from every member with the camera on the finest ground, each
member through its own max pyramid, and the highest terrain wins each bin
(:meth:`DemStack.render`).
"""

from __future__ import annotations

import hashlib
import logging

import numpy as np

from .dem import Dem, load_dem
from .errors import DemError
from .workcrs import MAX_SCALE_ERROR, as_typed, lonlat_hint

log = logging.getLogger(__name__)


class DemStack:
    """DEMs of one place in one work CRS, finest first. Offers the read API of
    :class:`skyfix.dem.Dem` that the pipeline uses (heights, bounds, CRS, body, checksum) on the
    finest covering member.

    A camera stands on the finest member L that holds its position; its skyline is that member's
    terrain plus every coarser member with what members L.. already cover masked out (a ray
    leaving the fine DEM goes on over the coarse one). Members finer than L do not hold the camera
    and their ground is seen through the coarse approximation."""

    def __init__(self, members: list[Dem]):
        if len(members) < 2:
            raise DemError("a DEM stack needs at least two DEMs")
        self.members = members
        self._layers: dict[int, list[Dem]] = {}
        first = members[0]
        self.crs_wkt, self.crs_name, self.body = first.crs_wkt, first.crs_name, first.body
        self.dx, self.dy = first.dx, first.dy
        self.scale_error = first.scale_error
        self.sources = [{"path": m.source, "sha256": m.checksum, "cell_m": m.cell_m} for m in members]
        self.source = " + ".join(m.source for m in members)
        self.checksum = hashlib.sha256("+".join(m.checksum for m in members).encode()).hexdigest()
        self.voids = first.voids

    # --- the Dem read API ------------------------------------------------------------------------
    @property
    def cell_m(self) -> float:
        return self.members[0].cell_m

    @property
    def shape(self):
        return self.members[0].shape

    @property
    def z(self):
        return self.members[0].z

    @property
    def bounds(self):
        """The union of the members' bounds [m] (xmin, ymin, xmax, ymax)."""
        b = np.array([m.bounds for m in self.members])
        return (float(b[:, 0].min()), float(b[:, 1].min()), float(b[:, 2].max()), float(b[:, 3].max()))

    def describe(self) -> str:
        """One line per member, finest first, as :meth:`skyfix.dem.Dem.describe` gives it."""
        return f"{len(self.members)} DEMs, the finest wins where it has heights:\n" + \
            "\n".join(f"  {m.describe()}" for m in self.members)

    def height_at(self, x, y):
        """Height [m] of the finest member with one at (x, y) [m] (NaN where none)."""
        x, y = np.asarray(x, float), np.asarray(y, float)
        out = np.full(np.broadcast(x, y).shape, np.nan)
        for m in self.members:
            need = ~np.isfinite(out)
            if not need.any():
                break
            inside = np.asarray(m.contains(x, y), bool) & need
            if inside.any():
                h = np.asarray(m.height_at(np.where(inside, x, m.x0), np.where(inside, y, m.y0)))
                out = np.where(inside & np.isfinite(h), h, out)
        return out if out.ndim else float(out)

    def contains(self, x, y, margin_m: float = 0.0):
        c = np.zeros(np.broadcast(np.asarray(x), np.asarray(y)).shape, bool)
        for m in self.members:
            c |= np.asarray(m.contains(x, y, margin_m), bool)
        return c

    def require_inside(self, x, y, what: str = "point", lonlat_options: str = "") -> None:
        """:meth:`skyfix.dem.Dem.require_inside` on the stack: a height in some member."""
        h = np.atleast_1d(self.height_at(x, y))
        if not np.all(np.isfinite(h)):
            k = int(np.flatnonzero(~np.isfinite(h))[0])
            xs, ys = np.atleast_1d(x), np.atleast_1d(y)
            b = self.bounds
            from .errors import OutsideDemError

            raise OutsideDemError(
                f"{what} ({as_typed(xs[k])}, {as_typed(ys[k])}) has no height in any DEM of the stack "
                f"(x {b[0]:.1f}..{b[2]:.1f}, y {b[1]:.1f}..{b[3]:.1f} in {self.crs_name})"
                + lonlat_hint(xs, ys, b, self.members[0].source or "DEM", lonlat_options))

    def level_of(self, x, y):
        """Index of the finest member with a height at each (x, y) [m] (-1 where none)."""
        x, y = np.atleast_1d(np.asarray(x, float)), np.atleast_1d(np.asarray(y, float))
        lev = np.full(x.shape, -1)
        for i, m in enumerate(self.members):
            need = lev < 0
            if not need.any():
                break
            inside = np.asarray(m.contains(x, y), bool) & need
            if inside.any():
                h = np.asarray(m.height_at(np.where(inside, x, m.x0), np.where(inside, y, m.y0)))
                lev = np.where(inside & np.isfinite(h), i, lev)
        return lev

    def layers(self, level: int) -> list[Dem]:
        """What a camera on member ``level`` sees: that member, then each coarser one masked where
        members ``level``.. already hold heights."""
        if level not in self._layers:
            out = [self.members[level]]
            for k in range(level + 1, len(self.members)):
                out.append(_mask_covered(self.members[k], self.members[level:k]))
            self._layers[level] = out
        return self._layers[level]

    # --- rendering -------------------------------------------------------------------------------
    def render(self, x, y, *, camera_height_m=1.5, planet=None, azimuth_bins=360,
               max_distance_m=None, skip_tol_deg=0.001):
        """:func:`skyfix.horizon.render_horizons` over the stack: for the points on each member,
        its :meth:`layers` rendered from the camera on that member's ground, the highest
        elevation per bin winning (with its terrain's distance)."""
        from .horizon import HorizonBatch, render_horizons

        x = np.atleast_1d(np.asarray(x, np.float64)).ravel()
        y = np.atleast_1d(np.asarray(y, np.float64)).ravel()
        self.require_inside(x, y)
        ground = np.atleast_1d(self.height_at(x, y)).astype(np.float64)
        bins = int(azimuth_bins)
        el = np.full((x.size, bins), np.nan, np.float32)
        dist = np.full((x.size, bins), np.nan, np.float32)
        length = np.zeros((x.size, bins), np.float32)
        lev = self.level_of(x, y)
        pl = None
        for level in np.unique(lev):
            sel = np.flatnonzero(lev == level)
            zc = ground[sel] + float(camera_height_m)
            for m in self.layers(int(level)):
                inside = np.asarray(m.contains(x[sel], y[sel]), bool)
                hb = render_horizons(m, np.where(inside, x[sel], m.x0), np.where(inside, y[sel], m.y0),
                                     camera_height_m=camera_height_m, planet=planet,
                                     azimuth_bins=bins, max_distance_m=max_distance_m,
                                     skip_tol_deg=skip_tol_deg, camera_z_m=zc)
                pl = hb.planet
                e = np.where(inside[:, None], hb.elevation_deg, np.nan)
                cur = el[sel]
                higher = np.isfinite(e) & ~(e <= np.nan_to_num(cur, nan=-np.inf))
                el[sel] = np.where(higher, e, cur)
                dist[sel] = np.where(higher, hb.skyline_distance_m, dist[sel])
                length[sel] = np.maximum(length[sel], np.where(inside[:, None], hb.ray_length_m, 0))
        return HorizonBatch(x, y, el, length, ground, float(camera_height_m),
                            float(max_distance_m or np.inf), pl, dist)


def _mask_covered(coarse: Dem, finer: list[Dem]) -> Dem:
    """``coarse`` with NaN at every node whose whole neighbourhood (the node and its 8
    neighbours) a finer member holds: every coarse cell that reaches beyond the finer members
    keeps its four corners, so no ring of terrain is lost at their edge (within that overlap the
    higher of the two surfaces wins, a fraction of a coarse cell from the fine DEM's edge)."""
    import cv2  # not scipy.ndimage: the board install (locate with several DEMs) has no scipy

    ny, nx = coarse.z.shape
    xs = coarse.x0 + np.arange(nx) * coarse.dx
    ys = coarse.y0 - np.arange(ny) * coarse.dy
    gx, gy = np.meshgrid(xs, ys)
    z = coarse.z.copy()
    for f in finer:
        inside = np.asarray(f.contains(gx, gy), bool)
        h = np.full(z.shape, np.nan)
        if inside.any():
            h[inside] = f.height_at(gx[inside], gy[inside])
        # a node is covered when it and its 8 neighbours are; beyond the grid counts as uncovered
        covered = cv2.erode(np.isfinite(h).astype(np.uint8), np.ones((3, 3), np.uint8),
                            borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
        z[covered] = np.nan
    return Dem(z, coarse.x0, coarse.y0, coarse.dx, coarse.dy, coarse.crs_wkt, coarse.crs_name,
               source=coarse.source, checksum=coarse.checksum, voids=coarse.voids, body=coarse.body,
               scale_error=coarse.scale_error)


def load_dems(paths, *, crs: str | None = None):
    """One DEM (a :class:`Dem`) or several (a :class:`DemStack`, finest first, in the finest's
    work CRS; each coarser one reprojected there at its own cell size). DEMs of two bodies, that
    do not overlap, or whose heights differ by more than :data:`MAX_MEDIAN_HEIGHT_GAP_M` in the
    median where they overlap (another unit or datum) are refused."""
    paths = [paths] if isinstance(paths, (str, bytes)) or not hasattr(paths, "__iter__") else list(paths)
    if not paths:
        raise DemError("no DEM given")
    if len(paths) == 1:
        return load_dem(paths[0], crs=crs)
    # A finer member's voids are not filled: a coarser member's heights show through them. Filled
    # by interpolation (up to 100 cells from data) they hid the coarse DEM's real terrain: a 1 m
    # DTM's 120 m void over a hilltop put the stack 27 m below it. The coarsest is filled as a
    # single DEM is (nothing lies behind it).
    first = [load_dem(p, crs=crs, fill_max_cells=0) for p in paths]
    bodies = {d.body.name if d.body is not None else "unknown" for d in first}
    if len(bodies) > 1:
        raise DemError(f"the DEMs are on different bodies ({', '.join(sorted(bodies))}): a stack "
                       "describes one place")
    order = sorted(range(len(first)), key=lambda i: first[i].cell_m)
    finest = first[order[0]]
    coarsest = order[-1]
    wide = _stack_work_crs(first, finest) if crs is None else None
    if wide is not None:
        log.info("%s: its CRS stretches distances by more than %.1f %% over the whole stack: the "
                 "stack is read in %s", paths[order[0]], 100 * MAX_SCALE_ERROR, wide.name)
        finest = first[order[0]] = load_dem(paths[order[0]], crs=wide.to_wkt(), fill_max_cells=0)
    members = [finest]
    for i in order[1:]:
        d = first[i]
        apart = DemError(f"{paths[i]} does not overlap {paths[order[0]]}: a stack describes one "
                         "place (check their CRSs and extents with skyfix info)")
        if d.crs_wkt != finest.crs_wkt:  # into the finest's work CRS, at its own resolution
            # first where each lies on the body: reading a DEM from the far side of the world
            # into the finest's CRS only to refuse it warned of its stretch before the refusal
            if not _lonlat_overlap(d, finest):
                raise apart
            d = load_dem(paths[i], crs=finest.crs_wkt, resolution_m=d.cell_m,
                         **({} if i == coarsest else {"fill_max_cells": 0}))
        elif i == coarsest:  # read as before, its voids filled
            d = load_dem(paths[i], crs=crs)
        b, f = d.bounds, finest.bounds
        if b[0] > f[2] or b[2] < f[0] or b[1] > f[3] or b[3] < f[1]:
            raise apart
        _check_heights_agree(finest, d, paths[order[0]], paths[i])
        members.append(d)
    return DemStack(members)


def _stack_work_crs(members, finest: Dem):
    """A work CRS for the whole stack when the finest member's own stretches distances by more
    than 0.1 % over the union of the members (None: keep it). The finest's projection is chosen
    over the finest alone; rays run on to the coarsest's edge, and a HiRISE DTM's equirectangular
    at its own latitude turned a 200 km MOLA DEM's far ridges by up to 0.31 deg (against 0.004 in
    a transverse Mercator). The new one is centred on the finest (where the rover is): its UTM
    zone on Earth where that holds the union within 0.1 %, else a transverse Mercator."""
    from pyproj import CRS, Transformer

    from .planets import EARTH
    from .workcrs import geographic_bounds, local_tm_crs, mid_longitude, scale_error, utm_crs_for

    boxes = []
    for d in members:
        try:
            boxes.append(geographic_bounds(d.crs_wkt, d.bounds))
        except Exception:  # noqa: BLE001 - pyproj raises several types for bounds it cannot carry
            return None
    b = np.array(boxes, float)
    if not np.all(np.isfinite(b)) or np.any(b[:, 0] > b[:, 2]):  # across the antimeridian
        return None
    union = (b[:, 0].min(), b[:, 1].min(), b[:, 2].max(), b[:, 3].max())
    own = CRS.from_wkt(finest.crs_wkt)
    geo = own.geodetic_crs

    def fits(c) -> bool:
        try:
            xy = Transformer.from_crs(geo, c, always_xy=True).transform_bounds(*union)
        except Exception:  # noqa: BLE001
            return False
        return bool(scale_error(c, xy) <= MAX_SCALE_ERROR)

    if fits(own):
        return None
    w, s, e, n = geographic_bounds(finest.crs_wkt, finest.bounds)
    lon0, lat0 = mid_longitude(w, e), (s + n) / 2
    if finest.body is EARTH:
        utm = utm_crs_for(lon0, lat0)
        if fits(utm):
            return utm
    return local_tm_crs(own, lon0, lat0)


def _lonlat_overlap(a: Dem, b: Dem) -> bool:
    """Whether the longitude/latitude boxes of two DEMs on one body meet (True where either box
    cannot be had, or crosses the antimeridian: the check in the work CRS then decides)."""
    from .workcrs import geographic_bounds

    try:
        (aw, as_, ae, an), (bw, bs, be, bn) = (geographic_bounds(d.crs_wkt, d.bounds) for d in (a, b))
    except Exception:  # noqa: BLE001 - pyproj raises several types for bounds it cannot carry
        return True
    if not np.all(np.isfinite([aw, as_, ae, an, bw, bs, be, bn])) or aw > ae or bw > be:
        return True
    return not (aw > be or ae < bw or as_ > bn or an < bs)


#: [m] the largest median height difference two members of a stack may have where they overlap.
#: A median, signed: a coarse DEM smooths ridges down and valleys up, by as much each way, so
#: the median stays near 0 however the two resolutions differ (the Alps tile against its own
#: 1 km average: 4 m, where the median |difference| is 84 m and would refuse a sound stack);
#: heights in another unit (feet: 3.3 x the metres; km) or above another datum (the geoid lies up
#: to 106 m from the ellipsoid) move it all one way. Past 50 m the step where the fine DEM ends
#: lifts or drops the coarse skyline by 0.3 deg at 10 km, hundreds of times what skyfix resolves.
MAX_MEDIAN_HEIGHT_GAP_M = 50.0


def _check_heights_agree(fine: Dem, coarse: Dem, fine_path, coarse_path) -> None:
    """Refuse two members whose heights disagree grossly where they overlap (on the fine
    member's nodes, at most ~200 x 200 of them, against the coarse member's bilinear heights)."""
    ny, nx = fine.z.shape
    step = max(1, int(np.ceil(max(ny, nx) / 200)))
    rows, cols = np.arange(0, ny, step), np.arange(0, nx, step)
    gx, gy = np.meshgrid(fine.x0 + cols * fine.dx, fine.y0 - rows * fine.dy)
    zf = fine.z[np.ix_(rows, cols)].astype(np.float64)
    inside = np.asarray(coarse.contains(gx, gy), bool) & np.isfinite(zf)
    if inside.sum() < 4:  # too little overlap to say anything
        return
    zc = np.asarray(coarse.height_at(gx[inside], gy[inside]), np.float64)
    diff = zc - zf[inside]
    diff = diff[np.isfinite(diff)]
    if diff.size < 4:
        return
    gap = float(np.median(diff))
    if abs(gap) > MAX_MEDIAN_HEIGHT_GAP_M:
        raise DemError(
            f"{coarse_path} and {fine_path} disagree on heights where they overlap: {coarse_path} "
            f"lies {abs(gap):,.0f} m {'above' if gap > 0 else 'below'} {fine_path} in the median of "
            f"{diff.size} points (more than {MAX_MEDIAN_HEIGHT_GAP_M:g} m: heights in another unit, "
            "feet or km, or above another datum?): convert one so both hold metres above one datum")
