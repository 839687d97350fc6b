"""The coarse index of a store (:data:`~.layout.COARSE`): its array, its chunks written with each
block, or added to a store built without it (which blocks have theirs: :mod:`.integrity`).

Why it exists: a full search scores every second position on skylines averaged over four bins,
then only the best few per cent exactly. Read from the full skylines, that coarse pass decodes every
byte of the store (1.4 GB for the 7 x 7 km database at 5 m, ~2 s of CPU, the search's critical
path). From this index it decodes a sixteenth of that, and the exact pass then decodes only the
blocks that hold a survivor (20-30 % of them for a full turn; ``match/indexed.py``).

The index is derived data: each chunk is a function of its block's elevation chunk alone
(:func:`~.layout.coarse_of`), so it needs no checksum of its own (``skyfix verify`` recomputes it),
and a chunk file is present only once it is whole (zarr writes a chunk beside its name and renames
it). A block's coarse chunk is written before its marker, so a built block of a store created
with the index always has its chunk.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from .chunks import skyline_codecs
from .integrity import coarse_array_ok, indexed_blocks
from .layout import (COARSE, COARSE_FACTOR, COARSE_STRIDE, MISSING, SCALE_DEG, Grid,
                     coarse_block_slices, coarse_of, coarse_shape, has_coarse_layout)
from .store import open_database

log = logging.getLogger(__package__)


def create_coarse_array(group, grid: Grid, bins: int):
    """Create the empty ``coarse`` array in the store's zarr group (None where the grid's blocks or
    bins do not allow one: :func:`~.layout.has_coarse_layout`)."""
    if not has_coarse_layout(grid.block, bins):
        return None
    b = grid.block // COARSE_STRIDE
    return group.create_array(
        COARSE, shape=coarse_shape(grid, bins), chunks=(b, b, bins // COARSE_FACTOR), dtype="int16",
        fill_value=MISSING, overwrite=True,
        # its own dimension names: xarray reads every array of a store as one dataset
        dimension_names=("coarse_y", "coarse_x", "coarse_azimuth"),
        attributes={"units": "deg", "scale_deg": SCALE_DEG, "stride": COARSE_STRIDE,
                    "bins_averaged": COARSE_FACTOR,
                    "meaning": f"[i, j, g] = mean of elevation[{COARSE_STRIDE} i, {COARSE_STRIDE} j, "
                               f"{COARSE_FACTOR} g .. {COARSE_FACTOR} g + {COARSE_FACTOR - 1}] (no "
                               "terrain counted as 0 deg), raw * scale_deg; the search's coarse pass"},
        **skyline_codecs(b))


def write_coarse_block(array, grid: Grid, br: int, bc: int, elevation_raw: np.ndarray) -> None:
    """Write block (br, bc)'s coarse chunk from its int16 (rows, cols, bins) skylines."""
    rs, cs = coarse_block_slices(grid, br, bc)
    array[rs, cs] = coarse_of(elevation_raw)


def add_coarse_index(path, *, progress: bool = False) -> int:
    """Add the coarse index to a store built without it (or finish one a killed run began): the
    array if absent, then the chunk of every built block that lacks it, from the block's stored
    skylines. Returns the blocks indexed now; 0 where the store's layout allows none."""
    import zarr

    db = open_database(path, allow_incomplete=True)
    bins = db.azimuth_bins
    if not has_coarse_layout(db.grid.block, bins):
        return 0
    g = zarr.open_group(str(path), mode="r+")
    array = g[COARSE] if coarse_array_ok(g, db.grid, bins) else create_coarse_array(g, db.grid, bins)
    have = indexed_blocks(path, g, db.grid, bins)
    todo = [b for b in db.grid.blocks() if db.is_built(*b) and not db.data_missing(*b) and b not in have]
    if not todo:
        return 0
    from tqdm import tqdm

    t0 = time.perf_counter()
    for br, bc in tqdm(todo, unit="block", desc="coarse index", disable=not progress,
                       dynamic_ncols=True):
        write_coarse_block(array, db.grid, br, bc, db.read_raw("elevation", br, bc))
    log.info("coarse index: %d blocks of %s in %.1f s", len(todo), path, time.perf_counter() - t0)
    return len(todo)
