"""Rendering images of a DEM stack (``conventions.md``: at every point the finest DEM that covers
it is the terrain): what :func:`skyfix.raycast.cast_image` and
:func:`skyfix.raycast.column_skyline` do for one DEM, over the layers a camera sees
(:meth:`skyfix.stack.DemStack.layers`: the member it stands on, then each coarser one with what the
finer ones hold masked out). Each pixel's ray meets the nearest of the layers' surfaces, so a
ridge beyond the fine DEM's edge is drawn from the coarse one and hides nothing nearer.

A plain :class:`skyfix.dem.Dem` goes straight to the single-DEM functions (the same pixels).
"""

from __future__ import annotations

import numpy as np

from ..raycast import CastResult, Projection, cast_image, column_skyline, ground_hits


def scene_layers(dem, origin) -> list:
    """The surfaces a camera at ``origin`` (x, y, z) [m] sees: ``[dem]`` for one DEM, the stack's
    layers for the member the camera stands on otherwise."""
    layers = getattr(dem, "layers", None)
    if layers is None:
        return [dem]
    level = int(dem.level_of(origin[0], origin[1])[0])
    return layers(level)


def cast_layers(layers, origin, proj: Projection, *, planet="earth", rocks=None) -> CastResult:
    """:func:`skyfix.raycast.cast_image` over several surfaces: per pixel the nearest terrain hit
    (horizontal distance [m]) and that surface's normal; rocks as for one DEM."""
    first = cast_image(layers[0], origin, proj, planet=planet, rocks=rocks)
    if len(layers) == 1:
        return first
    t, normal = first.terrain_t.copy(), first.normal.copy()
    for m in layers[1:]:
        r = cast_image(m, origin, proj, planet=planet, rocks=rocks)
        nearer = r.terrain_t < t
        t[nearer] = r.terrain_t[nearer]
        # each cast already chose between its terrain and a nearer rock for the normal
        normal[nearer] = r.normal[nearer]
    return CastResult(first.direction, t, first.rock_s, first.rock_id, normal, first.origin)


def skyline_layers(layers, origin, proj: Projection, sky_mask: np.ndarray, *, planet="earth",
                   rocks=None, iterations: int = 30) -> np.ndarray:
    """:func:`skyfix.raycast.column_skyline` over several surfaces: sub-pixel row [px] per column
    of the first sky-to-ground edge from the top (NaN where none), bisected on the union of the
    surfaces (a ray is ground when it meets any of them)."""
    if len(layers) == 1:
        return column_skyline(layers[0], origin, proj, sky_mask, planet=planet, rocks=rocks,
                              iterations=iterations)
    sky = np.asarray(sky_mask, bool)
    H, W = sky.shape
    out = np.full(W, np.nan)
    has_sky = sky.any(axis=0)
    first_sky = np.argmax(sky, axis=0)
    ground_after = ~sky & (np.arange(H)[:, None] > first_sky[None, :])
    cols = np.flatnonzero(has_sky & ground_after.any(axis=0))
    if cols.size == 0:
        return out
    hi = np.argmax(ground_after[:, cols], axis=0).astype(np.float64)  # first ground pixel centre
    lo = hi - 1.0  # the sky pixel centre above it
    u = cols.astype(np.float64)
    for _ in range(int(iterations)):
        mid = 0.5 * (lo + hi)
        g = np.zeros(cols.size, bool)
        for m in layers:
            g |= ground_hits(m, origin, proj, u, mid, planet=planet, rocks=rocks)
        hi = np.where(g, mid, hi)
        lo = np.where(g, lo, mid)
    out[cols] = 0.5 * (lo + hi)
    return out
