"""Procedural value noise and fractal Brownian motion (numba), fixed in world coordinates so that
overlapping frames agree: the ground's albedo texture and the roughness of its normals.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def _hash01(ix, iy, seed):
    h = (ix * 73856093) ^ (iy * 19349663) ^ (seed * 83492791)
    h = (h ^ (h >> 13)) * 1274126177
    h = h ^ (h >> 16)
    return (h & 0xFFFFFF) / 16777215.0


@numba.njit(cache=True, nogil=True)
def _lattice(x, y, seed):
    """Cell offsets (fx, fy) of (x, y) and the hashed values at the cell's four corners."""
    ix = math.floor(x)
    iy = math.floor(y)
    i = np.int64(ix)
    j = np.int64(iy)
    return (x - ix, y - iy, _hash01(i, j, seed), _hash01(i + 1, j, seed), _hash01(i, j + 1, seed),
            _hash01(i + 1, j + 1, seed))


@numba.njit(cache=True, nogil=True)
def _value_noise(x, y, seed):
    fx, fy, a, b, c, d = _lattice(x, y, seed)
    sx = fx * fx * (3 - 2 * fx)
    sy = fy * fy * (3 - 2 * fy)
    return (a * (1 - sx) + b * sx) * (1 - sy) + (c * (1 - sx) + d * sx) * sy


@numba.njit(cache=True, nogil=True)
def _value_noise_grad(x, y, seed):
    """Gradient of :func:`_value_noise` with respect to (x, y) [per noise cell]."""
    fx, fy, a, b, c, d = _lattice(x, y, seed)
    sx = fx * fx * (3 - 2 * fx)
    sy = fy * fy * (3 - 2 * fy)
    return (((b - a) * (1 - sy) + (d - c) * sy) * 6.0 * fx * (1 - fx),
            ((c - a) * (1 - sx) + (d - b) * sx) * 6.0 * fy * (1 - fy))


@numba.njit(cache=True, nogil=True)
def _fbm(x, y, seed, wavelength, octaves, footprint):
    """Fractal value noise in [0, 1] at (x, y) [m]; octaves finer than the footprint fade to their mean."""
    total = 0.0
    norm = 0.0
    amp = 1.0
    w = wavelength
    for k in range(octaves):
        fade = min(max((w / max(footprint, 1e-9) - 1.0) / 3.0, 0.0), 1.0)
        v = _value_noise(x / w, y / w, seed + k)
        total += amp * (fade * v + (1 - fade) * 0.5)
        norm += amp
        amp *= 0.55
        w *= 0.5
    return total / norm


@numba.njit(cache=True, parallel=True, nogil=True)
def albedo_texture(px, py, footprint, seed, wavelength, octaves, out):
    """Fill ``out`` (H, W) with fractal value noise at the world points (px, py) [m], each pixel
    band-limited to its ground ``footprint`` [m] (no aliasing far away); ``wavelength`` [m] of the
    coarsest octave."""
    H, W = out.shape
    for i in numba.prange(H):
        for j in range(W):
            if math.isfinite(px[i, j]):
                out[i, j] = _fbm(px[i, j], py[i, j], seed, wavelength, octaves, footprint[i, j])
            else:
                out[i, j] = 0.5


@numba.njit(cache=True, nogil=True)
def _fbm_slope(x, y, seed, wavelength, octaves, footprint, slope, decay):
    """Gradient (dh/dx, dh/dy) [m/m] of a fractal height field below the DEM's resolution.

    Octave k has wavelength ``wavelength / 2**k`` [m] and a slope amplitude ``slope decay**k``
    (a rough surface is steeper at small scales); octaves finer than the footprint fade out, as
    in :func:`_fbm`, so distant ground shows only the relief its pixels can resolve.
    """
    gx = 0.0
    gy = 0.0
    w = wavelength
    a = slope
    for k in range(octaves):
        fade = min(max((w / max(footprint, 1e-9) - 1.0) / 3.0, 0.0), 1.0)
        if fade > 0.0:
            # height = a w (value noise - 0.5): its gradient is a times the noise's unit derivative
            nx, ny = _value_noise_grad(x / w, y / w, seed + 50 + k)
            gx += fade * a * nx
            gy += fade * a * ny
        w *= 0.5
        a *= decay
    return gx, gy


@numba.njit(cache=True, parallel=True, nogil=True)
def roughen_normals(px, py, footprint, ground, seed, normal):
    """Tilt the ground's normals (in place) by the slopes of :func:`_fbm_slope`.

    The DEM's bilinear facets are smooth inside a cell; real ground is rough at every scale, and
    its shading is what gives terrain its texture in images (measured on the Curiosity dev
    mosaics: the terrain's local gradient is 10-20x the sky's; without this, 2-4x). Only the
    shading changes, so the skyline stays the ray caster's exact one.
    """
    H, W = ground.shape
    for i in numba.prange(H):
        for j in range(W):
            if not ground[i, j]:
                continue
            gx, gy = _fbm_slope(px[i, j], py[i, j], seed, 40.0, 10, footprint[i, j], 0.35, 0.9)
            nx = normal[i, j, 0]
            ny = normal[i, j, 1]
            nz = normal[i, j, 2]
            if nz <= 1e-3:
                continue
            # surface z = Z + h: normal ~ (-Zx - hx, -Zy - hy, 1), with -Zx = nx / nz
            ax = nx / nz - gx
            ay = ny / nz - gy
            inv = 1.0 / math.sqrt(ax * ax + ay * ay + 1.0)
            normal[i, j, 0] = ax * inv
            normal[i, j, 1] = ay * inv
            normal[i, j, 2] = inv
