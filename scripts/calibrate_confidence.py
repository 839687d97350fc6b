"""Fit the confidence model of ``skyfix.pose`` on simulated fixes and print a reliability table.

For each shared DEM: a small skyline store (``--area-m`` square, ``--spacing-m`` grid) is rendered
in memory, then rovers at random off-grid positions, headings and (for a share of the cases)
pitch/roll up to 10 deg with a zero prior are simulated with noise, outliers and partial views
(``skyfix.pose.synthetic_profile``). Each fix is "correct" when within ``--tolerance-m``.
A logistic regression on ``skyfix.pose.FEATURES`` is fitted and written to
``src/skyfix/models/confidence.json`` (with an isotonic table on top when there are enough cases).

    PYTHONPATH=src python scripts/calibrate_confidence.py --cases 40 --out src/skyfix/models/confidence.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "dem"
DEMS = ["sierra_nevada_30m.tif", "south_glacier_20m.tif"]


def simulate_cases(dem_name, n_cases, rng, area_m, spacing_m, tolerance_m):
    from skyfix.dem import load_dem
    from skyfix.match import MemoryStore
    from skyfix.pose import FEATURES, locate, synthetic_profile

    dem = load_dem(DATA / dem_name)
    x0, y0, x1, y1 = dem.bounds
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    half = area_m / 2
    xs = np.arange(cx - half, cx + half + 1e-6, spacing_m)
    ys = np.arange(cy + half, cy - half - 1e-6, -spacing_m)
    t = time.perf_counter()
    st = MemoryStore.from_dem(dem, xs, ys)
    print(f"{dem_name}: store {st.shape} rendered in {time.perf_counter() - t:.0f} s", flush=True)
    rows = []
    for i in range(n_cases):
        tx = rng.uniform(cx - half + spacing_m, cx + half - spacing_m)
        ty = rng.uniform(cy - half + spacing_m, cy + half - spacing_m)
        h = rng.uniform(0, 360)
        tilt = i % 3 == 2
        p, r = (rng.uniform(-10, 10, 2) if tilt else (0.0, 0.0))
        noise = rng.uniform(0.1, 0.3)
        cov = rng.choice([360.0, 360.0, 240.0, 150.0])
        prof = synthetic_profile(dem, tx, ty, h, p, r, noise_deg=noise, outlier_fraction=0.03,
                                 coverage_deg=cov, rng=rng)
        fix = locate(prof, db=st, dem=dem)
        err = float(np.hypot(fix.x - tx, fix.y - ty))
        herr = float(abs((fix.heading_deg - h + 180) % 360 - 180))
        rows.append({"dem": dem_name, "err_m": err, "heading_err_deg": herr, "tilt": bool(tilt),
                     "coverage_deg": cov, "noise_deg": noise, "correct": err <= tolerance_m,
                     "confidence_before": fix.confidence,
                     **{k: fix.features[k] for k in FEATURES}})
        print(f"  case {i}: err {err:6.2f} m heading {herr:5.2f} deg tilt={tilt} cov={cov:.0f} "
              f"conf={fix.confidence:.2f}", flush=True)
    return rows


def reliability(conf, correct, edges=(0, 0.5, 0.7, 0.9, 1.0001)):
    print("confidence bin   n   mean conf  share correct")
    for lo, hi in zip(edges[:-1], edges[1:]):
        k = (conf >= lo) & (conf < hi)
        if k.any():
            print(f"[{lo:.2f}, {min(hi, 1):.2f})  {k.sum():4d}   {conf[k].mean():.2f}       {correct[k].mean():.2f}")
    k = conf >= 0.9
    if k.any():
        print(f"conf >= 0.9: {k.sum()} fixes, {correct[k].mean():.0%} correct")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", type=int, default=40, help="cases per DEM")
    ap.add_argument("--area-m", type=float, default=1000.0)
    ap.add_argument("--spacing-m", type=float, default=10.0)
    ap.add_argument("--tolerance-m", type=float, default=5.0)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "src" / "skyfix" / "models" / "confidence.json"))
    ap.add_argument("--cases-json", default="calibration_cases.json")
    args = ap.parse_args()
    if not DATA.is_dir():
        raise SystemExit(f"shared DEMs not found at {DATA}")
    from sklearn.isotonic import IsotonicRegression
    from sklearn.linear_model import LogisticRegression

    from skyfix._io import write_json
    from skyfix.pose import FEATURES

    rng = np.random.default_rng(args.seed)
    rows = []
    for name in DEMS:
        rows += simulate_cases(name, args.cases, rng, args.area_m, args.spacing_m, args.tolerance_m)
    write_json(args.cases_json, rows)
    x = np.array([[r[k] for k in FEATURES] for r in rows])
    y = np.array([r["correct"] for r in rows], int)
    print(f"{len(rows)} cases, {y.mean():.0%} correct within {args.tolerance_m} m")
    model = {"features": list(FEATURES), "tolerance_m": args.tolerance_m, "n_cases": len(rows)}
    if y.min() == y.max():
        print("all cases have the same outcome: cannot fit; writing a constant model")
        lr_coef, lr_b = [0.0] * len(FEATURES), float(np.log((y.mean() + 0.02) / (1.02 - y.mean())))
    else:
        # C small: few cases, keep the fit smooth; cross-validated predictions for the table.
        lr = LogisticRegression(C=0.5, max_iter=1000).fit(x, y)
        lr_coef, lr_b = lr.coef_[0].tolist(), float(lr.intercept_[0])
        from sklearn.model_selection import cross_val_predict

        cv = cross_val_predict(LogisticRegression(C=0.5, max_iter=1000), x, y, cv=5,
                               method="predict_proba")[:, 1]
        print("reliability (5-fold cross-validated logistic):")
        reliability(cv, y)
    model.update({"coef": lr_coef, "intercept": lr_b})
    out = {"locate": model}
    write_json(args.out, out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
