"""One simulated acquisition: a frame set or a panorama rendered from a DEM, with exact truth.

:func:`simulate_acquisition` ray-casts every pixel of a frame set (pinhole frames on a mast) or a
body-levelled equirectangular panorama (:mod:`skyfix.raycast`), shades it and writes the
acquisition format of ``conventions.md``: ``acquisition.json`` with ``truth``, the PNG images and
for each image ``NAME.skyline.json``, the exact terrain skyline (sub-pixel row per column where the
pixel ray first meets the DEM, ``null`` where the column has no sky-to-ground edge). With rocks,
which the DEM lacks, ``NAME.visible.skyline.json`` holds the skyline a camera really sees.

Looks: Lambert shading from a sun direction, an albedo texture fixed in world coordinates (so
overlapping frames agree), a planet sky, distance haze, optics blur, vignetting, sensor noise.
:class:`Conditions` adds dust, clouds, snow, a lake, rocks, glare, exposure faults and blur, each
with a strength in [0, 1]. :func:`simulate_set` draws the named robustness sets (:data:`SETS`).
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from .._io import atomic_path
from ..camera import Camera, get_camera
from ..dem import Dem
from ..detect.options import MIN_HEIGHT_PX, MIN_WIDTH_PX
from ..errors import ParameterError
from ..formats import (Acquisition, Frame, PanoramaSpec, Skyline, Truth, save_acquisition,
                       write_skyline_json)
from ..formats.acquisition import MAX_PAN_DEG
from ..planets import get_planet, resolve_planet
from ..raycast import Projection, camera_centre
from .conditions import as_conditions, check_planet
from .folders import check_out_folder, staged_folder
from .layered import cast_layers, scene_layers, skyline_layers
from .scene import Scene, lake_level, make_scene, rock_layout
from .shading import shade


log = logging.getLogger(__package__)  # messages name the stage, as before the split


#: panorama size [px] and extent [deg]: 4096 x 1024 over 360 x 90 deg gives square pixels
PANO_WIDTH, PANO_HEIGHT = 4096, 1024


PANO_ELEVATION_TOP_DEG, PANO_VFOV_DEG = 45.0, 90.0


#: the largest panorama the simulator renders [px] (a 100000 x 50000 request died of a NumPy
#: MemoryError, with a traceback, asking for 56 GiB)
MAX_PANO_PIXELS = 64 * 10**6


#: most frames one acquisition may have: one a degree of a full turn
MAX_FRAMES = 360


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
    if n > MAX_FRAMES:
        # a step of 1e-9 deg built its list of angles until the memory ran out, with no message
        raise ParameterError(f"{n} frames (a pan step of {step:g} deg) is more than {MAX_FRAMES}: "
                             "one a degree already overlaps far more than projection or "
                             "stitching needs; give a pan step of 1 deg or more")
    if (n - 1) * step >= 360:
        raise ParameterError(f"{n} frames every {step:g} deg span more than 360 deg: use fewer frames")
    if pan_start_deg is None:
        pan_start_deg = 0.0 if n * step >= 360 - 1e-9 else -(n - 1) * step / 2
    return [float(pan_start_deg + k * step) for k in range(n)]


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
    """Check the options an acquisition and a set share; returns (camera, planet or None when not
    given, pans or None).

    Called before any output is touched, so a refusal leaves nothing behind.
    """
    if mode not in ("frames", "panorama"):
        raise ParameterError(f"unknown mode {mode!r}: use 'frames' or 'panorama'")
    check_seed(seed)
    if not (np.isfinite(camera_height_m) and camera_height_m >= 0):
        raise ParameterError(f"camera height must be >= 0 m, got {camera_height_m}")
    if not (np.isfinite(tilt_deg) and abs(tilt_deg) <= 90):
        raise ParameterError(f"mast tilt must be within +-90 deg (up positive), got {tilt_deg}")
    pl = get_planet(planet) if planet is not None else None
    cam = get_camera(camera) if isinstance(camera, str) else camera
    pans = None
    if mode == "frames":
        for name, v in (("pan start", pan_start_deg), ("pan step", pan_step_deg)):
            if v is not None and not np.isfinite(v):
                raise ParameterError(f"{name} must be a finite angle in degrees, got {v}")
        # the acquisition must be one skyfix reads back (1e12 deg was written, then refused)
        if pan_start_deg is not None and abs(pan_start_deg) > MAX_PAN_DEG:
            raise ParameterError(f"pan start must be within +-{MAX_PAN_DEG:g} deg, got {pan_start_deg:g}")
        pans = frame_pans(cam, frames, pan_start_deg, pan_step_deg)
    else:
        w, h = int(pano_size[0]), int(pano_size[1])
        if w < MIN_WIDTH_PX or h < MIN_HEIGHT_PX:  # the detector's least: smaller was written, then refused
            raise ParameterError(f"panorama size must be at least {MIN_WIDTH_PX} x {MIN_HEIGHT_PX} px, "
                                 f"got {w} x {h}")
        if w * h > MAX_PANO_PIXELS:  # one of the ray caster's arrays alone is 12 bytes a pixel
            raise ParameterError(f"panorama size {w} x {h} px is more than the "
                                 f"{MAX_PANO_PIXELS // 10**6} MP the simulator renders (e.g. "
                                 "16384 x 3906); the default is 4096 x 1024")
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


def column_ranges(mask) -> list:
    """[[start, stop), ...] of the runs of True in a 1-D bool array (JSON-ready ints)."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    edges = np.flatnonzero(m[1:] != m[:-1])
    return [[int(a), int(b)] for a, b in zip(edges[::2], edges[1::2])]


def _render_one(layers, origin, proj: Projection, scene: Scene, planet, name: str, out: Path,
                focal_px: float, rng, sun_pixel, vignetting: bool) -> dict:
    rocks = scene.rocks_array()
    cast = cast_layers(layers, origin, proj, planet=planet, rocks=rocks)
    terrain_sky = ~np.isfinite(cast.terrain_t)
    sky = cast.kind == 0  # what the camera sees as sky: neither terrain nor a boulder
    rows = skyline_layers(layers, origin, proj, terrain_sky, planet=planet)
    vis = rows
    if len(rocks):
        vis = skyline_layers(layers, origin, proj, sky, planet=planet, rocks=rocks)
    img = shade(cast, scene, focal_px=focal_px, rng=rng, sun_pixel=sun_pixel, vignetting=vignetting,
                edge_rows=vis)
    _write_png(out / name, img)
    stem = name[: -len(".png")]
    write_skyline_json(out / f"{stem}.skyline.json", Skyline(rows, proj.width, proj.height, name))
    # A column without a skyline row is all sky or all ground (the skyline above the frame's
    # top): the row cannot say which, these ranges can (what a trainer labels them)
    info = {"image": name, "terrain_skyline_columns": int(np.isfinite(rows).sum()),
            "ground_only_columns": column_ranges(~sky.any(axis=0)),
            "sky_only_columns": column_ranges(sky.all(axis=0))}
    if len(rocks):
        write_skyline_json(out / f"{stem}.visible.skyline.json", Skyline(vis, proj.width, proj.height, name))
        info["rock_columns"] = int(np.sum(np.isfinite(vis) & (~np.isfinite(rows) | (np.abs(vis - rows) > 0.5))))
    return info


def simulate_acquisition(dem: Dem, truth: Truth, out, *, camera: str | Camera = "navcam",
                         mode: str = "frames", frames: int | None = None,
                         pan_start_deg: float | None = None, pan_step_deg: float | None = None,
                         tilt_deg: float = 0.0, camera_height_m: float = 1.5, planet=None,
                         conditions=None, seed: int = 0, overwrite: bool = False,
                         attitude_prior: tuple[float, float] | None = None,
                         pano_size: tuple[int, int] = (PANO_WIDTH, PANO_HEIGHT),
                         elevation_top_deg: float = PANO_ELEVATION_TOP_DEG,
                         vfov_deg: float = PANO_VFOV_DEG,
                         sun_az_deg: float | None = None, sun_el_deg: float | None = None,
                         simulation_meta: dict | None = None) -> Path:
    """Render one acquisition into folder ``out`` and return it.

    Every option is checked before ``out`` is touched; the acquisition is rendered into a hidden
    sibling folder that takes ``out``'s place (with ``overwrite``: replaces it whole) only once
    complete, so a refusal, a failure or a kill leaves an earlier ``out`` as it was.

    dem : the terrain (a :class:`skyfix.dem.Dem`, or a :class:`skyfix.stack.DemStack`: the finest
        member that covers a point is the terrain there); truth : rover position [m] and attitude (yaw, pitch, roll) [deg]; the yaw
        is written normalised to [0, 360) (400 -> 40)
    camera : preset name (``navcam``, ``wide``) or a :class:`Camera` (frames mode)
    mode : ``frames`` (mast frame set) or ``panorama`` (equirectangular, levelled in the body frame)
    frames, pan_start_deg, pan_step_deg : frame set (see :func:`frame_pans`) [deg]
    tilt_deg : [deg] mast tilt of every frame (up positive)
    camera_height_m : [m] camera centre above the DEM surface
    planet : ``earth``, ``mars`` or a radius [m] (curvature, sky and soil colours); None: the
        DEM's body
    conditions : :class:`Conditions`, a dict or a string like ``"dust:0.5,rocks"``
    seed : makes the looks (sun, texture, noise, rocks) reproducible
    attitude_prior : (pitch, roll) [deg] the inclinometer reports, finite and within +-60; default
        the true values
    pano_size, elevation_top_deg, vfov_deg : panorama size [px] and vertical extent [deg]
    sun_az_deg, sun_el_deg : [deg] sun direction; default drawn from ``seed`` (glare puts it in view)
    simulation_meta : more to record under ``simulation`` in ``acquisition.json`` (a set's map
        errors: how the world rendered here differs from the map)
    """
    cam, pl, pans = check_render_options(
        mode=mode, camera=camera, camera_height_m=camera_height_m, tilt_deg=tilt_deg, planet=planet,
        seed=seed, frames=frames, pan_start_deg=pan_start_deg, pan_step_deg=pan_step_deg,
        pano_size=pano_size, vfov_deg=vfov_deg, elevation_top_deg=elevation_top_deg)
    pl = resolve_planet(planet, getattr(dem, "body", None))
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
    cond = as_conditions(conditions)
    check_planet(cond, planet_key)
    origin = camera_centre(dem, truth.x, truth.y, camera_height_m)
    layers = scene_layers(dem, origin)  # one DEM, or a stack's members as seen from here
    check_out_folder(out, overwrite)  # before the rock layout's horizon rendering

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
        rocks = rock_layout(dem, origin, truth, camera_height_m, az_lo, az_span, cond.rocks, rng, pl)
    if cond.glare > 0 and sun_az_deg is None:
        # Put the sun inside the view, a little above the horizon.
        if mode == "frames":
            k = int(rng.integers(0, len(pans)))
            sun_az_deg = truth.yaw_deg + pans[k] + rng.uniform(-0.3, 0.3) * cam.hfov_deg
            sun_el_deg = tilt_deg + rng.uniform(0.05, 0.35) * cam.vfov_deg
        else:
            sun_az_deg = truth.yaw_deg + rng.uniform(-180, 180)
            sun_el_deg = rng.uniform(5, 25)
    lake = lake_level(dem, truth.x, truth.y, cond.lake) if cond.lake > 0 else math.nan
    scene = make_scene(planet_key, cond, seed, sun_az_deg=sun_az_deg, sun_el_deg=sun_el_deg, rocks=rocks,
                       lake_z_m=lake)

    out = Path(out)
    with staged_folder(out, overwrite) as tmp:
        infos = []
        if mode == "frames":
            frame_list = []
            for k, pan in enumerate(pans):
                name = f"frame_{k:03d}.png"
                proj = Projection.frame(cam, truth.yaw_deg, truth.pitch_deg, truth.roll_deg, pan, tilt_deg)
                sun_px = sun_pixel(cam, proj, scene)
                infos.append(_render_one(layers, origin, proj, scene, pl, name, tmp, focal, rng, sun_px, True))
                frame_list.append(Frame(name, pan, float(tilt_deg)))
            acq = Acquisition(out, cam, float(camera_height_m), frames=tuple(frame_list))
        else:
            proj = Projection.panorama(pano, w, h, truth.yaw_deg, truth.pitch_deg, truth.roll_deg)
            infos.append(_render_one(layers, origin, proj, scene, pl, pano.image, tmp, focal, rng, None, False))
            acq = Acquisition(out, None, float(camera_height_m), panorama=pano)

        acq = replace(acq, prior_pitch_deg=prior[0], prior_roll_deg=prior[1])
        sim = {
            **(simulation_meta or {}),
            "planet": pl.name, "seed": int(seed), "conditions": cond.active(), "mode": mode,
            "dem": {"source": dem.source, "checksum": dem.checksum, "crs": dem.crs_name,
                    **({"sources": dem.sources} if hasattr(dem, "sources") else {})},
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


def sun_pixel(cam: Camera, proj: Projection, scene: Scene):
    """(u, v) [px] of the sun in a frame, or None when it lies well outside (glare needs it)."""
    d_cam = proj.rotation.T @ scene.sun
    u, v, front = cam.ray_to_pixel(d_cam)
    if front and -0.2 * cam.width < u < 1.2 * cam.width and -0.2 * cam.height < v < 1.2 * cam.height:
        return float(u), float(v)
    return None
