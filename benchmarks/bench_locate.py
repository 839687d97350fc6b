"""Full-database search: wall time and peak RSS of the locate process (target <= 10 s, 256 MB).

With the real store (``/work/data/sierra_7km_5m.zarr`` and ``skyfix.database``) this runs
``skyfix locate --profile P --db DB`` under ``/usr/bin/time -v`` (database level only, no DEM
refinement unless ``--dem``). Without it, a stand-in store of the same size (1401 x 1401
positions x 360 bins, int16, streamed in 128 x 128 blocks made by tiling 4096 profiles rendered
from sierra_nevada_30m) is searched by ``match_database`` in a subprocess: it measures the
matcher's compute and memory but not zarr decompression.

    PYTHONPATH=src python benchmarks/bench_locate.py [--db PATH] [--dem PATH] [--n 1401] [--preset fast]
Timings are noisy on a shared 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEM = ROOT.parent / "shared" / "data" / "dem" / "sierra_nevada_30m.tif"

CHILD = r"""
import json, resource, sys, time
t_start = time.perf_counter()
import numpy as np
from skyfix.match import Block, MatchConfig, PRESETS, match_database
n, preset = int(sys.argv[1]), sys.argv[2]
pool = np.load(sys.argv[3])
query = np.load(sys.argv[4])
truth = int(sys.argv[5])

class Tiled:
    shape = (n, n); azimuth_bins = 360; spacing_m = 5.0; scale_deg = 0.01; missing = -32768
    x_coords = np.arange(n) * 5.0; y_coords = (n - 1 - np.arange(n)) * 5.0
    def iter_blocks(self, b=128):
        k = 0
        for r0 in range(0, n, b):
            for c0 in range(0, n, b):
                r1, c1 = min(n, r0 + b), min(n, c0 + b)
                m = (r1 - r0) * (c1 - c0)
                idx = (np.arange(m) * 7919 + k) % (pool.shape[0] - 1)  # the truth's profile only once
                k += m
                el = pool[idx]
                rr, cc = np.divmod(np.arange(m), c1 - c0)
                rr += r0; cc += c0
                hit = (rr * n + cc) == truth
                if hit.any():
                    el = el.copy(); el[hit] = pool[-1]
                yield Block(r0, c0, r1 - r0, c1 - c0, self.x_coords[cc], self.y_coords[rr], el)

t0 = time.perf_counter()
res = match_database(Tiled(), query, PRESETS[preset])
wall = time.perf_counter() - t0
c = res.candidates[0]
tr, tc = divmod(truth, n)
print(json.dumps({"search_s": wall, "process_s": time.perf_counter() - t_start,
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "positions": res.n_positions, "scored_exact": res.n_scored_exact,
                  "timing": res.timing, "top1_is_truth": (c.row, c.col) == (tr, tc),
                  "heading_deg": c.heading_deg}))
"""


def stand_in(n, preset):
    import numpy as np

    from skyfix.dem import load_dem
    from skyfix.horizon import render_horizons

    dem = load_dem(DEM)
    x0, y0, x1, y1 = dem.bounds
    rng = np.random.default_rng(0)
    xs = rng.uniform(x0 + 3000, x1 - 3000, 4096)
    ys = rng.uniform(y0 + 3000, y1 - 3000, 4096)
    el = render_horizons(dem, xs, ys).elevation_deg
    pool = np.round(np.nan_to_num(el) / 0.01).astype(np.int16)
    q = pool[-1] * 0.01
    q = np.roll(q, -123) + rng.normal(0, 0.2, 360)  # heading 123 deg, noise
    q[200:300] = np.nan
    truth = (n // 2) * n + n // 3
    with tempfile.TemporaryDirectory() as d:
        np.save(f"{d}/pool.npy", pool)
        np.save(f"{d}/q.npy", q)
        env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
        out = subprocess.run([sys.executable, "-c", CHILD, str(n), preset, f"{d}/pool.npy",
                              f"{d}/q.npy", str(truth)], capture_output=True, text=True, env=env)
    if out.returncode:
        raise SystemExit(out.stderr)
    r = json.loads(out.stdout.strip().splitlines()[-1])
    print(f"stand-in store {n} x {n} = {r['positions']:,} positions x 360 bins (int16 blocks, "
          f"no zarr), preset {preset}")
    print(f"  search wall {r['search_s']:.2f} s, whole process {r['process_s']:.2f} s, "
          f"peak RSS {r['peak_rss_mb']:.0f} MB")
    t = r["timing"]
    print(f"  where: block supply {t['read_s']:.2f} s, coarse pass {t['coarse_s']:.2f} s, "
          f"exact pass {t['exact_s']:.2f} s on {r['scored_exact']:,} positions, nms {t['nms_s']:.2f} s")
    print(f"  top-1 is the true position: {r['top1_is_truth']} (heading {r['heading_deg']:.2f}, truth 123)")


def real(db, dem, profile, preset):
    cmd = ["/usr/bin/time", "-v", sys.executable, "-m", "skyfix.cli.main", "locate", "--profile",
           profile, "--db", db, "--preset", preset] + (["--dem", dem] if dem else [])
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    out = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = re.search(r"Elapsed \(wall clock\) time.*: (.*)", out.stderr)
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", out.stderr)
    print(out.stdout[-2000:])
    print(f"skyfix locate --db {db}: exit {out.returncode}, wall {wall and wall.group(1)}, "
          f"peak RSS {int(rss.group(1)) / 1024 if rss else float('nan'):.0f} MB")
    if out.returncode:
        print(out.stderr[-3000:])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--db", default="/work/data/sierra_7km_5m.zarr")
    ap.add_argument("--dem")
    ap.add_argument("--profile", help="body-frame profile JSON for the real store")
    ap.add_argument("--n", type=int, default=1401)
    ap.add_argument("--preset", default="fast")
    args = ap.parse_args()
    try:
        import skyfix.database  # noqa: F401
        have_db = Path(args.db).exists() and args.profile
    except ImportError:
        have_db = False
    if have_db:
        real(args.db, args.dem, args.profile, args.preset)
    else:
        print(f"(no database module/store/--profile: using the stand-in store)")
        stand_in(args.n, args.preset)


if __name__ == "__main__":
    main()
