"""Skylines of a whole grid at once: a horizon sweep that finds, exact rays that decide.

:func:`skyfix.horizon.render_horizons` traces every ray of every position on its own (about 130
pyramid steps a ray on the Sierra DEM, 67 of them exact cell maxima near the skyline), so a
7 x 7 km database at 5 m costs 700 M such rays. Neighbouring positions look at almost the same
terrain; this renderer shares that work the way a horizon sweep does (Stewart 1998), while every
value it returns stays, as the kernel's, the maximum over true points of the position's own ray:

1. **Lines** (shared). For each azimuth, lines of that azimuth every ``line_spacing_m`` across the
   grid, on a lattice fixed to the DEM's corner (a position's answer does not depend on which
   other positions share the call: a resumed block gets the values it got in its group). Along
   each line the terrain is sampled where the line crosses the DEM's grid lines (the bilinear
   surface's kinks) and at the crest of every piece between them that bulges upward, from the
   DEM edge back to the grid, and kept as an upper convex hull.
   Curvature and refraction enter exactly: with ``w(s) = z(s) - c s**2`` for terrain and camera
   alike, the tangent of the elevation angle from along-position ``a`` is the slope from
   ``(a, w_cam)`` to ``(s, w(s))`` plus ``2 c a`` (``c`` = :attr:`Planet.curvature_coeff`), and a
   shear keeps a hull a hull. The hull holds only terrain at least ``near_m`` ahead of the query
   (samples enter as the query point walks back), and a binary search gives the hull vertex a
   camera sees highest: on each of the two lines that bracket a position, *where* its skyline
   most likely lies.
2. **Own ray** (per position, exact). The position's own ray is maximised exactly, cell by cell
   in closed form as the per-point kernel's level 0 does, over its near field (``t <= near_m``,
   where lines a few metres apart see different terrain), on out to ``rising_m`` where the ray is
   still climbing at ``near_m`` (a slope whose crest lies just beyond), and over ``+-window_m``
   around the two lines' skyline points and a few hull vertices beside them that the lines see
   only a little lower (:func:`~skyfix.sweep_lines.alternates`). Every value is thus a true point of the position's own
   ray: the renderer never overstates the skyline (beyond the kernel's own skip tolerance), and
   understates it only where the position's skyline lies on terrain that neither bracketing line
   ranks highest (a knob between the lines, 100 m - 1 km away, that both pass beside).

Against the per-point kernel (``benchmarks/bench_sweep.py``: every position and bin of a 1 x 1 km
block at 5 m, four DEMs, held-out blocks too; the figures and what was tried in
``docs/results.md``, "Grid sweep vs the per-point kernel"): p99 under 0.001 deg, max 0.04-0.35 deg
(a handful of bins in millions: knobs between the lines), 1.5-3.9x the kernel's rate. Where the
time goes (one 256 x 256 task, one thread): the positions' own rays about 60 % (their near field
alone 40 %), the lines' samples and hulls 25 %, setting up each azimuth (positions sorted into
lines, outputs transposed) 10 %, the hull queries 5 %. The defaults (``NEAR_M``, ``RISING_M``,
``ARC_TOL_DEG``, ``ALT_DELTA_DEG``, ``LATERAL_SLOPE``) trade those bins against that time.
``max_distance_m`` is not supported (a hull cannot forget terrain behind the limit); callers use
the per-point kernel then.
"""

from __future__ import annotations

import math

import numpy as np

from .dem import Dem
from .errors import ParameterError
from .horizon import (T_MIN_M, HorizonBatch, azimuth_centres, bilinear, cell_max,
                      edge_distance, packed_pyramid, pyramid_block, trace_ray)
from .jit import njit, prange
from .planets import resolve_planet
from .sweep_lines import ARC_MAX, alternates, line_samples, line_span, tangent_vertex

#: [m] the widest spacing of the lines (the grid's own spacing where finer): a position at most
#: half of it from a line. Lines as far apart as a coarse grid's positions see other terrain than
#: the positions between them (at 100 m spacing 4.8 % of bins more than 0.01 deg low, by up to
#: 9.4 deg); a grid coarser than this costs more lines per position (the kernel is the cheaper
#: renderer there)
LINE_SPACING_M = 5.0
#: [m] every position's own ray is traced exactly out to this distance
NEAR_M = 100.0
#: [m] how far a ray still rising at ``NEAR_M`` is traced exactly
RISING_M = 400.0
#: [m] least half-width of the exact window around each bracketing line's skyline point (it is
#: one DEM cell where cells are larger: a line's crest sample and the tangent's maximum can lie
#: most of a cell apart on a broad crest)
WINDOW_M = 15.0
#: [deg] a line's concave pieces (the bilinear surface along it between grid lines) are sampled
#: densely enough that no chord lies more than this below the arc seen from ``near_m`` away
#: (0.52 m at 100 m; less seen from farther): the hull of the samples must not miss a slope whose
#: sight line touches mid-piece. The same everywhere (not from the nearest query), so that a
#: line's samples, hence a position's skyline, do not depend on the other positions
ARC_TOL_DEG = 0.3
#: [deg] hull vertices beside a line's tangent vertex that may still be the position's skyline
#: are those it sees at most this far below the tangent vertex ...
ALT_DELTA_DEG = 1.0
#: ... and at most ``LATERAL_SLOPE * e * (1/d_t + 1/d_i)`` [rad] below it, ``e`` [m] the line's
#: offset from the position, ``d_t``, ``d_i`` the two distances: how much lower or higher the
#: position's own ray may see each of them on terrain that slopes this steeply across the line
LATERAL_SLOPE = 0.5


def render_grid(dem: Dem, x_west: float, y_north: float, spacing_m: float, rows: int, cols: int,
                *, camera_height_m: float = 1.5, planet=None, azimuth_bins: int = 360,
                skip_tol_deg: float = 0.001, near_m: float = NEAR_M,
                line_spacing_m: float | None = None, window_m: float | None = None,
                rising_m: float = RISING_M, arc_tol_deg: float = ARC_TOL_DEG,
                alt_delta_deg: float = ALT_DELTA_DEG,
                lateral_slope: float = LATERAL_SLOPE) -> HorizonBatch:
    """Skylines of a regular grid of positions (row-major, north to south, west to east).

    x_west, y_north : [m] the first position (row 0, column 0) in the DEM's CRS
    spacing_m : [m] grid spacing; rows, cols : grid shape
    camera_height_m : [m] camera centre above the DEM surface; planet : as in
        :func:`~skyfix.horizon.render_horizons`; azimuth_bins : bins over 360 deg
    skip_tol_deg : [deg] block-skip tolerance of the pyramid trace past ``near_m`` (as the
        per-point kernel's)
    near_m : [m] every position's own ray is exact out to this distance
    line_spacing_m : [m] distance between the sweep lines (default: ``spacing_m``, at most
        :data:`LINE_SPACING_M`)
    window_m : [m] half-width of the exact trace around each line's skyline point (default: one
        DEM cell, at least :data:`WINDOW_M`)
    rising_m : [m] a ray whose near-field maximum is at ``near_m`` (still rising) is traced
        exactly out to this distance
    arc_tol_deg : [deg] how far below a line's concave pieces the chords between its samples may
        lie, seen from ``near_m`` away (:data:`ARC_TOL_DEG`; 0: crossings and crests only)
    alt_delta_deg, lateral_slope : which hull vertices beside a line's tangent vertex also get an
        exact window (:data:`ALT_DELTA_DEG`, :data:`LATERAL_SLOPE`; 0: none)

    Rays run to the DEM edge (no maximum distance). Returns a :class:`HorizonBatch` as
    :func:`~skyfix.horizon.render_horizons` does, with ``skyline_distance_m``. Memory: three float32
    arrays of (positions, bins), built bin-major and then transposed: about 8.6 kB per position at
    360 bins (0.57 GB for 256 x 256).
    """
    if not (spacing_m > 0 and math.isfinite(spacing_m)):
        raise ParameterError(f"grid spacing must be > 0 m, got {spacing_m}")
    if int(rows) != rows or int(cols) != cols or rows < 1 or cols < 1:
        raise ParameterError(f"grid shape must be positive whole numbers, got {rows} x {cols}")
    if not np.isfinite(camera_height_m) or camera_height_m < 0:
        raise ParameterError(f"camera height must be >= 0 m, got {camera_height_m}")
    if int(azimuth_bins) != azimuth_bins or azimuth_bins <= 0:
        raise ParameterError(f"azimuth bins must be a positive whole number, got {azimuth_bins}")
    ls = min(float(spacing_m), LINE_SPACING_M) if line_spacing_m is None else float(line_spacing_m)
    win = max(WINDOW_M, dem.dx, dem.dy) if window_m is None else float(window_m)
    for name, v in (("line spacing", ls), ("near field", near_m), ("window", win),
                    ("rising distance", rising_m)):
        if not (v > 0 and math.isfinite(v)):
            raise ParameterError(f"{name} must be > 0 m, got {v}")
    if not (0 <= arc_tol_deg < 90):
        raise ParameterError(f"arc tolerance must be in [0, 90) deg, got {arc_tol_deg}")
    if not (0 <= alt_delta_deg < 90 and 0 <= lateral_slope < np.inf):
        raise ParameterError(f"alternates need 0 <= delta < 90 deg and a slope >= 0, got "
                             f"{alt_delta_deg}, {lateral_slope}")
    rows, cols = int(rows), int(cols)
    xs = x_west + np.arange(cols) * float(spacing_m)
    ys = y_north - np.arange(rows) * float(spacing_m)
    gx, gy = np.meshgrid(xs, ys)
    x, y = gx.ravel(), gy.ravel()
    dem.require_inside(x, y)
    planet = resolve_planet(planet, getattr(dem, "body", None))
    bins = int(azimuth_bins)
    data, offs, prows, pcols = packed_pyramid(dem)
    az = np.radians(azimuth_centres(bins))
    # bin-major while rendering (one bin's positions together), position-major as returned
    elev = np.empty((bins, x.size), np.float32)
    length = np.empty((bins, x.size), np.float32)
    dist = np.empty((bins, x.size), np.float32)
    ground = np.empty(x.size, np.float64)
    _sweep_grid(dem.z, data, offs, prows, pcols, dem.x0, dem.y0, dem.dx, dem.dy, x, y,
                float(camera_height_m), np.sin(az), np.cos(az), planet.curvature_coeff,
                math.tan(math.radians(skip_tol_deg)), T_MIN_M, float(near_m), float(rising_m), ls,
                win, math.tan(math.radians(arc_tol_deg)), math.tan(math.radians(alt_delta_deg)),
                float(lateral_slope), elev, length, ground, dist)
    return HorizonBatch(x, y, np.ascontiguousarray(elev.T), np.ascontiguousarray(length.T), ground,
                        float(camera_height_m), float(np.inf), planet, np.ascontiguousarray(dist.T))


@njit(cache=True, nogil=True)
def _exact_span(z, u0, v0, us, vs, zc, curv, lo, hi):
    """The ray's exact maximum tangent over [lo, hi] [m] and where it is: every cell the span
    crosses maximised in closed form (:func:`~skyfix.horizon.cell_max`, the per-point kernel's
    level 0), without the pyramid (a span of a few cells gains nothing from skipping).
    (-inf, 0) over nodata only.

    The cells are walked as a line is rasterised: the first is found as
    :func:`~skyfix.horizon.pyramid_block` finds it, each next one by stepping a column or a row at
    the nearer grid-line crossing, which is what the near field, a few cells a ray, mostly costs
    (a quarter less time here than locating every cell afresh)."""
    ny, nx = z.shape
    best = -np.inf
    tb = 0.0
    ru = 1.0 / us if us != 0.0 else 0.0
    rv = 1.0 / vs if vs != 0.0 else 0.0
    j, i = -1, -1
    if hi > lo:
        i, j, _, _, _ = pyramid_block(u0, v0, us, vs, ru, rv, lo, 0, nx, ny, hi)
    # next crossing of a column (u) or row (v) line: at (j + 1 - u0) / us going east, and so on
    ju = 1 if us > 0.0 else 0
    iv = 1 if vs > 0.0 else 0
    tu = (j + ju - u0) * ru if us != 0.0 else np.inf
    tv = (i + iv - v0) * rv if vs != 0.0 else np.inf
    t = lo
    while t < hi:
        te = min(tu, tv, hi)
        if te <= t:  # rounding at a crossing: move on as pyramid_block does
            te = t + 1e-6
        f, tf = cell_max(z, i, j, u0, v0, us, vs, zc, curv, t, te)
        if f > best:
            best = f
            tb = tf
        if tu <= te:
            j += 1 if us > 0.0 else -1
            if 0 <= j <= nx - 2:
                tu = max((j + ju - u0) * ru, te + 1e-6)
            else:  # off the DEM's cells: only at its edge, which ends the span
                j = min(max(j, 0), nx - 2)
                tu = np.inf
        if tv <= te:
            i += 1 if vs > 0.0 else -1
            if 0 <= i <= ny - 2:
                tv = max((i + iv - v0) * rv, te + 1e-6)
            else:
                i = min(max(i, 0), ny - 2)
                tv = np.inf
        t = te
    return best, tb


@njit(cache=True, nogil=True)
def _window(z, u0, v0, us, vs, zc, curv, lo, hi, near, t_end):
    """The exact maximum (tangent, distance [m]) of the ray over [lo, hi] clipped to
    [near, t_end]; (-inf, 0) when that is empty."""
    lo = max(lo, near)
    hi = min(hi, t_end)
    if hi <= lo:
        return -np.inf, 0.0
    return _exact_span(z, u0, v0, us, vs, zc, curv, lo, hi)


@njit(cache=True, parallel=True, nogil=True)
def _sweep_grid(z, pdata, poffs, prows, pcols, x0, y0, dx, dy, xs, ys, h, saz, caz, curv, tol,
                t_min, near, rising, ls, win, arc_tol, alt_td, alt_slope, out_el, out_len,
                out_ground, out_dist):
    ny, nx = z.shape
    n = xs.shape[0]
    nb = saz.shape[0]
    zc = np.empty(n)
    for k in range(n):
        g = bilinear(z, (xs[k] - x0) / dx, (y0 - ys[k]) / dy)
        out_ground[k] = g
        zc[k] = g + h
    cap = (8 + 2 * ARC_MAX) * (nx + ny) + 16  # crossings, crests and arcs of the longest line
    for b in prange(nb):
        sa = saz[b]
        ca = caz[b]
        if abs(sa) < 1e-12:
            sa = 0.0
        if abs(ca) < 1e-12:
            ca = 0.0
        # Along (a) the ray and across (o) it, d = (sa, ca), n = (ca, -sa) in (east, north), from
        # the DEM's corner, with lines on a lattice fixed to it: a position's candidates, hence
        # its skyline, do not depend on which other positions share the call.
        a = (xs - x0) * sa + (ys - y0) * ca
        o = (xs - x0) * ca - (ys - y0) * sa
        m_glob = np.floor(o / ls).astype(np.int64)
        m_lo = m_glob.min()
        m_of = m_glob - m_lo
        nl = m_of.max() + 2
        # Positions by line, each line's in descending a (the order the sweep meets them), and
        # what the queries read gathered in that order: memory is read in sequence, not at random.
        start = np.zeros(nl + 1, np.int64)
        for k in range(n):
            start[m_of[k] + 1] += 1
        for m in range(nl):
            start[m + 1] += start[m]
        fill = start[:-1].copy()
        order = np.empty(n, np.int64)
        for k in range(n):
            order[fill[m_of[k]]] = k
            fill[m_of[k]] += 1
        for m in range(nl - 1):
            seg = order[start[m]:start[m + 1]]
            if seg.size > 1:
                order[start[m]:start[m + 1]] = seg[np.argsort(-a[seg], kind="mergesort")]
        qa = a[order]
        qw = zc[order] - curv * qa * qa
        cand = np.full((n, 2), np.nan)  # per position (grid order): the two lines' answers
        use_alt = alt_td > 0.0 and alt_slope > 0.0
        alt = np.full((n if use_alt else 0, 4), np.nan)  # and their alternates
        cl = np.empty(6)
        buf_s = np.empty(cap)
        buf_w = np.empty(cap)
        hs = np.empty(cap)
        hw = np.empty(cap)
        q = np.empty(n, np.int64)
        qslot = np.empty(n, np.int64)
        us = sa / dx
        vs = -ca / dy
        for m in range(nl):
            # queries: the positions below this line (slot 1) and above it (slot 0), merged by a
            i0, i1 = (start[m - 1], start[m]) if m > 0 else (0, 0)
            j0, j1 = start[m], start[m + 1] if m < nl - 1 else start[m]
            nq = 0
            while i0 < i1 or j0 < j1:
                if j0 >= j1 or (i0 < i1 and qa[i0] >= qa[j0]):
                    q[nq] = i0
                    qslot[nq] = 1
                    i0 += 1
                else:
                    q[nq] = j0
                    qslot[nq] = 0
                    j0 += 1
                nq += 1
            if nq == 0:
                continue
            om = (m + m_lo) * ls
            lx = x0 + om * ca
            ly = y0 - om * sa
            uc = (lx - x0) / dx
            vc = (y0 - ly) / dy
            s_in, s_out = line_span(uc, vc, us, vs, nx, ny)
            s_a = max(s_in, qa[q[nq - 1]] + near)
            if s_a >= s_out:
                continue
            ns = line_samples(z, uc, vc, us, vs, s_a, s_in, s_out, curv, buf_s, buf_w, arc_tol,
                               near)
            top = -1
            p = ns - 1
            for j in range(nq):
                r = q[j]
                lim = qa[r] + near
                while p >= 0 and buf_s[p] >= lim:
                    ps = buf_s[p]
                    pw = buf_w[p]
                    # keep the upper hull: drop vertices under the new leftmost point's chord
                    while top >= 1 and ((hw[top] - pw) * (hs[top - 1] - ps)
                                        <= (hw[top - 1] - pw) * (hs[top] - ps)):
                        top -= 1
                    top += 1
                    hs[top] = ps
                    hw[top] = pw
                    p -= 1
                if top < 0:
                    continue
                v = tangent_vertex(hs, hw, top, qa[r], qw[r])
                cand[order[r], qslot[j]] = hs[v] - qa[r]
                if use_alt:
                    alternates(hs, hw, top, v, qa[r], qw[r], 2.0 * curv * qa[r], alt_td,
                                alt_slope * abs(o[order[r]] - om), win, alt, order[r],
                                2 * qslot[j])
        # Each position's own ray, in grid order (the outputs are written in sequence): the exact
        # near field, and exact windows around the candidates.
        for k in range(n):
            u0 = (xs[k] - x0) / dx
            v0 = (y0 - ys[k]) / dy
            t_end = edge_distance(u0, v0, us, vs, nx, ny) * (1 - 1e-9)
            out_len[b, k] = t_end
            if not math.isfinite(zc[k]):
                out_el[b, k] = np.nan
                out_dist[b, k] = np.nan
                continue
            best, tb = _exact_span(z, u0, v0, us, vs, zc[k], curv, t_min, min(near, t_end))
            rising_near = tb >= near * (1.0 - 1e-6)
            c0 = cand[k, 0]
            c1 = cand[k, 1]
            if t_end > near and (not (math.isfinite(c0) or math.isfinite(c1))
                                 or (t_end <= rising and (c0 > t_end or c1 > t_end))):
                # Neither line reached the DEM (a position at its edge), or one ran on past this
                # short ray's end at the DEM edge: the lines say nothing of this ray. All of it.
                v, tv = trace_ray(z, pdata, poffs, prows, pcols, u0, v0, us, vs, zc[k], t_end,
                                  curv, tol, near, 0.0, best)
                if v > best:
                    best, tb = v, tv
                c0 = c1 = np.nan
                rising_near = False
            # A line that ran on past this (long) ray's end saw its skyline on terrain the ray
            # never reaches: the ray's own maximum is then most likely near its end.
            # Windows around the candidates (and their alternates, unless the lines said nothing
            # of this ray), sorted, overlapping ones traced as one.
            nc = 0
            for jc in range(6 if use_alt and (math.isfinite(c0) or math.isfinite(c1)) else 2):
                c = c0 if jc == 0 else c1 if jc == 1 else alt[k, jc - 2]
                if not math.isfinite(c):
                    continue
                if c > t_end:
                    c = t_end - win
                ic = nc
                while ic > 0 and cl[ic - 1] > c:
                    cl[ic] = cl[ic - 1]
                    ic -= 1
                cl[ic] = c
                nc += 1
            if nc > 0:
                lo = cl[0] - win
                hi = cl[0] + win
                for ic in range(1, nc + 1):
                    if ic < nc and cl[ic] - win <= hi:
                        hi = cl[ic] + win
                        continue
                    v, tv = _window(z, u0, v0, us, vs, zc[k], curv, lo, hi, near, t_end)
                    if v > best:
                        best, tb = v, tv
                    if ic < nc:
                        lo = cl[ic] - win
                        hi = cl[ic] + win
            if rising_near and t_end > near:
                # Still climbing at the near field's end (a slope whose crest lies beyond, where
                # lines a few metres to the side see another slope): exact on to ``rising``, where
                # the pyramid skips what cannot beat the skyline found so far.
                v, tv = trace_ray(z, pdata, poffs, prows, pcols, u0, v0, us, vs, zc[k],
                                  min(rising, t_end), curv, tol, near, 0.0, best)
                if v > best:
                    best, tb = v, tv
            out_el[b, k] = math.degrees(math.atan(best)) if best > -np.inf else np.nan
            out_dist[b, k] = tb if best > -np.inf else np.nan


__all__ = ["render_grid", "NEAR_M", "WINDOW_M", "ARC_TOL_DEG", "ALT_DELTA_DEG", "LATERAL_SLOPE"]
