"""One photograph: roll, pitch and heading from a single simulated navcam frame (45 deg wide), the
skyline detected in the image, at a known position (the NASA Ames use; ``skyfix attitude``).

    python benchmarks/bench_single_frame.py --dem DEM [--dem DEM2 ...] --out DIR [--cases 20]
        [--map-errors] [--prior-sigma-deg 5] [--heading-offset-deg 5] [--detector dp|net]

Per case: a position drawn inside the DEM, a heading uniform in [0, 360), true pitch and roll
N(0, 3 deg); one frame on a mast tilted 15 deg up, rendered from the map or (``--map-errors``)
from a world that differs from it (``skyfix.simulate.world``); the inclinometer prior off by
N(0, prior sigma) in pitch and roll and the heading prior off by U(-offset, +offset) (window
+-10 deg), as in the NASA study's noisy INS. Then, timed: the frame's skyline detected and
projected (``acquisition_profile``) and ``estimate_heading`` on the map at the truth's place on
the map. Prints, with the load average: heading within 1 deg, pitch and roll within 0.5 deg,
the fixes at confidence >= 0.9 and how many are right, time per frame. A frame whose skyline
cannot be detected counts as a miss (the command refuses it with exit 2).

The same figures are also given for the frames a map can serve, chosen before any solve from what
the simulation knows of each frame, never from its outcome: its terrain skyline spans at least a
third of the frame's width (the issue's own partial-skyline case), and the skyline in view lies,
in the median column, beyond ``--map-sigma-m / tan(0.5 deg)`` (229 m for a 2 m map error: nearer,
the map's height error alone moves the horizon by more than the pitch and roll bar). A frame looking
up a slope 25 m away sees the DEM's own cell, not a landmark.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from cache import check_reuse, record


def _ang(a):
    return (a + 180.0) % 360.0 - 180.0


def _skyline_columns(case: Path) -> int:
    """Columns of the frame whose terrain meets the sky, as the simulator recorded them."""
    import json

    meta = json.loads((case / "acquisition.json").read_text())
    return int(meta["simulation"]["images"][0]["terrain_skyline_columns"])


def _figures(rows, label):
    he = np.array([r["he"] for r in rows])
    pe = np.array([r["pe"] for r in rows])
    re_ = np.array([r["re"] for r in rows])
    conf = np.array([r["conf"] for r in rows])
    sure = conf >= 0.9
    print(f"{label} ({len(rows)} frames): heading within 1 deg {np.mean(he <= 1):.0%}, pitch within "
          f"0.5 deg {np.mean(pe <= 0.5):.0%}, roll within 0.5 deg {np.mean(re_ <= 0.5):.0%}, refused "
          f"{sum(not r['ok'] for r in rows)}; confidence >= 0.9: {int(sure.sum())}, "
          f"{int((he[sure] <= 1).sum())} right")


def run_dem(dem_path, out: Path, args) -> list[dict]:
    from skyfix.dem import load_dem
    from skyfix.errors import SkyfixError
    from skyfix.formats import Truth, load_acquisition
    from skyfix.pose import estimate_heading
    from skyfix.pose.image_plane import IMAGE_PLANE_RENDER_BINS, attitude_cost, frames_from_acquisition
    from skyfix.profile import acquisition_profile, detect_frames
    from skyfix.simulate import simulate_acquisition
    from skyfix.simulate.world import MapErrors, map_offset, world_dem

    from skyfix.horizon import render_horizons

    dem = load_dem(dem_path)
    name = Path(dem_path).stem
    world, off = dem, (0.0, 0.0)
    if args.map_errors:
        world, off = world_dem(dem, MapErrors(), args.seed), map_offset(MapErrors(), args.seed)
    # what the kept frames depend on (the heading prior is drawn anew on every run)
    settings = dict(dem=name, seed=args.seed, prior_sigma_deg=args.prior_sigma_deg,
                    map_errors=bool(args.map_errors))
    marker = out / f"{name}_settings.json"
    check_reuse(marker, settings, made=any(out.glob(f"{name}_[0-9][0-9][0-9]")))
    record(marker, settings)
    rng = np.random.default_rng([args.seed, 5])
    x0, y0, x1, y1 = dem.bounds
    m = 0.25 * min(x1 - x0, y1 - y0)
    rows = []
    for k in range(args.cases):
        tx, ty = float(rng.uniform(x0 + m, x1 - m)), float(rng.uniform(y0 + m, y1 - m))
        yaw, pitch, roll = float(rng.uniform(0, 360)), float(rng.normal(0, 3)), float(rng.normal(0, 3))
        dpp, dpr = rng.normal(0, args.prior_sigma_deg, 2)
        dh = float(rng.uniform(-args.heading_offset_deg, args.heading_offset_deg))
        case = out / f"{name}_{k:03d}"
        if not (case / "acquisition.json").is_file():
            simulate_acquisition(world, Truth(tx, ty, yaw, pitch, roll), case, mode="frames", frames=1,
                                 pan_start_deg=0.0, tilt_deg=15.0, seed=k, overwrite=True,
                                 attitude_prior=(pitch + float(dpp), roll + float(dpr)))
        acq = load_acquisition(case)
        # what the frame holds, from the simulation and the map at the truth (not timed, no solve)
        cols = _skyline_columns(case)
        hb = render_horizons(dem, [tx + off[0]], [ty + off[1]], camera_height_m=acq.camera_height_m,
                             azimuth_bins=1440)
        az = np.arange(1440) * 0.25
        half = 0.5 * acq.camera.hfov_deg
        inview = np.abs(_ang(az - yaw)) <= half
        sky_m = float(np.nanmedian(hb.skyline_distance_m[0][inview])) if inview.any() else 0.0
        t0 = time.perf_counter()
        row = dict(dem=name, case=k, ok=False, conf=0.0, he=np.inf, pe=np.inf, re=np.inf,
                   sky_share=cols / acq.camera.width, sky_m=sky_m)
        frames = None
        try:
            skylines = detect_frames(acq, args.detector)
            prof = acquisition_profile(acq, skylines=skylines)
            frames = frames_from_acquisition(acq, skylines) if args.solve == "image" else None
            hf = estimate_heading(prof, dem, tx + off[0], ty + off[1], yaw + dh, 10.0,
                                  camera_height_m=acq.camera_height_m,
                                  prior_pitch_deg=acq.prior_pitch_deg, prior_roll_deg=acq.prior_roll_deg,
                                  frames=frames)
            row.update(ok=True, conf=hf.confidence, he=abs(_ang(hf.grid_heading_deg - yaw)),
                       pe=abs(hf.pitch_deg - pitch), re=abs(hf.roll_deg - roll),
                       hsig=hf.heading_sigma_deg, psig=hf.pitch_sigma_deg, rsig=hf.roll_sigma_deg)
        except SkyfixError as e:
            row["why"] = str(e).splitlines()[0]
        row["seconds"] = time.perf_counter() - t0
        rows.append(row)
        print(f"  {name} {k:3d}: " + (f"heading {row['he']:.2f} deg, pitch {row['pe']:.2f}, roll "
                                     f"{row['re']:.2f}, confidence {row['conf']:.2f}" if row["ok"]
                                     else f"refused: {row['why']}") + f" ({row['seconds']:.1f} s; skyline "
              f"over {row['sky_share']:.0%} of the width, {row['sky_m']:.0f} m away in the median column)",
              flush=True)
        missed = row["he"] > 1 or row["pe"] > 0.5 or row["re"] > 0.5
        if args.diagnose and row["ok"] and missed and frames:
            # on the map at the truth's place: the truth's cost against the answer's
            fine = render_horizons(dem, [tx + off[0]], [ty + off[1]],
                                   camera_height_m=acq.camera_height_m,
                                   azimuth_bins=IMAGE_PLANE_RENDER_BINS).elevation_deg[0]
            ct, mt = attitude_cost(frames, fine, yaw, pitch, roll)
            ca, ma = attitude_cost(frames, fine, hf.grid_heading_deg, hf.pitch_deg, hf.roll_deg)
            row["search_missed"] = ct < ca
            print(f"    the truth costs {ct:.0f} (median {mt:.1f} px), the answer {ca:.0f} "
                  f"(median {ma:.1f} px): " + ("the search missed the truth" if ct < ca else
                                               "the map fits the answer better"))
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dem", action="append", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--cases", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--map-errors", action="store_true")
    ap.add_argument("--prior-sigma-deg", type=float, default=5.0)
    ap.add_argument("--heading-offset-deg", type=float, default=5.0)
    ap.add_argument("--detector", default="dp", choices=("dp", "bayes", "net"))
    ap.add_argument("--diagnose", action="store_true",
                    help="for each frame that misses a bar: the truth's cost on the map against the "
                         "answer's (a search that missed it, or a map that cannot hold it)")
    ap.add_argument("--map-sigma-m", type=float, default=2.0,
                    help="the map's height error [m] that sets the nearest skyline a map can serve")
    ap.add_argument("--solve", default="image", choices=("image", "profile"),
                    help="also solve in the image plane (what the CLI does), or the profile fit alone")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    load0 = os.getloadavg()[0]
    rows = [r for d in args.dem for r in run_dem(d, out, args)]
    he = np.array([r["he"] for r in rows])
    pe = np.array([r["pe"] for r in rows])
    re_ = np.array([r["re"] for r in rows])
    conf = np.array([r["conf"] for r in rows])
    secs = np.array([r["seconds"] for r in rows])
    sure = conf >= 0.9
    world = "a world with map errors" if args.map_errors else "the map itself"
    print(f"load average {load0:.2f} -> {os.getloadavg()[0]:.2f}; {len(rows)} frames from {world}, "
          f"detector {args.detector}, priors: pitch/roll N(0, {args.prior_sigma_deg:g} deg), heading "
          f"U(+-{args.heading_offset_deg:g} deg)")
    print(f"heading within 1 deg: {np.mean(he <= 1):.0%}; pitch within 0.5 deg: {np.mean(pe <= 0.5):.0%}; "
          f"roll within 0.5 deg: {np.mean(re_ <= 0.5):.0%}; refused {sum(not r['ok'] for r in rows)}")
    print(f"confidence >= 0.9: {int(sure.sum())} frames, {int((he[sure] <= 1).sum())} with the heading "
          f"within 1 deg; time per frame median {np.median(secs):.2f} s, max {secs.max():.2f} s "
          f"(detection and projection included)")
    ok = np.array([r["ok"] for r in rows])
    if ok.any():
        cover = []
        for name, err, key in (("heading", he, "hsig"), ("pitch", pe, "psig"), ("roll", re_, "rsig")):
            sig = np.array([r.get(key, np.nan) for r in rows])[ok]
            z = err[ok] / sig
            cover.append(f"{name} {np.mean(z <= 1):.0%} / {np.mean(z <= 2):.0%}")
        print("the error within 1 / 2 of the reported sigmas: " + ", ".join(cover))
        # the frames beyond a bar are where a sigma that knows only its own basin fails
        cover = []
        for name, err, key, bar in (("heading", he, "hsig", 1.0), ("pitch", pe, "psig", 0.5),
                                    ("roll", re_, "rsig", 0.5)):
            sig = np.array([r.get(key, np.nan) for r in rows])
            miss = ok & (err > bar)
            z = err[miss] / sig[miss]
            cover.append(f"{name} {np.mean(z <= 1):.0%} / {np.mean(z <= 2):.0%} of {int(miss.sum())}"
                         if miss.any() else f"{name}: none beyond")
        print("  of the errors beyond the bar: " + ", ".join(cover))
    near_m = args.map_sigma_m / np.tan(np.radians(0.5))
    served = [r for r in rows if r["sky_share"] >= 1 / 3 and r["sky_m"] >= near_m]
    if args.diagnose:
        seen = [r for r in rows if "search_missed" in r]
        print(f"of {len(seen)} frames that missed a bar, the search missed the truth in "
              f"{sum(r['search_missed'] for r in seen)}; the map fits the answer better in the rest")
    print(f"frames a map can serve (skyline over >= 1/3 of the width, beyond {near_m:.0f} m in the "
          f"median column): {len(served)} of {len(rows)}")
    _figures(served, "  served")
    _figures([r for r in rows if r not in served], "  the others")
    for d in args.dem:
        n = Path(d).stem
        k = np.array([r["dem"] == n for r in rows])
        print(f"  {n}: heading {np.mean(he[k] <= 1):.0%}, pitch {np.mean(pe[k] <= 0.5):.0%}, "
              f"roll {np.mean(re_[k] <= 0.5):.0%} ({int(k.sum())} frames)")


if __name__ == "__main__":
    main()
