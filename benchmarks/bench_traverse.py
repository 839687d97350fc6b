"""Traverses of 3 km with a stop every 50 m: heading error at every stop, position error after each
leg's fix, odometry alone beside it, time per heading update and per leg-end fix.

    python benchmarks/bench_traverse.py --dem ../shared/data/dem/south_glacier_20m.tif --out /tmp/tg
    (--length-m, --spacing-m, --seed; --stop-conditions K=COND as in simulate-traverse;
    --dem-sigma-m as in skyfix traverse: 0 says the map is the world, as it is here without
    --map-errors)

Simulates the traverse (skipped when OUT/traverse already holds one), runs ``skyfix traverse`` on
it, and prints the figures against the truth. The images are rendered from the map DEM itself
unless --map-errors (a world that differs from the map, see skyfix.simulate.world) or --world-dem
is given: read the figures with that in mind. Position errors count from where the truth's
terrain lies on the map (the simulated misregistration cannot be undone).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from cache import check_reuse, record


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dem", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--length-m", type=float, default=3000.0)
    ap.add_argument("--spacing-m", type=float, default=50.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--stop-conditions", action="append", default=[])
    ap.add_argument("--mode", default="frames")
    ap.add_argument("--map-errors", action="store_true")
    ap.add_argument("--dem-sigma-m", type=float, default=None,
                    help="skyfix traverse --dem-sigma-m (default: its own, 2 m)")
    ap.add_argument("--db", help="skyline database for the leg-end fixes (default: DEM only, in a "
                                 "disc around the prediction)")
    ap.add_argument("--world-dem")
    args = ap.parse_args(argv)
    out = Path(args.out)
    trav, res = out / "traverse", out / "result"
    sky = [sys.executable, "-m", "skyfix.cli.main"]
    load0 = os.getloadavg()[0]
    # what the kept traverse depends on: a rerun with other settings must not score it
    settings = dict(dem=Path(args.dem).name, length_m=args.length_m, spacing_m=args.spacing_m,
                    seed=args.seed, mode=args.mode, stop_conditions=list(args.stop_conditions),
                    map_errors=bool(args.map_errors), world_dem=args.world_dem)
    check_reuse(out / "traverse_settings.json", settings, made=(trav / "truth.jsonl").is_file())
    if not (trav / "truth.jsonl").is_file():
        record(out / "traverse_settings.json", settings)
        cmd = sky + ["simulate-traverse", args.dem, "-o", str(trav), "--length-m", str(args.length_m),
                     "--stop-spacing-m", str(args.spacing_m), "--seed", str(args.seed), "--mode", args.mode]
        for c in args.stop_conditions:
            cmd += ["--stop-conditions", c]
        cmd += ["--map-errors"] if args.map_errors else []
        cmd += ["--world-dem", args.world_dem] if args.world_dem else []
        subprocess.run(cmd, check=True)
    t0 = time.perf_counter()
    proc = subprocess.run(sky + ["traverse", str(trav), "--dem", args.dem, "-o", str(res)]
                          + (["--db", args.db] if args.db else [])
                          + ([] if args.dem_sigma_m is None else
                             ["--dem-sigma-m", str(args.dem_sigma_m)]),
                          capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        print(proc.stderr)
        raise SystemExit(proc.returncode)
    from skyfix.dem import load_dem
    from skyfix.traverse import convergence_function, read_traverse
    from skyfix.traverse.evaluation import traverse_errors

    dem = load_dem(args.dem)
    rows = [json.loads(line) for line in (res / "stops.jsonl").read_text().splitlines()]
    _, pe, he, ope, ohe = traverse_errors(rows, read_traverse(trav), convergence_function(dem.crs_wkt))
    fixes = [k for k, r in enumerate(rows) if r["update"] == "position"]
    upd = [r["update"] for r in rows]
    world = ("world = map" if not (args.map_errors or args.world_dem) else
             "world: map errors" if args.map_errors else f"world: {Path(args.world_dem).name}")
    print(f"load average {load0:.2f} -> {os.getloadavg()[0]:.2f}; {Path(args.dem).name}, "
          f"{len(rows)} stops over {args.length_m:g} m, seed {args.seed}, {args.mode}, {world}, "
          f"fixes {'with the database ' + Path(args.db).name if args.db else 'on the DEM alone'}; "
          f"traverse wall {wall:.0f} s")
    print(f"updates: {upd.count('heading')} heading, {upd.count('position')} position, "
          f"{upd.count('rejected')} rejected, {upd.count('none')} none; operator requests at "
          f"{[k for k, r in enumerate(rows) if r['operator_request']]}")
    print(f"heading error: fused <= 1 deg at {np.mean(he <= 1):.0%} of stops (median {np.median(he):.3f}, "
          f"max {he.max():.2f} deg); odometry alone at the end {ohe[-1]:.2f} deg")
    print(f"position error: fused median {np.median(pe):.2f} m, max {pe.max():.2f} m, at the end "
          f"{pe[-1]:.2f} m; odometry alone at the end {ope[-1]:.1f} m (max {ope.max():.1f} m)")
    for kind in ("heading", "position"):
        secs = [r["seconds"] for r in rows if r["attempted"] == kind]
        if secs:
            print(f"time per {kind} update: median {np.median(secs):.1f} s, max {max(secs):.1f} s "
                  f"({len(secs)} stops, detection included)")
    print("after each leg-end fix: " + ", ".join(f"stop {k}: {pe[k]:.2f} m" for k in fixes))
    print("per stop (k, update, position error m, heading error deg, odometry-only error m):")
    for k, r in enumerate(rows):
        print(f"  {k:3d} {r['update']:9s} {pe[k]:7.2f} {he[k]:6.3f} {ope[k]:7.1f}")


if __name__ == "__main__":
    main()
