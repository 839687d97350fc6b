"""Build-rate and size benchmark of the skyline database (prints figures, asserts nothing).

Builds a square area (2 x 2 km at 5 m by default) of sierra_nevada_30m, centred in the 7 x 7 km
reference search area, through the default path (an embedded Dask LocalCluster, one
single-threaded worker per core), with each renderer in turn (the per-point kernel, then the
grid sweep: ``build-db --renderer``), and extrapolates to the 7 x 7 km / 5 m store. The rate ratio
of the two is measured in the same run; the stores are compared bin by bin (raw int16 steps of
0.01 deg).

    PYTHONPATH=src python benchmarks/bench_build_db.py [--size-km 2] [--spacing-m 5] [--workers N]
        [--renderers kernel,sweep] [--malloc-ab [--repeat N]]

``--malloc-ab`` builds with the sweep under Dask's own malloc settings for its workers and under
skyfix's (``skyfix.database.executors.WORKER_MALLOC``) in turn, ``--repeat`` times each.

Timings on a shared machine are noisy: the load average is printed beside them.
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

DEM = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "dem" / "sierra_nevada_30m.tif"
#: the 7 x 7 km reference search area (the DEM's work CRS, UTM 11N) and its centre
AREA_7KM = (297800.0, 4143100.0, 304800.0, 4150100.0)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size-km", type=float, default=2.0, help="side of the benchmark area [km]")
    ap.add_argument("--spacing-m", type=float, default=5.0)
    ap.add_argument("--workers", type=int, default=None, help="default: one per core (LocalCluster)")
    ap.add_argument("--keep", type=Path, default=None, help="keep the stores in this folder")
    ap.add_argument("--renderers", default="kernel,sweep", help="comma-separated, built in turn")
    ap.add_argument("--malloc-ab", action="store_true",
                    help="the sweep under Dask's malloc settings for its workers, then skyfix's")
    ap.add_argument("--repeat", type=int, default=1, help="rounds of --malloc-ab")
    a = ap.parse_args()
    if not DEM.exists():
        print(f"skipped: {DEM} not found (expected ../shared/data beside the repo)")
        return

    from skyfix.database import Grid, build_database, dir_size

    cx, cy = (AREA_7KM[0] + AREA_7KM[2]) / 2, (AREA_7KM[1] + AREA_7KM[3]) / 2
    h = a.size_km * 500.0
    bounds = (cx - h, cy - h, cx + h, cy + h)
    tmp = Path(tempfile.mkdtemp(prefix="bench_db_"))
    folder = a.keep or tmp
    rates = {}
    arms = [(r, None) for r in a.renderers.split(",")]
    if a.malloc_ab:
        arms = [("sweep", m) for _ in range(a.repeat) for m in ("dask", "skyfix")]
    try:
        for renderer, malloc in arms:
            out = folder / f"bench_{renderer}.zarr"
            load0 = os.getloadavg()[0]
            c0, f0, s0 = _cpu_s(), _children_faults(), _system_s()
            t0 = time.perf_counter()
            with _worker_malloc(malloc):
                r = build_database(DEM, out, bounds, a.spacing_m, workers=a.workers,
                                   overwrite=True, progress=False, renderer=renderer)
            wall = time.perf_counter() - t0
            cpu, sys_s = _cpu_s() - c0, _system_s()
            if malloc is not None:
                print(f"--- sweep, the workers' malloc settings {malloc}'s: {wall:.1f} s wall, "
                      f"CPU {cpu:.1f} s ({sys_s - s0:.1f} s of it in the kernel), minor page "
                      f"faults of the workers {_children_faults() - f0:,}; load {load0:.1f} "
                      f"before, {os.getloadavg()[0]:.1f} after")
                continue
            elev = dir_size(out / "elevation")
            n = r.positions
            rate_tasks = r.skylines_per_s  # from the first task submitted to the last one finished
            rate_wall = n / wall  # including DEM checks, store creation and the cluster's start/stop
            rates[renderer] = (rate_tasks, out, cpu / n)
            full = Grid.from_bounds(AREA_7KM, a.spacing_m)
            n_full = full.ny * full.nx
            print(f"--- renderer {renderer}")
            print(f"area            {a.size_km:g} x {a.size_km:g} km at {a.spacing_m:g} m: {n} skylines, "
                  f"{r.n_blocks} blocks, workers {a.workers if a.workers is not None else 'one per core'}")
            print(f"load average    {load0:.1f} before, {os.getloadavg()[0]:.1f} after "
                  f"({os.cpu_count()} cores)")
            print(f"build           {wall:.1f} s wall, {rate_wall:,.0f} skylines/s end to end, "
                  f"{rate_tasks:,.0f} skylines/s while rendering; CPU {cpu:.1f} s, "
                  f"{cpu / n * 1e3:.2f} ms/skyline (this process and its workers: steadier than "
                  "wall time on a shared machine)")
            print(f"size            {r.size_bytes / 1e6:.2f} MB, {r.size_bytes / n:.0f} B/skyline on disk "
                  f"({elev / n:.0f} B/skyline for the elevation array; raw int16 is "
                  f"{2 * 360} B)")
            print(f"7 x 7 km @ {a.spacing_m:g} m {n_full} skylines: ~{n_full / rate_tasks / 60:.1f} min, "
                  f"~{n_full * r.size_bytes / n / 1e9:.2f} GB (extrapolated; targets < 30 min, < 2 GB)")
        if "kernel" in rates and "sweep" in rates:
            compare(rates["kernel"], rates["sweep"])
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _cpu_s() -> float:
    """[s] CPU of this process and of its children that have ended (the cluster's nanny and
    worker processes, once it is closed)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def _system_s() -> float:
    t = os.times()
    return t.system + t.children_system


def _children_faults() -> int:
    import resource

    return resource.getrusage(resource.RUSAGE_CHILDREN).ru_minflt


@contextmanager
def _worker_malloc(which: str | None):
    """Dask's malloc settings for the workers ('dask') instead of skyfix's, for the A/B."""
    from skyfix.database import executors

    saved = executors.WORKER_MALLOC
    if which == "dask":
        executors.WORKER_MALLOC = {}
    try:
        yield
    finally:
        executors.WORKER_MALLOC = saved


def compare(kernel, sweep) -> None:
    """The sweep's rate over the kernel's, and its stored skylines against the kernel's."""
    import numpy as np
    import zarr

    from skyfix.database import MISSING

    k = np.asarray(zarr.open_group(str(kernel[1]), mode="r")["elevation"][:], np.int32)
    w = np.asarray(zarr.open_group(str(sweep[1]), mode="r")["elevation"][:], np.int32)
    ok = (k != MISSING) & (w != MISSING)
    d = (w - k)[ok]
    print(f"--- sweep / kernel: {sweep[0] / kernel[0]:.2f}x the rate (target >= 5x), "
          f"{kernel[2] / sweep[2]:.2f}x less CPU a skyline")
    print(f"stored bins     {d.size:,}; missing differs in {int(((k == MISSING) != (w == MISSING)).sum())}; "
          f"sweep - kernel [steps of 0.01 deg]: max {d.max():+d}, min {d.min():+d}; "
          f"|diff| > 1 step in {np.mean(np.abs(d) > 1) * 100:.3f} % of bins, > 10 steps in "
          f"{np.mean(np.abs(d) > 10) * 100:.4f} %")


if __name__ == "__main__":  # the LocalCluster spawns processes that re-import this file
    main()
