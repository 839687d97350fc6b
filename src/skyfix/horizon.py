"""Stage 2: the skyline a DEM predicts from a point.

For each azimuth bin (bin k centred on ``k * 360 / n`` degrees, clockwise from grid north) a ray
leaves the camera horizontally and the highest elevation angle of the terrain along it is kept:
``atan((z(t) - z_cam - (1 - k) t**2 / 2R) / t)`` for distance ``t`` from ``t_min`` out to the
DEM edge or ``max_distance_m``.

Two implementations:

* :func:`render_horizons` (numba, parallel over points). Along a ray the bilinear surface inside
  one DEM cell is a quadratic in ``t``, so the elevation-angle tangent is
  ``A/t + B + C t`` there and its maximum over the cell is found in closed form (the two cell
  crossings plus one stationary point). Cells that cannot raise the current maximum are skipped
  wholesale with the DEM's max pyramid (a block's maximum bounds every height inside it), coarse
  blocks far away, fine blocks near the camera. The only approximation is ``skip_tol_deg``: a
  block is skipped when it could raise the horizon by less than that.
* :func:`reference_horizon` (NumPy, slow): samples every ray densely (0.25 m steps over the first
  cell, then every quarter cell) with bilinear heights. Tests compare the two.

A pure horizon sweep (Stewart 1998) is no substitute for this kernel: a sweep shares each line of
one azimuth among the positions near it, so a position's ray runs up to half the line spacing
sideways, an error of slope x offset / distance: degrees in the near field, and 0.06 deg at p99
with lines 5 m apart even past 100 m (Sierra, 2026-11-27). :mod:`skyfix.sweep` uses the lines only
to find *where* each position's skyline lies and maximises the position's own ray exactly there
and near it, with this module's cell maxima (``build-db --renderer sweep``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .dem import Dem
from .errors import ParameterError
from .jit import njit, prange
from .planets import EARTH, Planet, resolve_planet

#: [m] closest sample to the camera: the near field matters on slopes
T_MIN_M = 0.1


@dataclass
class HorizonBatch:
    """Rendered skylines for N points.

    elevation_deg : float32 (N, bins) [deg] skyline elevation; NaN where the ray saw no terrain
    ray_length_m : float32 (N, bins) [m] how far each ray went (the DEM edge or max distance)
    ground_z_m : float64 (N,) [m] DEM height under each point
    camera_height_m : [m]; max_distance_m : [m]; planet
    skyline_distance_m : float32 (N, bins) [m] horizontal distance to the terrain point that makes
        the skyline (NaN where none): how much a DEM height error there moves it
    """

    x: np.ndarray
    y: np.ndarray
    elevation_deg: np.ndarray
    ray_length_m: np.ndarray
    ground_z_m: np.ndarray
    camera_height_m: float
    max_distance_m: float
    planet: Planet
    skyline_distance_m: np.ndarray | None = None

    @property
    def azimuth_deg(self) -> np.ndarray:
        return azimuth_centres(self.elevation_deg.shape[1])


def azimuth_centres(bins: int) -> np.ndarray:
    """Bin centres [deg]: ``k * 360 / bins``."""
    return np.arange(bins) * (360.0 / bins)


def _check(dem: Dem, x, y, camera_height_m, azimuth_bins, max_distance_m, heights=True):
    if not np.isfinite(camera_height_m) or camera_height_m < 0:
        raise ParameterError(f"camera height must be >= 0 m, got {camera_height_m}")
    if int(azimuth_bins) != azimuth_bins or azimuth_bins <= 0:
        raise ParameterError(f"azimuth bins must be a positive whole number, got {azimuth_bins}")
    if max_distance_m is not None and not max_distance_m > T_MIN_M:
        # rays start T_MIN_M out (the camera's own cell is no skyline): a shorter limit left
        # every bin empty, without a word
        raise ParameterError(f"maximum distance must be more than {T_MIN_M:g} m (where rays "
                             f"start), got {max_distance_m}")
    if heights:  # (a stack member is rendered from the stack's ground, which was checked)
        dem.require_inside(x, y)


def render_horizons(dem: Dem, x, y, *, camera_height_m: float = 1.5, planet=None,
                    azimuth_bins: int = 360, max_distance_m: float | None = None,
                    skip_tol_deg: float = 0.001, camera_z_m=None) -> HorizonBatch:
    """Skylines at many points (parallel over points with numba's threads).

    x, y : [m] positions in the DEM's CRS (scalars or 1-D arrays)
    camera_height_m : [m] camera centre above the DEM surface
    planet : ``earth``, ``mars``, a radius [m] or a :class:`Planet` (curvature and refraction);
        None (default): the DEM's body (:attr:`Dem.body`), Earth when unknown
    azimuth_bins : number of bins over 360 deg
    max_distance_m : [m] ray length limit (default: to the DEM edge)
    skip_tol_deg : [deg] a block is skipped when it could raise the skyline by less than this
    camera_z_m : [m] absolute camera heights per point instead of ``camera_height_m`` above this
        DEM (a DEM stack renders each member from the finest member's ground)

    ``dem`` may be a :class:`skyfix.stack.DemStack`: every member is rendered and the highest
    terrain wins each bin (finer members mask what they cover in the coarser ones).
    """
    if hasattr(dem, "members"):
        return dem.render(x, y, camera_height_m=camera_height_m, planet=planet,
                          azimuth_bins=azimuth_bins, max_distance_m=max_distance_m,
                          skip_tol_deg=skip_tol_deg)
    x = np.atleast_1d(np.asarray(x, np.float64)).ravel()
    y = np.atleast_1d(np.asarray(y, np.float64)).ravel()
    if x.shape != y.shape:
        raise ParameterError("x and y must have the same length")
    _check(dem, x, y, camera_height_m, azimuth_bins, max_distance_m, heights=camera_z_m is None)
    planet = resolve_planet(planet, getattr(dem, "body", None))
    bins = int(azimuth_bins)
    data, offs, rows, cols = packed_pyramid(dem)
    az = np.radians(azimuth_centres(bins))
    elev = np.empty((x.size, bins), np.float32)
    length = np.empty((x.size, bins), np.float32)
    dist = np.empty((x.size, bins), np.float32)
    ground = np.empty(x.size, np.float64)
    cam_z = (np.full(x.size, np.nan) if camera_z_m is None else
             np.broadcast_to(np.asarray(camera_z_m, np.float64), x.shape).copy())
    _render_batch(dem.z, data, offs, rows, cols, dem.x0, dem.y0, dem.dx, dem.dy, x, y,
                  float(camera_height_m), np.sin(az), np.cos(az),
                  float(max_distance_m or np.inf), planet.curvature_coeff,
                  math.tan(math.radians(skip_tol_deg)), T_MIN_M, elev, length, ground, dist, cam_z)
    return HorizonBatch(x, y, elev, length, ground, float(camera_height_m),
                        float(max_distance_m or np.inf), planet, dist)


def render_horizon(dem: Dem, x: float, y: float, **kw) -> HorizonBatch:
    """One point's skyline: :func:`render_horizons` with scalars (row 0 of the batch)."""
    return render_horizons(dem, [x], [y], **kw)


def packed_pyramid(dem: Dem):
    """The DEM's max pyramid packed for the numba kernels (:meth:`Dem.packed_pyramid`: data,
    offsets, rows, cols per level), built once per DEM instance and cached on it."""
    # Cache on the instance: building and packing the pyramid is O(cells).
    p = dem.__dict__.get("_packed_pyramid")
    if p is None:
        p = dem.packed_pyramid()
        dem.__dict__["_packed_pyramid"] = p
    return p


@njit(cache=True, fastmath=False, nogil=True)
def bilinear(z, u, v):
    """Bilinear height [m] of grid ``z`` at fractional column ``u`` and row ``v`` (index space)."""
    ny, nx = z.shape
    j = min(int(math.floor(u)), nx - 2)
    i = min(int(math.floor(v)), ny - 2)
    return corner_sum(z, i, j, u - j, v - i)


@njit(cache=True, nogil=True, inline="always")
def corner_sum(z, i, j, fu, fv):
    """Bilinear height [m] in cell (i, j) at fractions ``fu`` (column), ``fv`` (row) in [0, 1]
    across it. A corner of weight 0 is left out, not multiplied: on a grid line beside a void
    the height is the line's own (NaN * 0 made it NaN on one side of a void and not the
    other)."""
    h = 0.0
    w = (1 - fu) * (1 - fv)
    if w != 0.0:
        h += z[i, j] * w
    w = fu * (1 - fv)
    if w != 0.0:
        h += z[i, j + 1] * w
    w = (1 - fu) * fv
    if w != 0.0:
        h += z[i + 1, j] * w
    w = fu * fv
    if w != 0.0:
        h += z[i + 1, j + 1] * w
    return h


@njit(cache=True, nogil=True)
def pyramid_block(u0, v0, du, dv, ru, rv, t, level, nx, ny, t_end):
    """Where a ray stands in the max pyramid: the level-0 cell (i, j) at distance ``t`` [m], its
    block (bi, bj) at ``level``, and the distance [m] at which the ray leaves that block (> t).

    u = u0 + du t, v = v0 + dv t in index space; ``ru``, ``rv`` = 1 / du, 1 / dv (0 where those
    are 0), computed once a ray: a walk calls this about 130 times a ray, and two divisions a call
    were 7 % of the kernel's time. Shared by the horizon renderer and the ray caster.
    """
    # Nudge along the ray before flooring: a point exactly on a grid line (a position on a whole
    # cell coordinate, a ray along a row) must land in the block it is entering, or the exit
    # distance is t itself and the walk creeps forward in 1e-6 m steps.
    u = u0 + du * t + (1e-9 if du > 0.0 else (-1e-9 if du < 0.0 else 0.0))
    v = v0 + dv * t + (1e-9 if dv > 0.0 else (-1e-9 if dv < 0.0 else 0.0))
    j = min(max(int(math.floor(u)), 0), nx - 2)
    i = min(max(int(math.floor(v)), 0), ny - 2)
    bi = i >> level
    bj = j >> level
    size = 1 << level
    # du, dv are exactly 0 for rays along grid lines (see _render_batch).
    if du > 0.0:
        tu = ((bj + 1) * size - u0) * ru
    elif du < 0.0:
        tu = (bj * size - u0) * ru
    else:
        tu = np.inf
    if dv > 0.0:
        tv = ((bi + 1) * size - v0) * rv
    elif dv < 0.0:
        tv = (bi * size - v0) * rv
    else:
        tv = np.inf
    t_exit = min(tu, tv, t_end)
    if t_exit <= t:
        t_exit = t + 1e-6
    return i, j, bi, bj, t_exit


@njit(cache=True, nogil=True, inline="always")  # in the kernels' loops: no call per ray
def edge_distance(u0, v0, du, dv, nx, ny):
    """Distance [m] along the ray u = u0 + du t, v = v0 + dv t (index space) from its start to
    the DEM's pixel-centre hull, where heights end (inf for a ray that never leaves it)."""
    t_edge = np.inf
    if du > 0.0:
        t_edge = min(t_edge, (nx - 1 - u0) / du)
    elif du < 0.0:
        t_edge = min(t_edge, -u0 / du)
    if dv > 0.0:
        t_edge = min(t_edge, (ny - 1 - v0) / dv)
    elif dv < 0.0:
        t_edge = min(t_edge, -v0 / dv)
    return t_edge


@njit(cache=True, nogil=True, inline="always")  # in the kernels' loops: no call per cell
def cell_max(z, i, j, u0, v0, du, dv, zc, curv, t0, t1):
    """The ray's maximum tangent over [t0, t1] [m] inside cell (i, j), and where: along a ray the
    bilinear surface of one cell is a quadratic in ``t``, so the tangent is ``A/t + B + C t`` and
    its maximum lies at an end or at the one stationary point ``sqrt(A/C)``. (-inf, t0) where a
    corner is nodata. u = u0 + du t, v = v0 + dv t in index space; zc [m] the camera height;
    curv [1/m] the curvature and refraction coefficient."""
    z00 = z[i, j]
    z01 = z[i, j + 1]
    z10 = z[i + 1, j]
    z11 = z[i + 1, j + 1]
    au = u0 - j
    av = v0 - i
    # A ray along one of the cell's edges sees only that edge's two corners: the other two
    # have weight 0 all along it and may be void (the cell beside a void's edge), as the
    # neighbouring cell on the line's other side would say.
    if du == 0.0:
        if au == 0.0:
            z01 = z00
            z11 = z10
        elif au == 1.0:  # the DEM's last column: its cell is the one to the west
            z00 = z01
            z10 = z11
    if dv == 0.0:
        if av == 0.0:
            z10 = z00
            z11 = z01
        elif av == 1.0:
            z00 = z10
            z01 = z11
    if not (math.isfinite(z00) and math.isfinite(z01) and math.isfinite(z10) and math.isfinite(z11)):
        return -np.inf, t0
    e = z00 - z01 - z10 + z11
    p = z00 + (z01 - z00) * au + (z10 - z00) * av + e * au * av
    b = (z01 - z00) * du + (z10 - z00) * dv + e * (au * dv + av * du)
    aa = p - zc
    cc = e * du * dv - curv
    f0 = aa / t0 + b + cc * t0
    f1 = aa / t1 + b + cc * t1
    if f0 >= f1:
        f = f0
        tf = t0
    else:
        f = f1
        tf = t1
    if aa < 0.0 and cc < 0.0:
        ts = math.sqrt(aa / cc)
        if t0 < ts < t1:
            fs = aa / ts + b + cc * ts
            if fs > f:
                f = fs
                tf = ts
    return f, tf


@njit(cache=True, nogil=True)
def trace_ray(z, pdata, poffs, prows, pcols, u0, v0, du, dv, zc, t_end, curv, tol, t_min, t_seed,
              floor=-np.inf):
    """Max tangent of the elevation angle along one ray (index space; t in metres).

    u = u0 + du t is the fractional column, v = v0 + dv t the fractional row.
    ``t_seed`` [m] (where the neighbouring azimuth found its skyline) is sampled first: a real
    point of this ray, so a valid lower bound that lets most near-field cells be skipped.
    ``floor``: a tangent the ray reaches elsewhere (outside [t_min, t_end]); blocks that cannot
    beat it are skipped, and it comes back, with distance 0, when nothing here does.
    Returns (max tangent or -inf if no terrain was seen, distance of that maximum).
    """
    ny, nx = z.shape
    nlev = prows.shape[0]
    best = floor
    t_best = 0.0
    if t_min < t_seed < t_end:
        hs = bilinear(z, u0 + du * t_seed, v0 + dv * t_seed)
        if math.isfinite(hs) and (hs - zc) / t_seed - curv * t_seed > best:
            best = (hs - zc) / t_seed - curv * t_seed
            t_best = t_seed
    t = t_min
    level = 0
    eps_t = 1e-6
    ru = 1.0 / du if du != 0.0 else 0.0
    rv = 1.0 / dv if dv != 0.0 else 0.0
    while t < t_end:
        i, j, bi, bj, t_exit = pyramid_block(u0, v0, du, dv, ru, rv, t, level, nx, ny, t_end)
        hmax = pdata[poffs[level] + bi * pcols[level] + bj]
        if hmax == -np.inf:
            ub = -np.inf
        else:
            a = hmax - zc
            # the larger of a / t and a / t_exit (t < t_exit): one division, not two
            ub = (a / t if a >= 0.0 else a / t_exit) - curv * t
        if ub <= best + tol:
            t = t_exit + eps_t * (1.0 + t_exit * 1e-9)
            if level + 1 < nlev:
                level += 1
            continue
        if level > 0:
            level -= 1
            continue
        # Level 0: the exact maximum inside cell (i, j).
        f, tf = cell_max(z, i, j, u0, v0, du, dv, zc, curv, t, t_exit)
        if f > best:
            best = f
            t_best = tf
        t = t_exit + eps_t
    return best, t_best


@njit(cache=True, parallel=True, nogil=True)
def _render_batch(z, pdata, poffs, prows, pcols, x0, y0, dx, dy, xs, ys, h, saz, caz, max_d,
                  curv, tol, t_min, out_el, out_len, out_ground, out_dist, cam_z):
    ny, nx = z.shape
    n = xs.shape[0]
    nb = saz.shape[0]
    for k in prange(n):
        u0 = (xs[k] - x0) / dx
        v0 = (y0 - ys[k]) / dy
        zg = bilinear(z, u0, v0)
        out_ground[k] = zg
        # an absolute camera height where given (a DEM stack: the ground is the finest DEM's)
        zc = cam_z[k] if math.isfinite(cam_z[k]) else zg + h
        t_seed = 0.0
        for b in range(nb):
            du = saz[b] / dx
            dv = -caz[b] / dy
            # cos(90 deg) is 6e-17, not 0: a ray along a grid line with such a residual slope
            # never leaves its row (exit distance 0, 1e-6 m steps: an apparent hang).
            if abs(du) < 1e-12:
                du = 0.0
            if abs(dv) < 1e-12:
                dv = 0.0
            # rays stop at the DEM edge
            t_end = min(edge_distance(u0, v0, du, dv, nx, ny) * (1 - 1e-9), max_d)
            out_len[k, b] = t_end
            if not math.isfinite(zc):
                out_el[k, b] = np.nan
                out_dist[k, b] = np.nan
                continue
            best, t_seed = trace_ray(z, pdata, poffs, prows, pcols, u0, v0, du, dv, zc, t_end,
                                      curv, tol, t_min, t_seed)
            out_el[k, b] = math.degrees(math.atan(best)) if best > -np.inf else np.nan
            out_dist[k, b] = t_seed if best > -np.inf else np.nan


def reference_horizon(dem: Dem, x: float, y: float, *, camera_height_m: float = 1.5,
                      planet=None, azimuth_bins: int = 360, max_distance_m: float | None = None,
                      near_step_m: float = 0.25, step_cells: float = 0.25):
    """Slow, obviously-correct skyline: (elevation_deg, ray_length_m), each (bins,).

    Every ray is sampled at ``near_step_m`` out to one cell, then every ``step_cells`` cell, and at
    every crossing of a grid line (where a bilinear surface has its kinks, so ridge crests on cell
    edges are never stepped over), to the DEM edge or ``max_distance_m``, with bilinear heights; the
    highest elevation angle wins.
    """
    _check(dem, [x], [y], camera_height_m, azimuth_bins, max_distance_m)
    planet = resolve_planet(planet, getattr(dem, "body", None))
    ny, nx = dem.z.shape
    zc = float(dem.height_at(x, y)) + camera_height_m
    u0, v0 = dem.xy_to_colrow(x, y)
    az = np.radians(azimuth_centres(int(azimuth_bins)))
    elev = np.full(az.size, np.nan)
    length = np.zeros(az.size)
    cell = dem.cell_m
    for b, a in enumerate(az):
        du, dv = np.sin(a) / dem.dx, -np.cos(a) / dem.dy
        lims = []
        for d, lo, hi, p in ((du, 0, nx - 1, u0), (dv, 0, ny - 1, v0)):
            if d > 1e-15:
                lims.append((hi - p) / d)
            elif d < -1e-15:
                lims.append((lo - p) / d)
        t_end = min(min(lims) * (1 - 1e-9), max_distance_m or np.inf)
        length[b] = t_end
        t = np.concatenate([np.arange(T_MIN_M, cell, near_step_m), np.arange(cell, t_end, cell * step_cells),
                            [t_end]])
        # Bilinear heights have kinks only where the ray crosses a grid line: sample each crossing.
        t = np.concatenate([t, _grid_crossings(u0, du, t_end), _grid_crossings(v0, dv, t_end)])
        t = np.sort(t[(t >= T_MIN_M) & (t <= t_end)])
        u = np.clip(u0 + du * t, 0, nx - 1)
        v = np.clip(v0 + dv * t, 0, ny - 1)
        zz = dem.z
        h = np.full(t.shape, np.nan)
        # On a grid line the height is that of either cell beside it: where one of them has a
        # no-data corner (a void, a reprojection's wedge) the other one's edge is the terrain.
        # (a crossing lands within rounding of the line, on either side)
        for ju in (u - 1e-7, u + 1e-7):
            for iv in (v - 1e-7, v + 1e-7):
                j = np.clip(np.floor(ju), 0, nx - 2).astype(int)
                i = np.clip(np.floor(iv), 0, ny - 2).astype(int)
                fu, fv = u - j, v - i
                h = np.fmax(h, zz[i, j] * (1 - fu) * (1 - fv) + zz[i, j + 1] * fu * (1 - fv)
                            + zz[i + 1, j] * (1 - fu) * fv + zz[i + 1, j + 1] * fu * fv)
        ang = np.degrees(np.arctan((h - zc - planet.drop_m(t)) / t))
        if np.any(np.isfinite(ang)):
            elev[b] = np.nanmax(ang)
    return elev, length


def _grid_crossings(p0: float, dp: float, t_end: float) -> np.ndarray:
    """Distances t in (0, t_end] where p0 + dp * t is a whole number."""
    if abs(dp) < 1e-15:
        return np.empty(0)
    p1 = p0 + dp * t_end
    lo, hi = sorted((p0, p1))
    k = np.arange(np.ceil(lo), np.floor(hi) + 1)
    return (k - p0) / dp


__all__ = ["HorizonBatch", "render_horizons", "render_horizon", "reference_horizon",
           "azimuth_centres", "EARTH"]
