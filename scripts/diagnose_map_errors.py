"""Which skyline bins pull a fix away when the map is not the world (issue: the map is not the
world, "diagnose each DEMERR miss first").

    python scripts/diagnose_map_errors.py --dem MAP_DEM CASE_DIR [CASE_DIR ...] [--fixes results.csv]

For each simulated case (``simulate-set`` / ``evaluate`` case folders whose world differs from
the map), at the best position the map allows (the truth plus the simulated map offset), with the
simulator's exact skylines (no detection error):

- the attitude is fitted there and the residual profile taken (what the map's errors leave);
- the position Jacobian of the rendered horizon, by central differences (+-0.5 m);
- the Gauss-Newton step the residuals ask for, -(J'J)^-1 J' r, whole and split by the distance of
  the terrain that makes each bin's skyline (near < 300 m, mid 300 m - 2 km, far > 2 km): the
  share of the pull each band exerts, and the pull with the camera's height fitted too.

The step is where a least-squares fit on this profile would go from the right answer: its length
is the error the map's errors cause before any search, weighting or robust loss.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
from pathlib import Path

import numpy as np

BANDS = (("near", 0.0, 300.0), ("mid", 300.0, 2000.0), ("far", 2000.0, np.inf))


def case_pull(dem, case_dir: Path, *, render_bins=1440, h=0.5, dem_sigma_m=2.0, noise_deg=0.05):
    from skyfix.evaluate import map_offset_of, truth_skylines
    from skyfix.formats import load_acquisition, load_truth
    from skyfix.horizon import render_horizons
    from skyfix.pose.attitude import fit_attitude
    from skyfix.pose.forward import body_profile, residual_profile
    from skyfix.pose.scoring import body_distances
    from skyfix.profile import acquisition_profile

    truth = load_truth(case_dir)
    acq = load_acquisition(case_dir)
    prof = acquisition_profile(acq, skylines=truth_skylines(acq))
    q = np.asarray(prof.elevation_deg, float)
    ox, oy = map_offset_of(case_dir)
    x, y = truth.x + ox, truth.y + oy
    pts = [(x, y), (x + h, y), (x - h, y), (x, y + h), (x, y - h)]
    hb = render_horizons(dem, [p[0] for p in pts], [p[1] for p in pts], azimuth_bins=render_bins,
                         camera_height_m=acq.camera_height_m)
    kw = dict(prior_pitch_deg=acq.prior_pitch_deg, prior_roll_deg=acq.prior_roll_deg)
    att = fit_attitude(q, hb.elevation_deg[0], truth.yaw_deg, truth.pitch_deg, truth.roll_deg, **kw)
    r = residual_profile(q, hb.elevation_deg[0], att, **kw)
    n = q.size

    def body(el):
        return body_profile(el, att.yaw_deg, att.pitch_deg, att.roll_deg, n_bins=n, **kw)

    jx = (body(hb.elevation_deg[1]) - body(hb.elevation_deg[2])) / (2 * h)
    jy = (body(hb.elevation_deg[3]) - body(hb.elevation_deg[4])) / (2 * h)
    d = body_distances(hb.skyline_distance_m[0], att.yaw_deg, n)
    el = body(hb.elevation_deg[0])
    jz = -np.degrees(np.cos(np.radians(el)) ** 2 / np.maximum(d, 1.0))  # deg per m of camera height
    ok = np.isfinite(r) & np.isfinite(jx) & np.isfinite(jy) & np.isfinite(d)
    r = r - np.median(r[ok])
    one = np.ones(n)
    out = {"case": case_dir.name, "bins": int(ok.sum()), "rms_deg": float(np.sqrt(np.mean(r[ok] ** 2)))}
    # the DEM-error weighting of PoseConfig.dem_sigma_m: a bin's elevation error from a height
    # error sigma_h at its skyline's distance, beside the profile's own noise
    sig = np.degrees(np.arctan(dem_sigma_m / np.maximum(d, 1.0)))
    wgt = 1.0 / (noise_deg ** 2 + sig ** 2)
    for label, cols, w in (("xy", (jx, jy, one), None), ("xyz", (jx, jy, one, jz), None),
                           ("xyz_weighted", (jx, jy, one, jz), wgt),
                           ("xyz_near", (jx, jy, one, jz), np.minimum(1.0, (d / (10 * dem.cell_m)) ** 2)),
                           ("xyz_floor", (jx, jy, one, jz), 1.0 / (0.08 ** 2 + sig ** 2))):
        J = np.stack([c[ok] for c in cols], axis=1)
        W = np.ones(ok.sum()) if w is None else w[ok]
        N = J.T @ (J * W[:, None])
        step = -np.linalg.solve(N, (J * W[:, None]).T @ r[ok])
        out[f"pull_{label}_m"] = float(math.hypot(step[0], step[1]))
        if label == "xyz":
            out["camera_dz_m"] = float(step[3])
        elif label == "xy":
            for band, lo, hi in BANDS:
                sel = (d[ok] >= lo) & (d[ok] < hi)
                part = -np.linalg.solve(N, J[sel].T @ r[ok][sel])
                out[f"{band}_bins"] = int(sel.sum())
                out[f"{band}_pull_m"] = float(math.hypot(part[0], part[1]))
                out[f"{band}_rms_deg"] = float(np.sqrt(np.mean(r[ok][sel] ** 2))) if sel.any() else float("nan")
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dem", required=True, help="the map DEM (the database's)")
    ap.add_argument("cases", nargs="+")
    ap.add_argument("--fixes", help="an evaluate results.csv, to print each case's error beside")
    args = ap.parse_args(argv)
    from skyfix.dem import load_dem

    dem = load_dem(args.dem)
    errs = {}
    if args.fixes:
        with open(args.fixes) as f:
            for row in csv.DictReader(f):
                errs[(row["set"], row["case"])] = row
    rows = []
    for c in map(Path, args.cases):
        o = case_pull(dem, c)
        e = errs.get((c.parent.name, c.name))
        o["fix_error_map_m"] = float(e["position_error_map_m"]) if e else float("nan")
        o["confidence"] = float(e["confidence"]) if e else float("nan")
        rows.append(o)
        print(json.dumps({k: (round(v, 3) if isinstance(v, float) else v) for k, v in o.items()}), flush=True)
    a = {k: np.array([r[k] for r in rows], float) for k in rows[0] if k != "case"}
    print(f"{len(rows)} cases: pull (least squares from the right answer) median "
          f"{np.median(a['pull_xy_m']):.2f} m; with the camera height fitted {np.median(a['pull_xyz_m']):.2f} m, "
          f"and weighted by the DEM error {np.median(a['pull_xyz_weighted_m']):.2f} m; "
          f"by band (median): near {np.nanmedian(a['near_pull_m']):.2f}, mid {np.nanmedian(a['mid_pull_m']):.2f}, "
          f"far {np.nanmedian(a['far_pull_m']):.2f} m; residual rms near/mid/far "
          f"{np.nanmedian(a['near_rms_deg']):.3f}/{np.nanmedian(a['mid_rms_deg']):.3f}/"
          f"{np.nanmedian(a['far_rms_deg']):.3f} deg")


if __name__ == "__main__":
    main()
