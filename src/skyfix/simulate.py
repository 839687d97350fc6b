"""Stage 4: realistic rover acquisitions from a DEM, with exact ground truth.

:func:`simulate_acquisition` ray-casts every pixel of a frame set (pinhole frames on a mast) or a
body-levelled equirectangular panorama (:mod:`skyfix.raycast`), shades it and writes the
acquisition format of ``conventions.md``: ``acquisition.json`` with ``truth``, the PNG images and
for each image ``NAME.skyline.json``, the exact terrain skyline (sub-pixel row per column where the
pixel ray first meets the DEM, ``null`` where the column has no sky-to-ground edge). With rocks,
which the DEM lacks, ``NAME.visible.skyline.json`` holds the skyline a camera really sees.

Looks: Lambert shading from a sun direction, an albedo texture fixed in world coordinates (so
overlapping frames agree), a planet sky, distance haze, optics blur, vignetting, sensor noise.
:class:`Conditions` adds dust, clouds, rocks, glare, exposure faults and blur, each with a strength
in [0, 1]. :func:`simulate_set` draws the named robustness sets (:data:`SETS`).
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import tempfile
from contextlib import contextmanager
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numba
import numpy as np

from ._io import atomic_path, write_json
from .camera import Camera, get_camera
from .dem import Dem
from .errors import OutputExistsError, ParameterError
from .formats import Acquisition, Frame, PanoramaSpec, Skyline, Truth, save_acquisition, write_skyline_json
from .planets import get_planet
from .raycast import CastResult, Projection, camera_centre, cast_image, column_skyline

log = logging.getLogger(__name__)

#: panorama size [px] and extent [deg]: 4096 x 1024 over 360 x 90 deg gives square pixels
PANO_WIDTH, PANO_HEIGHT = 4096, 1024
PANO_ELEVATION_TOP_DEG, PANO_VFOV_DEG = 45.0, 90.0


# --- conditions ----------------------------------------------------------------------------------

@dataclass(frozen=True)
class Conditions:
    """Degradations of an acquisition, each a strength in [0, 1] (0 = absent).

    dust : airborne dust: short haze distance, low contrast at the horizon
    clouds : bright cloud structures above the skyline (Earth only)
    rocks : boulders near the rover that the DEM does not contain and that cut the skyline
    glare : the sun in view, with veiling glare and lens flare
    overexposed, dark : exposure faults (gain up to x3 and clipped; gain down to x0.15, noisier)
    blur : defocus / motion blur (up to about 4 px)
    """

    dust: float = 0.0
    clouds: float = 0.0
    rocks: float = 0.0
    glare: float = 0.0
    overexposed: float = 0.0
    dark: float = 0.0
    blur: float = 0.0

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if not (isinstance(v, (int, float)) and 0.0 <= v <= 1.0):
                raise ParameterError(f"condition {f.name} strength must be in [0, 1], got {v!r}")

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    @classmethod
    def parse(cls, spec: str | None) -> "Conditions":
        """``"dust,rocks:0.5"``: comma-separated names, each optionally ``:strength`` (default 1)."""
        if spec is None or not str(spec).strip():
            return cls()
        kw = {}
        for item in str(spec).split(","):
            item = item.strip()
            if not item:
                continue
            name, _, val = item.partition(":")
            name = name.strip().lower()
            if name not in cls.names():
                raise ParameterError(
                    f"unknown condition {name!r}: choose from {', '.join(cls.names())} "
                    "(e.g. --conditions dust:0.5,rocks)")
            try:
                kw[name] = float(val) if val.strip() else 1.0
            except ValueError:
                raise ParameterError(f"condition {name}: strength {val!r} is not a number in [0, 1]") from None
        return cls(**kw)

    def active(self) -> dict:
        return {k: v for k, v in asdict(self).items() if v > 0}

    def __str__(self) -> str:
        return ",".join(f"{k}:{v:g}" for k, v in self.active().items()) or "nominal"


def _conditions(c) -> Conditions:
    if c is None:
        return Conditions()
    if isinstance(c, Conditions):
        return c
    if isinstance(c, str):
        return Conditions.parse(c)
    if isinstance(c, dict):
        return Conditions(**c)
    raise ParameterError(f"conditions must be a Conditions, a dict or a string, got {type(c).__name__}")


# --- scene ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Scene:
    """Everything the renderer needs besides geometry (drawn once per acquisition).

    sun_az_deg, sun_el_deg : [deg] sun direction (azimuth from grid north)
    haze_m : [m] distance at which haze hides 63 % of the terrain's own light
    gain : exposure gain (1 nominal)
    rocks : (K, 5) ellipsoids (x, y, z, radius_h, radius_v) [m]
    """

    planet: str
    sun_az_deg: float
    sun_el_deg: float
    haze_m: float
    gain: float
    noise: float
    blur_px: float
    conditions: Conditions
    texture_seed: int
    cloud_seed: int
    rocks: tuple = ()

    @property
    def sun(self) -> np.ndarray:
        a, e = math.radians(self.sun_az_deg), math.radians(self.sun_el_deg)
        return np.array([math.cos(e) * math.sin(a), math.cos(e) * math.cos(a), math.sin(e)])

    def rocks_array(self) -> np.ndarray:
        return np.asarray(self.rocks, float).reshape(-1, 5)


def _palette(planet: str, dust: float):
    """(terrain base colour, terrain variant colour, sky at horizon, sky at zenith), linear RGB."""
    if planet == "mars":
        ground_a = np.array([0.50, 0.31, 0.18])
        ground_b = np.array([0.30, 0.22, 0.17])
        horizon = np.array([0.78, 0.60, 0.42])
        zenith = np.array([0.50, 0.38, 0.28])
    else:
        ground_a = np.array([0.42, 0.38, 0.32])
        ground_b = np.array([0.20, 0.25, 0.14])
        horizon = np.array([0.72, 0.80, 0.90])
        zenith = np.array([0.18, 0.36, 0.72])
    if dust > 0:  # dust whitens and flattens the sky towards the haze colour
        dust_col = np.array([0.80, 0.66, 0.50]) if planet == "mars" else np.array([0.78, 0.74, 0.66])
        horizon = (1 - 0.7 * dust) * horizon + 0.7 * dust * dust_col
        zenith = (1 - 0.6 * dust) * zenith + 0.6 * dust * horizon
    return ground_a, ground_b, horizon, zenith


def _rock_layout(dem: Dem, origin, truth: Truth, camera_height_m: float, az_lo: float,
                 az_span: float, strength: float, rng: np.random.Generator, planet) -> tuple:
    """Boulders near the rover inside the viewed azimuths, (x, y, z, radius_h, radius_v) [m].

    Half of them rise above the rendered skyline behind them (by 0.3 to 3.5 deg with strength),
    so they cut it whatever the terrain; the rest are clutter on the ground.
    """
    from .horizon import render_horizons

    hb = render_horizons(dem, [truth.x], [truth.y], camera_height_m=camera_height_m, planet=planet,
                         azimuth_bins=720)
    sky_el = np.nan_to_num(hb.elevation_deg[0], nan=0.0)
    n = int(round(2 + 6 * strength))
    rocks: list[tuple] = []
    for attempt in range(n * 40):
        if len(rocks) >= n:
            break
        az_deg = (truth.yaw_deg + az_lo + rng.uniform(0, az_span)) % 360.0
        az = math.radians(az_deg)
        bury = rng.uniform(0.1, 0.4)  # centre above the ground, in vertical radii
        # Where no boulder can reach the skyline (a steep slope down), settle for clutter.
        cutting = len(rocks) % 2 == 0 and attempt < n * 30
        if cutting:
            dist = rng.uniform(3.0, 6.0 + 12.0 * strength)
        else:
            dist = rng.uniform(2.0, 12.0)
        x = origin[0] + dist * math.sin(az)
        y = origin[1] + dist * math.cos(az)
        if not dem.contains(x, y) or not np.isfinite(g := float(dem.height_at(x, y))):
            continue
        if cutting:
            # The top must clear the line of sight to the skyline behind it.
            el = sky_el[int(round(az_deg * 2)) % 720] + rng.uniform(0.3, 1.0 + 2.5 * strength)
            top = origin[2] + dist * math.tan(math.radians(min(el, 60.0)))
            r_v = (top - g) / (1.0 + bury)
            if not 0.2 <= r_v <= 1.0 + 1.5 * strength:  # too big for a boulder here: try again
                continue
        else:
            r_v = rng.uniform(0.1, 0.2 + 0.5 * strength)
        r_h = r_v / rng.uniform(0.6, 0.9)
        if dist < r_h + 1.5 or any(math.hypot(x - q[0], y - q[1]) < r_h + q[3] for q in rocks):
            continue
        zc = g + bury * r_v
        rocks.append((x, y, zc, r_h, r_v))
    return tuple(rocks)


def make_scene(planet: str, conditions: Conditions, seed: int, *, sun_az_deg=None, sun_el_deg=None,
               rocks=()) -> Scene:
    rng = np.random.default_rng([seed, 17])
    c = conditions
    if c.clouds > 0 and planet != "earth":
        raise ParameterError("the clouds condition is for Earth only: drop it or use --planet earth")
    # Dust shortens the haze distance geometrically: 0.5 -> about 6 km on Mars, 1 -> 1.6 km.
    haze = (40_000.0 if planet == "earth" else 20_000.0) * math.exp(-2.5 * c.dust)
    gain = 1.0 * (1.0 + 2.0 * c.overexposed) * (1.0 - 0.85 * c.dark)
    noise = 0.008 * (1.0 + 3.0 * c.dark)
    blur = 0.6 + 3.5 * c.blur
    return Scene(
        planet=planet,
        sun_az_deg=float(rng.uniform(0, 360) if sun_az_deg is None else sun_az_deg),
        sun_el_deg=float(rng.uniform(20, 55) if sun_el_deg is None else sun_el_deg),
        haze_m=haze, gain=gain, noise=noise, blur_px=blur, conditions=c,
        texture_seed=int(rng.integers(0, 2**20)), cloud_seed=int(rng.integers(0, 2**20)),
        rocks=tuple(rocks),
    )


# --- shading -------------------------------------------------------------------------------------

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
def _texture(px, py, footprint, seed, wavelength, octaves, out):
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
def _roughen_normals(px, py, footprint, ground, seed, normal):
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
    _texture(px, py, np.full(dz.shape, 1.0), scene.cloud_seed, 3000.0, 6, n)
    thr = 0.62 - 0.22 * strength
    cover = np.clip((n - thr) / 0.12, 0, 1) * up
    # Fade the layer out towards the horizon so clouds stay above the skyline.
    return cover * np.clip((dz - 0.02) / 0.08, 0, 1)


def _antialias_edge(img: np.ndarray, edge_rows: np.ndarray) -> None:
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
    ground_a, ground_b, horizon, zenith = _palette(scene.planet, c.dust)

    # Albedo fixed in world coordinates; rock texture in the rock's own frame.
    footprint = np.where(np.isfinite(dist), dist / focal_px, 1.0)
    grazing = np.abs(np.sum(d * cast.normal, axis=-1))
    footprint = footprint / np.maximum(grazing, 0.15)
    tex = np.empty((H, W))
    _texture(pts[..., 0].copy(), pts[..., 1].copy(), footprint, scene.texture_seed, 400.0, 11, tex)
    tex2 = np.empty((H, W))
    _texture(pts[..., 0] + 0.37 * pts[..., 2], pts[..., 1] - 0.29 * pts[..., 2], footprint,
             scene.texture_seed + 101, 3.0, 5, tex2)
    mix = np.clip((tex - 0.35) * 2.0, 0, 1)[..., None]
    albedo = ground_a * (1 - mix) + ground_b * mix
    # Metre-scale albedo (stones, soil, plants) varies by about +-20 % (tex2's std is 0.12). It
    # is multiplicative, so it survives in shadow, where the roughness below gives no texture:
    # at +-6 % a slope in its own shadow rendered smooth and read as sky.
    albedo = albedo * np.clip(1.0 + 1.6 * (tex2[..., None] - 0.5), 0.4, 1.6)
    rock = kind == 2
    if rock.any():
        rock_col = np.array([0.30, 0.24, 0.20]) if scene.planet == "mars" else np.array([0.33, 0.32, 0.30])
        albedo[rock] = rock_col * (0.6 + 0.8 * tex2[rock, None])

    # Lambert shading with a sky ambient term, on ground roughened below the DEM's resolution.
    sun = scene.sun
    normal = cast.normal.astype(np.float64)
    _roughen_normals(pts[..., 0].copy(), pts[..., 1].copy(), footprint, kind == 1,
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

    # Aerial perspective: distant terrain takes the colour of the sky at the horizon.
    haze = 1.0 - np.exp(-np.where(np.isfinite(dist), dist, 0.0) / scene.haze_m)
    surf = surf * (1 - haze[..., None]) + horizon * haze[..., None]
    img = np.where((kind == 0)[..., None], sky, surf)
    if edge_rows is not None:
        _antialias_edge(img, edge_rows)

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


# --- acquisitions --------------------------------------------------------------------------------

def frame_pans(camera: Camera, frames: int | None = None, pan_start_deg: float | None = None,
               pan_step_deg: float | None = None) -> list[float]:
    """Mast pan angles [deg] of a frame set overlapping by about a third of a frame.

    Default step: 2/3 of the horizontal field of view rounded to whole degrees (navcam 45 -> 30);
    default count: enough for 360 deg; default start: 0 for a full turn, else centred on forward.
    """
    step = float(pan_step_deg) if pan_step_deg is not None else float(round(camera.hfov_deg * 2 / 3))
    if not step > 0:
        raise ParameterError(f"pan step must be > 0 deg, got {step}")
    n = int(frames) if frames is not None else int(math.ceil(360.0 / step - 1e-9))
    if n < 1:
        raise ParameterError(f"need at least one frame, got {n}")
    if (n - 1) * step >= 360:
        raise ParameterError(f"{n} frames every {step:g} deg span more than 360 deg: use fewer frames")
    if pan_start_deg is None:
        pan_start_deg = 0.0 if n * step >= 360 - 1e-9 else -(n - 1) * step / 2
    return [float(pan_start_deg + k * step) for k in range(n)]


def _check_out_folder(out, overwrite: bool) -> Path:
    """Refuse an ``out`` that is a file, or a non-empty folder without ``overwrite``; touch nothing."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{out} exists and is not a folder: choose another --out")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise OutputExistsError(f"{out} is not empty: pass --overwrite to replace it")
    return out


_UMASK = os.umask(0)
os.umask(_UMASK)
#: renameat2(2) flag that swaps two paths in one step (Linux >= 3.15, most local filesystems)
_RENAME_EXCHANGE = 2


def _exchange(a: Path, b: Path) -> bool:
    """Swap the two existing paths ``a`` and ``b`` atomically; False where the system cannot."""
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd = -100  # paths relative to the current folder, as os.rename takes them
    return renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), _RENAME_EXCHANGE) == 0


def _replace_folder(new: Path, out: Path) -> None:
    """Put the finished folder ``new`` in the place of ``out`` (which may exist).

    An atomic exchange where the filesystem offers one; else two renames, during which the old
    folder is kept beside ``out`` and put back if the second fails: never a moment where the old
    content is gone and the new one not yet in place.
    """
    if not out.exists():
        os.rename(new, out)
        return
    if _exchange(new, out):
        shutil.rmtree(new)  # holds the old content now
        return
    old = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old", dir=out.parent))
    os.rmdir(old)
    os.rename(out, old)
    try:
        os.rename(new, out)
    except BaseException:
        os.rename(old, out)
        raise
    shutil.rmtree(old)


@contextmanager
def _staged_folder(out, overwrite: bool):
    """Yield an empty hidden sibling of ``out`` to render into; it replaces ``out`` only when the
    block succeeds, so a failure or a kill leaves any earlier ``out`` as it was."""
    out = _check_out_folder(out, overwrite)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".partial", dir=out.parent))
    try:
        yield tmp
        os.chmod(tmp, 0o777 & ~_UMASK)  # mkdtemp makes it private; give it a plain mkdir's mode
        _check_out_folder(out, overwrite)  # something may have appeared there meanwhile
        _replace_folder(tmp, out)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def check_seed(seed) -> int:
    """A seed as numpy's generators take it: a whole number >= 0."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ParameterError(f"seed must be a whole number >= 0, got {seed!r}")
    return int(seed)


def check_render_options(*, mode: str, camera, camera_height_m: float, tilt_deg: float, planet, seed,
                         frames: int | None = None, pan_start_deg: float | None = None,
                         pan_step_deg: float | None = None, pano_size=(PANO_WIDTH, PANO_HEIGHT),
                         vfov_deg: float = PANO_VFOV_DEG,
                         elevation_top_deg: float = PANO_ELEVATION_TOP_DEG):
    """Check the options an acquisition and a set share; returns (camera, planet, pans or None).

    Called before any output is touched, so a refusal leaves nothing behind.
    """
    if mode not in ("frames", "panorama"):
        raise ParameterError(f"unknown mode {mode!r}: use 'frames' or 'panorama'")
    check_seed(seed)
    if not (np.isfinite(camera_height_m) and camera_height_m >= 0):
        raise ParameterError(f"camera height must be >= 0 m, got {camera_height_m}")
    if not (np.isfinite(tilt_deg) and abs(tilt_deg) <= 90):
        raise ParameterError(f"mast tilt must be within +-90 deg (up positive), got {tilt_deg}")
    pl = get_planet(planet)
    cam = get_camera(camera) if isinstance(camera, str) else camera
    pans = None
    if mode == "frames":
        for name, v in (("pan start", pan_start_deg), ("pan step", pan_step_deg)):
            if v is not None and not np.isfinite(v):
                raise ParameterError(f"{name} must be a finite angle in degrees, got {v}")
        pans = frame_pans(cam, frames, pan_start_deg, pan_step_deg)
    else:
        w, h = int(pano_size[0]), int(pano_size[1])
        if w < 2 or h < 2:
            raise ParameterError(f"panorama size must be at least 2 x 2 px, got {w} x {h}")
        if not (np.isfinite(vfov_deg) and 0 < vfov_deg <= 180):
            raise ParameterError(f"panorama vfov must be in (0, 180] deg, got {vfov_deg}")
        if not np.isfinite(elevation_top_deg):
            raise ParameterError(f"panorama top elevation must be finite, got {elevation_top_deg}")
    return cam, pl, pans


def _write_png(path: Path, rgb: np.ndarray) -> None:
    import cv2

    with atomic_path(path, suffix=".png") as tmp:
        if not cv2.imwrite(str(tmp), np.ascontiguousarray(rgb[..., ::-1])):
            raise OSError(f"could not write {path}")


def _render_one(dem, origin, proj: Projection, scene: Scene, planet, name: str, out: Path,
                focal_px: float, rng, sun_pixel, vignetting: bool) -> dict:
    rocks = scene.rocks_array()
    cast = cast_image(dem, origin, proj, planet=planet, rocks=rocks)
    terrain_sky = ~np.isfinite(cast.terrain_t)
    rows = column_skyline(dem, origin, proj, terrain_sky, planet=planet)
    vis = rows
    if len(rocks):
        vis = column_skyline(dem, origin, proj, cast.kind == 0, planet=planet, rocks=rocks)
    img = shade(cast, scene, focal_px=focal_px, rng=rng, sun_pixel=sun_pixel, vignetting=vignetting,
                edge_rows=vis)
    _write_png(out / name, img)
    stem = name[: -len(".png")]
    write_skyline_json(out / f"{stem}.skyline.json", Skyline(rows, proj.width, proj.height, name))
    info = {"image": name, "terrain_skyline_columns": int(np.isfinite(rows).sum())}
    if len(rocks):
        write_skyline_json(out / f"{stem}.visible.skyline.json", Skyline(vis, proj.width, proj.height, name))
        info["rock_columns"] = int(np.sum(np.isfinite(vis) & (~np.isfinite(rows) | (np.abs(vis - rows) > 0.5))))
    return info


def simulate_acquisition(dem: Dem, truth: Truth, out, *, camera: str | Camera = "navcam",
                         mode: str = "frames", frames: int | None = None,
                         pan_start_deg: float | None = None, pan_step_deg: float | None = None,
                         tilt_deg: float = 0.0, camera_height_m: float = 1.5, planet="earth",
                         conditions=None, seed: int = 0, overwrite: bool = False,
                         attitude_prior: tuple[float, float] | None = None,
                         pano_size: tuple[int, int] = (PANO_WIDTH, PANO_HEIGHT),
                         elevation_top_deg: float = PANO_ELEVATION_TOP_DEG,
                         vfov_deg: float = PANO_VFOV_DEG,
                         sun_az_deg: float | None = None, sun_el_deg: float | None = None) -> Path:
    """Render one acquisition into folder ``out`` and return it.

    Every option is checked before ``out`` is touched; the acquisition is rendered into a hidden
    sibling folder that takes ``out``'s place (with ``overwrite``: replaces it whole) only once
    complete, so a refusal, a failure or a kill leaves an earlier ``out`` as it was.

    dem : the terrain; truth : rover position [m] and attitude (yaw, pitch, roll) [deg]; the yaw
        is written normalised to [0, 360) (400 -> 40)
    camera : preset name (``navcam``, ``wide``) or a :class:`Camera` (frames mode)
    mode : ``frames`` (mast frame set) or ``panorama`` (equirectangular, levelled in the body frame)
    frames, pan_start_deg, pan_step_deg : frame set (see :func:`frame_pans`) [deg]
    tilt_deg : [deg] mast tilt of every frame (up positive)
    camera_height_m : [m] camera centre above the DEM surface
    planet : ``earth``, ``mars`` or a radius [m] (curvature, sky and soil colours)
    conditions : :class:`Conditions`, a dict or a string like ``"dust:0.5,rocks"``
    seed : makes the looks (sun, texture, noise, rocks) reproducible
    attitude_prior : (pitch, roll) [deg] the inclinometer reports, finite and within +-60; default
        the true values
    pano_size, elevation_top_deg, vfov_deg : panorama size [px] and vertical extent [deg]
    sun_az_deg, sun_el_deg : [deg] sun direction; default drawn from ``seed`` (glare puts it in view)
    """
    cam, pl, pans = check_render_options(
        mode=mode, camera=camera, camera_height_m=camera_height_m, tilt_deg=tilt_deg, planet=planet,
        seed=seed, frames=frames, pan_start_deg=pan_start_deg, pan_step_deg=pan_step_deg,
        pano_size=pano_size, vfov_deg=vfov_deg, elevation_top_deg=elevation_top_deg)
    for name, v in (("x", truth.x), ("y", truth.y), ("yaw", truth.yaw_deg), ("pitch", truth.pitch_deg),
                    ("roll", truth.roll_deg)):
        if not np.isfinite(v):
            raise ParameterError(f"{name} must be a finite number, got {v}")
    if abs(truth.pitch_deg) > 60 or abs(truth.roll_deg) > 60:
        raise ParameterError("pitch and roll must be within +-60 deg for a rover on the ground")
    truth = replace(truth, yaw_deg=normalise_yaw(truth.yaw_deg))
    prior = (truth.pitch_deg, truth.roll_deg) if attitude_prior is None else attitude_prior
    prior = check_attitude_prior(prior)
    planet_key = pl.name if pl.name in ("earth", "mars") else "earth"
    cond = _conditions(conditions)
    if cond.clouds > 0 and planet_key != "earth":
        raise ParameterError("the clouds condition is for Earth only: drop it or use --planet earth")
    origin = camera_centre(dem, truth.x, truth.y, camera_height_m)
    _check_out_folder(out, overwrite)  # before the rock layout's horizon rendering

    if mode == "frames":
        az_lo = min(pans) - cam.hfov_deg / 2
        az_span = min(max(pans) - min(pans) + cam.hfov_deg, 360.0)
        focal = cam.fx
    else:
        w, h = int(pano_size[0]), int(pano_size[1])
        pano = PanoramaSpec("pano.png", -180.0, 360.0, float(elevation_top_deg), float(vfov_deg))
        az_lo, az_span = -180.0, 360.0
        focal = w / (2 * math.pi)

    rng = np.random.default_rng([seed, 1])
    rocks = ()
    if cond.rocks > 0:
        rocks = _rock_layout(dem, origin, truth, camera_height_m, az_lo, az_span, cond.rocks, rng, pl)
    if cond.glare > 0 and sun_az_deg is None:
        # Put the sun inside the view, a little above the horizon.
        if mode == "frames":
            k = int(rng.integers(0, len(pans)))
            sun_az_deg = truth.yaw_deg + pans[k] + rng.uniform(-0.3, 0.3) * cam.hfov_deg
            sun_el_deg = tilt_deg + rng.uniform(0.05, 0.35) * cam.vfov_deg
        else:
            sun_az_deg = truth.yaw_deg + rng.uniform(-180, 180)
            sun_el_deg = rng.uniform(5, 25)
    scene = make_scene(planet_key, cond, seed, sun_az_deg=sun_az_deg, sun_el_deg=sun_el_deg, rocks=rocks)

    out = Path(out)
    with _staged_folder(out, overwrite) as tmp:
        infos = []
        if mode == "frames":
            frame_list = []
            for k, pan in enumerate(pans):
                name = f"frame_{k:03d}.png"
                proj = Projection.frame(cam, truth.yaw_deg, truth.pitch_deg, truth.roll_deg, pan, tilt_deg)
                sun_px = _sun_pixel(cam, proj, scene)
                infos.append(_render_one(dem, origin, proj, scene, pl, name, tmp, focal, rng, sun_px, True))
                frame_list.append(Frame(name, pan, float(tilt_deg)))
            acq = Acquisition(out, cam, float(camera_height_m), frames=tuple(frame_list))
        else:
            proj = Projection.panorama(pano, w, h, truth.yaw_deg, truth.pitch_deg, truth.roll_deg)
            infos.append(_render_one(dem, origin, proj, scene, pl, pano.image, tmp, focal, rng, None, False))
            acq = Acquisition(out, None, float(camera_height_m), panorama=pano)

        acq = replace(acq, prior_pitch_deg=prior[0], prior_roll_deg=prior[1])
        sim = {
            "planet": pl.name, "seed": int(seed), "conditions": cond.active(), "mode": mode,
            "dem": {"source": dem.source, "checksum": dem.checksum, "crs": dem.crs_name},
            "ground_z_m": float(origin[2] - camera_height_m),
            "sun": {"azimuth_deg": scene.sun_az_deg % 360.0, "elevation_deg": scene.sun_el_deg},
            "rocks": [dict(zip(("x", "y", "z", "radius_h_m", "radius_v_m"), r)) for r in rocks],
            "images": infos,
        }
        save_acquisition(tmp, acq, truth=truth, extra={"simulation": sim})
    return out


def normalise_yaw(yaw_deg: float) -> float:
    """A heading [deg] brought into [0, 360), the range of every azimuth in ``conventions.md``."""
    y = float(yaw_deg) % 360.0
    return 0.0 if y >= 360.0 else y  # -1e-14 % 360 rounds to 360.0


def check_attitude_prior(prior) -> tuple[float, float]:
    """The inclinometer's (pitch, roll) [deg]: two finite angles a rover on the ground can have."""
    try:
        p, r = (float(v) for v in prior)
    except (TypeError, ValueError):
        raise ParameterError(f"attitude prior must be two angles (pitch, roll) [deg], got {prior!r}") from None
    if not (math.isfinite(p) and math.isfinite(r)):
        raise ParameterError(f"attitude prior must be finite angles [deg], got pitch {p}, roll {r}")
    if abs(p) > 60 or abs(r) > 60:
        raise ParameterError(f"attitude prior must be within +-60 deg for a rover on the ground, "
                             f"got pitch {p:g}, roll {r:g}")
    return p, r


def _sun_pixel(cam: Camera, proj: Projection, scene: Scene):
    d_cam = proj.rotation.T @ scene.sun
    u, v, front = cam.ray_to_pixel(d_cam)
    if front and -0.2 * cam.width < u < 1.2 * cam.width and -0.2 * cam.height < v < 1.2 * cam.height:
        return float(u), float(v)
    return None


# --- robustness sets -----------------------------------------------------------------------------

#: The named robustness sets of the source study's test plan.
SETS = {
    "REF": "nominal: level rover, no degradation",
    "HREL": "flat, featureless horizons: the lowest-relief positions of a larger random pool",
    "SCOM": "skyline partly outside the view: the camera tilted so the skyline leaves the frame",
    "LREL": "pitch and roll up to +-10 deg; attitude prior 0 or noisy (1 deg)",
    "CLUT": "clutter: dust (and clouds on Earth)",
    "OCCL": "occlusion: boulders near the rover that the DEM lacks",
    "COND": "bad light: glare (sun in view), over- or under-exposure",
}


def default_area(dem: Dem, margin_m: float | None = None) -> tuple[float, float, float, float]:
    """The DEM's bounds minus a margin [m] (default: 10 cells or 5 % of the extent, the larger)."""
    xmin, ymin, xmax, ymax = dem.bounds
    ext = min(xmax - xmin, ymax - ymin)
    m = max(10 * dem.cell_m, 0.05 * ext) if margin_m is None else float(margin_m)
    m = min(m, 0.25 * ext)
    return (xmin + m, ymin + m, xmax - m, ymax - m)


def _check_area(dem: Dem, area) -> tuple[float, float, float, float]:
    if area is None:
        return default_area(dem)
    try:
        xmin, ymin, xmax, ymax = (float(a) for a in area)
    except (TypeError, ValueError):
        raise ParameterError("area must be four numbers XMIN YMIN XMAX YMAX [m]") from None
    if not (xmin < xmax and ymin < ymax):
        raise ParameterError(f"area {area} is empty: need XMIN < XMAX and YMIN < YMAX")
    if not (dem.contains(xmin, ymin) and dem.contains(xmax, ymax)):
        b = dem.bounds
        raise ParameterError(f"area {tuple(area)} reaches outside the DEM bounds "
                             f"{tuple(round(v, 1) for v in b)}: choose an area inside them")
    return xmin, ymin, xmax, ymax


def _draw_positions(dem: Dem, area, n: int, rng: np.random.Generator) -> np.ndarray:
    xmin, ymin, xmax, ymax = area
    pts = []
    for _ in range(200 * n + 100):
        if len(pts) >= n:
            break
        x, y = rng.uniform(xmin, xmax), rng.uniform(ymin, ymax)
        if np.isfinite(dem.height_at(x, y)):
            pts.append((x, y))
    if len(pts) < n:
        raise ParameterError("could not draw positions with known heights in the area: the DEM is "
                             "mostly void there; choose another --area")
    return np.array(pts)


def plan_set(dem: Dem, name: str, cases: int, seed: int, *, area=None, camera: str | Camera = "navcam",
             mode: str = "frames", camera_height_m: float = 1.5, planet="earth") -> list[dict]:
    """The cases of a named set: per case ``truth`` and the keyword arguments of
    :func:`simulate_acquisition` (deterministic for ``seed``)."""
    from .horizon import render_horizons

    key = str(name).upper()
    if key not in SETS:
        raise ParameterError(f"unknown set {name!r}: choose one of {', '.join(SETS)}")
    if int(cases) != cases or cases < 1:
        raise ParameterError(f"cases must be a positive whole number, got {cases}")
    cases = int(cases)
    seed = check_seed(seed)
    area = _check_area(dem, area)
    rng = np.random.default_rng([int(seed), sum(map(ord, key))])
    pl = get_planet(planet)
    cam = get_camera(camera) if isinstance(camera, str) else camera
    if key == "HREL":
        pool = _draw_positions(dem, area, 6 * cases, rng)
        hb = render_horizons(dem, pool[:, 0], pool[:, 1], camera_height_m=camera_height_m, planet=pl)
        relief = np.nanmax(hb.elevation_deg, axis=1) - np.nanmin(hb.elevation_deg, axis=1)
        pos = pool[np.argsort(relief, kind="stable")[:cases]]
    else:
        pos = _draw_positions(dem, area, cases, rng)
    plans = []
    for k in range(cases):
        x, y = float(pos[k, 0]), float(pos[k, 1])
        yaw = float(rng.uniform(0, 360))
        kw: dict = {"seed": int(rng.integers(0, 2**31))}
        pitch = roll = 0.0
        if key == "SCOM":
            hb = render_horizons(dem, [x], [y], camera_height_m=camera_height_m, planet=pl)
            med = float(np.nanmedian(hb.elevation_deg[0]))
            if mode == "frames":
                kw["tilt_deg"] = med - cam.vfov_deg / 2 + float(rng.uniform(-1.0, 3.0))
            else:
                kw["elevation_top_deg"] = med + float(rng.uniform(-1.0, 1.0))
        elif key == "LREL":
            pitch, roll = (float(v) for v in rng.uniform(-10, 10, 2))
            noise = rng.normal(0, 1.0, 2)
            kw["attitude_prior"] = (0.0, 0.0) if k % 2 == 0 else (pitch + noise[0], roll + noise[1])
        elif key == "CLUT":
            c = {"dust": float(rng.uniform(0.3, 1.0))}
            if pl.name == "earth":
                c["clouds"] = float(rng.uniform(0.3, 1.0))
            kw["conditions"] = c
        elif key == "OCCL":
            kw["conditions"] = {"rocks": float(rng.uniform(0.4, 1.0))}
        elif key == "COND":
            which = ("glare", "overexposed", "dark")[k % 3]
            kw["conditions"] = {which: float(rng.uniform(0.5, 1.0))}
        plans.append({"folder": f"case_{k:03d}", "truth": Truth(x, y, yaw, pitch, roll), "kwargs": kw})
    return plans


def simulate_set(dem: Dem, name: str, cases: int, seed: int, out, *, area=None,
                 camera: str | Camera = "navcam", mode: str = "frames", frames: int | None = None,
                 camera_height_m: float = 1.5, planet="earth", overwrite: bool = False,
                 pano_size: tuple[int, int] = (PANO_WIDTH, PANO_HEIGHT),
                 progress: bool = False, tilt_deg: float = 0.0) -> list[Path]:
    """Render a named robustness set (:data:`SETS`) into ``out/case_NNN`` folders.

    Positions are drawn uniformly (off-grid) inside ``area`` (XMIN, YMIN, XMAX, YMAX) [m], default
    :func:`default_area`; headings uniform in [0, 360) deg; everything deterministic for ``seed``.
    Also writes ``out/set.json`` listing the cases. Returns the case folders. As for
    :func:`simulate_acquisition`, options are checked first and ``out`` is replaced (with
    ``overwrite``) only by a complete set.
    tilt_deg : [deg] mast tilt of every frame (mountain skylines sit high: 10-15 deg keeps them in
        a navcam's view), except where the set chooses its own (SCOM)
    """
    # Everything is checked and planned before ``out`` is touched (or a progress bar shown), and
    # the set is rendered into a hidden sibling that replaces ``out`` only once complete.
    check_render_options(mode=mode, camera=camera, camera_height_m=camera_height_m, tilt_deg=tilt_deg,
                  planet=planet, seed=seed, frames=frames, pano_size=pano_size)
    plans = plan_set(dem, name, cases, seed, area=area, camera=camera, mode=mode,
                     camera_height_m=camera_height_m, planet=planet)
    out = _check_out_folder(out, overwrite)
    with _staged_folder(out, overwrite) as tmp:
        it = plans
        if progress:
            from tqdm import tqdm

            it = tqdm(plans, desc=f"set {name.upper()}", unit="case")
        for p in it:
            simulate_acquisition(
                dem, p["truth"], tmp / p["folder"], camera=camera, mode=mode, frames=frames,
                camera_height_m=camera_height_m, planet=planet, pano_size=pano_size,
                **{"tilt_deg": tilt_deg, **p["kwargs"]})
        listing = {
            "set": name.upper(), "description": SETS[name.upper()], "seed": int(seed), "cases": [
                {"folder": p["folder"], "truth": asdict(p["truth"]),
                 **{k: v for k, v in p["kwargs"].items()}} for p in plans],
        }
        write_json(tmp / "set.json", listing)
    return [out / p["folder"] for p in plans]
