"""The store's layout: format constants, the position grid, int16 quantisation of elevations and the
names of the per-block markers.

Position grid
    ``x = x0 + col * spacing_m`` (col = 0 .. nx-1), ``y = y0 - row * spacing_m`` (row = 0 .. ny-1),
    with ``x0 = xmin`` and ``y0 = ymax`` of the requested bounds: row 0 is north, as in the DEM.
    ``nx = floor((xmax - xmin) / spacing_m) + 1`` (both edges included when the spacing divides the
    extent), likewise ``ny``.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError


FORMAT = "skyfix-skyline-db"


FORMAT_VERSION = 1


#: [deg] quantisation step of the stored elevation angles
SCALE_DEG = 0.01


#: raw value of an azimuth bin whose ray saw no terrain
MISSING = -32768


#: positions per block side (one zarr chunk per block)
BLOCK = 64
#: the largest block side [positions]: a block is rendered whole, 256 x 256 skylines of 360 bins in
#: three float32 arrays (~0.28 GB)
MAX_BLOCK = 256


#: [deg] the renderer's skip tolerance used for every build (a build parameter)
SKIP_TOL_DEG = 0.002


META_DIR = "_skyfix"


MARKER_DIR = f"{META_DIR}/blocks"


#: the per-position arrays, one chunk of each per block
DATA_ARRAYS = ("elevation", "ground_z", "min_ray_m", "edge_bins")


#: the coarse index: array ``coarse`` (ny', nx', bins / COARSE_FACTOR), int16 in the elevation's
#: scale, holding every COARSE_STRIDE-th position along rows and columns (row 2i, col 2j at [i, j])
#: with each COARSE_FACTOR neighbouring azimuth bins averaged (bins without terrain counted as
#: 0 deg, as the search's coarse pass takes them), rounded to the step. Derived from ``elevation``
#: alone: a search reads it for its coarse pass (1/16 of the skylines' bytes) and then only the
#: blocks whose positions survive it. Optional: stores built before 2026-11-27 lack it until
#: ``skyfix build-db`` adds it, and a store without it is searched the older way.
COARSE = "coarse"
COARSE_STRIDE = 2
COARSE_FACTOR = 4
#: the fewest azimuth bins a store may have: a profile needs this many observed bins to be
#: searched (:attr:`skyfix.match.MatchConfig.min_observed`)
MIN_SEARCH_BINS = 20


#: a build larger than this is refused up front (the 7 x 7 km area at 5 m is 1.96 M skylines, 425 MB)
MAX_POSITIONS = 1_000_000_000


#: [bytes] ... or whose estimated size on disk exceeds this
MAX_BUILD_BYTES = 500e9


#: compressed share of the raw int16 skylines (measured 171 B of 720 at 360 bins, see above; a bit
#: pessimistic so that the estimate errs on the large side)
COMPRESSED_SHARE = 0.3


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
        if block > MAX_BLOCK:  # a block is rendered and held whole: 1e5 asked zarr for 6.5 TiB
            raise ParameterError(f"block size must be at most {MAX_BLOCK} positions a side ({MAX_BLOCK}^2 "
                                 f"skylines held at once), got {block}; the default is {BLOCK}")
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


def has_coarse_layout(block: int, bins: int) -> bool:
    """Whether a store of ``block``-position blocks and ``bins`` azimuth bins can hold the coarse
    index: each block's subgrid must start on an even row and column, and the bins group evenly."""
    return block % COARSE_STRIDE == 0 and bins % COARSE_FACTOR == 0


def coarse_shape(grid: "Grid", bins: int) -> tuple[int, int, int]:
    """Shape of the ``coarse`` array of a grid: every second row and column, bins / 4."""
    s = COARSE_STRIDE
    return (-(-grid.ny // s), -(-grid.nx // s), bins // COARSE_FACTOR)


def coarse_of(raw: np.ndarray, missing: int = MISSING) -> np.ndarray:
    """A block's coarse index: int16 (ceil(rows / 2), ceil(cols / 2), bins / 4) from its int16
    (rows, cols, bins) raw skylines (:data:`COARSE`). The block must start on an even grid row and
    column (:func:`has_coarse_layout`)."""
    sub = np.asarray(raw)[::COARSE_STRIDE, ::COARSE_STRIDE]
    r, c, n = sub.shape
    v = np.where(sub == missing, 0, sub).astype(np.int32)
    total = v.reshape(r, c, n // COARSE_FACTOR, COARSE_FACTOR).sum(axis=-1)
    return np.rint(total / COARSE_FACTOR).astype(np.int16)


def coarse_block_slices(grid: "Grid", br: int, bc: int) -> tuple[slice, slice]:
    """Block (br, bc)'s rows and columns in the ``coarse`` array."""
    rs, cs = grid.block_slices(br, bc)
    s = COARSE_STRIDE
    return slice(rs.start // s, -(-rs.stop // s)), slice(cs.start // s, -(-cs.stop // s))


def array_sha256(a: np.ndarray) -> str:
    """SHA-256 (hex) of an array's bytes in C order: the per-block checksum in its marker."""
    # hashed in place: a copy through tobytes() added 0.1-0.5 ms to the 1.6 ms of a 64 x 64 x 360 block
    return hashlib.sha256(np.ascontiguousarray(a)).hexdigest()


def marker_name(br: int, bc: int) -> str:
    """Path of block (row ``br``, column ``bc``)'s marker under ``MARKER_DIR``: the ``zarr.json``
    of a zarr group whose attributes are the marker, so the store stays a clean zarr hierarchy
    (a bare ``rRRRR_cCCCC.json`` made ``zarr.open`` warn of an unknown object)."""
    return f"r{br:04d}_c{bc:04d}/zarr.json"


def legacy_marker_name(br: int, bc: int) -> str:
    """The marker's path in stores built before markers were zarr groups (still read)."""
    return f"r{br:04d}_c{bc:04d}.json"


def marker_document(marker: dict) -> dict:
    """The ``zarr.json`` that holds ``marker`` as a group's attributes."""
    return {"zarr_format": 3, "node_type": "group", "attributes": marker}


def read_marker(store, br: int, bc: int) -> dict | None:
    """Block (br, bc)'s marker in the database folder ``store`` (either layout), None if absent.
    Raises ``OSError`` or ``ValueError`` when it exists but cannot be read, or does not hold a
    block's record with its checksums (``[]``, ``{"attributes": null}``: a marker that only
    looked like one made verify crash, and the build call the block built)."""
    import json
    from pathlib import Path

    d = Path(store) / MARKER_DIR
    p = d / marker_name(br, bc)
    old = d / legacy_marker_name(br, bc)
    if p.is_file():
        doc = json.loads(p.read_text())
        marker = doc.get("attributes") if isinstance(doc, dict) else doc
    elif old.is_file():
        marker = json.loads(old.read_text())
    else:
        return None
    if not isinstance(marker, dict) or not isinstance(marker.get("sha256"), dict):
        kind = ("an object without checksums" if isinstance(marker, dict) else
                {list: "an array", str: "a string", type(None): "null"}.get(type(marker), "a number"))
        raise ValueError(f"it holds {kind}, not a block's record with its checksums")
    return marker
