"""The sweep's lines (:mod:`skyfix.sweep`): the terrain along a line of one azimuth, sampled where
its bilinear surface kinks or bulges, and the queries on its upper hull (where a camera on the
line sees it highest, and the vertices beside that which a position between lines may see higher).
Distances along a line are metres; ``w = z - curv s**2`` takes curvature and refraction in."""

from __future__ import annotations

import math

import numpy as np

from .horizon import bilinear, corner_sum
from .jit import njit

#: most points added along one concave piece of a line
ARC_MAX = 8


@njit(cache=True, nogil=True)
def line_span(uc, vc, us, vs, nx, ny):
    """The along-line interval [s_in, s_out] [m] inside the DEM's pixel-centre hull for the line
    u = uc + us s, v = vc + vs s (index space); s_in > s_out when the line misses the DEM."""
    lo = -np.inf
    hi = np.inf
    for c, d, top in ((uc, us, nx - 1.0), (vc, vs, ny - 1.0)):
        if d == 0.0:
            if c < 0.0 or c > top:
                return 1.0, 0.0
        else:
            s0 = (0.0 - c) / d
            s1 = (top - c) / d
            lo = max(lo, min(s0, s1))
            hi = min(hi, max(s0, s1))
    return lo, hi


@njit(cache=True, nogil=True)
def _crossings(c, d, s_a):
    """Where the coordinate ``c + d s`` crosses whole numbers around ``s_a`` [m]: the last
    crossing at or before it, the next one after it, and the step between crossings (-inf, inf,
    inf when the line runs along the axis)."""
    if d == 0.0:
        return -np.inf, np.inf, np.inf
    k = math.floor(c + d * s_a) if d > 0 else math.ceil(c + d * s_a)
    return (k - c) / d, (k + (1.0 if d > 0 else -1.0) - c) / d, abs(1.0 / d)


@njit(cache=True, nogil=True, inline="always")
def _in_cell(z, i, j, u, v):
    """Bilinear height [m] at (u, v) from cell (i, j)'s corners alone, the fractions clamped to
    the cell: a crossing on the cell's edge read from the piece's own cell, whatever void lies
    across the edge (:func:`~skyfix.horizon.bilinear` reads the cell a rounding picks)."""
    # corners of weight 0 left out, as horizon.bilinear does: a line along the cell's edge has
    # the edge's height whichever side a void lies
    return corner_sum(z, i, j, min(max(u - j, 0.0), 1.0), min(max(v - i, 0.0), 1.0))


@njit(cache=True, nogil=True)
def line_samples(z, uc, vc, us, vs, s_a, s_in, s_b, curv, out_s, out_w, arc_tol, near):
    """Terrain along a line from the grid-line crossing at or before ``s_a`` (not before the
    DEM entry ``s_in``) to ``s_b``, ascending: out_s [m] and ``w = z - curv s**2`` [m], at every
    grid-line crossing (the bilinear surface's kinks), at both ends, and at the top of every
    crossing-to-crossing piece that bulges upward (inside a cell the surface along a line is the
    parabola ``h + b s + e us vs s**2``: a ridge crossing a cell diagonally crests between the
    crossings, metres above both). Along such a piece also points enough that no chord lies
    more than ``arc_tol * near`` [m] (``arc_tol`` an angle's tangent) below the parabola: a sight
    line can touch a concave piece anywhere, not only at its crest (a slope that still climbs
    where it meets the next grid line), and the hull of crossings and crests alone misses it by up
    to the parabola's sagitta (metres on 80 m cells). Starting on a crossing makes the samples
    past any point the same whichever queries asked for the line. Samples over nodata are left
    out. Returns the count."""
    ny, nx = z.shape
    cap = out_s.shape[0]
    s0u, ku, step_u = _crossings(uc, us, s_a)
    s0v, kv, step_v = _crossings(vc, vs, s_a)
    s0 = max(s_in, s0u, s0v)
    s_a = min(s0, s_a)
    s = s_a
    h0 = bilinear(z, uc + us * s, vc + vs * s)
    n = 0
    if math.isfinite(h0):
        out_s[0] = s
        out_w[0] = h0 - curv * s * s
        n = 1
    uv = us * vs
    # A line that enters the DEM beside the grid starts on the hull's edge, a grid line: rounding
    # can put the "next" crossing on the start itself, a piece of length 0 (no crest to look for).
    while s < s_b and n < cap - 2 - ARC_MAX:
        nxt = min(ku, kv, s_b)
        if ku <= nxt:
            ku += step_u
        if kv <= nxt:
            kv += step_v
        mid = 0.5 * (s + nxt)
        j = min(max(int(math.floor(uc + us * mid)), 0), nx - 2)
        i = min(max(int(math.floor(vc + vs * mid)), 0), ny - 2)
        if nxt <= s:  # a piece of length 0 (see above): its end is its start
            h1 = bilinear(z, uc + us * nxt, vc + vs * nxt)
        else:
            # Both ends from the piece's own cell: a crossing read from the cell beyond it was
            # NaN where that cell touches a void (a reprojected DEM's wedges), and the whole
            # valid piece before it, crest and end, was lost to the hull (skylines 1.5-4.9 deg
            # low beside voids)
            h0 = _in_cell(z, i, j, uc + us * s, vc + vs * s)
            h1 = _in_cell(z, i, j, uc + us * nxt, vc + vs * nxt)
            if math.isfinite(h0) and (n == 0 or out_s[n - 1] != s):
                out_s[n] = s
                out_w[n] = h0 - curv * s * s
                n += 1
        if uv != 0.0 and nxt > s and math.isfinite(h0) and math.isfinite(h1):
            q = (z[i, j] - z[i, j + 1] - z[i + 1, j] + z[i + 1, j + 1]) * uv
            if q < 0.0:  # concave: its vertex, if inside the piece, and points along it
                d = nxt - s
                b = (h1 - h0) / d - q * d
                x = -b / (2.0 * q)
                ka = 1  # parts: a chord over a part of length d / ka lies q (d / ka)**2 / 8 low
                if arc_tol > 0.0:
                    tol_m = arc_tol * near
                    ka = min(int(math.ceil(d * math.sqrt(-q / (8.0 * tol_m)))), ARC_MAX)
                crest = 0.0 < x < d
                for ia in range(1, ka + 1):
                    xa = d * ia / ka
                    if crest and x <= xa:
                        sv = s + x
                        out_s[n] = sv
                        out_w[n] = h0 + b * x + q * x * x - curv * sv * sv
                        n += 1
                        crest = False
                    if ia < ka and xa != x:
                        sv = s + xa
                        out_s[n] = sv
                        out_w[n] = h0 + b * xa + q * xa * xa - curv * sv * sv
                        n += 1
        if math.isfinite(h1):
            out_s[n] = nxt
            out_w[n] = h1 - curv * nxt * nxt
            n += 1
        s = nxt
        h0 = h1
    return n


@njit(cache=True, nogil=True)
def tangent_vertex(hs, hw, top, qs, qw):
    """Index of the upper-hull vertex with the steepest slope from (qs, qw), which lies left of
    every vertex. The hull is hs/hw[0..top], its leftmost vertex at ``top``: slopes from the query
    rise then fall along it, so a binary search finds the peak."""
    lo = 0  # count from the left: vertex j is hs[top - j]
    hi = top
    while lo < hi:
        mid = (lo + hi) // 2
        i = top - mid
        # rising where the next edge is steeper than the sight line to this vertex
        if (hw[i - 1] - hw[i]) * (hs[i] - qs) > (hw[i] - qw) * (hs[i - 1] - hs[i]):
            lo = mid + 1
        else:
            hi = mid
    return top - lo


@njit(cache=True, nogil=True)
def alternates(hs, hw, top, v, qs, qw, ca, td, ge, win, out, row, slot):
    """Two hull vertices besides the tangent vertex ``v`` that may make the position's skyline
    where the line ranks them a little lower: the nearer neighbour of ``v`` (out[row, slot]) and
    the first vertex more than ``2 win`` beyond it (out[row, slot + 1], distances [m] from the
    query; the one between lie in the tangent's own window). Each only if the query sees it at
    most an angle of tangent ``td`` below ``v``, and at most ``ge (1/d_t + 1/d_i)`` [rad]
    (``ge``: a lateral slope times the line's offset from the position). Slopes from the query
    (``ca``: the curvature's shear) rise from ``top`` to ``v`` and fall past it."""
    dt = hs[v] - qs
    tv = (hw[v] - qw) / dt + ca
    thr = (tv - td) / (1.0 + tv * td) - ca  # the slope seen td below the tangent vertex
    gs = ge * (1.0 + tv * tv)  # angle to slope, near the tangent's angle
    if v < top:
        di = hs[v + 1] - qs
        wi = hw[v + 1] - qw
        if wi >= thr * di and tv - ca - wi / di <= gs * (1.0 / dt + 1.0 / di):
            out[row, slot] = di
    i = v - 1
    while i >= 0 and hs[i] - hs[v] <= 2.0 * win:
        i -= 1
    if i >= 0:
        di = hs[i] - qs
        wi = hw[i] - qw
        if wi >= thr * di and tv - ca - wi / di <= gs * (1.0 / dt + 1.0 / di):
            out[row, slot + 1] = di


__all__ = ["ARC_MAX", "line_span", "line_samples", "tangent_vertex", "alternates"]
