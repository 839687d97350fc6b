"""The grid sweep (:func:`skyfix.sweep.render_grid`) against the per-point kernel, side by side.

Prints, never asserts. Usage (from the repo root):

    python benchmarks/bench_sweep.py                       # 1 x 1 km at 5 m on 3 shared DEMs + a generated one
    python benchmarks/bench_sweep.py --side-m 500 --dems generated     # quicker
    python benchmarks/bench_sweep.py --speed-side 256      # also a 1.28 km grid, speed only
    python benchmarks/bench_sweep.py --offset 0.3,-0.3     # another block: held out from the tuning

The sweep's thresholds (``ARC_TOL_DEG``, ``ALT_DELTA_DEG``, ``LATERAL_SLOPE``) were chosen on the
default blocks, the middle of each DEM; ``--offset FX,FY`` moves the block's centre by those
fractions of the DEM's half-width east and half-height north, terrain they never saw.

Accuracy: |sweep - kernel| [deg] over every position and bin of a ``--side-m`` square grid at
``--spacing-m`` in the middle of each DEM, 360 bins, rays to the DEM edge, curvature and
refraction of the DEM's body, the camera ``--camera-height-m`` above the ground (the issue's bar:
p99 <= 0.01, max <= 0.1). Speed: skylines/s of both on the same grid in the same run, numba's
default threads, with the load average (1 min) beside it.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from skyfix.dem import fractal_dem, load_dem
from skyfix.horizon import render_horizons
from skyfix.sweep import render_grid

DEM_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "dem"
SHARED = {"sierra": "sierra_nevada_30m", "alps": "alps_srtm3_n46e008", "glacier": "south_glacier_20m"}


def the_dem(name: str):
    if name == "generated":
        return fractal_dem(1024, 30.0, relief_m=2500.0, seed=7)
    return load_dem(DEM_DIR / f"{SHARED[name]}.tif")


def centred_grid(dem, side_m: float, spacing_m: float, offset=(0.0, 0.0)):
    """The block's first position and its side in positions; ``offset`` moves its centre by
    those fractions of the DEM's half-width (east) and half-height (north)."""
    xmin, ymin, xmax, ymax = dem.bounds
    n = int(round(side_m / spacing_m)) + 1
    half = (n - 1) * spacing_m / 2
    cx = (xmin + xmax) / 2 + offset[0] * (xmax - xmin) / 2
    cy = (ymin + ymax) / 2 + offset[1] * (ymax - ymin) / 2
    return cx - half, cy + half, n


def compare(name: str, side_m: float, spacing_m: float, camera_height_m: float, kernel: bool,
            offset=(0.0, 0.0)):
    dem = the_dem(name)
    x_w, y_n, n = centred_grid(dem, side_m, spacing_m, offset)
    corners = dem.height_at(np.array([x_w, x_w + (n - 1) * spacing_m] * 2),
                         np.array([y_n] * 2 + [y_n - (n - 1) * spacing_m] * 2))
    if not np.all(np.isfinite(corners)):
        raise SystemExit(f"{name}: the block at offset {offset} leaves the DEM's data; "
                         "choose a smaller --offset or --side-m")
    kw = dict(camera_height_m=camera_height_m)
    render_grid(dem, x_w, y_n, spacing_m, 2, 2, **kw)  # compile / load the cache
    render_horizons(dem, [x_w], [y_n], **kw)
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    sw = render_grid(dem, x_w, y_n, spacing_m, n, n, **kw)
    t_sw = time.perf_counter() - t0
    if not kernel:
        print(f"  {name:10s} {n}x{n}: sweep {n * n / t_sw:8.0f} skylines/s (load {load0:.1f})")
        return
    t0 = time.perf_counter()
    ke = render_horizons(dem, sw.x, sw.y, **kw)
    t_ke = time.perf_counter() - t0
    load1 = os.getloadavg()[0]
    d = sw.elevation_deg.astype(np.float64) - ke.elevation_deg
    ok = np.isfinite(d)
    nan_mismatch = int(np.sum(np.isnan(sw.elevation_deg) != np.isnan(ke.elevation_deg)))
    a = np.abs(d[ok])
    print(f"  {name:10s} {n}x{n} {a.size:>10,d} {np.percentile(a, 99):9.5f} {np.percentile(a, 99.9):9.4f} "
          f"{a.max():7.3f} {np.mean(a > 0.01) * 100:8.3f} {d[ok].max():+9.5f} {nan_mismatch:6d} | "
          f"{n * n / t_sw:7.0f} {n * n / t_ke:7.0f} {t_ke / t_sw:6.2f}  (load {load0:.1f}-{load1:.1f})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dems", default="sierra,alps,glacier,generated",
                    help="comma-separated: sierra, alps, glacier, generated")
    ap.add_argument("--side-m", type=float, default=1000.0)
    ap.add_argument("--spacing-m", type=float, default=5.0)
    ap.add_argument("--camera-height-m", type=float, default=1.5)
    ap.add_argument("--speed-side", type=int, default=0,
                    help="also time the sweep alone on an N x N grid (its sharing grows with N)")
    ap.add_argument("--offset", default="0,0", metavar="FX,FY",
                    help="move the block's centre by these fractions of the DEM's half-width (east) "
                         "and half-height (north): a block the thresholds were not chosen on")
    args = ap.parse_args()
    try:
        offset = tuple(float(v) for v in args.offset.split(","))
    except ValueError:
        offset = ()
    if len(offset) != 2 or not all(abs(v) < 1 for v in offset):
        ap.error(f"--offset {args.offset!r}: give two fractions between -1 and 1, e.g. 0.3,-0.3")
    import numba

    print(f"sweep vs per-point kernel: {args.side_m:g} m square at {args.spacing_m:g} m, 360 bins, "
          f"camera {args.camera_height_m:g} m, rays to the DEM edge, {numba.get_num_threads()} threads, "
          f"block centre offset {offset[0]:g}, {offset[1]:g} of the half-extent")
    print(f"  {'DEM':10s} {'grid':7s} {'bins':>10s} {'p99':>9s} {'p99.9':>9s} {'max':>7s} {'>0.01 %':>8s} "
          f"{'most over':>9s} {'NaN!=':>6s} | {'sweep/s':>7s} {'kern/s':>7s} {'ratio':>6s}   (deg; bar p99 <= 0.01, max <= 0.1)")
    for name in args.dems.split(","):
        compare(name.strip(), args.side_m, args.spacing_m, args.camera_height_m, kernel=True,
                offset=offset)
    if args.speed_side:
        print(f"speed alone, {args.speed_side} x {args.speed_side} positions at {args.spacing_m:g} m:")
        for name in args.dems.split(","):
            compare(name.strip(), (args.speed_side - 1) * args.spacing_m, args.spacing_m,
                    args.camera_height_m, kernel=False, offset=offset)


if __name__ == "__main__":
    main()
