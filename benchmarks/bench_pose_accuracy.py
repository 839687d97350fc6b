"""Pose accuracy on simulated off-grid cases, per scenario and DEM, with the reliability curve.

Prints (never asserts) tables like the source study's:

- scenario 1 (``locate`` over a skyline store): share within 5 m for REF-like cases (level,
  noise 0.05-0.4 deg, 0-3 % outliers, 120-360 deg views), LREL cases (pitch/roll up to 10 deg,
  prior 0) and low-relief positions; targets >= 95 % (REF) and >= 90 % (LREL);
- scenario 2 (DEM only, 40 x 40 m prior, truth drifted up to 20 m): share within 1 m, target >= 90 %;
- scenario 3 (``estimate_heading`` 0/5/10/20 m off): share of heading errors <= 1 deg with
  position errors up to 10 m (target >= 95 %) and <= 2 deg at 20 m;
- the reliability of the shipped confidence (``skyfix/models/confidence.json``).

Cases come from ``scripts/calibrate_confidence.py`` (same simulator), with another seed by
default: the reliability table is out of sample by seed only, not by site (the default DEMs and
area are those the shipped confidence was fitted on; ``--dems`` another DEM for a held-out
site). The scenario-1 store is an in-memory grid
(``--area-m``, ``--spacing-m``) rendered from each DEM unless ``--store DEMNAME=ZARR`` names a
built one; ``--db /work/data/sierra_7km_5m.zarr`` runs scenario 1 on the real 7 x 7 km / 5 m store
(Sierra) instead. ``--from-cases FILE`` prints the tables from an existing case file only.

    PYTHONPATH=src python benchmarks/bench_pose_accuracy.py --n-locate 12 --n-prior 8 --n-heading 24
    PYTHONPATH=src python benchmarks/bench_pose_accuracy.py --db /work/data/sierra_7km_5m.zarr \\
        --dems sierra_nevada_30m.tif --n-locate 20 --n-prior 0 --n-heading 0
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import time
import zlib
from pathlib import Path

import numpy as np

from installs import load_average

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("calibrate_confidence",
                                              ROOT / "scripts" / "calibrate_confidence.py")
cal = importlib.util.module_from_spec(spec)
spec.loader.exec_module(cal)


def _row_fmt(label, dem, errs, ok, unit):
    e = np.asarray(errs, float)
    if e.size == 0:
        return None
    return (f"  {label:26s} {dem:24s} {e.size:4d}   {np.mean(ok):6.0%}   "
            f"{np.median(e):7.2f} {np.percentile(e, 95):8.2f} {unit}")


def tables(rows):
    hdr = "  {:26s} {:24s} {:>4s}   {:>6s}   {:>7s} {:>8s}".format("subset", "DEM", "n", "ok",
                                                                     "median", "p95")
    dems = sorted({r["dem"] for r in rows})
    s1 = [r for r in rows if r["scenario"] == "locate"]
    if s1:
        print("\nScenario 1: database search, ok = position error <= 5 m")
        print(hdr)
        for dem in dems:
            for kind, label in (("ref", "REF (level)"), ("lrel", "LREL (10 deg, prior 0)"),
                                ("low_relief", "low relief (level)")):
                rr = [r for r in s1 if r["dem"] == dem and r["kind"] == kind]
                line = _row_fmt(label, dem, [r["err_m"] for r in rr], [r["err_m"] <= 5 for r in rr], "m")
                if line:
                    print(line)
            rr = [r for r in s1 if r["dem"] == dem]
            line = _row_fmt("heading error, all", dem, [r["heading_err_deg"] for r in rr],
                            [r["heading_err_deg"] <= 1 for r in rr], "deg")
            if line:
                print(line)
            lr = [r for r in rr if r["kind"] == "lrel"]
            if lr:
                att = [max(abs(r["pitch_err_deg"]), abs(r["roll_err_deg"])) for r in lr]
                print(_row_fmt("LREL pitch/roll error", dem, att, [a <= 1 for a in att], "deg"))
    s2 = [r for r in rows if r["scenario"] == "locate_prior"]
    if s2:
        print("\nScenario 2: DEM only, 40 x 40 m prior, ok = position error <= 1 m")
        print(hdr)
        for dem in dems:
            for kinds, label in ((("ref", "low_relief"), "level"), (("lrel",), "LREL (10 deg, prior 0)")):
                rr = [r for r in s2 if r["dem"] == dem and r["kind"] in kinds]
                line = _row_fmt(label, dem, [r["err_m"] for r in rr], [r["err_m"] <= 1 for r in rr], "m")
                if line:
                    print(line)
    s3 = [r for r in rows if r["scenario"] == "heading"]
    if s3:
        print("\nScenario 3: heading from a rough position, ok = heading error <= 1 deg (<= 2 deg at 20 m)")
        print(hdr)
        for dem in dems:
            for pe in (0.0, 5.0, 10.0, 20.0):
                rr = [r for r in s3 if r["dem"] == dem and r["position_error_m"] == pe]
                tol = 2.0 if pe > 10 else 1.0
                line = _row_fmt(f"position off {pe:.0f} m", dem, [r["err"] for r in rr],
                                [r["err"] <= tol for r in rr], "deg")
                if line:
                    print(line)
    print("\nSigma check (median of error / reported 1-sigma; ~0.8-1.2 when the sigma is honest):")
    for key in ("locate", "locate_prior", "heading"):
        rr = [r for r in rows if r["scenario"] == key and r["correct"] and r.get("sigma")]
        if rr:
            z = np.array([r["err"] / r["sigma"] for r in rr])
            print(f"  {key:13s} n={len(rr):3d}  median |err|/sigma {np.median(z):.2f}  "
                  f"p90 {np.percentile(z, 90):.2f}")
    print("\nReliability of the shipped confidence (each scenario judged at its own tolerance; out of "
          "sample by seed, not by site where the DEMs are the ones it was fitted on):")
    for key in ("locate", "locate_prior", "heading"):
        rr = [r for r in rows if r["scenario"] == key]
        if rr:
            print(f" {key}: {len(rr)} fixes, {np.mean([r['correct'] for r in rr]):.0%} correct")
            cal.reliability(np.array([r["confidence"] for r in rr]), np.array([r["correct"] for r in rr]))
    if rows:
        print(" all scenarios:")
        cal.reliability(np.array([r["confidence"] for r in rows]), np.array([r["correct"] for r in rows]))


def simulate(args):
    from skyfix.dem import load_dem
    from skyfix.match import MemoryStore

    stores = dict(s.split("=", 1) for s in args.store)
    rows = []
    for name in args.dems:
        dem = load_dem(cal.DATA / name)
        for key, n in (("locate", args.n_locate), ("locate_prior", args.n_prior), ("heading", args.n_heading)):
            if n <= 0:
                continue
            store = None
            if key == "locate":
                if args.db:
                    from skyfix.database import open_database

                    store = open_database(args.db, allow_incomplete=args.allow_incomplete)
                elif name in stores:
                    from skyfix.database import open_database

                    store = open_database(stores[name])
                else:
                    x0, y0, x1, y1 = cal._area(dem, None, args.area_m / 2)
                    t = time.perf_counter()
                    store = MemoryStore.from_dem(dem, np.arange(x0, x1 + 1e-6, args.spacing_m),
                                                 np.arange(y1, y0 - 1e-6, -args.spacing_m))
                    print(f"{name}: in-memory store {store.shape} at {args.spacing_m} m rendered in "
                          f"{time.perf_counter() - t:.0f} s", flush=True)
            area = cal._area(dem, store) if store is not None else cal._area(dem, None, args.area_m / 2)
            rng = np.random.default_rng([args.seed, zlib.crc32(name.encode()), list(cal.TOLERANCE).index(key)])
            for i in range(n):
                case = cal.draw_case(dem, rng, area, i)
                row = cal.run_case(key, dem, case, rng, store)
                row.update(dem=name, index=i)
                rows.append(row)
                print(f"  {key:12s} {name:22s} {i:3d} {case['kind']:10s} err {row['err']:7.2f} "
                      f"conf {row['confidence']:.2f} {row['seconds']:5.1f} s", flush=True)
                if args.save_cases:
                    with open(args.save_cases, "a") as f:
                        f.write(json.dumps(row) + "\n")
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dems", nargs="+", default=["sierra_nevada_30m.tif", "south_glacier_20m.tif"])
    ap.add_argument("--n-locate", type=int, default=12, help="scenario-1 cases per DEM")
    ap.add_argument("--n-prior", type=int, default=8, help="scenario-2 cases per DEM")
    ap.add_argument("--n-heading", type=int, default=24, help="scenario-3 cases per DEM")
    ap.add_argument("--area-m", type=float, default=600.0, help="[m] side of the in-memory store")
    ap.add_argument("--spacing-m", type=float, default=5.0, help="[m] in-memory store spacing")
    ap.add_argument("--store", nargs="*", default=[], metavar="DEMNAME=ZARR",
                    help="built stores to use for scenario 1, per DEM file name")
    ap.add_argument("--db", help="one real store for scenario 1 (e.g. /work/data/sierra_7km_5m.zarr); "
                                 "give --dems its DEM only")
    ap.add_argument("--allow-incomplete", action="store_true")
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--save-cases", help="append each case to this JSON-lines file")
    ap.add_argument("--from-cases", nargs="*", help="print the tables from these case files only")
    args = ap.parse_args()
    if args.from_cases:
        rows = [json.loads(ln) for p in args.from_cases for ln in Path(p).read_text().splitlines() if ln.strip()]
    else:
        if not cal.DATA.is_dir():
            raise SystemExit(f"shared DEMs not found at {cal.DATA}")
        t = time.perf_counter()
        rows = simulate(args)
        print(f"{len(rows)} cases in {time.perf_counter() - t:.0f} s (shared, loaded CPU: timings noisy)")
    tables(rows)


if __name__ == "__main__":
    print(f"load average at the start: {load_average()}", flush=True)
    main()
    print(f"load average at the end: {load_average()}")
