"""Profile accuracy on simulated acquisitions vs the horizon renderer's truth at the true pose.

For each case (a random position on a real DEM, random heading and attitude):
  frames360 : navcam, 12 frames over 360 deg; partial : wide camera, 5 frames over 242 deg;
  panorama  : an equirectangular body panorama.
It prints, per method, the median and 95th percentile of |profile - truth| [deg] over observed bins
(truth = ``render_horizons`` at the true (x, y), rotated into the body frame: body[az] = world[az +
yaw]), measured both with the simulator's exact skylines (projection error alone) and with the
``dp`` detector (end to end); the pan recovery after injecting +-1 deg mast pan errors into
acquisition.json; and how often stitching fails.

    PYTHONPATH=src python benchmarks/bench_profile.py --cases 3 --out /tmp/bench_profile
"""

from __future__ import annotations

import argparse
import json
import logging
import shutil
import time
from pathlib import Path

import numpy as np

from installs import load_average
from skyfix.dem import load_dem
from skyfix.errors import SkyfixError
from skyfix.formats import Skyline, Truth, load_acquisition, load_truth, read_skyline_json
from skyfix.horizon import render_horizons
from skyfix.profile import acquisition_profile, panorama_profile, profile_from_skylines

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def body_truth(world: np.ndarray, yaw: float) -> np.ndarray:
    n = world.size
    az = (np.arange(n) * 360.0 / n + yaw) % 360.0
    return np.interp(az, np.arange(n + 1) * 360.0 / n, np.r_[world, world[0]])


def err_stats(prof, body):
    e = np.abs(prof.elevation_deg - body)
    e = e[np.isfinite(e)]
    if e.size == 0:
        return {"n": 0, "median": np.nan, "p95": np.nan}
    return {"n": int(e.size), "median": float(np.median(e)), "p95": float(np.percentile(e, 95))}


def truth_skylines(acq):
    return [read_skyline_json(acq.root / (f.image[:-4] + ".skyline.json")) for f in acq.frames]


def pick_positions(dem, n, rng, max_el=15.0):
    """Random inner positions whose rendered skyline stays mostly inside a navcam's view."""
    xmin, ymin, xmax, ymax = dem.bounds
    out = []
    tries = 0
    while len(out) < n and tries < 200:
        tries += 1
        x = rng.uniform(xmin + 0.3 * (xmax - xmin), xmax - 0.3 * (xmax - xmin))
        y = rng.uniform(ymin + 0.3 * (ymax - ymin), ymax - 0.3 * (ymax - ymin))
        h = render_horizons(dem, [x], [y], azimuth_bins=360).elevation_deg[0]
        if np.nanpercentile(h, 90) < max_el and np.nanmin(h) > -10:
            out.append((x, y, h.astype(float)))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dem", default=str(DATA / "dem" / "sierra_nevada_30m.tif"))
    ap.add_argument("--cases", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="/tmp/bench_profile")
    ap.add_argument("--kinds", default="frames360,partial,panorama")
    ap.add_argument("--no-detect", action="store_true", help="truth skylines only")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    from skyfix.simulate import simulate_acquisition

    dem = load_dem(args.dem)
    rng = np.random.default_rng(args.seed)
    out = Path(args.out)
    rows = []
    pan_rec = []
    stitch_runs = stitch_fail = 0
    kinds = args.kinds.split(",")
    for c, (x, y, world) in enumerate(pick_positions(dem, args.cases, rng)):
        yaw = float(rng.uniform(0, 360))
        pitch, roll = (float(v) for v in rng.uniform(-5, 5, 2))
        truth = Truth(x, y, yaw, pitch, roll)
        body = body_truth(world, yaw)
        for kind in kinds:
            folder = out / f"case{c}_{kind}"
            t0 = time.perf_counter()
            if kind == "frames360":
                simulate_acquisition(dem, truth, folder, camera="navcam", seed=c, overwrite=True)
            elif kind == "partial":
                simulate_acquisition(dem, truth, folder, camera="wide", frames=5, pan_step_deg=38.0,
                                     seed=c, overwrite=True)
            else:
                simulate_acquisition(dem, truth, folder, mode="panorama", seed=c, overwrite=True)
            t_sim = time.perf_counter() - t0
            acq = load_acquisition(folder)
            assert load_truth(folder).yaw_deg == yaw
            res = {"case": c, "kind": kind, "sim_s": round(t_sim, 1)}
            if kind == "panorama":
                sky = read_skyline_json(folder / "pano.skyline.json")
                p = panorama_profile(acq.panorama, sky, pitch_deg=acq.prior_pitch_deg, roll_deg=acq.prior_roll_deg)
                res["truth_sky"] = err_stats(p, body)
            else:
                p = profile_from_skylines(acq, truth_skylines(acq))
                res["truth_sky"] = err_stats(p, body)
            if not args.no_detect:
                t0 = time.perf_counter()
                try:
                    p = acquisition_profile(acq, method="project")
                    res["detect"] = err_stats(p, body)
                    res["detect"]["frames_dropped"] = p.meta.get("frames_dropped", 0)
                except SkyfixError as e:
                    res["detect"] = {"error": str(e)}
                res["detect_s"] = round(time.perf_counter() - t0, 1)
            if kind != "panorama":
                stitch_runs += 1
                res["stitch"] = run_stitch(acq, body, detect=not args.no_detect)
                stitch_fail += "error" in res["stitch"]
                pan_rec.append(pan_recovery(folder, out / f"case{c}_{kind}_panerr", body, c))
            rows.append(res)
            print(json.dumps(res))
    print("\n=== summary (errors in deg; median / p95 over observed bins, pooled medians over cases)")
    for kind in kinds:
        sel = [r for r in rows if r["kind"] == kind]
        for key in ("truth_sky", "detect"):
            v = [r[key] for r in sel if key in r and "median" in r[key] and r[key]["n"]]
            if v:
                print(f"{kind:10s} project {key:9s}: median {np.median([a['median'] for a in v]):.4f}  "
                      f"p95 {np.median([a['p95'] for a in v]):.4f}  worst p95 {max(a['p95'] for a in v):.4f}  "
                      f"cases {len(v)}/{len(sel)}")
        for key in ("truth_overlay", "detect"):
            v = [r["stitch"][key] for r in sel if "stitch" in r and key in r["stitch"] and r["stitch"][key].get("n")]
            if v:
                print(f"{kind:10s} stitch  {key:9s}: median {np.median([a['median'] for a in v]):.4f}  "
                      f"p95 {np.median([a['p95'] for a in v]):.4f}  worst p95 {max(a['p95'] for a in v):.4f}  "
                      f"cases {len(v)}/{len(sel)}")
    print(f"stitching failed in {stitch_fail}/{stitch_runs} frame sets")
    rel = [r["max_rel_err_deg"] for r in pan_rec if r]
    if pan_rec and not rel:
        print(f"pan recovery: none of the {len(pan_rec)} sets could be recovered")
    elif rel:
        print(f"pan recovery (+-1 deg injected, truth skylines): max |error| after removing the common "
              f"offset: worst {max(rel):.3f} deg over {len(rel)} sets; common offset vs -mean(injected): "
              f"worst {max(abs(r['offset_deg'] + r['mean_injected_deg']) for r in pan_rec if r):.3f} deg")


def run_stitch(acq, body, detect=True):
    """Stitch; score the panorama geometry with the truth skylines warped alike (overlay) and,
    if asked, the end-to-end profile with the detector."""
    from skyfix.stitch import stitch_panorama

    res = {}
    try:
        sk = truth_skylines(acq)
        overlays = [_two_tone(s) for s in sk]
        t0 = time.perf_counter()
        pano, valid, spec, info = stitch_panorama(acq, overlays=overlays)
        res["stitch_s"] = round(time.perf_counter() - t0, 1)
        res["frames_dropped"] = info["frames_dropped"]
        ov = info["overlay"]
        rows = _two_tone_rows(ov, valid)
        p = panorama_profile(spec, Skyline(rows, ov.shape[1], ov.shape[0]))
        res["truth_overlay"] = err_stats(p, body)
        if detect:
            from skyfix.stitch import stitched_profile
            try:
                p = stitched_profile(acq)
                res["detect"] = err_stats(p, body)
            except SkyfixError as e:
                res["detect"] = {"error": str(e)}
    except SkyfixError as e:
        res["error"] = str(e)
    return res


def _two_tone(s: Skyline) -> np.ndarray:
    """White above the truth skyline, black-ish below (anti-aliased), NaN columns all ground."""
    i = np.arange(s.height)[:, None]
    r = np.where(np.isfinite(s.rows), s.rows, -1.0)[None, :]
    sky = np.clip(r - (i - 0.5), 0.0, 1.0)
    g = (20 + 235 * sky).astype(np.uint8)
    return np.repeat(g[..., None], 3, axis=2)


def _two_tone_rows(ov, valid):
    """First ground row per column of a warped two-tone image: where the sky fraction crosses 1/2
    going down from the column's first valid pixel."""
    f = (ov[..., 0].astype(float) - 20.0) / 235.0
    rows = np.full(ov.shape[1], np.nan)
    for j in range(ov.shape[1]):
        v = np.flatnonzero(valid[:, j])
        if v.size < 3:
            continue
        col = f[v[0]:v[-1] + 1, j]
        if col[0] < 0.5 or col[-1] >= 0.5:
            continue  # no sky at the top or no ground at the bottom: no skyline in this column
        k = int(np.argmax(col < 0.5))
        a, b = col[k - 1], col[k]
        rows[j] = v[0] + k - 1 + (a - 0.5) / (a - b)  # where the sky fraction is 1/2
    return rows


def pan_recovery(folder: Path, dst: Path, body, seed):
    """Inject +-1 deg pan errors into acquisition.json (the images keep the true pointing) and see
    whether ``project`` recovers them from the exact skylines."""
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(folder, dst)
    d = json.loads((dst / "acquisition.json").read_text())
    n = len(d["frames"])
    err = np.random.default_rng(seed + 100).choice([-1.0, 1.0], n) * np.random.default_rng(seed).uniform(0.5, 1.0, n)
    for f, e in zip(d["frames"], err):
        f["pan_deg"] = f["pan_deg"] - e  # nominal = true - e, so the correction to find is +e
    (dst / "acquisition.json").write_text(json.dumps(d))
    acq = load_acquisition(dst)
    p = profile_from_skylines(acq, truth_skylines(acq))
    corr = np.array([f.get("pan_correction_deg", np.nan) for f in p.meta["frames"]])
    ok = np.isfinite(corr)
    if ok.sum() < 2:
        return None
    res = corr[ok] - err[ok]
    off = float(np.mean(res))
    out = {"frames": int(ok.sum()), "max_rel_err_deg": float(np.max(np.abs(res - off))),
           "offset_deg": off, "mean_injected_deg": float(np.mean(err[ok])),
           "profile": err_stats(p, body)}
    print("  pan recovery:", json.dumps(out))
    return out


if __name__ == "__main__":
    print(f"load average at the start: {load_average()}", flush=True)
    main()
    print(f"load average at the end: {load_average()}")
