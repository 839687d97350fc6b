"""The named robustness sets (:data:`SETS`): cases drawn over an area of the DEM, each simulated
with its set's conditions.
"""

from __future__ import annotations

import logging
from dataclasses import asdict
from pathlib import Path

import numpy as np

from .._io import write_json
from ..camera import Camera, get_camera
from ..dem import Dem
from ..errors import ParameterError
from ..formats import Truth
from ..planets import resolve_planet
from .acquisition import (PANO_HEIGHT, PANO_WIDTH, check_render_options, check_seed,
                          simulate_acquisition)
from .folders import check_out_folder, staged_folder
from .world import MapErrors, check_world_covers, check_world_heights, world_dem, world_record

log = logging.getLogger(__package__)




#: The named robustness sets of the source study's test plan.
SETS = {
    "REF": "nominal: level rover, no degradation",
    "HREL": "flat, featureless horizons: the lowest-relief positions of a larger random pool",
    "SCOM": "skyline partly outside the view: the camera tilted so the skyline leaves the frame",
    "LREL": "pitch and roll up to +-10 deg; attitude prior 0 or noisy (1 deg)",
    "CLUT": "clutter: dust (and clouds on Earth)",
    "OCCL": "occlusion: boulders near the rover that the DEM lacks",
    "COND": "bad light: glare (sun in view), over- or under-exposure",
    "DEMERR": "the map is not the world: nominal imaging of a world DEM that differs from the map "
              "(2x finer with fractal detail, 2 m rms correlated height error, spikes and pits, "
              "3 m misregistration; see skyfix.simulate.world)",
}
#: sets whose world differs from the map by default
MAP_ERROR_SETS = {"DEMERR"}


def default_margin(dem: Dem, margin_m: float | None = None) -> float:
    """[m] how far the default area keeps from the DEM's edge: 10 cells or 5 % of the extent, the
    larger, at most a quarter of it."""
    xmin, ymin, xmax, ymax = dem.bounds
    ext = min(xmax - xmin, ymax - ymin)
    m = max(10 * dem.cell_m, 0.05 * ext) if margin_m is None else float(margin_m)
    return min(m, 0.25 * ext)


def default_area(dem: Dem, margin_m: float | None = None) -> tuple[float, float, float, float]:
    """The DEM's bounds minus :func:`default_margin` [m]."""
    xmin, ymin, xmax, ymax = dem.bounds
    m = default_margin(dem, margin_m)
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


#: unit vectors (east, north) of the 8 directions a position is kept clear of the data's edge in
_DIRECTIONS = np.stack([np.sin(np.radians(np.arange(0.0, 360.0, 45.0))),
                        np.cos(np.radians(np.arange(0.0, 360.0, 45.0)))], 1)


def _clear_of_data_edge(dem: Dem, x: float, y: float, clear_m: float) -> bool:
    """Whether the DEM has heights ``clear_m`` [m] from (x, y) [m] in all 8 directions."""
    ring = 0.999 * clear_m * _DIRECTIONS  # a hair short: a full grid's own edge is inside
    return bool(np.isfinite(dem.height_at(x + ring[:, 0], y + ring[:, 1])).all())


def _draw_positions(dem: Dem, area, n: int, rng: np.random.Generator,
                    clear_m: float = 0.0) -> np.ndarray:
    """n positions [m] with heights in ``area``; with ``clear_m`` [m], also heights 8 points
    around each at that distance: the default area keeps its margin from the DEM's data, not only
    from its grid's edge, where a reprojected DEM's corners hold none (its cases had stood 68 m
    from the end of the terrain)."""
    xmin, ymin, xmax, ymax = area
    pts = []
    for _ in range(200 * n + 100):
        if len(pts) >= n:
            break
        x, y = rng.uniform(xmin, xmax), rng.uniform(ymin, ymax)
        if np.isfinite(dem.height_at(x, y)) and (clear_m <= 0 or _clear_of_data_edge(dem, x, y, clear_m)):
            pts.append((x, y))
    if len(pts) < n:
        raise ParameterError("could not draw positions with known heights in the area: the DEM is "
                             "mostly void there; choose another --area")
    return np.array(pts)


def _near_data_edge(dem: Dem, pos: np.ndarray, clear_m: float) -> int:
    """How many positions [m] have a point without height ``clear_m`` [m] away (8 directions)."""
    return sum(not _clear_of_data_edge(dem, x, y, clear_m) for x, y in pos)


def plan_set(dem: Dem, name: str, cases: int, seed: int, *, area=None, camera: str | Camera = "navcam",
             mode: str = "frames", camera_height_m: float = 1.5, planet=None) -> list[dict]:
    """The cases of a named set: per case ``truth`` and the keyword arguments of
    :func:`simulate_acquisition` (deterministic for ``seed``)."""
    from ..horizon import render_horizons

    key = str(name).upper()
    if key not in SETS:
        raise ParameterError(f"unknown set {name!r}: choose one of {', '.join(SETS)}")
    if int(cases) != cases or cases < 1:
        raise ParameterError(f"cases must be a positive whole number, got {cases}")
    cases = int(cases)
    seed = check_seed(seed)
    clear = default_margin(dem) if area is None else 0.0
    area = _check_area(dem, area)
    rng = np.random.default_rng([int(seed), sum(map(ord, key))])
    pl = resolve_planet(planet, getattr(dem, "body", None))
    cam = get_camera(camera) if isinstance(camera, str) else camera
    if key == "HREL":
        pool = _draw_positions(dem, area, 6 * cases, rng, clear)
        hb = render_horizons(dem, pool[:, 0], pool[:, 1], camera_height_m=camera_height_m, planet=pl)
        relief = np.nanmax(hb.elevation_deg, axis=1) - np.nanmin(hb.elevation_deg, axis=1)
        pos = pool[np.argsort(relief, kind="stable")[:cases]]
    else:
        pos = _draw_positions(dem, area, cases, rng, clear)
    if clear == 0.0:
        # a user's area is drawn as given, but a case near the end of the DEM's data sees the
        # terrain stop there (a cliff into nothing), which no real skyline shows
        margin = default_margin(dem)
        near = _near_data_edge(dem, pos, margin)
        if near:
            log.warning(f"{near} of {len(pos)} {key} cases lie within {margin:.0f} m of where the "
                        "DEM's heights end (the area given reaches there): their skylines see the "
                        f"terrain stop; keep the area {margin:.0f} m inside the data for cases like "
                        "real ones")
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
                 camera_height_m: float = 1.5, planet=None, overwrite: bool = False,
                 pano_size: tuple[int, int] = (PANO_WIDTH, PANO_HEIGHT),
                 progress: bool = False, tilt_deg: float = 0.0, map_errors: MapErrors | None = None,
                 world: Dem | None = None) -> list[Path]:
    """Render a named robustness set (:data:`SETS`) into ``out/case_NNN`` folders.

    Positions are drawn uniformly (off-grid) inside ``area`` (XMIN, YMIN, XMAX, YMAX) [m], default
    :func:`default_area`; headings uniform in [0, 360) deg; everything deterministic for ``seed``.
    Also writes ``out/set.json`` listing the cases. Returns the case folders. As for
    :func:`simulate_acquisition`, options are checked first and ``out`` is replaced (with
    ``overwrite``) only by a complete set.
    tilt_deg : [deg] mast tilt of every frame (mountain skylines sit high: 10-15 deg keeps them in
        a navcam's view), except where the set chooses its own (SCOM)
    map_errors : render every case from :func:`skyfix.simulate.world.world_dem` of ``dem`` with
        these errors (DEMERR: :class:`MapErrors` defaults unless given), one world per set drawn
        from ``seed``; each case's ``acquisition.json`` records the errors and the map offset
    world : render from this DEM instead (``--world-dem``: any second DEM of the same place)
    """
    # Everything is checked and planned before ``out`` is touched (or a progress bar shown), and
    # the set is rendered into a hidden sibling that replaces ``out`` only once complete.
    check_render_options(mode=mode, camera=camera, camera_height_m=camera_height_m, tilt_deg=tilt_deg,
                  planet=planet, seed=seed, frames=frames, pano_size=pano_size)
    if world is not None:
        check_world_covers(world, _check_area(dem, area), "the area where cases are drawn on the map",
                           "a smaller --area inside both")
    plans = plan_set(dem, name, cases, seed, area=area, camera=camera, mode=mode,
                     camera_height_m=camera_height_m, planet=planet)
    if world is not None:
        check_world_heights(world, [p["truth"].x for p in plans], [p["truth"].y for p in plans],
                            "case positions", "a smaller --area inside its data")
    if map_errors is None and str(name).upper() in MAP_ERROR_SETS and world is None:
        map_errors = MapErrors()
    sim_meta = world_record(map_errors, seed, world)
    if world is None and map_errors is not None:
        world = world_dem(dem, map_errors, seed)
    render = world if world is not None else dem
    out = check_out_folder(out, overwrite)
    with staged_folder(out, overwrite) as tmp:
        it = plans
        if progress:
            from tqdm import tqdm

            it = tqdm(plans, desc=f"set {name.upper()}", unit="case")
        for p in it:
            simulate_acquisition(
                render, p["truth"], tmp / p["folder"], camera=camera, mode=mode, frames=frames,
                camera_height_m=camera_height_m, planet=planet, pano_size=pano_size,
                simulation_meta=sim_meta, **{"tilt_deg": tilt_deg, **p["kwargs"]})
        listing = {
            "set": name.upper(), "description": SETS[name.upper()], "seed": int(seed), **sim_meta,
            "cases": [
                {"folder": p["folder"], "truth": asdict(p["truth"]),
                 **{k: v for k, v in p["kwargs"].items()}} for p in plans],
        }
        write_json(tmp / "set.json", listing)
    return [out / p["folder"] for p in plans]
