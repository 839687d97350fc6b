"""What the coarse pass's stride and the coarse index cost: the database search with
``coarse_stride`` 1 and 2 over every block, and from the store's coarse index (stride 2, the best
survivors of the whole store, only their blocks decoded), on the same queries, side by side.

Queries are rendered at random off-grid positions inside the database (``--margin-m`` from its
edge), every other one from a world that differs from the map (``skyfix.simulate.world``: the
map refined, 2 m correlated heights, a 3 m shift), with pitch and roll N(0, 3 deg), 0.1 deg
noise, and every third a 120-deg view instead of a full turn (``--views``: the widths in turn). Per query and stride: the best
candidate's grid position, its distance from the truth, the nearest candidate's distance, the
runner-up basin's score, the positions scored exactly, the blocks decoded and the search's CPU
seconds (one thread for BLAS and FFT). Prints how often each agrees with stride 1 over every
block, by view width, and the median CPU time. (Here the 120-deg views take stride 2 and the
index too; ``skyfix locate`` searches views under ``stride_min_coverage`` with stride 1.)

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


#: the searches compared: (coarse stride, read the store's coarse index)
VARIANTS = {"stride1": (1, False), "stride2": (2, False), "index": (2, True)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--db", required=True)
    ap.add_argument("--queries", type=int, default=60)
    ap.add_argument("--seed", type=int, default=123)
    ap.add_argument("--world-seed", type=int, default=7)
    ap.add_argument("--margin-m", type=float, default=100.0)
    ap.add_argument("--json", help="write every query's record here")
    ap.add_argument("--views", default="360,360,120",
                    help="view widths [deg] the queries take in turn (narrow views alone: 250,180,120)")
    args = ap.parse_args(argv)

    from skyfix.database import open_database
    from skyfix.dem import load_dem
    from skyfix.match import PRESETS, match_database
    from skyfix.pose import synthetic_profile
    from skyfix.simulate.world import MapErrors, world_dem

    views = [float(v) for v in args.views.split(",")]
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
        view = views[i % len(views)]
        heading, pitch, roll = rng.uniform(0, 360), rng.normal(0, 3), rng.normal(0, 3)
        prof = synthetic_profile(world if i % 2 else dem, x, y, heading, pitch, roll,
                                 camera_height_m=db.camera_height_m, n_bins=db.azimuth_bins,
                                 noise_deg=0.1, coverage_deg=view, rng=int(rng.integers(1 << 30)))
        rec = {"query": i, "map_errors": bool(i % 2), "view_deg": view}
        for name, (stride, index) in VARIANTS.items():
            cfg = dataclasses.replace(PRESETS["fast"], coarse_stride=stride, stride_min_coverage=0.0,
                                      workers=1, coarse_index=index)
            c0 = time.process_time()
            res = match_database(db, prof.elevation_deg, cfg)
            cpu = time.process_time() - c0
            d = [float(np.hypot(c.x - x, c.y - y)) for c in res.candidates]
            top = res.candidates[0]
            rec[name] = {"row": top.row, "col": top.col, "score": top.score,
                         "second": res.candidates[1].score if len(res.candidates) > 1 else None,
                         "top_m": d[0], "nearest_m": min(d), "cpu_s": cpu,
                         "scored_exactly": res.n_scored_exact,
                         "blocks_read": res.timing.get("blocks_read", db.n_blocks)}
        recs.append(rec)
        print(f"  {i:3d} {'map errors' if rec['map_errors'] else 'map = world'} {view:3.0f} deg: "
              + "; ".join(f"{k} ({r['row']}, {r['col']}) {r['top_m']:.1f} m, CPU {r['cpu_s']:.2f} s"
                          for k, r in ((k, rec[k]) for k in VARIANTS)), flush=True)
    print(f"load average {load0:.2f} -> {os.getloadavg()[0]:.2f}; {len(recs)} queries, 1 BLAS/FFT thread"
          f"{'' if db.has_coarse_index else '; the store has no coarse index: index = stride2'}")
    ref = "stride1"
    for view in dict.fromkeys(views):
        sub = [r for r in recs if r["view_deg"] == view]
        if not sub:
            continue
        near = {k: sum(r[k]["top_m"] < 15.0 for r in sub) for k in VARIANTS}
        print(f"{view:.0f}-deg views ({len(sub)}), best within 15 m of the truth: "
              + ", ".join(f"{k} {near[k]}" for k in VARIANTS))
        for k in VARIANTS:
            if k == ref:
                continue
            same = sum((r[ref]["row"], r[ref]["col"]) == (r[k]["row"], r[k]["col"]) for r in sub)
            lost = sum(r[ref]["top_m"] < 15.0 <= r[k]["top_m"] for r in sub)
            lower2 = sum(r[k]["second"] is not None and r[ref]["second"] is not None
                         and r[k]["second"] < r[ref]["second"] - 1e-6 for r in sub)
            print(f"  {k} against {ref}: same best position {same} of {len(sub)}, lost {lost}; "
                  f"runner-up basin scored lower (a closer rival found) in {lower2}")
    for k in VARIANTS:
        print(f"{k}: search CPU median {np.median([r[k]['cpu_s'] for r in recs]):.2f} s, scored "
              f"exactly median {np.median([r[k]['scored_exactly'] for r in recs]):,.0f}, blocks "
              f"decoded median {np.median([r[k]['blocks_read'] for r in recs]):.0f} of {db.n_blocks}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(recs, fh, indent=1)


if __name__ == "__main__":
    main()
