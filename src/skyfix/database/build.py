"""Building a store: tasks of one block (the per-point kernel) or a group of blocks (the grid
sweep) that render their positions, write the chunks, then atomically each block's marker
(:mod:`.tasks`), resumable, through any ``concurrent.futures.Executor`` (:mod:`.executors`).

Compression (measured on sierra_nevada_30m at 5 m, one 64 x 64 block, 720 raw bytes per skyline):
zstd 9 alone 276 B/skyline, blosc-zstd with byte shuffle 277, delta along the azimuth + byte
shuffle + zstd 9: 171 B/skyline at ~40 ms to encode a block (rendering it takes seconds).
Stores built since 2026-11-26 first transpose the chunk to (azimuth, y, x), so the delta runs along x, from
each position to its neighbour at the same azimuth: on 16 blocks of the 7 x 7 km Sierra store at
5 m, 212 -> 185 B/skyline (-13 %; along y -14 %, a second difference +1 %, zstd 13 instead of 9
-0.5 % at 4x the time, blosc's bit shuffle +11 %). Stores of the earlier layout stay readable.
The delta and shuffle codecs come from numcodecs (readable by zarr-python; not in the zarr v3
core spec); the transpose is a core codec.

Measured for the search's speed and not taken (2026-11-27, 20-40 chunks of that store, one core):
LZ4HC (blosc, level 9, after the same delta and shuffle) decodes about twice as fast as zstd (1.8
against 0.9 GB/s; 4.4 against 1.5 in a warmer run) for 16 % more bytes, but encodes at 13 MB/s
(zstd 9: 68), and decompression is only half of the search's reader thread (zstd 1.1 s, undoing
the shuffle and delta 0.5-0.8 s of ~2 s per full search): ~0.5 s of CPU saved for a new format
and a larger store. (The undo pass as four interleaved prefix sums was no faster either.)
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import time
from concurrent.futures import FIRST_COMPLETED, Executor, wait
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import __version__
from .._io import check_staging_writable
from ..errors import DatabaseError, OutputExistsError, ParameterError
from ..planets import Planet, get_planet, resolve_planet
from .chunks import skyline_codecs
from .coarse import add_coarse_index, create_coarse_array
from .executors import check_executor_options, make_executor
from .integrity import clean_partials, indexed_blocks, intact_blocks, root_state
from .layout import (BLOCK, COMPRESSED_SHARE, FORMAT, FORMAT_VERSION, MAX_BUILD_BYTES,
                     MAX_POSITIONS, META_DIR, MIN_SEARCH_BINS, MISSING, SCALE_DEG, SKIP_TOL_DEG,
                     Grid, has_coarse_layout)
from .tasks import BuildSpec, build_blocks, check_renderer, remember_dem, tasks_of


log = logging.getLogger(__package__)  # messages name the stage, as before the split


# --- build -----------------------------------------------------------------------------------------
def estimate_build_bytes(grid: Grid, azimuth_bins: int) -> float:
    """[bytes] rough size on disk of a complete build (errs on the large side)."""
    per = azimuth_bins * 2 * COMPRESSED_SHARE + 10  # + ground_z, min_ray_m, edge_bins
    return float(grid.ny) * float(grid.nx) * per


def check_build_size(grid: Grid, azimuth_bins: int) -> None:
    """Refuse a grid too large to be meant (a typo in --spacing-m), before any work."""
    n = grid.ny * grid.nx
    est = estimate_build_bytes(grid, azimuth_bins)
    if n > MAX_POSITIONS or est > MAX_BUILD_BYTES:
        raise ParameterError(
            f"the grid has {n:,} positions ({grid.nx:,} x {grid.ny:,} at {grid.spacing_m:g} m), about "
            f"{est / 1e9:,.0f} GB on disk: more than skyfix builds ({MAX_POSITIONS:,} positions or "
            f"{MAX_BUILD_BYTES / 1e9:.0f} GB); raise --spacing-m or narrow --bounds")


def build_params(*, dem_sha256: str, grid: Grid, bounds, camera_height_m: float, azimuth_bins: int,
                 max_distance_m: float | None, planet: Planet, renderer: str = "kernel") -> dict:
    """The parameters that define a build's content: a resume must match every one of them.
    (``renderer`` is recorded only when it is the sweep: a kernel build's parameters are those of
    the stores built before the sweep existed, which therefore still resume.)"""
    params = {"format_version": FORMAT_VERSION, "dem_sha256": dem_sha256,
              "bounds": [float(b) for b in bounds], "spacing_m": grid.spacing_m,
              "camera_height_m": float(camera_height_m), "azimuth_bins": int(azimuth_bins),
              "max_distance_m": None if max_distance_m is None else float(max_distance_m),
              "planet": planet.to_attr(), "block_positions": grid.block, "scale_deg": SCALE_DEG,
              "skip_tol_deg": SKIP_TOL_DEG}
    if renderer != "kernel":
        params["renderer"] = renderer
    return params


def _create_store(out: Path, grid: Grid, bins: int, attrs: dict) -> None:
    """Create the empty store atomically: built beside ``out``, then renamed onto it."""
    import zarr
    from zarr.codecs import ZstdCodec

    for stale in out.parent.glob(f".{out.name}.creating-*"):  # left by a build killed right here
        shutil.rmtree(stale, ignore_errors=True)
    tmp = out.parent / f".{out.name}.creating-{os.getpid()}"
    try:
        g = zarr.open_group(str(tmp), mode="w", zarr_format=3)
        b = grid.block
        g.create_array("elevation", shape=(grid.ny, grid.nx, bins), chunks=(b, b, bins),
                       dtype="int16", fill_value=MISSING, dimension_names=("y", "x", "azimuth"),
                       attributes={"units": "deg", "scale_deg": SCALE_DEG, "missing": MISSING},
                       **skyline_codecs(b))
        create_coarse_array(g, grid, bins)
        small = {"compressors": [ZstdCodec(level=9, checksum=True)]}
        g.create_array("ground_z", shape=grid.shape, chunks=(b, b), dtype="float32", fill_value=np.nan,
                       dimension_names=("y", "x"), attributes={"units": "m"}, **small)
        g.create_array("min_ray_m", shape=grid.shape, chunks=(b, b), dtype="float32", fill_value=np.nan,
                       dimension_names=("y", "x"), attributes={"units": "m"}, **small)
        g.create_array("edge_bins", shape=grid.shape, chunks=(b, b), dtype="int16", fill_value=-1,
                       dimension_names=("y", "x"), attributes={"units": "bins"}, **small)
        for name, vals, dim, unit in (("x", grid.x_coords, "x", "m"), ("y", grid.y_coords, "y", "m"),
                                      ("azimuth", np.arange(bins) * (360.0 / bins), "azimuth", "deg")):
            a = g.create_array(name, shape=vals.shape, chunks=vals.shape, dtype="float64",
                               dimension_names=(dim,), attributes={"units": unit}, **small)
            a[:] = vals
        g.attrs.update(attrs)
        # Marker folders are zarr groups so that zarr tools see a clean hierarchy.
        g.create_group(META_DIR, attributes={"about": "skyfix build bookkeeping"}).create_group(
            "blocks", attributes={"about": "one JSON marker per finished block, with its checksums"})
        os.replace(tmp, out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _differences(old: dict, new: dict) -> list[str]:
    def shown(k, v):
        # the renderer is recorded only for the sweep: a store without it was the kernel's
        return "'kernel'" if k == "renderer" and v is None else repr(v)

    keys = sorted(set(old) | set(new))
    return [f"{k}: the store has {shown(k, old.get(k))}, this build asks for {shown(k, new.get(k))}"
            for k in keys if old.get(k) != new.get(k)]


@dataclass(frozen=True)
class BuildResult:
    """What a build did: path, blocks built now / already there, positions, seconds, bytes, and
    the blocks built earlier whose coarse index it added."""

    path: Path
    n_blocks: int
    built: int
    resumed_from: int
    positions: int
    seconds: float
    skylines_per_s: float
    size_bytes: int
    indexed: int = 0


def build_database(dem_path, out, bounds, spacing_m: float, *, camera_height_m: float = 1.5,
                   azimuth_bins: int = 360, max_distance_m: float | None = None, planet=None,
                   workers: int | None = None, scheduler: str | None = None,
                   executor: Executor | None = None, overwrite: bool = False, progress: bool = True,
                   block: int = BLOCK, renderer: str = "kernel") -> BuildResult:
    """Build (or resume) a skyline database over ``bounds``.

    dem_path : DEM file (read with :func:`skyfix.dem.load_dem`, the DEM's own CRS if metric), or
        several files of one place (:func:`skyfix.stack.load_dems`: the finest wins everywhere)
    out : the zarr store to write (a directory)
    bounds : (xmin, ymin, xmax, ymax) [m] of the position grid, in the DEM's CRS
    spacing_m : [m] grid spacing
    camera_height_m : [m] camera above the ground; azimuth_bins : bins over 360 deg
    max_distance_m : [m] ray length limit (None: to the DEM edge)
    planet : ``earth``, ``mars``, a radius [m] or a Planet; None (default): the DEM's body
    workers : 0 = in process; N = a local Dask cluster of N processes (default: one per core)
    scheduler : an existing Dask scheduler address instead; executor : any Executor instead (its
        tasks must see the same files; numba keeps its default threads)
    overwrite : replace an existing store (else a store built with the same parameters resumes,
        and anything else is refused)
    block : [positions] block side (one chunk per block; one task per block with the kernel)
    renderer : ``kernel`` (every ray traced on its own: :func:`skyfix.horizon.render_horizons`)
        or ``sweep`` (:func:`skyfix.sweep.render_grid` over groups of up to :data:`SWEEP_GROUP`
        x :data:`SWEEP_GROUP` blocks, smaller where that leaves the workers too few tasks, one
        task each: 1.7-2.5x faster, 2-2.5x less CPU from 2 x 2 km up, its skylines never above the
        kernel's and below them by more than 0.01 deg in at most 0.05 % of bins at 5 m spacing;
        its lines stay at most :data:`skyfix.sweep.LINE_SPACING_M` apart, so a coarser grid costs
        more lines per position; one DEM, rays to its edge). A build parameter: a resume keeps it
    """
    from ..stack import load_dems

    # Absolute paths: a task runs in a worker whose working folder may be another (an external
    # scheduler's workers), where a relative --out named nothing.
    out = Path(out).absolute()
    paths = [dem_path] if isinstance(dem_path, (str, os.PathLike)) else list(dem_path)
    paths = [str(Path(p).absolute()) for p in paths]
    dem_path = paths[0] if len(paths) == 1 else tuple(paths)
    grid = Grid.from_bounds(bounds, spacing_m, block)
    planet_spec = planet
    if planet is not None:
        get_planet(planet)  # a bad --planet is refused before the DEM is read
    if int(azimuth_bins) != azimuth_bins or azimuth_bins <= 0:
        raise ParameterError(f"azimuth bins must be a positive whole number, got {azimuth_bins}")
    azimuth_bins = int(azimuth_bins)
    if azimuth_bins > 65535:
        raise ParameterError(f"at most 65535 azimuth bins, got {azimuth_bins}")
    # a store no profile could be searched against is refused now, not after hours of building
    if azimuth_bins < MIN_SEARCH_BINS:
        raise ParameterError(f"at least {MIN_SEARCH_BINS} azimuth bins (a profile needs that many "
                             f"observed to be searched), got {azimuth_bins}; 360 is the default")
    if max_distance_m is not None and not (max_distance_m > 0 and math.isfinite(max_distance_m)):
        raise ParameterError(f"maximum distance must be > 0 m, got {max_distance_m}")
    if not (math.isfinite(camera_height_m) and camera_height_m >= 0):
        raise ParameterError(f"camera height must be >= 0 m, got {camera_height_m}")
    check_build_size(grid, azimuth_bins)
    check_renderer(renderer, paths, max_distance_m)
    if executor is None:
        check_executor_options(workers, scheduler)

    dem = load_dems(list(paths))
    planet = resolve_planet(planet_spec, dem.body)  # the DEM's CRS says which body
    xs, ys = grid.x_coords, grid.y_coords
    # Every position must have a height: the corners catch a wrong area, the full grid a void.
    dem.require_inside([xs[0], xs[-1], xs[0], xs[-1]], [ys[0], ys[0], ys[-1], ys[-1]],
                       what="database bounds corner")
    for r0 in range(0, grid.ny, 256):
        yy, xx = np.meshgrid(ys[r0:r0 + 256], xs, indexing="ij")
        dem.require_inside(xx.ravel(), yy.ravel(), what="database position")

    params = build_params(dem_sha256=dem.checksum, grid=grid, bounds=bounds,
                          camera_height_m=camera_height_m, azimuth_bins=azimuth_bins,
                          max_distance_m=max_distance_m, planet=planet, renderer=renderer)
    with build_lock(out):  # before the plan: a build finishing meanwhile would make it stale
        return _plan_and_build(out, params, grid, overwrite, executor, workers, scheduler,
                               dem_path, dem, planet, progress)


def _plan_and_build(out, params, grid, overwrite, executor, workers, scheduler, dem_path, dem,
                    planet, progress) -> BuildResult:
    action = _plan_output(out, params, grid, overwrite)  # refuses, deletes nothing
    if action in ("new", "replace", "unlink", "rmdir"):  # staged beside it, renamed into place
        check_staging_writable(out)
    if action == "complete":
        n = len(grid.blocks())
        log.info("%s is already complete, built with these parameters: nothing to do "
                 "(--overwrite rebuilds it)", out)
        return BuildResult(out, n, 0, n, 0, 0.0, float("nan"), dir_size(out))
    # The executor starts (the scheduler is reached) before anything is deleted: a bad --scheduler
    # must not cost the database that --overwrite was about to replace.
    with (nullcontext((executor, 2, False)) if executor is not None
          else make_executor(workers, scheduler)) as (ex, slots, single):
        if scheduler is not None:
            _check_workers_see(ex, dem_path, out)
        return _build(out, action, dem_path, dem, grid, params, planet, ex, slots, single, progress)


@contextmanager
def build_lock(out: Path):
    """Hold ``.NAME.lock`` beside the store ``out`` while writing it: a second build of the same
    store (another shell, a script run twice) is refused instead of deleting the first one's
    staging folder and leaving a store of neither's parameters. The lock goes with the process
    (``flock``), killed or not; the file is removed when the build ends (a killed one leaves it,
    unlocked, for the next to take)."""
    import fcntl

    lock = out.parent / f".{out.name}.lock"
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
        f = open(lock, "a+")
    except OSError:  # a folder it cannot write: the checks that follow say so, or resume needs none
        yield
        return
    with f:
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            f.seek(0)
            who = f.read().strip() or "another process"
            raise DatabaseError(f"another skyfix build-db is writing {out} ({who}): wait for it "
                                "to finish, or stop it, then run this command again") from None
        f.seek(0)
        f.truncate()
        f.write(f"process {os.getpid()}")
        f.flush()
        try:
            yield
        finally:
            # removed while still held: a build that opened it meanwhile fails to lock it and is
            # refused; one that starts after finds no file and makes its own
            lock.unlink(missing_ok=True)
            fcntl.flock(f, fcntl.LOCK_UN)


def _paths_seen(dem_path, out_parent: str) -> tuple[bool, bool]:
    """(the DEM file(s) exist, the output's folder exists) where this runs (a worker)."""
    paths = dem_path if isinstance(dem_path, tuple) else (dem_path,)
    return all(os.path.isfile(p) for p in paths), os.path.isdir(out_parent)


def _check_workers_see(ex: Executor, dem_path: str, out: Path) -> None:
    """Refuse, before any work, a cluster whose workers cannot see the DEM or the output's folder
    at the paths this process uses (another machine, another mount)."""
    dem_ok, out_ok = ex.submit(_paths_seen, dem_path, str(out.parent)).result(timeout=60)
    if not (dem_ok and out_ok):
        what = " and ".join(w for w, ok in ((f"the DEM {dem_path}", dem_ok),
                                           (f"the output folder {out.parent}", out_ok)) if not ok)
        raise ParameterError(f"the Dask workers cannot see {what}: put both on storage the "
                             "workers share, at the same path, or build with --workers instead")


def _build(out: Path, action: str, dem_path, dem, grid: Grid, params: dict, planet: Planet,
           ex: Executor, slots: int, single: bool, progress: bool) -> BuildResult:
    paths = list(dem_path) if isinstance(dem_path, tuple) else [dem_path]
    """The part of :func:`build_database` that writes: every option checked, the executor running."""
    resumed = _apply_plan(out, action)
    azimuth_bins = params["azimuth_bins"]
    if not resumed:
        attrs = {
            "format": FORMAT, "format_version": FORMAT_VERSION, "software_version": __version__,
            "crs_wkt": dem.crs_wkt, "crs_name": dem.crs_name, "grid": grid.to_attr(),
            "camera_height_m": params["camera_height_m"], "planet": planet.to_attr(),
            "azimuth_bins": azimuth_bins, "max_distance_m": params["max_distance_m"],
            "elevation": {"scale_deg": SCALE_DEG, "missing": MISSING,
                          "max_quantisation_error_deg": SCALE_DEG / 2,
                          "meaning": "elevation angle [deg] = raw * scale_deg; missing = no terrain "
                                     "seen along that ray"},
            "dem": {"sha256": dem.checksum,
                    "source": " + ".join(paths),
                    "shape": list(dem.shape), "cell_m": [dem.dx, dem.dy], "bounds": list(dem.bounds),
                    **({"sources": dem.sources} if hasattr(dem, "sources") else {})},
            "build": params,
        }
        _create_store(out, grid, azimuth_bins, attrs)

    spec = BuildSpec(dem_path, dem.checksum, str(out), grid,
                      params["camera_height_m"], azimuth_bins, params["max_distance_m"], planet,
                      single_thread=single, renderer=params.get("renderer", "kernel"))
    remember_dem(spec, dem)
    n_indexed = 0
    if resumed:  # a store begun without the coarse index gets it for the blocks already built
        n_indexed = add_coarse_index(out, progress=progress)
    done = intact_blocks(out, grid)
    todo = [b for b in grid.blocks() if b not in done]
    n_blocks = len(grid.blocks())
    if resumed:
        msg = f"resuming {out}: {len(done)} of {n_blocks} blocks already built, {len(todo)} to go"
        log.warning(msg)
        if progress:
            print(msg, flush=True)
    t0 = time.perf_counter()
    positions = 0
    if todo:
        positions = _run(ex, slots, spec, todo, n_blocks, len(done), progress)
    dt = time.perf_counter() - t0
    missing = set(grid.blocks()) - intact_blocks(out, grid)
    if missing:  # cannot happen unless a task lied; never report an incomplete store as built
        raise DatabaseError(f"{len(missing)} blocks of {out} have no marker or no data after the build: "
                            "run it again")
    return BuildResult(out, n_blocks, len(todo), len(done), positions, dt,
                       positions / dt if dt > 0 else float("nan"), dir_size(out), n_indexed)


def _plan_output(out: Path, params: dict, grid: Grid, overwrite: bool) -> str:
    """What to do with ``out``, refusing what must not happen; changes nothing on disk.

    Returns ``new`` (nothing there), ``rmdir`` (an empty folder), ``unlink`` (a file, with
    --overwrite), ``replace`` (a skyfix database, with --overwrite), ``resume``, ``index`` (a
    complete store built without the coarse index: it is added), or ``complete`` (nothing to do).
    """
    if out.is_symlink() and overwrite:
        raise OutputExistsError(f"{out} is a symbolic link (to {os.path.realpath(out)}): give "
                                "the store's own path to --overwrite it (skyfix does not delete "
                                "through a link)")
    if not out.exists():
        return "new"
    if not out.is_dir():
        if not overwrite:
            raise OutputExistsError(f"{out} already exists: pass --overwrite to replace it")
        return "unlink"
    state, attrs = root_state(out)
    if state != "ok":
        if state == "damaged" and (out / META_DIR).is_dir():  # ours, with its zarr.json spoiled
            if overwrite:
                return "replace"
            raise DatabaseError(f"{out} is a skyfix database whose metadata are damaged ({attrs}): "
                                "pass --overwrite to rebuild it from scratch")
        if any(out.iterdir()):
            raise OutputExistsError(f"{out} exists and is not a skyfix database: choose another --out "
                                    "(skyfix will not delete a directory it did not write)")
        return "rmdir"  # empty: nothing to lose
    if overwrite:
        return "replace"
    old = attrs.get("build", {})
    if old != params:
        diffs = _differences(old if isinstance(old, dict) else {}, params)
        raise DatabaseError(f"{out} was built with other parameters ({'; '.join(diffs)}): use the "
                            "original parameters to resume it, or --overwrite to start afresh")
    if len(intact_blocks(out, grid)) == len(grid.blocks()):
        if _index_missing(out, grid, params["azimuth_bins"]):
            return "index"
        # nothing to do: the same command run again (a script rerunning a build that was killed
        # after its last block) succeeds, as a resume does
        return "complete"
    return "resume"


def _index_missing(out: Path, grid: Grid, bins: int) -> bool:
    """Whether a store lacks coarse-index chunks that its layout allows (built before the index
    existed, or a run adding it was killed)."""
    import zarr

    if not has_coarse_layout(grid.block, bins):
        return False
    g = zarr.open_group(str(out), mode="r")
    return len(indexed_blocks(out, g, grid, bins)) < len(grid.blocks())


def _apply_plan(out: Path, action: str) -> bool:
    """Carry out :func:`_plan_output`'s decision; return True to resume ``out``."""
    if action in ("resume", "index"):
        clean_partials(out)
        return True
    if action == "replace":
        log.warning("--overwrite: deleting the existing database %s", out)
        shutil.rmtree(out)
    elif action == "unlink":
        out.unlink()
    elif action == "rmdir":
        out.rmdir()
    return False


def _run(ex: Executor, slots: int, spec: BuildSpec, todo, n_blocks: int, n_done: int,
         progress: bool) -> int:
    """Submit the tasks with a bounded window (memory and clean cancellation) and show progress."""
    from tqdm import tqdm

    pending: set = set()
    queue = tasks_of(todo, spec.renderer, slots, spec.grid.block)
    positions = 0
    t0 = time.perf_counter()
    window = max(2, 2 * slots)
    with tqdm(total=n_blocks, initial=n_done, unit="block", disable=not progress, smoothing=0.1,
              dynamic_ncols=True, desc="skylines") as bar:
        try:
            while queue or pending:
                while queue and len(pending) < window:
                    pending.add(ex.submit(build_blocks, spec, queue.pop(0)))
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for f in finished:
                    nb, n = f.result()
                    positions += n
                    bar.update(nb)
                dt = time.perf_counter() - t0
                bar.set_postfix_str(f"{positions / dt if dt > 0 else 0:,.0f} skylines/s", refresh=False)
        except BaseException:
            for f in pending:
                f.cancel()
            raise
    return positions


def dir_size(path) -> int:
    """Bytes on disk of every file under ``path``."""
    total = 0
    for d, _, files in os.walk(path):
        for f in files:
            try:
                total += os.path.getsize(os.path.join(d, f))
            except OSError:
                pass
    return total
