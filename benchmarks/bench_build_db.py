"""Build-rate and size benchmark of the skyline database (prints figures, asserts nothing).

Builds a square area (2 x 2 km at 5 m by default) of sierra_nevada_30m, centred in the 7 x 7 km
reference search area, through the default path (an embedded Dask LocalCluster, one
single-threaded worker per core), then extrapolates to the 7 x 7 km / 5 m store.

    PYTHONPATH=src python benchmarks/bench_build_db.py [--size-km 2] [--spacing-m 5] [--workers N]

Timings on a shared machine are noisy: the load average is printed beside them.
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

DEM = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "dem" / "sierra_nevada_30m.tif"
#: the 7 x 7 km reference search area (DEM CRS, ESRI:102003) and its centre
AREA_7KM = (-2020450.0, 238257.0, -2013450.0, 245257.0)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size-km", type=float, default=2.0, help="side of the benchmark area [km]")
    ap.add_argument("--spacing-m", type=float, default=5.0)
    ap.add_argument("--workers", type=int, default=None, help="default: one per core (LocalCluster)")
    ap.add_argument("--keep", type=Path, default=None, help="keep the store at this path")
    a = ap.parse_args()
    if not DEM.exists():
        print(f"skipped: {DEM} not found (expected ../shared/data beside the repo)")
        return

    from skyfix.database import Grid, build_database, dir_size

    cx, cy = (AREA_7KM[0] + AREA_7KM[2]) / 2, (AREA_7KM[1] + AREA_7KM[3]) / 2
    h = a.size_km * 500.0
    bounds = (cx - h, cy - h, cx + h, cy + h)
    tmp = Path(tempfile.mkdtemp(prefix="bench_db_"))
    out = a.keep or tmp / "bench.zarr"
    try:
        load0 = os.getloadavg()[0]
        t0 = time.perf_counter()
        r = build_database(DEM, out, bounds, a.spacing_m, workers=a.workers, overwrite=True,
                           progress=False)
        wall = time.perf_counter() - t0
        elev = dir_size(out / "elevation")
        n = r.positions
        rate_tasks = r.skylines_per_s  # from the first task submitted to the last one finished
        rate_wall = n / wall  # including DEM checks, store creation and the cluster's start/stop
        full = Grid.from_bounds(AREA_7KM, a.spacing_m)
        n_full = full.ny * full.nx
        print(f"area            {a.size_km:g} x {a.size_km:g} km at {a.spacing_m:g} m: {n} skylines, "
              f"{r.n_blocks} blocks, workers {a.workers if a.workers is not None else 'one per core'}")
        print(f"load average    {load0:.1f} before, {os.getloadavg()[0]:.1f} after "
              f"({os.cpu_count()} cores)")
        print(f"build           {wall:.1f} s wall, {rate_wall:,.0f} skylines/s end to end, "
              f"{rate_tasks:,.0f} skylines/s while rendering")
        print(f"size            {r.size_bytes / 1e6:.2f} MB, {r.size_bytes / n:.0f} B/skyline on disk "
              f"({elev / n:.0f} B/skyline for the elevation array; raw int16 is "
              f"{2 * 360} B)")
        print(f"7 x 7 km @ {a.spacing_m:g} m {n_full} skylines: ~{n_full / rate_tasks / 60:.1f} min, "
              f"~{n_full * r.size_bytes / n / 1e9:.2f} GB (extrapolated; targets < 30 min, < 2 GB)")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":  # the LocalCluster spawns processes that re-import this file
    main()
