"""What the coarse pass's stride costs: the database search with ``coarse_stride`` 1 and 2 on the
same queries, side by side.

Queries are rendered at random off-grid positions inside the database (``--margin-m`` from its
edge), every other one from a world that differs from the map (``skyfix.simulate.world``: the
map refined, 2 m correlated heights, a 3 m shift), with pitch and roll N(0, 3 deg), 0.1 deg
noise, and every third a 120-deg view instead of a full turn. Per query and stride: the best
candidate's grid position, its distance from the truth, the nearest candidate's distance, the
positions scored exactly, and the search's CPU seconds (one thread for BLAS and FFT). Prints how
often the two strides agree, by view width, and the median CPU time.

    python benchmarks/bench_search_recall.py --db DB [--queries 60] [--seed 123]
        [--world-seed 7] [--json OUT]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time

import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--db", required=True)
    ap.add_argument("--queries", type=int, default=60)
    ap.add_argument("--seed", type=int, default=123)
    ap.add_argument("--world-seed", type=int, default=7)
    ap.add_argument("--margin-m", type=float, default=100.0)
    ap.add_argument("--json", help="write every query's record here")
    args = ap.parse_args(argv)

    from skyfix.database import open_database
    from skyfix.dem import load_dem
    from skyfix.match import PRESETS, match_database
    from skyfix.pose import synthetic_profile
    from skyfix.simulate.world import MapErrors, world_dem

    db = open_database(args.db)
    dem = load_dem(db.attrs["dem"]["source"])
    world = world_dem(dem, MapErrors(), seed=args.world_seed)
    rng = np.random.default_rng(args.seed)
    xs, ys = np.asarray(db.x_coords), np.asarray(db.y_coords)
    m = args.margin_m
    load0 = os.getloadavg()[0]
    recs = []
    for i in range(args.queries):
        x = rng.uniform(xs.min() + m, xs.max() - m)
        y = rng.uniform(ys.min() + m, ys.max() - m)
        view = 120.0 if i % 3 == 2 else 360.0
        heading, pitch, roll = rng.uniform(0, 360), rng.normal(0, 3), rng.normal(0, 3)
        prof = synthetic_profile(world if i % 2 else dem, x, y, heading, pitch, roll,
                                 camera_height_m=db.camera_height_m, n_bins=db.azimuth_bins,
                                 noise_deg=0.1, coverage_deg=view, rng=int(rng.integers(1 << 30)))
        rec = {"query": i, "map_errors": bool(i % 2), "view_deg": view}
        for stride in (1, 2):
            cfg = dataclasses.replace(PRESETS["fast"], coarse_stride=stride, stride_min_coverage=0.0,
                                      workers=1)
            c0 = time.process_time()
            res = match_database(db, prof.elevation_deg, cfg)
            cpu = time.process_time() - c0
            d = [float(np.hypot(c.x - x, c.y - y)) for c in res.candidates]
            top = res.candidates[0]
            rec[f"stride{stride}"] = {"row": top.row, "col": top.col, "score": top.score,
                                      "top_m": d[0], "nearest_m": min(d), "cpu_s": cpu,
                                      "scored_exactly": res.n_scored_exact}
        recs.append(rec)
        a, b = rec["stride1"], rec["stride2"]
        print(f"  {i:3d} {'map errors' if rec['map_errors'] else 'map = world'} {view:3.0f} deg: "
              f"stride 1 ({a['row']}, {a['col']}) {a['top_m']:.1f} m, stride 2 ({b['row']}, {b['col']}) "
              f"{b['top_m']:.1f} m; CPU {a['cpu_s']:.2f} / {b['cpu_s']:.2f} s", flush=True)
    print(f"load average {load0:.2f} -> {os.getloadavg()[0]:.2f}; {len(recs)} queries, 1 BLAS/FFT thread")
    for view in (360.0, 120.0):
        sub = [r for r in recs if r["view_deg"] == view]
        if not sub:
            continue
        same = sum((r["stride1"]["row"], r["stride1"]["col"]) == (r["stride2"]["row"], r["stride2"]["col"])
                   for r in sub)
        near = {s: sum(r[f"stride{s}"]["top_m"] < 15.0 for r in sub) for s in (1, 2)}
        lost = sum(r["stride1"]["top_m"] < 15.0 <= r["stride2"]["top_m"] for r in sub)
        print(f"{view:.0f}-deg views: same best position {same} of {len(sub)}; best within 15 m of "
              f"the truth: stride 1 {near[1]}, stride 2 {near[2]}; lost by stride 2: {lost}")
    for s in (1, 2):
        print(f"stride {s}: search CPU median {np.median([r[f'stride{s}']['cpu_s'] for r in recs]):.2f} s, "
              f"scored exactly median {np.median([r[f'stride{s}']['scored_exactly'] for r in recs]):,.0f}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(recs, fh, indent=1)


if __name__ == "__main__":
    main()
