"""A build's tasks: what one task needs (:class:`BuildSpec`), rendering its blocks (one at a time
with the per-point kernel, a group at once with the grid sweep) and writing each block's chunks,
then its marker. :mod:`.build` plans the tasks and runs them.
"""

from __future__ import annotations

import logging

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._io import write_json
from ..errors import DatabaseError, ParameterError
from ..planets import Planet
from .coarse import write_coarse_block
from .layout import (COARSE, DATA_ARRAYS, MARKER_DIR, SKIP_TOL_DEG, Grid, array_sha256,
                     marker_document, marker_name, quantise)


@dataclass(frozen=True)
class BuildSpec:
    """Everything a block task needs (small: shipped to workers instead of the DEM)."""

    dem_path: str | tuple  # one DEM file, or a stack's files (skyfix.stack)
    dem_sha256: str
    out: str
    grid: Grid
    camera_height_m: float
    azimuth_bins: int
    max_distance_m: float | None
    planet: Planet
    single_thread: bool = False
    renderer: str = "kernel"


#: the skyline renderers a build can use (:func:`build_database`)
RENDERERS = ("kernel", "sweep")
#: blocks per side of one sweep task at most: its lines serve this many blocks' positions at once
#: (4 x 4 blocks of 64: 65,536 positions, about 0.6 GB of working arrays); :func:`tasks_of` halves
#: it where the build would leave workers without tasks
SWEEP_GROUP = 4
#: [positions] side of a sweep task at most, whatever the block size: groups of larger blocks
#: are smaller (blocks of 256 one to a task; 4 x 4 of them were 1 M positions, 9-16 GB a worker)
SWEEP_TASK_SIDE = SWEEP_GROUP * 64


#: worker-process DEM cache: (path, sha256) -> Dem, so a DEM is read once per process
_DEM_CACHE: dict = {}


def dem_for(path, sha256: str):
    """The DEM at ``path`` (or the stack of a tuple of paths), loaded once per process and checked
    against its ``sha256``."""
    from ..stack import load_dems

    key = (path, sha256)
    dem = _DEM_CACHE.get(key)
    if dem is None:
        # the build said the DEM's warnings when it read it first; a worker's reading says them
        # again, unprefixed, through the progress bar
        dem_log = logging.getLogger("skyfix.dem")
        level = dem_log.level
        dem_log.setLevel(logging.ERROR)
        try:
            dem = load_dems(list(path) if isinstance(path, tuple) else path)
        finally:
            dem_log.setLevel(level)
        if dem.checksum != sha256:
            raise DatabaseError(f"DEM {path} changed during the build (SHA-256 {dem.checksum[:12]}..., "
                                f"expected {sha256[:12]}...): restart the build with the DEM you want")
        _DEM_CACHE.clear()  # one DEM per process is all a build needs; keep memory bounded
        _DEM_CACHE[key] = dem
    return dem


def open_arrays(out: str, mode: str = "r+"):
    """The store's four data arrays by name (zarr arrays of the group at ``out``), and under
    :data:`~.layout.COARSE` its coarse index (None in a store created without one)."""
    import zarr

    g = zarr.open_group(out, mode=mode)
    arrays = {name: g[name] for name in DATA_ARRAYS}
    arrays[COARSE] = g[COARSE] if COARSE in g else None
    return arrays


def render_block(dem, spec: BuildSpec, br: int, bc: int) -> dict:
    """Render one block with the per-point kernel: arrays shaped (rows, cols[, bins]) as stored."""
    from ..horizon import render_horizons

    rs, cs = spec.grid.block_slices(br, bc)
    x, y = spec.grid.block_xy(br, bc)
    hb = render_horizons(dem, x, y, camera_height_m=spec.camera_height_m, planet=spec.planet,
                         azimuth_bins=spec.azimuth_bins, max_distance_m=spec.max_distance_m,
                         skip_tol_deg=SKIP_TOL_DEG)
    return stored_arrays(spec, hb.elevation_deg, hb.ray_length_m, hb.ground_z_m,
                         rs.stop - rs.start, cs.stop - cs.start)


def render_group(dem, spec: BuildSpec, blocks) -> dict:
    """Render blocks with the grid sweep (:func:`skyfix.sweep.render_grid`) as one rectangle, so
    that its lines serve them all: {(br, bc): arrays as :func:`render_block` gives them}. The
    rectangle spans the blocks given (a group of :func:`tasks_of`)."""
    from ..sweep import render_grid

    g = spec.grid
    spans = [g.block_slices(br, bc) for br, bc in blocks]
    r0, r1 = min(rs.start for rs, _ in spans), max(rs.stop for rs, _ in spans)
    c0, c1 = min(cs.start for _, cs in spans), max(cs.stop for _, cs in spans)
    hb = render_grid(dem, float(g.x_coords[c0]), float(g.y_coords[r0]), g.spacing_m, r1 - r0,
                     c1 - c0, camera_height_m=spec.camera_height_m, planet=spec.planet,
                     azimuth_bins=spec.azimuth_bins, skip_tol_deg=SKIP_TOL_DEG)
    shape = (r1 - r0, c1 - c0)
    el = hb.elevation_deg.reshape(*shape, -1)
    ln = hb.ray_length_m.reshape(*shape, -1)
    gz = hb.ground_z_m.reshape(shape)
    out = {}
    for (br, bc), (rs, cs) in zip(blocks, spans):
        sub = (slice(rs.start - r0, rs.stop - r0), slice(cs.start - c0, cs.stop - c0))
        rows, cols = rs.stop - rs.start, cs.stop - cs.start
        out[(br, bc)] = stored_arrays(spec, el[sub].reshape(rows * cols, -1),
                                      ln[sub].reshape(rows * cols, -1), gz[sub].ravel(), rows, cols)
    return out


def stored_arrays(spec: BuildSpec, elevation_deg, ray_length_m, ground_z_m, rows: int,
                  cols: int) -> dict:
    """A block's stored arrays from its rendered skylines ((rows * cols, bins) [deg] and [m],
    ground (rows * cols,) [m]): shaped (rows, cols[, bins])."""
    maxd = np.inf if spec.max_distance_m is None else spec.max_distance_m
    # A ray shorter than the maximum distance stopped at the DEM edge (rays end at min(edge, max)).
    edge = (ray_length_m < np.float32(maxd) * np.float32(1 - 1e-6)).sum(axis=1)
    return {
        "elevation": quantise(elevation_deg).reshape(rows, cols, spec.azimuth_bins),
        "ground_z": ground_z_m.astype(np.float32).reshape(rows, cols),
        "min_ray_m": ray_length_m.min(axis=1).astype(np.float32).reshape(rows, cols),
        "edge_bins": edge.astype(np.int16).reshape(rows, cols),
    }


def build_blocks(spec: BuildSpec, blocks) -> tuple[int, int]:
    """One task: render the blocks (each on its own with the kernel, together with the sweep),
    write each one's chunks, then its marker. Returns (blocks, positions)."""
    if spec.single_thread:
        import numba

        numba.set_num_threads(1)  # one worker process per core: numba must not fan out too
    dem = dem_for(spec.dem_path, spec.dem_sha256)
    if spec.renderer == "sweep":
        rendered = render_group(dem, spec, blocks)
    else:
        rendered = {(br, bc): render_block(dem, spec, br, bc) for br, bc in blocks}
    arrays = open_arrays(spec.out)
    n = 0
    for (br, bc), data in rendered.items():
        rs, cs = spec.grid.block_slices(br, bc)
        for name, a in data.items():
            arrays[name][rs, cs] = a
        if arrays.get(COARSE) is not None:
            write_coarse_block(arrays[COARSE], spec.grid, br, bc, data["elevation"])
        marker = {"block": [br, bc], "row0": rs.start, "col0": cs.start, "rows": rs.stop - rs.start,
                  "cols": cs.stop - cs.start,
                  "sha256": {k: array_sha256(v) for k, v in data.items()}}
        # Written only after every chunk is on disk: a block without a marker gets redone.
        mp = Path(spec.out) / MARKER_DIR / marker_name(br, bc)
        mp.parent.mkdir(parents=True, exist_ok=True)
        write_json(mp, marker_document(marker))
        n += (rs.stop - rs.start) * (cs.stop - cs.start)
    return len(rendered), n


def tasks_of(todo, renderer: str, slots: int = 1, block: int = 64) -> list[list[tuple[int, int]]]:
    """The blocks to build, as tasks: one block each for the kernel; for the sweep, the blocks
    of each square group together (a resumed group renders only its blocks still missing, as one
    rectangle over them).

    A group is :data:`SWEEP_GROUP` blocks on a side (fewer where blocks of ``block`` positions
    a side would make it wider than :data:`SWEEP_TASK_SIDE` positions), halved while that leaves
    fewer than two tasks per slot (``slots`` tasks run at once): a 1 x 1 km build at 5 m is one group of 4 x 4,
    which kept one of two workers idle (9.5 s instead of 12.0 s with groups of 2 x 2, for 18 %
    more CPU). The grouping changes no stored value: the sweep's lines lie on a lattice fixed to
    the DEM, and where a line's samples start (the rectangle's edge) moves the float sums by at
    most ~5e-7 deg, a fraction of the store's 0.01 deg step (a review saw 3 bins so among
    millions, none across a step; resumed 7 x 7 km stores byte-identical)."""
    if renderer != "sweep":
        return [[b] for b in todo]
    side = max(1, min(SWEEP_GROUP, SWEEP_TASK_SIDE // int(block)))
    while side > 1 and slots > 1 and len({(br // side, bc // side) for br, bc in todo}) < 2 * slots:
        side //= 2
    groups: dict = {}
    for br, bc in todo:
        groups.setdefault((br // side, bc // side), []).append((br, bc))
    return list(groups.values())


def check_renderer(renderer: str, dem_paths: list, max_distance_m: float | None) -> None:
    """Refuse, before any work, a renderer that is not one, or the sweep where it cannot serve."""
    if renderer not in RENDERERS:
        raise ParameterError(f"renderer must be one of {', '.join(RENDERERS)}, got {renderer!r}")
    if renderer == "sweep" and (len(dem_paths) > 1 or max_distance_m is not None):
        what = "a stack of DEMs" if len(dem_paths) > 1 else "--max-distance-m"
        raise ParameterError(f"the sweep renderer cannot build with {what} (its lines run to the "
                             "one DEM's edge): build with --renderer kernel")


def remember_dem(spec: BuildSpec, dem) -> None:
    """Seed this process's DEM cache with the build's own load (the in-process path reuses it)."""
    _DEM_CACHE.clear()
    _DEM_CACHE[(spec.dem_path, spec.dem_sha256)] = dem
