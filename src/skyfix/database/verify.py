"""Checking a store end to end (:func:`verify_database`: checksums of every block, a sample
re-rendered from the DEM) and describing it (:func:`describe`, for ``skyfix info``).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ParameterError
from .build import dir_size
from .executors import is_whole_at_least_0
from .layout import (COARSE, DATA_ARRAYS, SKIP_TOL_DEG, array_sha256, coarse_of, has_coarse_layout,
                     read_marker)
from .store import open_database


# Delta/Shuffle are numcodecs codecs: zarr-python reads them fine but flags them, on every open,
# as outside the zarr v3 core spec (a choice documented above).
warnings.filterwarnings("ignore", message="Numcodecs codecs are not in the Zarr")


#: A store built by the sweep renderer is re-rendered with the per-point kernel: its skylines are
#: true points of each ray, so they exceed the kernel's by at most the kernel's own skip tolerance
#: (0.002 deg, SKIP_TOL_DEG), and fall short of it in few bins (bench_sweep.py: 0.01-0.1 % beyond
#: 0.01 deg, at most 0.6 deg). A damaged chunk or another DEM errs both ways and in many bins.
SWEEP_OVER_DEG = 0.0025
SWEEP_SHORT_SHARE = 0.05
SWEEP_SHORT_MAX_DEG = 3.0


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
    #: the DEM given to re-render samples is not the one the store was built from
    dem_mismatch: bool = False

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
    from ..dem import Dem
    from ..horizon import render_horizons

    if not is_whole_at_least_0(samples):
        raise ParameterError(f"samples must be a whole number >= 0 (0: checksums only), got {samples!r}")
    samples = int(samples)
    if not is_whole_at_least_0(seed):  # numpy's generator refused it with a traceback
        raise ParameterError(f"seed must be a whole number >= 0, got {seed!r}")
    db = open_database(path, allow_incomplete=True)
    rep = VerifyReport(Path(path), db.n_blocks, samples_requested=samples)
    good = []
    indexed = db.indexed_blocks
    for br, bc in db.grid.blocks():
        try:
            marker = read_marker(path, br, bc)
        except (OSError, ValueError, KeyError) as e:
            rep.corrupt.append(((br, bc), f"marker unreadable: {type(e).__name__}: {e}"))
            continue
        if marker is None:
            rep.missing.append((br, bc))
            continue
        gone = db.data_missing(br, bc)
        if gone:
            rep.corrupt.append(((br, bc), f"data missing: no chunk file for {', '.join(gone)}"))
            continue
        try:
            got = {name: db.read_stored(name, br, bc) for name in DATA_ARRAYS}
            bad = [k for k, v in got.items() if array_sha256(v) != marker["sha256"].get(k)]
        except Exception as e:  # a damaged chunk fails to decode (zstd checksum) in many ways
            rep.corrupt.append(((br, bc), f"unreadable: {type(e).__name__}: {e}"))
            continue
        if bad:
            rep.corrupt.append(((br, bc), f"checksum mismatch in {', '.join(bad)}"))
            continue
        good.append((br, bc))
        if (br, bc) in indexed:  # derived data: checked against the skylines it comes from
            try:
                ok = np.array_equal(db.read_stored(COARSE, br, bc), coarse_of(got["elevation"]))
            except Exception as e:
                ok, e_text = False, f"unreadable: {type(e).__name__}: {e}"
            else:
                e_text = "differs from the block's skylines"
            if not ok:
                rep.corrupt.append(((br, bc), f"coarse index {e_text}"))
    unindexed = [b for b in good if b not in indexed]
    if unindexed and has_coarse_layout(db.grid.block, db.azimuth_bins):
        rep.notes.append(f"{len(unindexed)} of {db.n_blocks} blocks have no coarse index (a store "
                         "built before it existed): rerun the build-db command to add it, and the "
                         "search reads only the blocks it needs")
    if samples == 0:
        return rep
    if not good:
        rep.samples_skipped = "no intact block to sample from"
        return rep
    if dem is None:
        rec = db.attrs["dem"]
        srcs = [s["path"] for s in rec.get("sources", [])] or [rec.get("source", "")]
        missing = [s for s in srcs if not s or not Path(s).is_file()]
        if missing:
            rep.samples_skipped = (f"the DEM recorded at build time, {missing[0] or '(none)'}, is not "
                                   "there: pass --dem DEM to re-render samples (or --samples 0 to "
                                   "check the checksums only)")
            return rep
        dem = srcs if len(srcs) > 1 else srcs[0]
    if not (isinstance(dem, Dem) or hasattr(dem, "members")):
        from ..stack import load_dems

        dem = load_dems(dem)
    if dem.checksum != db.dem_sha256:
        rep.dem_mismatch = True
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
    diff = stored - hb.elevation_deg
    err = np.abs(diff)
    nan_mismatch = np.isnan(stored) != np.isnan(hb.elevation_deg)
    rep.samples = len(x)
    rep.sample_max_error_deg = float(np.nanmax(err)) if np.isfinite(err).any() else 0.0
    sweep = db.attrs["build"].get("renderer") == "sweep"
    if sweep:  # the kernel re-renders: the sweep's skylines may fall short of it, never exceed it
        short = np.nan_to_num(-diff) > tol
        rep.notes.append(
            f"built with the sweep renderer: {int(short.sum())} of {short.size} re-rendered bins "
            f"lie more than {tol:.4f} deg below the per-point kernel (allowed: up to "
            f"{SWEEP_SHORT_SHARE:.0%} of a position's bins, by up to {SWEEP_SHORT_MAX_DEG:g} deg)")
    for i in range(len(x)):
        if sweep:
            over = np.nanmax(diff[i], initial=0.0) > tol + SWEEP_OVER_DEG
            bad = (over or np.mean(np.nan_to_num(-diff[i]) > tol) > SWEEP_SHORT_SHARE
                   or np.nanmax(-diff[i], initial=0.0) > SWEEP_SHORT_MAX_DEG)
        else:
            bad = np.nanmax(err[i], initial=0.0) > tol
        if nan_mismatch[i].any() or bad:
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
        if db.is_built(br, bc):
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
        "renderer": a.get("build", {}).get("renderer", "kernel"),
        "blocks_done": db.blocks_done, "n_blocks": db.n_blocks, "complete": db.is_complete,
        "blocks_data_missing": [list(b) for b in db.blocks_data_missing],
        "coarse_index_blocks": len(db.indexed_blocks),
        "coarse_index_possible": has_coarse_layout(db.grid.block, db.azimuth_bins),
        "damage": db.damage_message(),
        "size_bytes": size,
        "positions_built": built,
        # of the skylines built so far (none yet: no meaningful figure)
        "bytes_per_skyline": size / built if built else None,
    }
