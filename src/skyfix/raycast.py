"""Per-pixel ray casting over a DEM (the simulator's geometry).

A pixel's ray leaves the camera centre ``C`` along a unit world direction ``d`` (ENU). At
horizontal distance ``t`` it is at height ``z_C + t tan(el)``; a terrain point there appears at
``z(t) - c t**2`` (curvature and refraction, ``c = Planet.curvature_coeff``), so the ray has hit
the terrain once

    f(t) = (z(t) - z_C) / t - c t  >=  tan(el),

the very quantity whose maximum over ``t`` is the horizon renderer's skyline tangent
(:mod:`skyfix.horizon`). A ray is therefore terrain exactly when its elevation lies below the
rendered skyline at its azimuth: the image's sky/terrain boundary and the rendered profile are
the same surface, up to floating point.

Inside one bilinear DEM cell ``z(t)`` is quadratic in ``t`` along the ray, so ``t f(t) - t tan(el)``
is a quadratic and the first hit in a cell is found in closed form. Empty space is skipped with
the DEM's max pyramid exactly as :func:`skyfix.horizon.trace_ray` does (a block whose maximum
height cannot reach the ray is stepped over, coarse far away, fine near the camera).

Rays start at ``T_MIN_M`` (as the horizon renderer) and end at the DEM's pixel-centre hull or
``max_distance_m``; a ray that leaves the DEM is sky.

Boulders that the DEM lacks (the ``rocks`` condition) are ellipsoids with a vertical axis,
intersected analytically.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from .camera import Camera, r_world_body, r_world_cam
from .dem import Dem
from .formats import PanoramaSpec
from .horizon import T_MIN_M, edge_distance, packed_pyramid, pyramid_block
from .planets import resolve_planet

#: projection codes of the kernels
PINHOLE, EQUIRECT = 0, 1


@dataclass(frozen=True)
class Projection:
    """How image coordinates map to world rays.

    kind : ``PINHOLE`` (a frame, OpenCV distortion) or ``EQUIRECT`` (a body-levelled panorama)
    params : float64 array; pinhole ``(fx, fy, cx, cy, k1, k2, p1, p2, k3)`` [px, -];
        equirect ``(azimuth_left, deg_per_col, elevation_top, deg_per_row)`` [deg]
    rotation : 3 x 3; pinhole: camera axes -> world; equirect: body axes -> world
    width, height : [px]
    """

    kind: int
    params: np.ndarray
    rotation: np.ndarray
    width: int
    height: int

    @classmethod
    def frame(cls, camera: Camera, yaw_deg, pitch_deg, roll_deg, pan_deg, tilt_deg) -> "Projection":
        d = camera.distortion
        p = np.array([camera.fx, camera.fy, camera.cx, camera.cy, d.k1, d.k2, d.p1, d.p2, d.k3])
        return cls(PINHOLE, p, r_world_cam(yaw_deg, pitch_deg, roll_deg, pan_deg, tilt_deg),
                   camera.width, camera.height)

    @classmethod
    def panorama(cls, spec: PanoramaSpec, width: int, height: int, yaw_deg, pitch_deg,
                 roll_deg) -> "Projection":
        p = np.array([spec.azimuth_left_deg, spec.hfov_deg / width, spec.elevation_top_deg,
                      spec.vfov_deg / height])
        return cls(EQUIRECT, p, r_world_body(yaw_deg, pitch_deg, roll_deg), int(width), int(height))

    def rays(self, u, v) -> np.ndarray:
        """Unit world directions ``(..., 3)`` of image points (u column, v row) [px]."""
        u, v = np.broadcast_arrays(np.asarray(u, float), np.asarray(v, float))
        out = np.empty(u.shape + (3,))
        _dirs(self.kind, self.params, self.rotation, u.ravel(), v.ravel(), out.reshape(-1, 3))
        return out


@dataclass
class CastResult:
    """Per-pixel result of :func:`cast_image` (arrays ``(H, W)`` unless stated).

    direction : float32 (H, W, 3) unit world ray
    terrain_t : [m] horizontal distance to the first terrain hit, inf for none (sky)
    rock_s : [m] 3-D distance to the first rock hit, inf for none
    rock_id : index of that rock, -1 for none
    normal : float32 (H, W, 3) unit surface normal (ENU) of the visible surface (0 for sky)
    origin : (3,) camera centre [m]
    """

    direction: np.ndarray
    terrain_t: np.ndarray
    rock_s: np.ndarray
    rock_id: np.ndarray
    normal: np.ndarray
    origin: np.ndarray

    @property
    def terrain_s(self) -> np.ndarray:
        """3-D distance [m] to the terrain hit (inf for sky)."""
        h = np.hypot(self.direction[..., 0], self.direction[..., 1]).astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(np.isfinite(self.terrain_t), self.terrain_t / np.maximum(h, 1e-12), np.inf)

    @property
    def distance(self) -> np.ndarray:
        """3-D distance [m] to the visible surface (inf for sky)."""
        return np.minimum(self.terrain_s, self.rock_s)

    @property
    def kind(self) -> np.ndarray:
        """0 sky, 1 terrain, 2 rock."""
        ts = self.terrain_s
        k = np.where(np.isfinite(ts), 1, 0).astype(np.int8)
        k[np.isfinite(self.rock_s) & (self.rock_s < ts)] = 2
        return k

    def points(self) -> np.ndarray:
        """World point [m] of each visible surface ``(H, W, 3)`` (NaN for sky)."""
        s = self.distance
        s = np.where(np.isfinite(s), s, np.nan)
        return self.origin + self.direction.astype(np.float64) * s[..., None]


def camera_centre(dem: Dem, x: float, y: float, camera_height_m: float) -> np.ndarray:
    """Camera centre [m]: ``camera_height_m`` above the bilinear DEM surface at (x, y)."""
    dem.require_inside(x, y, "rover position")
    return np.array([float(x), float(y), float(dem.height_at(x, y)) + float(camera_height_m)])


def _rocks_array(rocks) -> np.ndarray:
    if rocks is None or len(rocks) == 0:
        return np.zeros((0, 5))
    return np.ascontiguousarray(np.asarray(rocks, np.float64).reshape(-1, 5))


def cast_image(dem: Dem, origin, proj: Projection, *, planet=None, rocks=None,
               max_distance_m: float | None = None) -> CastResult:
    """Cast one ray per pixel centre (u = column, v = row, integers) of ``proj``.

    origin : (3,) camera centre [m] (see :func:`camera_centre`)
    planet : curvature and refraction; None (default): the DEM's body, as
        :func:`~skyfix.horizon.render_horizons` takes it (Earth was the default here, a Mars DEM's
        frames rendered with Earth's curvature)
    rocks : (K, 5) ellipsoids ``(x, y, z, radius_h, radius_v)`` [m], or None
    """
    planet = resolve_planet(planet, getattr(dem, "body", None))  # the DEM's body by default
    data, offs, rows, cols = packed_pyramid(dem)
    H, W = proj.height, proj.width
    direction = np.empty((H, W, 3), np.float32)
    terrain_t = np.empty((H, W))
    rock_s = np.empty((H, W))
    rock_id = np.empty((H, W), np.int32)
    normal = np.empty((H, W, 3), np.float32)
    o = np.asarray(origin, np.float64)
    _cast_kernel(dem.z, data, offs, rows, cols, dem.x0, dem.y0, dem.dx, dem.dy, o,
                 proj.kind, np.asarray(proj.params, np.float64), np.asarray(proj.rotation, np.float64),
                 float(max_distance_m or np.inf), planet.curvature_coeff, T_MIN_M, _rocks_array(rocks),
                 direction, terrain_t, rock_s, rock_id, normal)
    return CastResult(direction, terrain_t, rock_s, rock_id, normal, o)


def column_skyline(dem: Dem, origin, proj: Projection, sky_mask: np.ndarray, *, planet=None,
                   rocks=None, max_distance_m: float | None = None, iterations: int = 30) -> np.ndarray:
    """Sub-pixel skyline row per column [px], NaN where the column has no sky-to-ground edge.

    Scanning each column down from the top, the first sky pixel centre followed by a non-sky one
    brackets the edge; bisection along the continuous column then finds the row ``r`` where the
    ray first meets the surface (terrain, or terrain and ``rocks`` when given). Pixel centres
    ``v >= r`` are ground, so the first ground pixel is ``ceil(r)``.

    sky_mask : bool (H, W), True where the pixel-centre ray is sky for the same surfaces
    """
    planet = resolve_planet(planet, getattr(dem, "body", None))  # the DEM's body by default
    data, offs, rows, cols = packed_pyramid(dem)
    out = np.empty(proj.width)
    _skyline_kernel(dem.z, data, offs, rows, cols, dem.x0, dem.y0, dem.dx, dem.dy,
                    np.asarray(origin, np.float64), proj.kind, np.asarray(proj.params, np.float64),
                    np.asarray(proj.rotation, np.float64), float(max_distance_m or np.inf),
                    planet.curvature_coeff, T_MIN_M, _rocks_array(rocks),
                    np.ascontiguousarray(sky_mask, dtype=np.bool_), int(iterations), out)
    return out


def ground_hits(dem: Dem, origin, proj: Projection, u, v, *, planet=None, rocks=None,
                max_distance_m: float | None = None) -> np.ndarray:
    """True where the ray through the continuous pixel position (u = column, v = row) [px] meets
    the terrain of ``dem`` (or one of ``rocks``): the test :func:`column_skyline` bisects with,
    for callers that combine several surfaces (a DEM stack)."""
    planet = resolve_planet(planet, getattr(dem, "body", None))  # the DEM's body by default
    data, offs, rows, cols = packed_pyramid(dem)
    u = np.ascontiguousarray(u, np.float64).ravel()
    v = np.ascontiguousarray(v, np.float64).ravel()
    out = np.empty(u.size, np.bool_)
    _ground_kernel(dem.z, data, offs, rows, cols, dem.x0, dem.y0, dem.dx, dem.dy,
                   np.asarray(origin, np.float64), proj.kind, np.asarray(proj.params, np.float64),
                   np.asarray(proj.rotation, np.float64), float(max_distance_m or np.inf),
                   planet.curvature_coeff, T_MIN_M, _rocks_array(rocks), u, v, out)
    return out


# --- kernels -------------------------------------------------------------------------------------

@numba.njit(cache=True, nogil=True)
def _pixel_dir(kind, p, R, u, v):
    if kind == 0:
        xd = (u - p[2]) / p[0]
        yd = (v - p[3]) / p[1]
        k1, k2, p1, p2, k3 = p[4], p[5], p[6], p[7], p[8]
        x = xd
        y = yd
        if k1 != 0.0 or k2 != 0.0 or p1 != 0.0 or p2 != 0.0 or k3 != 0.0:
            # The inversion of Camera.undistort_normalized: OpenCV's fixed point, then Newton
            # steps (the fixed point alone stops degrees off at a strong wide lens's corners,
            # and the simulator and the profile would then disagree)
            for _ in range(20):
                r2 = x * x + y * y
                radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
                ddx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
                ddy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
                x = (xd - ddx) / radial
                y = (yd - ddy) / radial
            for _ in range(30):
                r2 = x * x + y * y
                radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
                ex = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) - xd
                ey = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y - yd
                if not (abs(ex) > 1e-12 or abs(ey) > 1e-12):
                    break
                dr = k1 + 2 * k2 * r2 + 3 * k3 * r2 * r2
                ja = radial + 2 * x * x * dr + 2 * p1 * y + 6 * p2 * x
                jb = 2 * x * y * dr + 2 * p1 * x + 2 * p2 * y
                je = radial + 2 * y * y * dr + 6 * p1 * y + 2 * p2 * x
                det = ja * je - jb * jb
                if det == 0.0:
                    break
                x -= (je * ex - jb * ey) / det
                y -= (ja * ey - jb * ex) / det
        a0, a1, a2 = x, y, 1.0
    else:
        az = math.radians(p[0] + (u + 0.5) * p[1])
        el = math.radians(p[2] - (v + 0.5) * p[3])
        ce = math.cos(el)
        a0, a1, a2 = ce * math.sin(az), ce * math.cos(az), math.sin(el)
    d0 = R[0, 0] * a0 + R[0, 1] * a1 + R[0, 2] * a2
    d1 = R[1, 0] * a0 + R[1, 1] * a1 + R[1, 2] * a2
    d2 = R[2, 0] * a0 + R[2, 1] * a1 + R[2, 2] * a2
    n = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    return d0 / n, d1 / n, d2 / n


@numba.njit(cache=True, nogil=True)
def _dirs(kind, p, R, us, vs, out):
    for k in range(us.shape[0]):
        a, b, c = _pixel_dir(kind, p, R, us[k], vs[k])
        out[k, 0] = a
        out[k, 1] = b
        out[k, 2] = c


@numba.njit(cache=True, nogil=True)
def _first_root(t0, t1, a, b, c):
    """Smallest s in [t0, t1] with a + b s + c s**2 >= 0, or -1."""
    if a + b * t0 + c * t0 * t0 >= 0.0:
        return t0
    if abs(c) < 1e-300:
        if b > 0.0:
            s = -a / b
            if t0 <= s <= t1:
                return s
        return -1.0
    disc = b * b - 4.0 * a * c
    if disc < 0.0:
        return -1.0
    sq = math.sqrt(disc)
    # Numerically stable pair of roots.
    qq = -0.5 * (b + (sq if b >= 0 else -sq))
    r1 = qq / c
    r2 = a / qq if qq != 0.0 else r1
    lo = min(r1, r2)
    hi = max(r1, r2)
    for s in (lo, hi):
        if t0 <= s <= t1:
            # Entering the non-negative side (q(t0) < 0, so the first root in range enters it).
            return s
    if a + b * t1 + c * t1 * t1 >= 0.0:  # rounding at the cell exit
        return t1
    return -1.0


@numba.njit(cache=True, nogil=True)
def _first_hit(z, pdata, poffs, prows, pcols, u0, v0, du, dv, zc, tan_el, t_end, curv, t_min):
    """Horizontal distance [m] of the first terrain hit of a ray, or inf.

    u = u0 + du t, v = v0 + dv t (index space; t in metres, horizontal).
    """
    ny, nx = z.shape
    nlev = prows.shape[0]
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
            ub = (a / t if a >= 0.0 else a / t_exit) - curv * t  # the larger of the two
        if ub < tan_el:
            t = t_exit + eps_t * (1.0 + t_exit * 1e-9)
            if level + 1 < nlev:
                level += 1
            continue
        if level > 0:
            level -= 1
            continue
        z00 = z[i, j]
        z01 = z[i, j + 1]
        z10 = z[i + 1, j]
        z11 = z[i + 1, j + 1]
        if not (math.isfinite(z00) and math.isfinite(z01) and math.isfinite(z10) and math.isfinite(z11)):
            t = t_exit + eps_t
            continue
        au = u0 - j
        av = v0 - i
        e = z00 - z01 - z10 + z11
        p = z00 + (z01 - z00) * au + (z10 - z00) * av + e * au * av
        b = (z01 - z00) * du + (z10 - z00) * dv + e * (au * dv + av * du)
        q = e * du * dv
        # t f(t) - t tan_el = (p - zc) + (b - tan_el) t + (q - curv) t**2 >= 0
        # From the camera itself in the first cell: a ray steep enough to meet the ground within
        # t_min (more than 86 deg down at 1.5 m) is already under it there, and was given t_min
        # (a hit tens of metres away along the ray, below the ground)
        # (downward rays only, the camera above the ground: one on it would hit at 0 whatever
        # its direction)
        s = _first_root(0.0 if t <= t_min and tan_el < 0.0 and p < zc else t, t_exit, p - zc,
                        b - tan_el, q - curv)
        if s >= 0.0:
            return s
        t = t_exit + eps_t
    return np.inf


@numba.njit(cache=True, nogil=True)
def _terrain_t(z, pdata, poffs, prows, pcols, x0, y0, dx, dy, o, d0, d1, d2, max_d, curv, t_min):
    ny, nx = z.shape
    h = math.sqrt(d0 * d0 + d1 * d1)
    if h < 1e-12:
        return t_min if d2 < 0 else np.inf
    u0 = (o[0] - x0) / dx
    v0 = (y0 - o[1]) / dy
    du = d0 / h / dx
    dv = -d1 / h / dy
    # a component within 1e-15 of zero runs along the grid line (no exit on that axis)
    t_edge = edge_distance(u0, v0, du if abs(du) > 1e-15 else 0.0, dv if abs(dv) > 1e-15 else 0.0,
                           nx, ny)
    t_end = min(t_edge * (1 - 1e-9), max_d)
    return _first_hit(z, pdata, poffs, prows, pcols, u0, v0, du, dv, o[2], d2 / h, t_end, curv, t_min)


@numba.njit(cache=True, nogil=True)
def _rock_hit(rocks, o, d0, d1, d2):
    """(3-D distance, index) of the nearest ellipsoid hit, (inf, -1) if none."""
    best = np.inf
    kb = -1
    for k in range(rocks.shape[0]):
        a = rocks[k, 3]
        c = rocks[k, 4]
        px = (o[0] - rocks[k, 0]) / a
        py = (o[1] - rocks[k, 1]) / a
        pz = (o[2] - rocks[k, 2]) / c
        qx = d0 / a
        qy = d1 / a
        qz = d2 / c
        A = qx * qx + qy * qy + qz * qz
        B = 2 * (px * qx + py * qy + pz * qz)
        C = px * px + py * py + pz * pz - 1.0
        disc = B * B - 4 * A * C
        if disc < 0:
            continue
        s = (-B - math.sqrt(disc)) / (2 * A)
        if s > 0 and s < best:
            best = s
            kb = k
    return best, kb


@numba.njit(cache=True, parallel=True, nogil=True)
def _cast_kernel(z, pdata, poffs, prows, pcols, x0, y0, dx, dy, o, kind, p, R, max_d, curv, t_min,
                 rocks, out_dir, out_t, out_rs, out_rid, out_n):
    H, W = out_t.shape
    ny, nx = z.shape
    for i in numba.prange(H):
        for j in range(W):
            d0, d1, d2 = _pixel_dir(kind, p, R, float(j), float(i))
            out_dir[i, j, 0] = d0
            out_dir[i, j, 1] = d1
            out_dir[i, j, 2] = d2
            t = _terrain_t(z, pdata, poffs, prows, pcols, x0, y0, dx, dy, o, d0, d1, d2, max_d, curv, t_min)
            out_t[i, j] = t
            rs, rk = _rock_hit(rocks, o, d0, d1, d2)
            out_rs[i, j] = rs
            out_rid[i, j] = rk
            h = math.sqrt(d0 * d0 + d1 * d1)
            if rk >= 0 and (not math.isfinite(t) or rs * h < t):
                a = rocks[rk, 3]
                c = rocks[rk, 4]
                gx = (o[0] + rs * d0 - rocks[rk, 0]) / (a * a)
                gy = (o[1] + rs * d1 - rocks[rk, 1]) / (a * a)
                gz = (o[2] + rs * d2 - rocks[rk, 2]) / (c * c)
            elif math.isfinite(t):
                # Bilinear surface gradient at the hit [m/m].
                u = (o[0] - x0) / dx + d0 / h / dx * t
                v = (y0 - o[1]) / dy - d1 / h / dy * t
                jj = min(max(int(math.floor(u)), 0), nx - 2)
                ii = min(max(int(math.floor(v)), 0), ny - 2)
                fu = u - jj
                fv = v - ii
                z00 = z[ii, jj]
                z01 = z[ii, jj + 1]
                z10 = z[ii + 1, jj]
                z11 = z[ii + 1, jj + 1]
                dzdu = (z01 - z00) * (1 - fv) + (z11 - z10) * fv
                dzdv = (z10 - z00) * (1 - fu) + (z11 - z01) * fu
                gx = -dzdu / dx
                gy = dzdv / dy
                gz = 1.0
            else:
                gx = 0.0
                gy = 0.0
                gz = 0.0
            n = math.sqrt(gx * gx + gy * gy + gz * gz)
            if n > 0:
                n = 1.0 / n
            out_n[i, j, 0] = gx * n
            out_n[i, j, 1] = gy * n
            out_n[i, j, 2] = gz * n


@numba.njit(cache=True, nogil=True)
def _ground_at(z, pdata, poffs, prows, pcols, x0, y0, dx, dy, o, kind, p, R, max_d, curv, t_min,
               rocks, u, v):
    d0, d1, d2 = _pixel_dir(kind, p, R, u, v)
    t = _terrain_t(z, pdata, poffs, prows, pcols, x0, y0, dx, dy, o, d0, d1, d2, max_d, curv, t_min)
    if math.isfinite(t):
        return True
    rs, rk = _rock_hit(rocks, o, d0, d1, d2)
    return rk >= 0


@numba.njit(cache=True, parallel=True, nogil=True)
def _skyline_kernel(z, pdata, poffs, prows, pcols, x0, y0, dx, dy, o, kind, p, R, max_d, curv, t_min,
                    rocks, sky, iterations, out):
    H, W = sky.shape
    for j in numba.prange(W):
        out[j] = np.nan
        first_sky = -1
        for i in range(H):
            if sky[i, j]:
                first_sky = i
                break
        if first_sky < 0:
            continue
        r1 = -1
        for i in range(first_sky + 1, H):
            if not sky[i, j]:
                r1 = i
                break
        if r1 < 0:
            continue
        lo = float(r1 - 1)  # sky
        hi = float(r1)  # ground
        for _ in range(iterations):
            mid = 0.5 * (lo + hi)
            if _ground_at(z, pdata, poffs, prows, pcols, x0, y0, dx, dy, o, kind, p, R, max_d, curv,
                          t_min, rocks, float(j), mid):
                hi = mid
            else:
                lo = mid
        out[j] = 0.5 * (lo + hi)


@numba.njit(cache=True, parallel=True, nogil=True)
def _ground_kernel(z, pdata, poffs, prows, pcols, x0, y0, dx, dy, o, kind, p, R, max_d, curv, t_min,
                   rocks, us, vs, out):
    for k in numba.prange(us.size):
        out[k] = _ground_at(z, pdata, poffs, prows, pcols, x0, y0, dx, dy, o, kind, p, R, max_d, curv,
                            t_min, rocks, us[k], vs[k])
