"""Stage 3: the skyline database, the ground segment's product (the file the rover carries).

A zarr v3 store holding, for every position of a regular grid over a search area, the skyline
the DEM predicts there.

Arrays (``dimension_names`` in brackets)
    ``elevation`` int16 (ny, nx, bins) [y, x, azimuth]: skyline elevation = raw * ``scale_deg``
    (0.01 deg, rounded to nearest, so the quantisation adds at most 0.005 deg); ``-32768`` where
    the ray saw no terrain. Azimuth bin k is centred on ``k * 360 / bins`` deg clockwise from grid
    north. ``ground_z`` float32 (ny, nx) [m] DEM height under each position. ``min_ray_m`` float32
    (ny, nx) [m] shortest ray of the position; ``edge_bins`` int16 (ny, nx) number of bins whose
    ray stopped at the DEM edge before ``max_distance_m`` (a skyline may lie beyond the DEM there).
    ``x`` (nx,), ``y`` (ny,), ``azimuth`` (bins,) coordinates [m, m, deg].
    ``coarse`` int16 (ceil(ny / 2), ceil(nx / 2), bins / 4) [coarse_y, coarse_x, coarse_azimuth]:
    the coarse index, ``elevation`` at every second row and column with four neighbouring bins
    averaged (no terrain counted as 0 deg), in the same scale; derived data the search's coarse
    pass reads instead of every skyline (:mod:`.coarse`). Stores built before 2026-11-27 lack it
    until the same ``skyfix build-db`` command adds it; they are searched the older way meanwhile.

Blocks
    The grid is cut into blocks of ``block`` x ``block`` positions (64 x 64 by default), one zarr
    chunk of every array per block. A block is one build task: it renders its positions, writes
    its chunks, then (atomically, after the data) a marker ``_skyfix/blocks/rRRRR_cCCCC/zarr.json``
    holding the SHA-256 of the block's decoded arrays. A block without a marker is not built, so a
    build killed at any moment resumes by redoing exactly the blocks without markers,
    :func:`verify_database` can tell an intact block from a corrupted one, and a reader checks
    each block it decodes against its marker (a chunk file swapped with another block's decodes
    without a fault); the coarse index, derived data without checksums, is checked by
    :func:`verify_database` only.

Files: :mod:`.layout` (format constants, the grid, quantisation), :mod:`.executors` (where blocks
run), :mod:`.integrity` (the state of a store on disk), :mod:`.chunks` (the skyline arrays' codecs
and their direct decoding), :mod:`.coarse` (the coarse index), :mod:`.tasks` (rendering and writing blocks), :mod:`.build`
(planning and running a build), :mod:`.store`
(reading), :mod:`.verify` (checks and ``skyfix info``).
"""

from .build import (BuildResult, build_database, build_params, check_build_size, dir_size,
                    estimate_build_bytes)
from .tasks import RENDERERS, render_block
from .executors import InProcessExecutor, check_executor_options, default_workers, make_executor
from .integrity import check_dem_crs, done_blocks
from .layout import (BLOCK, DATA_ARRAYS, FORMAT, FORMAT_VERSION, MARKER_DIR, MAX_BUILD_BYTES,
                     MAX_POSITIONS, META_DIR, MISSING, SCALE_DEG, SKIP_TOL_DEG, Grid, dequantise,
                     marker_name, quantise, read_marker)
from .store import Block, SkylineDatabase, nearest_position_m, open_database
from .verify import VerifyReport, describe, verify_database

__all__ = ["BLOCK", "DATA_ARRAYS", "FORMAT", "FORMAT_VERSION", "MARKER_DIR", "MAX_BUILD_BYTES",
           "MAX_POSITIONS", "META_DIR", "MISSING", "SCALE_DEG", "SKIP_TOL_DEG", "Block",
           "BuildResult", "Grid", "InProcessExecutor", "SkylineDatabase", "VerifyReport",
           "build_database", "build_params", "check_build_size", "check_dem_crs", "check_executor_options",
           "default_workers", "describe", "dequantise", "dir_size", "done_blocks",
           "estimate_build_bytes", "make_executor", "marker_name", "nearest_position_m", "open_database",
           "quantise",
           "read_marker", "render_block", "RENDERERS", "verify_database"]
