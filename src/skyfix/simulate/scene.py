"""The scene around a simulated rover: the planet's palette (ground albedo, sky colours), the sun,
and the rocks the DEM lacks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..dem import Dem
from ..formats import Truth
from .conditions import Conditions, check_planet


@dataclass(frozen=True)
class Scene:
    """Everything the renderer needs besides geometry (drawn once per acquisition).

    sun_az_deg, sun_el_deg : [deg] sun direction (azimuth from grid north)
    haze_m : [m] distance at which haze hides 63 % of the terrain's own light
    gain : exposure gain (1 nominal)
    rocks : (K, 5) ellipsoids (x, y, z, radius_h, radius_v) [m]
    lake_z_m : [m] level of still water over the terrain (NaN: none; see :func:`lake_level`)
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
    lake_z_m: float = math.nan

    @property
    def sun(self) -> np.ndarray:
        a, e = math.radians(self.sun_az_deg), math.radians(self.sun_el_deg)
        return np.array([math.cos(e) * math.sin(a), math.cos(e) * math.cos(a), math.sin(e)])

    def rocks_array(self) -> np.ndarray:
        return np.asarray(self.rocks, float).reshape(-1, 5)


def palette(planet: str, dust: float):
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


def rock_layout(dem: Dem, origin, truth: Truth, camera_height_m: float, az_lo: float,
                 az_span: float, strength: float, rng: np.random.Generator, planet) -> tuple:
    """Boulders near the rover inside the viewed azimuths, (x, y, z, radius_h, radius_v) [m].

    Half of them rise above the rendered skyline behind them (by 0.3 to 3.5 deg with strength),
    so they cut it whatever the terrain; the rest are clutter on the ground.
    """
    from ..horizon import render_horizons

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


def lake_level(dem: Dem, x: float, y: float, strength: float, radius_m: float = 2000.0) -> float:
    """Level [m] of a lake around (x, y): the ``5 + 35 strength`` percentile of the DEM's heights
    in the square of half-side ``radius_m`` [m] centred there, and at least 0.3 m under the
    ground at (x, y) so the rover stays dry.
    One level for the whole acquisition: overlapping frames see the same shoreline."""
    c0, r0 = dem.xy_to_colrow(x - radius_m, y + radius_m)
    c1, r1 = dem.xy_to_colrow(x + radius_m, y - radius_m)
    rs = sorted((int(np.floor(r0)), int(np.ceil(r1))))
    cs = sorted((int(np.floor(c0)), int(np.ceil(c1))))
    ny, nx = dem.z.shape
    z = dem.z[max(0, rs[0]):min(ny, rs[1] + 1), max(0, cs[0]):min(nx, cs[1] + 1)]
    z = z[np.isfinite(z)]
    ground = float(dem.height_at(x, y))
    if z.size == 0:
        return ground - 0.3
    return min(float(np.percentile(z, 5.0 + 35.0 * strength)), ground - 0.3)


def make_scene(planet: str, conditions: Conditions, seed: int, *, sun_az_deg=None, sun_el_deg=None,
               rocks=(), lake_z_m=math.nan) -> Scene:
    """The :class:`Scene` for a planet (``earth``/``mars`` palette), conditions and seed; the sun
    at (``sun_az_deg``, ``sun_el_deg``) [deg] or drawn from the seed; ``rocks`` from
    :func:`rock_layout`; ``lake_z_m`` from :func:`lake_level` (the lake condition)."""
    rng = np.random.default_rng([seed, 17])
    c = conditions
    check_planet(c, planet)
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
        rocks=tuple(rocks), lake_z_m=float(lake_z_m),
    )
