"""Horizon renderer: speed (skylines/s) and accuracy against the slow reference.

Prints, never asserts. Usage (from the repo root):

    python benchmarks/bench_horizon.py                 # speed on 10,000 points + accuracy on 200 x 3 DEMs
    python benchmarks/bench_horizon.py --points 2000 --accuracy-points 50   # quicker

Speed: sierra_nevada_30m, 360 bins, 30 km maximum distance, numba's default threads (both cores).
Accuracy: |fast - reference| over N random points x 360 azimuths on each shared DEM.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from installs import load_average
from skyfix.dem import load_dem
from skyfix.horizon import reference_horizon, render_horizons

DEM_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "dem"
DEMS = ["sierra_nevada_30m", "south_glacier_20m", "alps_srtm3_n46e008"]


def random_points(dem, n, seed, margin_m=0.0):
    """n points [m] with heights (a reprojected DEM's corners hold none), at least margin_m inside
    its bounds."""
    rng = np.random.default_rng(seed)
    xmin, ymin, xmax, ymax = dem.bounds
    x = rng.uniform(xmin + margin_m, xmax - margin_m, 4 * n + 100)
    y = rng.uniform(ymin + margin_m, ymax - margin_m, 4 * n + 100)
    on = np.flatnonzero(np.isfinite(dem.height_at(x, y)))[:n]
    return x[on], y[on]


def speed(points: int, repeats: int) -> None:
    import numba

    dem = load_dem(DEM_DIR / "sierra_nevada_30m.tif")
    xs, ys = random_points(dem, points, seed=1)
    render_horizons(dem, xs[:4], ys[:4], max_distance_m=30_000)  # compile / load the cache
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        render_horizons(dem, xs, ys, max_distance_m=30_000)
        rates.append(points / (time.perf_counter() - t0))
    n_ref = 20
    t0 = time.perf_counter()
    for k in range(n_ref):
        reference_horizon(dem, xs[k], ys[k], max_distance_m=30_000)
    ref_rate = n_ref / (time.perf_counter() - t0)
    fast = float(np.median(rates))
    print(f"speed: sierra_nevada_30m, {points} points x 360 bins, 30 km, {numba.get_num_threads()} threads")
    print(f"  fast kernel  {fast:8.0f} skylines/s (median of {repeats}; runs {', '.join(f'{r:.0f}' for r in rates)})")
    print(f"  reference    {ref_rate:8.1f} skylines/s  -> speed-up x{fast / ref_rate:.0f}")
    print(f"  target >= 3000 skylines/s: ratio {fast / 3000:.2f}; 7 x 7 km at 5 m (1.96 M) would take "
          f"{1_962_801 / fast / 60:.1f} min")


def accuracy(points: int) -> None:
    print(f"accuracy: fast vs reference, {points} random points x 360 azimuths, 30 km")
    print(f"  {'DEM':22s} {'p50':>9s} {'p99':>9s} {'max':>9s} {'mean signed':>12s}  (deg; bar p99 <= 0.05, max <= 0.2)")
    for name in DEMS:
        path = DEM_DIR / f"{name}.tif"
        if not path.exists():
            print(f"  {name}: not found, skipped")
            continue
        dem = load_dem(path)
        xs, ys = random_points(dem, points, seed=2)
        fast = render_horizons(dem, xs, ys, max_distance_m=30_000).elevation_deg
        d = np.concatenate([fast[k] - reference_horizon(dem, xs[k], ys[k], max_distance_m=30_000)[0]
                            for k in range(points)])
        a = np.abs(d)
        print(f"  {name:22s} {np.percentile(a, 50):9.5f} {np.percentile(a, 99):9.5f} {a.max():9.5f} {d.mean():12.6f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=10_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--accuracy-points", type=int, default=200)
    args = ap.parse_args()
    speed(args.points, args.repeats)
    accuracy(args.accuracy_points)


if __name__ == "__main__":
    print(f"load average at the start: {load_average()}", flush=True)
    main()
    print(f"load average at the end: {load_average()}")
