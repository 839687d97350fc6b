"""Seconds per simulated 1024 x 1024 navcam frame and per 4096 x 1024 panorama.

    PYTHONPATH=src python benchmarks/bench_simulate.py [DEM]

Default DEM: ../shared/data/dem/sierra_nevada_30m.tif (high relief, 1100 x 1100 cells). Prints the
split between ray casting, the sub-pixel skyline truth and shading + PNG writing. Numba kernels
are warmed up first (compile time is not counted). Target: <= 5 s per navcam frame.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from installs import load_average
from skyfix.camera import get_camera
from skyfix.dem import load_dem
from skyfix.formats import Truth
from skyfix.raycast import Projection, camera_centre, cast_image, column_skyline
from skyfix.simulate import simulate_acquisition

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "dem"


def main(path: str | None = None) -> None:
    import numba

    path = Path(path) if path else DATA / "sierra_nevada_30m.tif"
    dem = load_dem(path)
    print(dem.describe(), f"| numba threads: {numba.get_num_threads()}")
    xmin, ymin, xmax, ymax = dem.bounds
    x, y = (xmin + xmax) / 2 + 123.4, (ymin + ymax) / 2 - 56.7
    cam = get_camera("navcam")
    origin = camera_centre(dem, x, y, 1.5)
    # Warm-up (compiles or loads the cached kernels).
    with tempfile.TemporaryDirectory() as tmp:
        simulate_acquisition(dem, Truth(x, y, 0.0), Path(tmp) / "w", camera=cam.with_size(64, 64), frames=1)
        simulate_acquisition(dem, Truth(x, y, 0.0), Path(tmp) / "p", mode="panorama", pano_size=(64, 16))

    yaws = [0.0, 90.0, 180.0, 270.0]
    tc = ts = 0.0
    for yaw in yaws:
        proj = Projection.frame(cam, yaw, 0, 0, 0, 0)
        t0 = time.perf_counter()
        cast = cast_image(dem, origin, proj)
        t1 = time.perf_counter()
        column_skyline(dem, origin, proj, ~np.isfinite(cast.terrain_t))
        t2 = time.perf_counter()
        tc += t1 - t0
        ts += t2 - t1
    n = len(yaws)
    print(f"navcam 1024x1024: ray cast {tc / n:.2f} s, skyline truth {ts / n:.2f} s per frame")

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        simulate_acquisition(dem, Truth(x, y, 30.0), Path(tmp) / "f", frames=4, pan_start_deg=0.0, seed=1)
        tf = (time.perf_counter() - t0) / 4
        t0 = time.perf_counter()
        simulate_acquisition(dem, Truth(x, y, 30.0), Path(tmp) / "r", frames=4, pan_start_deg=0.0,
                             conditions="rocks,dust:0.5", seed=1)
        tr = (time.perf_counter() - t0) / 4
        t0 = time.perf_counter()
        simulate_acquisition(dem, Truth(x, y, 30.0), Path(tmp) / "pano", mode="panorama", seed=1)
        tp = time.perf_counter() - t0
    print(f"navcam frame, complete (cast + truth + shading + PNG): {tf:.2f} s "
          f"({'meets' if tf <= 5 else 'misses'} the 5 s target)")
    print(f"navcam frame with rocks and dust (two skylines): {tr:.2f} s")
    print(f"panorama 4096x1024, complete: {tp:.2f} s")


if __name__ == "__main__":
    print(f"load average at the start: {load_average()}", flush=True)
    main(*sys.argv[1:2])
    print(f"load average at the end: {load_average()}")
