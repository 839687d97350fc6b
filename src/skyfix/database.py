"""Stage 3: the skyline database, the ground segment's product (the file the rover carries).

A zarr v3 store holding, for every position of a regular grid over a search area, the skyline
the DEM predicts there.

Position grid
    ``x = x0 + col * spacing_m`` (col = 0 .. nx-1), ``y = y0 - row * spacing_m`` (row = 0 .. ny-1),
    with ``x0 = xmin`` and ``y0 = ymax`` of the requested bounds: row 0 is north, as in the DEM.
    ``nx = floor((xmax - xmin) / spacing_m) + 1`` (both edges included when the spacing divides the
    extent), likewise ``ny``.

Arrays (``dimension_names`` in brackets)
    ``elevation`` int16 (ny, nx, bins) [y, x, azimuth]: skyline elevation = raw * ``scale_deg``
    (0.01 deg, rounded to nearest, so the quantisation adds at most 0.005 deg); ``-32768`` where
    the ray saw no terrain. Azimuth bin k is centred on ``k * 360 / bins`` deg clockwise from grid
    north. ``ground_z`` float32 (ny, nx) [m] DEM height under each position. ``min_ray_m`` float32
    (ny, nx) [m] shortest ray of the position; ``edge_bins`` int16 (ny, nx) number of bins whose
    ray stopped at the DEM edge before ``max_distance_m`` (a skyline may lie beyond the DEM there).
    ``x`` (nx,), ``y`` (ny,), ``azimuth`` (bins,) coordinates [m, m, deg].

Blocks
    The grid is cut into blocks of ``block`` x ``block`` positions (64 x 64 by default), one zarr
    chunk of every array per block. A block is one build task: it renders its positions, writes
    its chunks, then (atomically, after the data) a marker ``_skyfix/blocks/rRRRR_cCCCC.json``
    holding the SHA-256 of the block's decoded arrays. A block without a marker is not built, so a
    build killed at any moment resumes by redoing exactly the blocks without markers, and
    :func:`verify_database` can tell an intact block from a corrupted one.

Compression (measured on sierra_nevada_30m at 5 m, one 64 x 64 block, 720 raw bytes per skyline):
zstd 9 alone 276 B/skyline, blosc-zstd with byte shuffle 277, delta along the azimuth + byte
shuffle + zstd 9: 171 B/skyline at ~40 ms to encode a block (rendering it takes seconds). The
delta and shuffle codecs come from numcodecs (readable by zarr-python; not in the zarr v3 core
spec).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import shutil
import time
import warnings
from concurrent.futures import FIRST_COMPLETED, Executor, Future, wait
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from . import __version__
from ._io import atomic_path, write_json
from .errors import DatabaseError, OutputExistsError, ParameterError
from .planets import Planet, get_planet

log = logging.getLogger(__name__)

# Delta/Shuffle are numcodecs codecs: zarr-python reads them fine but flags them, on every open,
# as outside the zarr v3 core spec (a choice documented above).
warnings.filterwarnings("ignore", message="Numcodecs codecs are not in the Zarr")

FORMAT = "skyfix-skyline-db"
FORMAT_VERSION = 1
#: [deg] quantisation step of the stored elevation angles
SCALE_DEG = 0.01
#: raw value of an azimuth bin whose ray saw no terrain
MISSING = -32768
#: positions per block side (one zarr chunk per block)
BLOCK = 64
#: [deg] the renderer's skip tolerance used for every build (a build parameter)
SKIP_TOL_DEG = 0.002
META_DIR = "_skyfix"
MARKER_DIR = f"{META_DIR}/blocks"
#: the per-position arrays, one chunk of each per block
DATA_ARRAYS = ("elevation", "ground_z", "min_ray_m", "edge_bins")
#: a build larger than this is refused up front (the 7 x 7 km area at 5 m is 1.96 M skylines, 425 MB)
MAX_POSITIONS = 1_000_000_000
#: [bytes] ... or whose estimated size on disk exceeds this
MAX_BUILD_BYTES = 500e9
#: compressed share of the raw int16 skylines (measured 171 B of 720 at 360 bins, see above; a bit
#: pessimistic so that the estimate errs on the large side)
_COMPRESSED_SHARE = 0.3


# --- grid ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Grid:
    """The position grid: ``x = x0 + col * spacing_m``, ``y = y0 - row * spacing_m`` [m]."""

    x0: float
    y0: float
    spacing_m: float
    ny: int
    nx: int
    block: int = BLOCK

    @classmethod
    def from_bounds(cls, bounds, spacing_m: float, block: int = BLOCK) -> "Grid":
        """Grid over ``bounds`` = (xmin, ymin, xmax, ymax) [m] at ``spacing_m`` [m]."""
        try:
            xmin, ymin, xmax, ymax = (float(b) for b in bounds)
        except (TypeError, ValueError):
            raise ParameterError(f"bounds must be four numbers XMIN YMIN XMAX YMAX, got {bounds!r}") from None
        try:
            spacing_m = float(spacing_m)
        except (TypeError, ValueError):
            raise ParameterError(f"spacing must be a number of metres, got {spacing_m!r}") from None
        if not (math.isfinite(spacing_m) and spacing_m > 0):
            raise ParameterError(f"spacing must be > 0 m, got {spacing_m}")
        if not all(math.isfinite(b) for b in (xmin, ymin, xmax, ymax)):
            raise ParameterError(f"bounds must be finite, got {bounds!r}")
        if not (xmax >= xmin and ymax >= ymin):
            raise ParameterError(f"bounds must be XMIN YMIN XMAX YMAX with XMIN <= XMAX and YMIN <= YMAX, "
                                 f"got {xmin} {ymin} {xmax} {ymax}")
        if int(block) != block or block < 1:
            raise ParameterError(f"block size must be a positive whole number, got {block}")
        fx, fy = (xmax - xmin) / spacing_m, (ymax - ymin) / spacing_m
        if not (math.isfinite(fx) and math.isfinite(fy)):  # a spacing of 1e-320 m overflows
            raise ParameterError(f"spacing {spacing_m} m is far too small for bounds {xmin} {ymin} {xmax} "
                                 f"{ymax}: raise --spacing-m")
        # The small slack keeps an exact multiple (7000 / 5) from losing its last position to rounding.
        nx = int(math.floor(fx + 1e-9)) + 1
        ny = int(math.floor(fy + 1e-9)) + 1
        return cls(xmin, ymax, spacing_m, ny, nx, int(block))

    @property
    def shape(self) -> tuple[int, int]:
        return (self.ny, self.nx)

    @property
    def n_blocks(self) -> tuple[int, int]:
        return (-(-self.ny // self.block), -(-self.nx // self.block))

    @property
    def x_coords(self) -> np.ndarray:
        return self.x0 + np.arange(self.nx) * self.spacing_m

    @property
    def y_coords(self) -> np.ndarray:
        return self.y0 - np.arange(self.ny) * self.spacing_m

    def block_slices(self, br: int, bc: int) -> tuple[slice, slice]:
        b = self.block
        return slice(br * b, min((br + 1) * b, self.ny)), slice(bc * b, min((bc + 1) * b, self.nx))

    def blocks(self) -> list[tuple[int, int]]:
        """Every block index (row-major: north to south, west to east)."""
        nby, nbx = self.n_blocks
        return [(br, bc) for br in range(nby) for bc in range(nbx)]

    def block_xy(self, br: int, bc: int) -> tuple[np.ndarray, np.ndarray]:
        """(x, y) [m] of a block's positions, row-major within the block."""
        rs, cs = self.block_slices(br, bc)
        yy, xx = np.meshgrid(self.y_coords[rs], self.x_coords[cs], indexing="ij")
        return xx.ravel(), yy.ravel()

    def to_attr(self) -> dict:
        return {"x0": self.x0, "y0": self.y0, "spacing_m": self.spacing_m, "shape": [self.ny, self.nx],
                "block_shape": [self.block, self.block], "n_blocks": list(self.n_blocks),
                "convention": "x = x0 + col * spacing_m, y = y0 - row * spacing_m; row 0 north; "
                              "elevation[row, col, k]: azimuth bin k centred on k * 360 / bins deg "
                              "clockwise from grid north"}


def quantise(elevation_deg: np.ndarray) -> np.ndarray:
    """float [deg] (NaN = no terrain) -> int16 raw in steps of :data:`SCALE_DEG` (NaN -> MISSING)."""
    e = np.asarray(elevation_deg, np.float64)
    q = np.rint(e / SCALE_DEG)
    # +-90 deg is 9000 steps: far inside int16, so clipping only guards against garbage.
    q = np.clip(np.where(np.isfinite(q), q, MISSING), MISSING, 32767)
    return q.astype(np.int16)


def dequantise(raw: np.ndarray, scale_deg: float = SCALE_DEG, missing: int = MISSING) -> np.ndarray:
    """int16 raw -> float32 [deg], NaN where missing."""
    raw = np.asarray(raw)
    out = raw.astype(np.float32) * np.float32(scale_deg)
    out[raw == missing] = np.nan
    return out


def _sha(a: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()


def _marker_name(br: int, bc: int) -> str:
    return f"r{br:04d}_c{bc:04d}.json"


# --- build -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _BuildSpec:
    """Everything a block task needs (small: shipped to workers instead of the DEM)."""

    dem_path: str
    dem_sha256: str
    out: str
    grid: Grid
    camera_height_m: float
    azimuth_bins: int
    max_distance_m: float | None
    planet: Planet
    single_thread: bool = False


#: worker-process DEM cache: (path, sha256) -> Dem, so a DEM is read once per process
_DEM_CACHE: dict = {}


def _dem_for(path: str, sha256: str):
    from .dem import load_dem

    key = (path, sha256)
    dem = _DEM_CACHE.get(key)
    if dem is None:
        dem = load_dem(path)
        if dem.checksum != sha256:
            raise DatabaseError(f"DEM {path} changed during the build (SHA-256 {dem.checksum[:12]}..., "
                                f"expected {sha256[:12]}...): restart the build with the DEM you want")
        _DEM_CACHE.clear()  # one DEM per process is all a build needs; keep memory bounded
        _DEM_CACHE[key] = dem
    return dem


def _open_arrays(out: str, mode: str = "r+"):
    import zarr

    g = zarr.open_group(out, mode=mode)
    return {name: g[name] for name in ("elevation", "ground_z", "min_ray_m", "edge_bins")}


def render_block(dem, spec: _BuildSpec, br: int, bc: int) -> dict:
    """Render one block: arrays shaped (rows, cols[, bins]) as they are stored."""
    from .horizon import render_horizons

    rs, cs = spec.grid.block_slices(br, bc)
    rows, cols = rs.stop - rs.start, cs.stop - cs.start
    x, y = spec.grid.block_xy(br, bc)
    hb = render_horizons(dem, x, y, camera_height_m=spec.camera_height_m, planet=spec.planet,
                         azimuth_bins=spec.azimuth_bins, max_distance_m=spec.max_distance_m,
                         skip_tol_deg=SKIP_TOL_DEG)
    maxd = np.inf if spec.max_distance_m is None else spec.max_distance_m
    # A ray shorter than the maximum distance stopped at the DEM edge (rays end at min(edge, max)).
    edge = (hb.ray_length_m < np.float32(maxd) * np.float32(1 - 1e-6)).sum(axis=1)
    return {
        "elevation": quantise(hb.elevation_deg).reshape(rows, cols, spec.azimuth_bins),
        "ground_z": hb.ground_z_m.astype(np.float32).reshape(rows, cols),
        "min_ray_m": hb.ray_length_m.min(axis=1).astype(np.float32).reshape(rows, cols),
        "edge_bins": edge.astype(np.int16).reshape(rows, cols),
    }


def _build_block(spec: _BuildSpec, br: int, bc: int) -> tuple[int, int, int]:
    """One task: render block (br, bc), write its chunks, then its marker. Returns (br, bc, n)."""
    if spec.single_thread:
        import numba

        numba.set_num_threads(1)  # one worker process per core: numba must not fan out too
    dem = _dem_for(spec.dem_path, spec.dem_sha256)
    data = render_block(dem, spec, br, bc)
    rs, cs = spec.grid.block_slices(br, bc)
    arrays = _open_arrays(spec.out)
    for name, a in data.items():
        arrays[name][rs, cs] = a
    marker = {"block": [br, bc], "row0": rs.start, "col0": cs.start, "rows": rs.stop - rs.start,
              "cols": cs.stop - cs.start, "sha256": {k: _sha(v) for k, v in data.items()}}
    # Written only after every chunk is on disk: a block without a marker gets redone.
    write_json(Path(spec.out) / MARKER_DIR / _marker_name(br, bc), marker)
    return br, bc, (rs.stop - rs.start) * (cs.stop - cs.start)


class InProcessExecutor(Executor):
    """Runs each task at once in the calling process (``--workers 0``); numba uses all its threads."""

    def submit(self, fn, /, *args, **kwargs):
        f = Future()
        try:
            f.set_result(fn(*args, **kwargs))
        except Exception as e:  # delivered through the future, like any executor
            f.set_exception(e)
        return f


def _is_whole_at_least_0(v) -> bool:
    """A count given by a user: a whole number >= 0 (3.0 counts, True and "3" do not)."""
    try:
        return not isinstance(v, bool) and int(v) == v and v >= 0
    except (TypeError, ValueError, OverflowError):
        return False


def check_executor_options(workers: int | None, scheduler: str | None) -> None:
    """Refuse bad ``workers`` / ``scheduler`` values (before a build touches any file)."""
    if workers is not None and scheduler is not None:
        raise ParameterError("give either --workers or --scheduler, not both")
    if workers is not None:
        if not _is_whole_at_least_0(workers):
            raise ParameterError(f"--workers must be a whole number >= 0 (0: in this process), got {workers}")
    if scheduler is not None:
        why = "not a string"
        if isinstance(scheduler, str):
            from distributed.comm import get_address_host_port

            # Parsed here, not left to Client(): a Client that fails on a malformed address (an
            # unknown scheme) hangs for 40 s at exit closing itself, and prints a traceback.
            try:
                get_address_host_port(scheduler)
                return
            except ValueError as e:  # "missing port number", "unknown address scheme"
                why = str(e)
        raise ParameterError(f"--scheduler {scheduler!r} is not a Dask scheduler address ({why}): give "
                             "tcp://HOST:PORT")


def default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


@contextmanager
def make_executor(workers: int | None = None, scheduler: str | None = None):
    """Yield ``(executor, slots, single_thread)`` for a build.

    workers : 0 = in the calling process; N = an embedded Dask LocalCluster of N single-threaded
        worker processes (default: one per core)
    scheduler : address of an existing Dask scheduler (``tcp://HOST:PORT``); its workers must see
        the DEM and the output at the same paths and import skyfix
    """
    check_executor_options(workers, scheduler)
    if scheduler is None and workers == 0:
        yield InProcessExecutor(), 1, False
        return
    from dask.distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, ValueError) as e:  # refused, unknown host, timed out
            raise ParameterError(f"cannot reach the Dask scheduler at {scheduler}: {e} (is it running, "
                                 "and is the address tcp://HOST:PORT right?)") from None
        with client:
            slots = max(1, sum(client.nthreads().values()))
            yield client.get_executor(pure=False), slots, True
        return
    n = default_workers() if workers is None else int(workers)
    dlog = logging.getLogger("distributed")
    if not log.isEnabledFor(logging.INFO):  # the cluster's start/stop chatter only with -v
        dlog.setLevel(logging.ERROR)
    with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        yield client.get_executor(pure=False), n, True


def estimate_build_bytes(grid: Grid, azimuth_bins: int) -> float:
    """[bytes] rough size on disk of a complete build (errs on the large side)."""
    per = azimuth_bins * 2 * _COMPRESSED_SHARE + 10  # + ground_z, min_ray_m, edge_bins
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
                 max_distance_m: float | None, planet: Planet) -> dict:
    """The parameters that define a build's content: a resume must match every one of them."""
    return {"format_version": FORMAT_VERSION, "dem_sha256": dem_sha256,
            "bounds": [float(b) for b in bounds], "spacing_m": grid.spacing_m,
            "camera_height_m": float(camera_height_m), "azimuth_bins": int(azimuth_bins),
            "max_distance_m": None if max_distance_m is None else float(max_distance_m),
            "planet": planet.to_attr(), "block_positions": grid.block, "scale_deg": SCALE_DEG,
            "skip_tol_deg": SKIP_TOL_DEG}


def _codecs():
    from zarr.codecs import Delta, Shuffle, ZstdCodec

    return {"filters": [Delta(dtype="i2")],
            "compressors": [Shuffle(elementsize=2), ZstdCodec(level=9, checksum=True)]}


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
                       **_codecs())
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


def _root_state(path: Path) -> tuple[str, dict | str | None]:
    """What ``path/zarr.json`` says: ``("ok", attrs)`` for a skyfix database, ``("damaged", why)``
    for a zarr.json that exists but cannot be read (or is gone from beside our block markers),
    ``("none", None)`` otherwise."""
    f = path / "zarr.json"
    if not f.is_file():
        if (path / MARKER_DIR).is_dir():  # our bookkeeping is there: a database that lost its root
            return "damaged", f"{f} is missing"
        return "none", None
    try:
        meta = json.loads(f.read_text())
    except (OSError, ValueError) as e:  # truncated, empty, binary garbage, unreadable
        why = "it is empty" if f.stat().st_size == 0 else f"{type(e).__name__}: {e}"
        return "damaged", f"{f} cannot be read ({why})"
    if not isinstance(meta, dict):
        return "damaged", f"{f} holds a JSON {type(meta).__name__}, not an object"
    attrs = meta.get("attributes")
    if not isinstance(attrs, dict) or attrs.get("format") != FORMAT:
        return "none", None
    return "ok", attrs


# What each recorded attribute must be: (dotted key, kind). Checked when a database is opened, so
# that a hand-edited or corrupted zarr.json is named instead of failing deep in a computation.
_ATTR_KINDS = (
    ("grid", "object"), ("grid.x0", "number"), ("grid.y0", "number"), ("grid.spacing_m", "positive"),
    ("grid.shape", "pair"), ("grid.block_shape", "pair"), ("azimuth_bins", "count"),
    ("camera_height_m", "number"), ("max_distance_m", "number or null"), ("planet", "object"),
    ("planet.name", "text"), ("planet.radius_m", "positive"), ("planet.refraction_k", "number"),
    ("elevation", "object"), ("elevation.scale_deg", "positive"), ("elevation.missing", "integer"),
    ("dem", "object"), ("dem.sha256", "text"), ("dem.source", "text"), ("crs_wkt", "text"),
    ("build", "object"),
)
_KIND_WORDS = {"object": "an object", "number": "a number", "positive": "a number > 0",
               "count": "a whole number > 0", "integer": "a whole number",
               "pair": "two whole numbers > 0", "text": "a string", "number or null": "a number or null"}


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _attr_ok(kind: str, v) -> bool:
    if kind == "object":
        return isinstance(v, dict)
    if kind == "number":
        return _is_number(v)
    if kind == "positive":
        return _is_number(v) and v > 0
    if kind == "number or null":
        return v is None or _is_number(v)
    if kind == "count":
        return _is_int(v) and v > 0
    if kind == "integer":
        return _is_int(v)
    if kind == "pair":
        return isinstance(v, list) and len(v) == 2 and all(_is_int(x) and x > 0 for x in v)
    return isinstance(v, str)


def _damaged(path, what: str) -> DatabaseError:
    return DatabaseError(f"{path}: database metadata damaged: {what} (its zarr.json was edited or "
                         "corrupted): rebuild it with `skyfix build-db ... --overwrite`")


def _check_attrs(path: Path, attrs: dict) -> None:
    """Raise a DatabaseError naming the first recorded attribute of the wrong type."""
    for key, kind in _ATTR_KINDS:
        v = attrs
        for part in key.split("."):
            if part not in v:
                raise _damaged(path, f"{key} is missing")
            v = v[part]
        if not _attr_ok(kind, v):
            raise _damaged(path, f"{key} must be {_KIND_WORDS[kind]}, got {v!r}")


def _check_arrays(path: Path, g, attrs: dict) -> None:
    """The arrays' own metadata must agree with the recorded grid (one chunk per block)."""
    ny, nx = attrs["grid"]["shape"]
    b = attrs["grid"]["block_shape"][0]
    bins = attrs["azimuth_bins"]
    for name in DATA_ARRAYS:
        a = g[name]
        want = (ny, nx, bins) if name == "elevation" else (ny, nx)
        chunks = (b, b, bins) if name == "elevation" else (b, b)
        if tuple(a.shape) != want or tuple(a.chunks) != chunks:
            raise _damaged(path, f"array {name} has shape {tuple(a.shape)} in chunks {tuple(a.chunks)}, "
                                 f"but grid.shape {[ny, nx]}, grid.block_shape and azimuth_bins {bins} "
                                 f"say {want} in chunks {chunks}")


def _chunk_keys(root: Path) -> set[str]:
    """Every file under ``root`` as a '/'-separated path relative to it (one listing, no reads)."""
    have = set()
    for d, _, files in os.walk(root):
        rel = os.path.relpath(d, root).replace(os.sep, "/")
        pre = "" if rel == "." else rel + "/"
        have.update(pre + f for f in files)
    return have


def _absent_data(path: Path, g, grid: Grid, done) -> dict:
    """Built blocks (with a marker) whose chunk file of some array is gone: {(br, bc): [names]}.

    zarr reads an absent chunk as the fill value without a word, so a deleted chunk file would
    read as a block of "no terrain" skylines and NaN heights. One directory listing per array at
    open time finds them (milliseconds for a 7 x 7 km database), so a read costs one set lookup.
    """
    blocks = sorted(set(done) & set(grid.blocks()))
    absent: dict = {}
    for name in DATA_ARRAYS:
        a = g[name]
        have = _chunk_keys(path / name)
        enc = a.metadata.chunk_key_encoding
        tail = (0,) * (a.ndim - 2)
        for br, bc in blocks:
            if enc.encode_chunk_key((br, bc) + tail) not in have:
                absent.setdefault((br, bc), []).append(name)
    # zarr does not write a chunk that is all fill value: legitimate if the marker's checksum says
    # the block really was all fill (only conceivable for elevation: every ray without terrain).
    for (br, bc), names in list(absent.items()):
        try:
            sha = json.loads((path / MARKER_DIR / _marker_name(br, bc)).read_text())["sha256"]
        except (OSError, ValueError, KeyError, TypeError):
            sha = {}
        rs, cs = grid.block_slices(br, bc)
        gone = []
        for name in names:
            a = g[name]
            fill = np.full((rs.stop - rs.start, cs.stop - cs.start) + tuple(a.shape[2:]), a.fill_value,
                           a.dtype)
            if not isinstance(sha, dict) or sha.get(name) != _sha(fill):
                gone.append(name)
        if gone:
            absent[(br, bc)] = gone
        else:
            del absent[(br, bc)]
    return absent


def _intact_blocks(path: Path, grid: Grid) -> set[tuple[int, int]]:
    """Blocks with a marker and every chunk file: a resume redoes the others."""
    import zarr

    done = done_blocks(path)
    try:
        g = zarr.open_group(str(path), mode="r")
        absent = _absent_data(path, g, grid, done)
    except Exception:  # a store too broken to list: the build below will say so, or redo it all
        return done
    return done - set(absent)


def _data_missing_message(path, absent: dict) -> str:
    (br, bc), names = min(absent.items())
    more = f" ({len(absent)} blocks in all)" if len(absent) > 1 else ""
    return (f"{path}: block ({br}, {bc}) data missing (no chunk file for {', '.join(names)}){more}: "
            f"run `skyfix verify {path}`, then rebuild (the same build-db command resumes and redoes "
            "such blocks)")


def done_blocks(path) -> set[tuple[int, int]]:
    """Blocks (br, bc) whose marker exists, i.e. whose data were fully written."""
    d = Path(path) / MARKER_DIR
    out = set()
    if d.is_dir():
        for p in d.iterdir():
            n = p.name
            if n.startswith("r") and n.endswith(".json") and "_c" in n:
                try:
                    out.add((int(n[1:5]), int(n[7:11])))
                except ValueError:
                    pass
    return out


def _clean_partials(path: Path) -> int:
    """Remove temporary files a killed build left behind (zarr's ``*.partial``, our ``.name.*``)."""
    n = 0
    for d, _, files in os.walk(path):
        for f in files:
            if f.endswith(".partial") or f.startswith("."):
                os.unlink(os.path.join(d, f))
                n += 1
    return n


def _differences(old: dict, new: dict) -> list[str]:
    keys = sorted(set(old) | set(new))
    return [f"{k}: the store has {old.get(k)!r}, this build asks for {new.get(k)!r}"
            for k in keys if old.get(k) != new.get(k)]


@dataclass(frozen=True)
class BuildResult:
    """What a build did: path, blocks built now / already there, positions, seconds, bytes."""

    path: Path
    n_blocks: int
    built: int
    resumed_from: int
    positions: int
    seconds: float
    skylines_per_s: float
    size_bytes: int


def build_database(dem_path, out, bounds, spacing_m: float, *, camera_height_m: float = 1.5,
                   azimuth_bins: int = 360, max_distance_m: float | None = None, planet="earth",
                   workers: int | None = None, scheduler: str | None = None,
                   executor: Executor | None = None, overwrite: bool = False, progress: bool = True,
                   block: int = BLOCK) -> BuildResult:
    """Build (or resume) a skyline database over ``bounds``.

    dem_path : DEM file (read with :func:`skyfix.dem.load_dem`, the DEM's own CRS if metric)
    out : the zarr store to write (a directory)
    bounds : (xmin, ymin, xmax, ymax) [m] of the position grid, in the DEM's CRS
    spacing_m : [m] grid spacing
    camera_height_m : [m] camera above the ground; azimuth_bins : bins over 360 deg
    max_distance_m : [m] ray length limit (None: to the DEM edge)
    planet : ``earth``, ``mars``, a radius [m] or a Planet
    workers : 0 = in process; N = a local Dask cluster of N processes (default: one per core)
    scheduler : an existing Dask scheduler address instead; executor : any Executor instead (its
        tasks must see the same files; numba keeps its default threads)
    overwrite : replace an existing store (else a store built with the same parameters resumes,
        and anything else is refused)
    block : [positions] block side (one task and one chunk per block)
    """
    from .dem import load_dem

    out = Path(out)
    grid = Grid.from_bounds(bounds, spacing_m, block)
    planet = get_planet(planet)
    if int(azimuth_bins) != azimuth_bins or azimuth_bins <= 0:
        raise ParameterError(f"azimuth bins must be a positive whole number, got {azimuth_bins}")
    azimuth_bins = int(azimuth_bins)
    if azimuth_bins > 65535:
        raise ParameterError(f"at most 65535 azimuth bins, got {azimuth_bins}")
    if max_distance_m is not None and not (max_distance_m > 0 and math.isfinite(max_distance_m)):
        raise ParameterError(f"maximum distance must be > 0 m, got {max_distance_m}")
    if not (math.isfinite(camera_height_m) and camera_height_m >= 0):
        raise ParameterError(f"camera height must be >= 0 m, got {camera_height_m}")
    check_build_size(grid, azimuth_bins)
    if executor is None:
        check_executor_options(workers, scheduler)

    dem = load_dem(dem_path)
    xs, ys = grid.x_coords, grid.y_coords
    # Every position must have a height: the corners catch a wrong area, the full grid a void.
    dem.require_inside([xs[0], xs[-1], xs[0], xs[-1]], [ys[0], ys[0], ys[-1], ys[-1]],
                       what="database bounds corner")
    for r0 in range(0, grid.ny, 256):
        yy, xx = np.meshgrid(ys[r0:r0 + 256], xs, indexing="ij")
        dem.require_inside(xx.ravel(), yy.ravel(), what="database position")

    params = build_params(dem_sha256=dem.checksum, grid=grid, bounds=bounds,
                          camera_height_m=camera_height_m, azimuth_bins=azimuth_bins,
                          max_distance_m=max_distance_m, planet=planet)
    action = _plan_output(out, params, grid, overwrite)  # refuses, deletes nothing
    # The executor starts (the scheduler is reached) before anything is deleted: a bad --scheduler
    # must not cost the database that --overwrite was about to replace.
    with (nullcontext((executor, 2, False)) if executor is not None
          else make_executor(workers, scheduler)) as (ex, slots, single):
        return _build(out, action, dem_path, dem, grid, params, planet, ex, slots, single, progress)


def _build(out: Path, action: str, dem_path, dem, grid: Grid, params: dict, planet: Planet,
           ex: Executor, slots: int, single: bool, progress: bool) -> BuildResult:
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
            "dem": {"sha256": dem.checksum, "source": str(Path(dem_path).resolve()),
                    "shape": list(dem.shape), "cell_m": [dem.dx, dem.dy], "bounds": list(dem.bounds)},
            "build": params,
        }
        _create_store(out, grid, azimuth_bins, attrs)

    spec = _BuildSpec(str(Path(dem_path).resolve()), dem.checksum, str(out), grid,
                      params["camera_height_m"], azimuth_bins, params["max_distance_m"], planet,
                      single_thread=single)
    _DEM_CACHE.clear()
    _DEM_CACHE[(spec.dem_path, spec.dem_sha256)] = dem  # the in-process path reuses this load
    done = _intact_blocks(out, grid)
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
    missing = set(grid.blocks()) - _intact_blocks(out, grid)
    if missing:  # cannot happen unless a task lied; never report an incomplete store as built
        raise DatabaseError(f"{len(missing)} blocks of {out} have no marker or no data after the build: "
                            "run it again")
    return BuildResult(out, n_blocks, len(todo), len(done), positions, dt,
                       positions / dt if dt > 0 else float("nan"), dir_size(out))


def _plan_output(out: Path, params: dict, grid: Grid, overwrite: bool) -> str:
    """What to do with ``out``, refusing what must not happen; changes nothing on disk.

    Returns ``new`` (nothing there), ``rmdir`` (an empty folder), ``unlink`` (a file, with
    --overwrite), ``replace`` (a skyfix database, with --overwrite) or ``resume``.
    """
    if not out.exists():
        return "new"
    if not out.is_dir():
        if not overwrite:
            raise OutputExistsError(f"{out} already exists: pass --overwrite to replace it")
        return "unlink"
    state, attrs = _root_state(out)
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
    if len(_intact_blocks(out, grid)) == len(grid.blocks()):
        raise OutputExistsError(f"{out} is already a complete database built with these parameters: "
                                "pass --overwrite to rebuild it")
    return "resume"


def _apply_plan(out: Path, action: str) -> bool:
    """Carry out :func:`_plan_output`'s decision; return True to resume ``out``."""
    if action == "resume":
        _clean_partials(out)
        return True
    if action == "replace":
        log.warning("--overwrite: deleting the existing database %s", out)
        shutil.rmtree(out)
    elif action == "unlink":
        out.unlink()
    elif action == "rmdir":
        out.rmdir()
    return False


def _run(ex: Executor, slots: int, spec: _BuildSpec, todo, n_blocks: int, n_done: int,
         progress: bool) -> int:
    """Submit the blocks with a bounded window (memory and clean cancellation) and show progress."""
    from tqdm import tqdm

    pending: set = set()
    queue = list(todo)
    positions = 0
    t0 = time.perf_counter()
    window = max(2, 2 * slots)
    with tqdm(total=n_blocks, initial=n_done, unit="block", disable=not progress, smoothing=0.1,
              dynamic_ncols=True, desc="skylines") as bar:
        try:
            while queue or pending:
                while queue and len(pending) < window:
                    br, bc = queue.pop(0)
                    pending.add(ex.submit(_build_block, spec, br, bc))
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for f in finished:
                    _, _, n = f.result()
                    positions += n
                    bar.update(1)
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


# --- reading ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Block:
    """One block of positions as stored.

    row0, col0 : origin in the position grid; rows, cols : block shape
    x, y : float64 (n,) [m] of each position, row-major within the block (n = rows * cols)
    elevation : int16 (n, bins) raw (multiply by ``scale_deg``; ``missing`` = no terrain)
    ground_z_m : float32 (n,) [m]; min_ray_m : float32 (n,) [m]; edge_bins : int16 (n,)
    (the last three None where a reader or an in-memory store does not provide them)
    """

    row0: int
    col0: int
    rows: int
    cols: int
    x: np.ndarray
    y: np.ndarray
    elevation: np.ndarray
    ground_z_m: np.ndarray | None = None
    min_ray_m: np.ndarray | None = None
    edge_bins: np.ndarray | None = None
    scale_deg: float = SCALE_DEG
    missing: int = MISSING

    @property
    def elevation_deg(self) -> np.ndarray:
        """float32 (n, bins) [deg], NaN where missing."""
        return dequantise(self.elevation, self.scale_deg, self.missing)


class SkylineDatabase:
    """A skyline database opened read-only (see :func:`open_database`).

    Memory stays bounded: :meth:`iter_blocks` holds one block at a time, :meth:`profiles_at`
    reads only the chunks holding the positions asked for.
    """

    def __init__(self, path: Path, group, attrs: dict, done: set, absent: dict | None = None):
        self.path = path
        self._g = group
        self._attrs = attrs
        self._done = done
        self._absent = absent or {}  # built blocks whose chunk files are gone (see _absent_data)
        self._arrays: dict = {}
        gr = attrs["grid"]
        self.grid = Grid(float(gr["x0"]), float(gr["y0"]), float(gr["spacing_m"]), int(gr["shape"][0]),
                         int(gr["shape"][1]), int(gr["block_shape"][0]))

    # --- metadata --------------------------------------------------------------------------------
    @property
    def attrs(self) -> dict:
        """Every root attribute (a copy)."""
        return json.loads(json.dumps(self._attrs))

    @property
    def crs_wkt(self) -> str:
        return self._attrs["crs_wkt"]

    @property
    def crs_name(self) -> str:
        return self._attrs.get("crs_name", "")

    @property
    def spacing_m(self) -> float:
        return self.grid.spacing_m

    @property
    def shape(self) -> tuple[int, int]:
        """(ny, nx) positions."""
        return self.grid.shape

    @property
    def x_coords(self) -> np.ndarray:
        """(nx,) [m] position x, west to east."""
        return self.grid.x_coords

    @property
    def y_coords(self) -> np.ndarray:
        """(ny,) [m] position y, north to south."""
        return self.grid.y_coords

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) [m] of the position centres."""
        xs, ys = self.x_coords, self.y_coords
        return (float(xs[0]), float(ys[-1]), float(xs[-1]), float(ys[0]))

    @property
    def azimuth_bins(self) -> int:
        return int(self._attrs["azimuth_bins"])

    @property
    def azimuth_deg(self) -> np.ndarray:
        """(bins,) [deg] bin centres ``k * 360 / bins``."""
        return np.arange(self.azimuth_bins) * (360.0 / self.azimuth_bins)

    @property
    def camera_height_m(self) -> float:
        return float(self._attrs["camera_height_m"])

    @property
    def planet(self) -> Planet:
        p = self._attrs["planet"]
        return Planet(p["name"], float(p["radius_m"]), float(p["refraction_k"]))

    @property
    def max_distance_m(self) -> float | None:
        """[m] ray length limit of the build, None when rays ran to the DEM edge."""
        m = self._attrs["max_distance_m"]
        return None if m is None else float(m)

    @property
    def scale_deg(self) -> float:
        return float(self._attrs["elevation"]["scale_deg"])

    @property
    def missing(self) -> int:
        return int(self._attrs["elevation"]["missing"])

    @property
    def dem_sha256(self) -> str:
        return self._attrs["dem"]["sha256"]

    @property
    def n_blocks(self) -> int:
        return len(self.grid.blocks())

    @property
    def blocks_done(self) -> int:
        return len(self._done & set(self.grid.blocks()))

    @property
    def blocks_data_missing(self) -> list[tuple[int, int]]:
        """Built blocks (marker present) whose chunk files are gone: unreadable until rebuilt."""
        return sorted(self._absent)

    @property
    def is_complete(self) -> bool:
        """Every block built, and every built block's data there."""
        return self.blocks_done == self.n_blocks and not self._absent

    # --- positions -------------------------------------------------------------------------------
    def index_of(self, x, y):
        """(row, col) int64 of the nearest grid position to (x, y) [m] (no bounds check)."""
        col = np.rint((np.asarray(x, np.float64) - self.grid.x0) / self.grid.spacing_m).astype(np.int64)
        row = np.rint((self.grid.y0 - np.asarray(y, np.float64)) / self.grid.spacing_m).astype(np.int64)
        return row, col

    def xy_of(self, row, col):
        """(x, y) [m] of grid position (row, col)."""
        return (self.grid.x0 + np.asarray(col, np.float64) * self.grid.spacing_m,
                self.grid.y0 - np.asarray(row, np.float64) * self.grid.spacing_m)

    def _rows_cols(self, x, y):
        x = np.atleast_1d(np.asarray(x, np.float64)).ravel()
        y = np.atleast_1d(np.asarray(y, np.float64)).ravel()
        if x.shape != y.shape:
            raise ParameterError("x and y must have the same length")
        row, col = self.index_of(x, y)
        bad = (row < 0) | (row >= self.grid.ny) | (col < 0) | (col >= self.grid.nx) | ~np.isfinite(x + y)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            xmin, ymin, xmax, ymax = self.bounds
            raise ParameterError(f"position ({x[k]:.1f}, {y[k]:.1f}) is outside the database grid "
                                 f"x {xmin:.1f}..{xmax:.1f}, y {ymin:.1f}..{ymax:.1f}")
        return row, col

    def raw_at(self, x, y) -> np.ndarray:
        """int16 (n, bins) raw skylines at the nearest grid positions to (x, y) [m]."""
        row, col = self._rows_cols(x, y)
        return self._gather("elevation", row, col)

    def _gather(self, name: str, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        # Group the positions by block so each chunk is decoded once, one chunk in memory at a time.
        arr = self._array(name)
        out = np.empty((row.size,) + tuple(arr.shape[2:]), arr.dtype)
        b = self.grid.block
        key = (row // b) * self.grid.n_blocks[1] + col // b
        order = np.argsort(key, kind="stable")
        starts = np.flatnonzero(np.r_[True, np.diff(key[order]) != 0])
        for s, e in zip(starts, np.r_[starts[1:], order.size]):
            idx = order[s:e]
            br, bc = int(row[idx[0]] // b), int(col[idx[0]] // b)
            rs, cs = self.grid.block_slices(br, bc)
            chunk = self.read_raw(name, br, bc)
            out[idx] = chunk[row[idx] - rs.start, col[idx] - cs.start]
        return out

    def _array(self, name: str):
        a = self._arrays.get(name)
        if a is None:  # opening reads the array's zarr.json: once, not once per block
            a = self._arrays[name] = self._g[name]
        return a

    def _read_unchecked(self, name: str, br: int, bc: int) -> np.ndarray:
        rs, cs = self.grid.block_slices(br, bc)
        return np.asarray(self._array(name)[rs, cs])

    def read_raw(self, name: str, br: int, bc: int) -> np.ndarray:
        """Array ``name``'s chunk of block (br, bc) as stored, shaped (rows, cols[, bins]).

        Raises :class:`~skyfix.errors.DatabaseError` naming the block if its chunk file is gone
        (zarr would hand back fill values) or cannot be decoded.
        """
        if name in self._absent.get((br, bc), ()):
            raise DatabaseError(_data_missing_message(self.path, {(br, bc): self._absent[(br, bc)]}))
        try:
            return self._read_unchecked(name, br, bc)
        except Exception as e:  # a damaged chunk fails to decode (zstd checksum) in many ways
            raise DatabaseError(
                f"{self.path}: block ({br}, {bc}) data unreadable ({name} chunk: {type(e).__name__}: "
                f"{e}): run `skyfix verify {self.path}`, then delete the damaged blocks' markers "
                f"({MARKER_DIR}/{_marker_name(br, bc)}) and rerun the build-db command (it resumes)"
            ) from None

    def profiles_at(self, x, y) -> np.ndarray:
        """float32 (n, bins) [deg] skylines at the nearest grid positions (NaN = no terrain)."""
        return dequantise(self.raw_at(x, y), self.scale_deg, self.missing)

    def ground_z_at(self, x, y) -> np.ndarray:
        """float32 (n,) [m] ground height at the nearest grid positions."""
        row, col = self._rows_cols(x, y)
        return self._gather("ground_z", row, col)

    # --- blocks ----------------------------------------------------------------------------------
    def read_block(self, br: int, bc: int) -> Block:
        """Block (br, bc) of the block grid."""
        rs, cs = self.grid.block_slices(br, bc)
        rows, cols = rs.stop - rs.start, cs.stop - cs.start
        x, y = self.grid.block_xy(br, bc)
        return Block(rs.start, cs.start, rows, cols, x, y,
                     self.read_raw("elevation", br, bc).reshape(rows * cols, -1),
                     self.read_raw("ground_z", br, bc).ravel(),
                     self.read_raw("min_ray_m", br, bc).ravel(),
                     self.read_raw("edge_bins", br, bc).ravel(), self.scale_deg, self.missing)

    def iter_blocks(self) -> Iterator[Block]:
        """Every built block in a fixed order (north to south, west to east), one in memory at a time."""
        for br, bc in self.grid.blocks():
            if (br, bc) in self._done:
                yield self.read_block(br, bc)

    def __repr__(self) -> str:
        ny, nx = self.shape
        return (f"SkylineDatabase({str(self.path)!r}, {nx} x {ny} positions at {self.spacing_m:g} m, "
                f"{self.azimuth_bins} bins, {self.blocks_done}/{self.n_blocks} blocks"
                + (f", {len(self._absent)} without data)" if self._absent else ")"))


def open_database(path, *, allow_incomplete: bool = False) -> SkylineDatabase:
    """Open a skyline database read-only.

    Raises :class:`~skyfix.errors.DatabaseError` if ``path`` is not a skyfix database, was written by
    a newer format, or (unless ``allow_incomplete``) is not completely built.
    """
    import zarr

    path = Path(path)
    if not path.exists():
        raise DatabaseError(f"database {path} does not exist: build it with `skyfix build-db`")
    state, attrs = _root_state(path) if path.is_dir() else ("none", None)
    if state == "damaged":
        raise DatabaseError(f"{path}: database metadata damaged: {attrs}: rebuild it with "
                            "`skyfix build-db ... --overwrite`")
    if state != "ok":
        raise DatabaseError(f"{path} is not a skyfix skyline database (no zarr.json with format "
                            f"{FORMAT!r}): give the folder `skyfix build-db` wrote")
    version = attrs.get("format_version")
    if not _is_int(version):
        raise _damaged(path, f"format_version must be a whole number, got {version!r}")
    if version > FORMAT_VERSION:
        raise DatabaseError(f"{path} has format version {version}, newer than this "
                            f"skyfix ({__version__}) reads ({FORMAT_VERSION}): upgrade skyfix")
    _check_attrs(path, attrs)
    try:
        g = zarr.open_group(str(path), mode="r")
        for name in DATA_ARRAYS:
            g[name]
    except Exception as e:  # zarr raises several unrelated types for a broken store
        raise DatabaseError(f"{path} is a damaged skyline database ({type(e).__name__}: {e})") from None
    _check_arrays(path, g, attrs)
    done = done_blocks(path)
    db = SkylineDatabase(path, g, attrs, done)
    db._absent = _absent_data(path, g, db.grid, done)
    if not allow_incomplete:
        if db.blocks_data_missing:
            raise DatabaseError(_data_missing_message(path, db._absent))
        if not db.is_complete:
            raise DatabaseError(f"{path} is incomplete ({db.blocks_done} of {db.n_blocks} blocks built): "
                                "run the same `skyfix build-db` command again to finish it")
    return db


# --- checks ----------------------------------------------------------------------------------------
@dataclass
class VerifyReport:
    """Outcome of :func:`verify_database`.

    ``ok`` when nothing was found wrong; ``samples_skipped`` says why the re-render asked for did
    not run (then ``ok`` covers the checksums only).
    """

    path: Path
    n_blocks: int
    missing: list = field(default_factory=list)
    corrupt: list = field(default_factory=list)
    samples: int = 0
    sample_max_error_deg: float = float("nan")
    sample_failures: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    samples_requested: int = 0
    samples_skipped: str = ""

    @property
    def ok(self) -> bool:
        return not (self.missing or self.corrupt or self.sample_failures)


def verify_database(path, *, dem=None, samples: int = 20, seed: int = 0) -> VerifyReport:
    """Check every block against its marker's checksums, then re-render ``samples`` positions.

    dem : DEM path or :class:`~skyfix.dem.Dem` for the re-render (default: the path recorded at
        build time; if it is not there the re-render is skipped and ``samples_skipped`` says so)
    samples : distinct positions of intact blocks re-rendered and compared within half the
        quantisation step (+ 1e-4 deg); all of them if there are fewer; 0 = checksums only
    """
    from .dem import Dem, load_dem
    from .horizon import render_horizons

    if not _is_whole_at_least_0(samples):
        raise ParameterError(f"samples must be a whole number >= 0 (0: checksums only), got {samples!r}")
    samples = int(samples)
    db = open_database(path, allow_incomplete=True)
    rep = VerifyReport(Path(path), db.n_blocks, samples_requested=samples)
    markers = Path(path) / MARKER_DIR
    good = []
    for br, bc in db.grid.blocks():
        mp = markers / _marker_name(br, bc)
        if not mp.exists():
            rep.missing.append((br, bc))
            continue
        gone = db._absent.get((br, bc))
        if gone:
            rep.corrupt.append(((br, bc), f"data missing: no chunk file for {', '.join(gone)}"))
            continue
        try:
            marker = json.loads(mp.read_text())
            got = {name: db._read_unchecked(name, br, bc) for name in DATA_ARRAYS}
            bad = [k for k, v in got.items() if _sha(v) != marker["sha256"].get(k)]
        except Exception as e:  # a damaged chunk fails to decode (zstd checksum) in many ways
            rep.corrupt.append(((br, bc), f"unreadable: {type(e).__name__}: {e}"))
            continue
        if bad:
            rep.corrupt.append(((br, bc), f"checksum mismatch in {', '.join(bad)}"))
        else:
            good.append((br, bc))
    if samples == 0:
        return rep
    if not good:
        rep.samples_skipped = "no intact block to sample from"
        return rep
    if dem is None:
        src = db.attrs["dem"].get("source", "")
        if not src or not Path(src).is_file():
            rep.samples_skipped = (f"the DEM recorded at build time, {src or '(none)'}, is not there: "
                                   "pass --dem DEM to re-render samples (or --samples 0 to check the "
                                   "checksums only)")
            return rep
        dem = src
    if not isinstance(dem, Dem):
        dem = load_dem(dem)
    if dem.checksum != db.dem_sha256:
        rep.sample_failures.append(f"DEM checksum {dem.checksum[:12]}... differs from the build's "
                                   f"{db.dem_sha256[:12]}...: not the DEM this database was built from")
        return rep
    # Distinct positions drawn uniformly over the intact blocks (flat index -> block -> row, col).
    r0, c0, ncol, size = (np.array(v, np.int64) for v in zip(*(
        (rs.start, cs.start, cs.stop - cs.start, (rs.stop - rs.start) * (cs.stop - cs.start))
        for rs, cs in (db.grid.block_slices(br, bc) for br, bc in good))))
    total = int(size.sum())
    if samples > total:
        rep.notes.append(f"{samples} samples asked for, but the intact blocks hold {total} positions: "
                         f"re-rendered all {total}")
    rng = np.random.default_rng(seed)
    flat = np.sort(rng.choice(total, size=min(samples, total), replace=False))
    ends = np.cumsum(size)
    bi = np.searchsorted(ends, flat, side="right")
    within = flat - (ends[bi] - size[bi])
    rows, cols = r0[bi] + within // ncol[bi], c0[bi] + within % ncol[bi]
    x, y = db.xy_of(rows, cols)
    hb = render_horizons(dem, x, y, camera_height_m=db.camera_height_m, planet=db.planet,
                         azimuth_bins=db.azimuth_bins, max_distance_m=db.max_distance_m,
                         skip_tol_deg=float(db.attrs["build"].get("skip_tol_deg", SKIP_TOL_DEG)))
    stored = db.profiles_at(x, y)
    tol = db.scale_deg / 2 + 1e-4
    err = np.abs(stored - hb.elevation_deg)
    nan_mismatch = np.isnan(stored) != np.isnan(hb.elevation_deg)
    rep.samples = len(x)
    rep.sample_max_error_deg = float(np.nanmax(err)) if np.isfinite(err).any() else 0.0
    for i in range(len(x)):
        if nan_mismatch[i].any() or np.nanmax(err[i], initial=0.0) > tol:
            rep.sample_failures.append(
                f"position row {rows[i]} col {cols[i]} ({x[i]:.1f}, {y[i]:.1f}): stored skyline differs "
                f"from a re-render by up to {np.nanmax(err[i], initial=0.0):.4f} deg "
                f"({int(nan_mismatch[i].sum())} bins differ in missing)")
    return rep


def describe(path) -> dict:
    """Metadata, completeness and size on disk of a database (complete or not), for ``skyfix info``.

    ``damage`` is the error message for built blocks whose data files are gone (None if none).
    """
    db = open_database(path, allow_incomplete=True)
    ny, nx = db.shape
    a = db.attrs
    size = dir_size(db.path)
    built = 0
    for br, bc in db.grid.blocks():
        if (br, bc) in db._done:
            rs, cs = db.grid.block_slices(br, bc)
            built += (rs.stop - rs.start) * (cs.stop - cs.start)
    return {
        "path": str(db.path), "format": f"{a['format']} v{a['format_version']}",
        "software_version": a.get("software_version"), "crs": db.crs_name or "(WKT only)",
        "grid": {"nx": nx, "ny": ny, "spacing_m": db.spacing_m, "x0": db.grid.x0, "y0": db.grid.y0,
                 "bounds": list(db.bounds), "block_shape": a["grid"]["block_shape"]},
        "positions": nx * ny, "azimuth_bins": db.azimuth_bins, "camera_height_m": db.camera_height_m,
        "planet": a["planet"], "max_distance_m": db.max_distance_m,
        "scale_deg": db.scale_deg, "dem": a["dem"],
        "blocks_done": db.blocks_done, "n_blocks": db.n_blocks, "complete": db.is_complete,
        "blocks_data_missing": [list(b) for b in db.blocks_data_missing],
        "damage": _data_missing_message(db.path, db._absent) if db._absent else None,
        "size_bytes": size,
        "positions_built": built,
        # of the skylines built so far (none yet: no meaningful figure)
        "bytes_per_skyline": size / built if built else None,
    }
