"""Reading a store: :func:`open_database` (checked first by :mod:`.integrity`) gives a read-only
:class:`SkylineDatabase` that streams :class:`Block` s of positions to the matcher.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from .. import __version__
from ..errors import DatabaseError, ParameterError
from ..planets import Planet
from .chunks import chunk_reader
from .integrity import (absent_data, check_arrays, check_attrs, check_build_record, damaged,
                        data_missing_message,
                        done_blocks, indexed_blocks, is_int, root_state)
from .layout import (COARSE, COARSE_STRIDE, DATA_ARRAYS, FORMAT, FORMAT_VERSION, Grid, MARKER_DIR,
                     MISSING, SCALE_DEG, array_sha256, coarse_block_slices, dequantise, marker_name,
                     read_marker)


# --- reading ---------------------------------------------------------------------------------------
_UNDECIDED = object()


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
        self._absent = absent or {}  # built blocks whose chunk files are gone (see absent_data)
        self._arrays: dict = {}
        self._readers: dict = {}  # see _direct_reader
        self._marker = (None, None)  # the last block's (br, bc) and marker checksums: see _checksums
        self._coarse = None  # see has_coarse_index
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

    def is_built(self, br: int, bc: int) -> bool:
        """Whether block (br, bc) was built (its marker is there; its data may still be gone)."""
        return (br, bc) in self._done

    def data_missing(self, br: int, bc: int) -> tuple[str, ...]:
        """The arrays whose chunk file of built block (br, bc) is gone (empty: all there)."""
        return tuple(self._absent.get((br, bc), ()))

    def damage_message(self) -> str | None:
        """What is gone and what to do (:func:`~.integrity.data_missing_message`), or None."""
        return data_missing_message(self.path, self._absent) if self._absent else None

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

    def read_stored(self, name: str, br: int, bc: int, contiguous: bool = False) -> np.ndarray:
        """:meth:`read_raw` without its checks: whatever zarr or the decoder gives or raises (the
        verifier's own access, which checks the bytes against the block's checksums itself).
        ``contiguous``: a chunk decoded directly comes in C order (see :mod:`.chunks`)."""
        rs, cs = (coarse_block_slices(self.grid, br, bc) if name == COARSE
                  else self.grid.block_slices(br, bc))
        if name in ("elevation", COARSE):  # the bulk of every search: decoded directly
            read = self._direct_reader(name)
            if read is not None:
                return read((br, bc, 0), contiguous)[: rs.stop - rs.start, : cs.stop - cs.start]
        return np.asarray(self._array(name)[rs, cs])

    def _direct_reader(self, name: str):
        """The direct chunk reader of the skyline array ``name`` (:mod:`.chunks`), or None where
        zarr must read it (another layout, or chunks that are not one block each); decided once."""
        read = self._readers.get(name, _UNDECIDED)
        if read is _UNDECIDED:
            a = self._array(name)
            side = self.grid.block // (COARSE_STRIDE if name == COARSE else 1)
            read = self._readers[name] = (chunk_reader(a) if tuple(a.chunks[:2]) == (side, side)
                                          else None)
        return read

    @property
    def indexed_blocks(self) -> set[tuple[int, int]]:
        """Blocks whose coarse index chunk (:data:`~.layout.COARSE`) is there; listed once."""
        if self._coarse is None:
            self._coarse = indexed_blocks(self.path, self._g, self.grid, self.azimuth_bins)
        return set(self._coarse)

    @property
    def has_coarse_index(self) -> bool:
        """Whether the store is complete and holds its coarse index for every block: the search
        then decodes the skylines only of the blocks its coarse pass keeps."""
        return self.is_complete and len(self.indexed_blocks) == self.n_blocks

    def read_coarse(self, br: int, bc: int) -> np.ndarray:
        """Block (br, bc)'s coarse index, int16 (ceil(rows / 2), ceil(cols / 2), bins / 4) raw (see
        :data:`~.layout.COARSE`); a DatabaseError naming the block where it cannot be read."""
        return self.read_raw(COARSE, br, bc)

    def read_raw(self, name: str, br: int, bc: int) -> np.ndarray:
        """Array ``name``'s chunk of block (br, bc) as stored, shaped (rows, cols[, bins]).

        Raises :class:`~skyfix.errors.DatabaseError` naming the block if its chunk file is gone
        (zarr would hand back fill values), cannot be decoded, or (a data array of a built block)
        decodes to other values than its marker's SHA-256 says were written: a chunk file swapped
        with another block's, or copied from another store, decodes without a fault (zstd checks
        only that the file is whole) and gave a confident wrong fix.
        """
        if name in self._absent.get((br, bc), ()):
            raise DatabaseError(data_missing_message(self.path, {(br, bc): self._absent[(br, bc)]}))
        check = name in DATA_ARRAYS and (br, bc) in self._done
        try:
            raw = self.read_stored(name, br, bc, contiguous=check)
        except Exception as e:  # a damaged chunk fails to decode (zstd checksum) in many ways
            if name == COARSE:  # derived data: redone from the block's skylines, nothing rendered
                key = self._array(COARSE).metadata.encode_chunk_key((br, bc, 0))
                raise DatabaseError(
                    f"{self.path}: block ({br}, {bc}) coarse index unreadable ({type(e).__name__}: "
                    f"{e}): delete {self.path / COARSE / key} and rerun the build-db command (it "
                    "adds the index again from the stored skylines)") from None
            raise DatabaseError(f"{self.path}: block ({br}, {bc}) data unreadable ({name} chunk: "
                                f"{type(e).__name__}: {e}): {self._rebuild_hint(br, bc)}") from None
        # The coarse index is not checked here: its check, coarse_of(the block's skylines), cost
        # more than the checksum (1.2-2.9 ms a block against 1.6-2.5), and its damage misleads
        # the coarse pass over blocks the search then does not decode; `skyfix verify` checks it.
        if check and array_sha256(raw) != self._checksums(br, bc).get(name):
            raise DatabaseError(
                f"{self.path}: block ({br}, {bc}) {name} differs from the checksum its marker "
                "recorded (a chunk file swapped with another block's, copied from another store or "
                f"otherwise damaged): {self._rebuild_hint(br, bc)}")
        return raw

    def _rebuild_hint(self, br: int, bc: int) -> str:
        return (f"run `skyfix verify {self.path}`, then delete the damaged blocks' markers "
                f"({MARKER_DIR}/{marker_name(br, bc)}) and rerun the build-db command (it resumes)")

    def _checksums(self, br: int, bc: int) -> dict:
        """Block (br, bc)'s marker checksums {array: SHA-256 hex}, read when the block is decoded
        (not all at open: one small file a block); the last block's kept for its other arrays."""
        key, sha = self._marker
        if key != (br, bc):
            try:
                sha = (read_marker(self.path, br, bc) or {})["sha256"]
                if not isinstance(sha, dict):
                    raise ValueError(f"sha256 is a {type(sha).__name__}, not an object")
            except (OSError, ValueError, KeyError, TypeError) as e:
                raise DatabaseError(f"{self.path}: block ({br}, {bc}) marker unreadable "
                                    f"({type(e).__name__}: {e}): {self._rebuild_hint(br, bc)}") from None
            self._marker = ((br, bc), sha)
        return sha

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


def nearest_position_m(db, x: float, y: float) -> float:
    """Distance [m] from (x, y) [m] to the nearest position of ``db``'s grid (anything with
    ``x_coords`` and ``y_coords``): on a rectangular grid, the nearest column's and the nearest
    row's."""
    xs, ys = np.asarray(db.x_coords, float), np.asarray(db.y_coords, float)
    gx = xs[np.argmin(np.abs(xs - x))]
    gy = ys[np.argmin(np.abs(ys - y))]
    return float(np.hypot(gx - x, gy - y))


def open_database(path, *, allow_incomplete: bool = False) -> SkylineDatabase:
    """Open a skyline database read-only.

    Raises :class:`~skyfix.errors.DatabaseError` if ``path`` is not a skyfix database, was written by
    a newer format, or (unless ``allow_incomplete``) is not completely built.
    """
    import zarr

    path = Path(path)
    if not path.exists():
        raise DatabaseError(f"database {path} does not exist: build it with `skyfix build-db`")
    state, attrs = root_state(path) if path.is_dir() else ("none", None)
    if state == "damaged":
        raise DatabaseError(f"{path}: database metadata damaged: {attrs}: rebuild it with "
                            "`skyfix build-db ... --overwrite`")
    if state != "ok":
        raise DatabaseError(f"{path} is not a skyfix skyline database (no zarr.json with format "
                            f"{FORMAT!r}): give the folder `skyfix build-db` wrote")
    version = attrs.get("format_version")
    if not is_int(version):
        raise damaged(path, f"format_version must be a whole number, got {version!r}")
    if version > FORMAT_VERSION:
        raise DatabaseError(f"{path} has format version {version}, newer than this "
                            f"skyfix ({__version__}) reads ({FORMAT_VERSION}): upgrade skyfix")
    check_attrs(path, attrs)
    check_build_record(path, attrs)
    try:
        g = zarr.open_group(str(path), mode="r")
        for name in DATA_ARRAYS:
            g[name]
    except Exception as e:  # zarr raises several unrelated types for a broken store
        raise DatabaseError(f"{path} is a damaged skyline database ({type(e).__name__}: {e})") from None
    check_arrays(path, g, attrs)
    done = done_blocks(path)
    db = SkylineDatabase(path, g, attrs, done)
    db._absent = absent_data(path, g, db.grid, done)
    if not allow_incomplete:
        if db.blocks_data_missing:
            raise DatabaseError(data_missing_message(path, db._absent))
        if not db.is_complete:
            raise DatabaseError(f"{path} is incomplete ({db.blocks_done} of {db.n_blocks} blocks built): "
                                "run the same `skyfix build-db` command again to finish it")
    return db
