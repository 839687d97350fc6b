"""From ray-cast geometry to pixels: Lambert shading from a sun direction, the albedo texture, snow,
a lake mirroring the sky, a planet sky, clouds, distance haze, optics blur, vignetting, glare and
sensor noise.
"""

from __future__ import annotations

import numpy as np

from ..raycast import CastResult
from .noise import albedo_texture, roughen_normals
from .scene import Scene, palette


def _sky(direction: np.ndarray, scene: Scene, horizon, zenith) -> np.ndarray:
    el = np.clip(direction[..., 2], -1, 1)
    w = np.clip(el, 0, 1) ** 0.45  # brighter near the horizon, quickly darker up
    sky = horizon * (1 - w[..., None]) + zenith * w[..., None]
    # Forward scattering: the sky brightens around the sun (wider on dusty Mars).
    cos_sun = direction @ scene.sun
    width = 0.25 if scene.planet == "mars" else 0.12
    glow = np.exp((cos_sun - 1.0) / width)
    sky = sky + 0.35 * glow[..., None] * np.array([1.0, 0.95, 0.85])
    return sky


def _clouds(direction: np.ndarray, scene: Scene, strength: float) -> np.ndarray:
    """Cloud cover in [0, 1] on a layer 2 km up (world-fixed, so frames agree)."""
    dz = direction[..., 2]
    up = dz > 0.02
    s = np.where(up, 2000.0 / np.maximum(dz, 0.02), np.nan)
    px = np.where(up, direction[..., 0] * s, np.nan).astype(np.float64)
    py = np.where(up, direction[..., 1] * s, np.nan).astype(np.float64)
    n = np.empty(dz.shape)
    albedo_texture(px, py, np.full(dz.shape, 1.0), scene.cloud_seed, 3000.0, 6, n)
    thr = 0.62 - 0.22 * strength
    cover = np.clip((n - thr) / 0.12, 0, 1) * up
    # Fade the layer out towards the horizon so clouds stay above the skyline.
    return cover * np.clip((dz - 0.02) / 0.08, 0, 1)


#: what still water shows of itself, linear RGB (dark, a little green)
WATER_BODY = np.array([0.025, 0.045, 0.05])


def _lake(d, pts, kind, dist, surf, scene: Scene, horizon, zenith, origin):
    """Terrain seen under the lake's level is water: a ray that meets the ground below the level
    crossed the water's surface first (it runs downwards there). The surface mirrors the sky
    (Schlick's Fresnel term for water: 2 % looking down, a mirror at grazing angles), faintly
    rippled by a world-fixed texture, over the dark water body. Returns (surface colours, 3-D
    distances [m]) with the water's put in; the lake mirrors the sky only, not the terrain."""
    dz = d[..., 2]
    under = (kind == 1) & (np.nan_to_num(pts[..., 2], nan=np.inf) < scene.lake_z_m) & (dz < 0)
    if not under.any():
        return surf, dist
    s = np.where(under, (scene.lake_z_m - origin[2]) / np.where(under, dz, -1.0), 0.0)
    # ripples tilt the mirrored rays by up to ~1 deg, fixed on the water (frames agree)
    wx, wy = origin[0] + d[..., 0] * s, origin[1] + d[..., 1] * s
    ripple = np.empty(dz.shape)
    albedo_texture(wx, wy, np.full(dz.shape, 1.0), scene.texture_seed + 202, 2.0, 3, ripple)
    up = np.clip(-dz + 0.03 * (ripple - 0.5), 1e-3, 1.0)
    mirrored = np.stack([d[..., 0], d[..., 1], up], axis=-1)
    mirrored /= np.linalg.norm(mirrored, axis=-1, keepdims=True)
    fresnel = (0.02 + 0.98 * (1.0 - np.clip(-dz, 0.0, 1.0)) ** 5)[..., None]
    water = fresnel * _sky(mirrored, scene, horizon, zenith) + (1 - fresnel) * WATER_BODY
    return np.where(under[..., None], water, surf), np.where(under, s, dist)


#: fresh snow's albedo, linear RGB (a little bluer than white)
SNOW_ALBEDO = np.array([0.86, 0.89, 0.93])


def snow_cover(z, normal_z, tex, camera_z, strength):
    """Snow cover in [0, 1] of terrain points at heights ``z`` [m] with surface normals' vertical
    component ``normal_z``: above a snow line ``600 (1 - strength) - 100`` m over the camera
    (strength 1: the camera's own valley floor is white), its edge ragged by the world-fixed
    texture ``tex`` (+-60 m), and only where the slope is under about 50 deg (rock faces
    steeper than that hold no snow)."""
    line = camera_z + 600.0 * (1.0 - strength) - 100.0 + 120.0 * (0.5 - tex)
    above = np.clip((np.nan_to_num(z, nan=-1e9) - line) / 30.0, 0.0, 1.0)
    flat_enough = np.clip((normal_z - 0.55) / 0.15, 0.0, 1.0)
    return above * flat_enough


def antialias_edge(img: np.ndarray, edge_rows: np.ndarray) -> None:
    """Blend the pixel holding each column's sub-pixel skyline row by its ground coverage.

    A pixel centre is ground when ``v >= r``; the pixel ``p = round(r)`` spans ``[p - 0.5, p + 0.5]``
    and is ground over ``p + 0.5 - r`` of it. Mixing its colour with its sky (above) or ground
    (below) neighbour puts the image's edge on the truth row, not on the pixel grid.
    """
    H = img.shape[0]
    cols = np.flatnonzero(np.isfinite(edge_rows))
    r = edge_rows[cols]
    p = np.round(r).astype(int)
    ok = (p >= 1) & (p <= H - 2)
    cols, r, p = cols[ok], r[ok], p[ok]
    f = np.clip(p + 0.5 - r, 0.0, 1.0)[:, None]
    centre_ground = p >= r
    ground = np.where(centre_ground[:, None], img[p, cols], img[p + 1, cols])
    sky = np.where(centre_ground[:, None], img[p - 1, cols], img[p, cols])
    img[p, cols] = f * ground + (1 - f) * sky


def shade(cast: CastResult, scene: Scene, *, focal_px: float, rng: np.random.Generator,
          sun_pixel=None, vignetting=True, edge_rows: np.ndarray | None = None) -> np.ndarray:
    """Render a :class:`CastResult` to an 8-bit RGB image ``(H, W, 3)``.

    focal_px : [px/rad] angular resolution (for texture filtering and blur scale)
    sun_pixel : (u, v) [px] of the sun where it is in view (lens flare ghosts), or None
    """
    import cv2

    c = scene.conditions
    H, W = cast.terrain_t.shape
    d = cast.direction.astype(np.float64)
    kind = cast.kind
    dist = cast.distance
    pts = cast.points()
    ground_a, ground_b, horizon, zenith = palette(scene.planet, c.dust)

    # Albedo fixed in world coordinates; rock texture in the rock's own frame.
    footprint = np.where(np.isfinite(dist), dist / focal_px, 1.0)
    grazing = np.abs(np.sum(d * cast.normal, axis=-1))
    footprint = footprint / np.maximum(grazing, 0.15)
    tex = np.empty((H, W))
    albedo_texture(pts[..., 0].copy(), pts[..., 1].copy(), footprint, scene.texture_seed, 400.0, 11, tex)
    tex2 = np.empty((H, W))
    albedo_texture(pts[..., 0] + 0.37 * pts[..., 2], pts[..., 1] - 0.29 * pts[..., 2], footprint,
             scene.texture_seed + 101, 3.0, 5, tex2)
    mix = np.clip((tex - 0.35) * 2.0, 0, 1)[..., None]
    albedo = ground_a * (1 - mix) + ground_b * mix
    # Metre-scale albedo (stones, soil, plants) varies by about +-20 % (tex2's std is 0.12). It
    # is multiplicative, so it survives in shadow, where the roughness below gives no texture:
    # at +-6 % a slope in its own shadow rendered smooth and read as sky.
    albedo = albedo * np.clip(1.0 + 1.6 * (tex2[..., None] - 0.5), 0.4, 1.6)
    if c.snow > 0:
        cover = snow_cover(pts[..., 2], cast.normal[..., 2], tex, cast.origin[2], c.snow)
        cover = np.where(kind == 1, cover, 0.0)[..., None]
        albedo = albedo * (1 - cover) + cover * SNOW_ALBEDO * (0.94 + 0.12 * tex2[..., None])
    rock = kind == 2
    if rock.any():
        rock_col = np.array([0.30, 0.24, 0.20]) if scene.planet == "mars" else np.array([0.33, 0.32, 0.30])
        albedo[rock] = rock_col * (0.6 + 0.8 * tex2[rock, None])

    # Lambert shading with a sky ambient term, on ground roughened below the DEM's resolution.
    sun = scene.sun
    normal = cast.normal.astype(np.float64)
    roughen_normals(pts[..., 0].copy(), pts[..., 1].copy(), footprint, kind == 1,
                     scene.texture_seed, normal)
    ndl = np.clip(normal @ sun, 0, None)
    # Sky light reaches a facet in proportion to the sky it sees, (1 + n_z) / 2 for a uniform
    # sky: the rough ground keeps some relief in shadow.
    light = 0.25 * 0.5 * (1.0 + normal[..., 2]) + 1.0 * ndl
    surf = albedo * light[..., None]

    sky = _sky(d, scene, horizon, zenith)
    if c.clouds > 0:
        cover = _clouds(d, scene, c.clouds)[..., None]
        sky = sky * (1 - cover) + cover * (np.array([0.95, 0.95, 0.97]) * (0.8 + 0.25 * tex2[..., None]))

    if c.lake > 0 and np.isfinite(scene.lake_z_m):
        surf, dist = _lake(d, pts, kind, dist, surf, scene, horizon, zenith, cast.origin)

    # Aerial perspective: distant terrain takes the colour of the sky at the horizon.
    haze = 1.0 - np.exp(-np.where(np.isfinite(dist), dist, 0.0) / scene.haze_m)
    surf = surf * (1 - haze[..., None]) + horizon * haze[..., None]
    img = np.where((kind == 0)[..., None], sky, surf)
    if edge_rows is not None:
        antialias_edge(img, edge_rows)

    if c.glare > 0:
        ang = np.arccos(np.clip(d @ sun, -1, 1))
        veil = c.glare * (1.6 * np.exp(-ang / 0.02) + 0.5 * np.exp(-ang / 0.12) + 0.12 * np.exp(-ang / 0.6))
        img = img + veil[..., None] * np.array([1.0, 0.97, 0.9])
        if sun_pixel is not None:
            img = img + c.glare * _flare(W, H, sun_pixel)
    if vignetting:
        uu, vv = np.meshgrid((np.arange(W) - (W - 1) / 2) / focal_px, (np.arange(H) - (H - 1) / 2) / focal_px)
        img = img * (1.0 / (1.0 + uu * uu + vv * vv) ** 1.5)[..., None]

    img = img * scene.gain
    sigma = scene.blur_px
    img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), sigma)
    if c.blur > 0:  # a short motion streak on top of defocus
        k = int(round(1 + 6 * c.blur))
        kernel = np.zeros((2 * k + 1, 2 * k + 1), np.float32)
        kernel[k, :] = 1.0 / (2 * k + 1)
        img = cv2.filter2D(img, -1, kernel)
    # Shot + read noise in linear units, then gamma and 8 bits.
    img = np.clip(img, 0, None)
    img = img + rng.normal(0, 1, img.shape) * np.sqrt(scene.noise * 0.02 * img + scene.noise**2)
    img = np.clip(img, 0, 1) ** (1 / 2.2)
    return np.round(img * 255).astype(np.uint8)


def _flare(W: int, H: int, sun_uv) -> np.ndarray:
    """Lens-flare ghosts along the line from the sun through the image centre."""
    su, sv = sun_uv
    cu, cv = (W - 1) / 2, (H - 1) / 2
    out = np.zeros((H, W, 3))
    uu, vv = np.meshgrid(np.arange(W), np.arange(H))
    cols = [(1.0, 0.6, 0.3), (0.4, 1.0, 0.5), (0.5, 0.6, 1.0), (1.0, 0.9, 0.6)]
    for k, (f, rad) in enumerate(((0.4, 0.04), (-0.3, 0.07), (-0.8, 0.03), (-1.3, 0.1))):
        gu, gv = cu + f * (su - cu), cv + f * (sv - cv)
        r = rad * W
        disc = np.clip(1 - np.hypot(uu - gu, vv - gv) / r, 0, 1) ** 0.5
        out += 0.08 * disc[..., None] * np.array(cols[k])
    return out
