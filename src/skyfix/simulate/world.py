"""The map is not the world: a "world" DEM that differs from the map the way a real orbital DEM
differs from the terrain, for rendering acquisitions that the map (the database and ``--dem``)
cannot match exactly.

:func:`world_dem` refines the map below its cell (bicubic, plus fractal detail at wavelengths the
map cannot hold), adds a spatially correlated height error, occasional spikes and pits (the map's
own artefacts, seen from the other side), and shifts the whole by a horizontal misregistration in
a random direction. The misregistration cannot be undone by any localiser: the best fix on the
map lies at the truth minus the shift, which :func:`map_offset` gives so that errors can be
counted beyond it.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..dem import Dem
from ..errors import ParameterError


@dataclass(frozen=True)
class MapErrors:
    """How the world differs from the map.

    refine : world cells per map cell along each axis (the world is that much finer)
    detail_rms_m : rms [m] of the fractal detail below the map's cell (wavelengths < 2 map cells)
    height_rms_m : rms [m] of the spatially correlated height error
    correlation_m : [m] width (sigma) of the Gaussian that blurs white noise into that error:
        its correlation is ``exp(-r^2 / (4 correlation_m^2))``, 1/e at twice it (300 m by
        default), smoother than the sigmas' model (:mod:`skyfix.pose.map_error`, ``exp(-r /
        150 m)``), which credits a simulated world 2-4x the height difference it has between
        points 30-150 m apart (measured: 0.29 against 1.20 m rms at 30 m, 1.38 against 2.25 m at
        150 m)
    spikes_per_km2 : spikes and pits per square kilometre, each one map cell wide
    spike_m : [m] their largest height (each drawn in +-[0.5, 1] of it)
    shift_m : [m] horizontal misregistration, in a random direction
    """

    refine: int = 2
    detail_rms_m: float = 1.0
    height_rms_m: float = 2.0
    correlation_m: float = 150.0
    spikes_per_km2: float = 1.0
    spike_m: float = 15.0
    shift_m: float = 3.0

    def __post_init__(self):
        if int(self.refine) != self.refine or not 1 <= self.refine <= 8:
            raise ParameterError(f"map errors: refine must be a whole number in 1..8, got {self.refine}")
        for name in ("detail_rms_m", "height_rms_m", "correlation_m", "spikes_per_km2", "spike_m",
                     "shift_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ParameterError(f"map errors: {name} must be a finite number >= 0, got {v}")

    def to_dict(self) -> dict:
        return asdict(self)


def _shift_direction(seed: int) -> float:
    return float(np.random.default_rng([int(seed), 77]).uniform(0.0, 2.0 * math.pi))


def map_offset(errors: MapErrors, seed: int) -> tuple[float, float]:
    """(dx, dy) [m] from the truth to where the truth's terrain lies on the map: minus the world's
    shift. A fix at truth + map_offset is as right as the map allows."""
    a = _shift_direction(seed)
    return (-errors.shift_m * math.sin(a), -errors.shift_m * math.cos(a))


def world_record(map_errors: MapErrors | None, seed: int, world: Dem | None = None) -> dict:
    """What a simulation records (under ``simulation``) about the world it rendered when that was
    not the map: ``{"world": source, sha256}`` for a second DEM, ``{"map_errors": the errors,
    seed and map_offset_m}`` for :func:`world_dem`'s, ``{}`` when the world was the map."""
    if world is not None:
        return {"world": {"source": world.source, "sha256": world.checksum}}
    if map_errors is not None:
        return {"map_errors": {**map_errors.to_dict(), "seed": int(seed),
                               "map_offset_m": list(map_offset(map_errors, seed))}}
    return {}


def check_world_covers(world: Dem, area, needed: str, remedy: str) -> None:
    """Refuse a world DEM that does not cover ``area`` (XMIN, YMIN, XMAX, YMAX) [m, the map's
    CRS], ``needed`` saying what lies there: outside it a rover stands off the world, refused
    as off "the DEM" only once the cases or stops before it were rendered."""
    xmin, ymin, xmax, ymax = (float(v) for v in area)
    wx0, wy0, wx1, wy1 = world.bounds
    if xmin >= wx0 and ymin >= wy0 and xmax <= wx1 and ymax <= wy1:
        return
    name = Path(world.source).name if world.source else "given"
    crs = world.crs_name or "the map's CRS"
    raise ParameterError(
        f"the world DEM ({name}) covers x {wx0:.1f}..{wx1:.1f}, y {wy0:.1f}..{wy1:.1f} in {crs}, "
        f"not all of {needed}, x {xmin:.1f}..{xmax:.1f}, y {ymin:.1f}..{ymax:.1f}: give a world "
        f"DEM that covers it, or {remedy}")


def check_world_heights(world: Dem, xs, ys, needed: str, remedy: str) -> None:
    """Refuse a world DEM without a height at every position (xs, ys) [m, the map's CRS] where
    ``needed`` stands: a grid that covers the area can still hold no data there (a reprojected
    DEM's empty corners), and the rover was refused only once the cases or stops before it were
    rendered, as off "the DEM" without naming the world."""
    xs, ys = np.atleast_1d(np.asarray(xs, float)), np.atleast_1d(np.asarray(ys, float))
    bad = np.flatnonzero(~np.isfinite(np.asarray(world.height_at(xs, ys), float)))
    if bad.size == 0:
        return
    name = Path(world.source).name if world.source else "given"
    i = int(bad[0])
    raise ParameterError(
        f"the world DEM ({name}) has no height at {bad.size} of the {xs.size} {needed} (the first "
        f"at x {xs[i]:.1f}, y {ys[i]:.1f}): it holds no data there; give a world DEM with data "
        f"over them, or {remedy}")


def recorded_map_offset(simulation: dict | None) -> tuple[float, float]:
    """The :func:`map_offset` a :func:`world_record` holds [m]; (0, 0) when the world was the map
    (or another DEM, whose offset is not known)."""
    off = ((simulation or {}).get("map_errors") or {}).get("map_offset_m") or (0.0, 0.0)
    return float(off[0]), float(off[1])


def fractal_noise(shape, cell_m, min_wavelength_m, max_wavelength_m, rng, beta=3.0):
    """Zero-mean, unit-rms noise with a power spectrum ~ f**-beta between two wavelengths [m]."""
    ny, nx = shape
    fy = np.fft.fftfreq(ny, cell_m)[:, None]
    fx = np.fft.rfftfreq(nx, cell_m)[None, :]
    f = np.hypot(fx, fy)
    band = (f >= 1.0 / max_wavelength_m) & (f <= 1.0 / min_wavelength_m)
    amp = np.where(band, np.power(np.where(f > 0, f, 1.0), -beta / 2.0), 0.0)
    spec = amp * (rng.normal(size=f.shape) + 1j * rng.normal(size=f.shape))
    out = np.fft.irfft2(spec, s=shape)
    s = out.std()
    return out / s if s > 0 else out


def world_dem(map_dem: Dem, errors: MapErrors = MapErrors(), seed: int = 0) -> Dem:
    """The world a rover sees where the map says ``map_dem`` (same CRS and body; cells
    ``refine`` times finer; shifted by ``errors.shift_m`` in a direction drawn from ``seed``)."""
    import cv2

    from ..optional import require

    ndimage = require("scipy.ndimage", "simulating map errors (a world DEM that differs from the map)")
    rng = np.random.default_rng([int(seed), 31])
    k = int(errors.refine)
    ny, nx = map_dem.z.shape
    z = map_dem.z.astype(np.float64)
    void = ~np.isfinite(z)
    zf = z
    if void.any():
        # each void cell takes its nearest height: the bicubic reaches two cells into a void, and
        # the whole DEM's mean there raised the world 200 m beside a reprojected DEM's corners
        # (p99 199 m 1.5-2.5 map cells from them; 13 m with the nearest height)
        near = ndimage.distance_transform_edt(void, return_distances=False, return_indices=True)
        zf = z[tuple(near)]
    cell = map_dem.dx / k, map_dem.dy / k
    # pixel centres of the fine grid span the map's: (ny - 1) k + 1 rows
    fine_shape = ((ny - 1) * k + 1, (nx - 1) * k + 1)
    xs = np.arange(fine_shape[1], dtype=np.float32) / k
    ys = np.arange(fine_shape[0], dtype=np.float32) / k
    mx, my = np.meshgrid(xs, ys)
    w = cv2.remap(zf.astype(np.float32), mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
    w = w.astype(np.float64)
    fine_cell = min(cell)
    if errors.detail_rms_m > 0 and k > 1:
        w += errors.detail_rms_m * fractal_noise(fine_shape, fine_cell, 2.0 * fine_cell,
                                            2.0 * map_dem.cell_m, rng)
    if errors.height_rms_m > 0:
        e = ndimage.gaussian_filter(rng.normal(size=fine_shape), errors.correlation_m / fine_cell,
                                    mode="wrap")
        w += errors.height_rms_m * e / max(e.std(), 1e-12)
    if errors.spikes_per_km2 > 0 and errors.spike_m > 0:
        area_km2 = (fine_shape[0] * cell[1]) * (fine_shape[1] * cell[0]) / 1e6
        n = rng.poisson(errors.spikes_per_km2 * area_km2)
        r = rng.integers(0, fine_shape[0] - k, n)
        c = rng.integers(0, fine_shape[1] - k, n)
        h = errors.spike_m * rng.uniform(0.5, 1.0, n) * rng.choice([-1.0, 1.0], n)
        for ri, ci, hi in zip(r, c, h):
            w[ri:ri + k, ci:ci + k] += hi
    if void.any():
        vf = cv2.remap(void.astype(np.float32), mx, my, cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_REPLICATE) > 0.01
        w[vf] = np.nan
    sx, sy = (-v for v in map_offset(errors, seed))
    return Dem(w.astype(np.float32), map_dem.x0 + sx, map_dem.y0 + sy, cell[0], cell[1],
               map_dem.crs_wkt, map_dem.crs_name, source=f"world of {map_dem.source or 'a map'}",
               body=getattr(map_dem, "body", None))
