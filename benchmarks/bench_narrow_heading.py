"""Heading from a single narrow frame (scenario 3 with one photograph): how often ``heading``
finds the true heading within 1 deg, against the arc the frame spans.

The images' world is not the map: each case's horizon is rendered from a world DEM
(:func:`skyfix.simulate.world.world_dem`: the map refined, correlated height errors, a shift)
and the heading is searched on the map DEM itself. The rover's true pitch and roll are drawn
N(0, 3 deg); the inclinometer prior it levels the profile with is off by N(0, 0.3 deg); the
heading prior is off by U(-8, 8) deg (window +-10 deg); 0.05 deg of noise per bin.

    python benchmarks/bench_narrow_heading.py --cases 40 --arcs 50,90,360
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from skyfix.dem import load_dem
from skyfix.formats import Profile
from skyfix.horizon import render_horizons
from skyfix.pose import estimate_heading
from skyfix.pose.forward import body_profile
from skyfix.simulate.world import MapErrors, world_dem

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DEM = os.path.join(ROOT, "..", "shared", "data", "dem", "sierra_nevada_30m.tif")


def cases(dem, n, seed, prior_sigma_deg=0.3, heading_offset_deg=8.0):
    rng = np.random.default_rng(seed)
    x0, y0, x1, y1 = dem.bounds
    m = 0.3 * min(x1 - x0, y1 - y0)
    for _ in range(n):
        yield dict(x=float(rng.uniform(x0 + m, x1 - m)), y=float(rng.uniform(y0 + m, y1 - m)),
                   yaw=float(rng.uniform(0, 360)), pitch=float(rng.normal(0, 3)),
                   roll=float(rng.normal(0, 3)), dpp=float(rng.normal(0, prior_sigma_deg)),
                   dpr=float(rng.normal(0, prior_sigma_deg)),
                   dh=float(rng.uniform(-heading_offset_deg, heading_offset_deg)),
                   start=float(rng.uniform(0, 360)), noise=rng.normal(0, 0.05, 360))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dem", default=DEM)
    ap.add_argument("--cases", type=int, default=30)
    ap.add_argument("--arcs", default="50,90,360", help="arc widths [deg]")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--map-is-world", action="store_true", help="render the images from the map DEM")
    ap.add_argument("--prior-sigma-deg", type=float, default=0.3,
                    help="1-sigma error of the pitch/roll prior [deg] (NASA Ames INS: ~5)")
    ap.add_argument("--heading-offset-deg", type=float, default=8.0,
                    help="heading prior off by U(-this, this) [deg]")
    args = ap.parse_args(argv)
    dem = load_dem(args.dem)
    world = dem if args.map_is_world else world_dem(dem, MapErrors(), seed=args.seed)
    print(f"load average {os.getloadavg()[0]:.2f}; DEM {os.path.basename(args.dem)}; "
          f"world {'= map' if args.map_is_world else 'DEMERR (map refined, errors, shift)'}")
    cs = list(cases(dem, args.cases, args.seed, args.prior_sigma_deg, args.heading_offset_deg))
    horizons = render_horizons(world, [c["x"] for c in cs], [c["y"] for c in cs],
                               azimuth_bins=1440).elevation_deg
    print(f"pitch/roll prior sigma {args.prior_sigma_deg} deg, heading prior within "
          f"+-{args.heading_offset_deg} deg")
    print("arc_deg  within_1deg  median_err_deg  conf>=0.9_right  mean_s  pitch/roll_within_0.5deg")
    for arc in [float(a) for a in args.arcs.split(",")]:
        errs, confs, secs, tilt_ok = [], [], [], []
        for c, w in zip(cs, horizons):
            pp, pr = c["pitch"] + c["dpp"], c["roll"] + c["dpr"]
            q = body_profile(w, c["yaw"], c["pitch"], c["roll"], n_bins=360,
                             prior_pitch_deg=pp, prior_roll_deg=pr) + c["noise"]
            if arc < 360:
                az = np.arange(360.0)
                q[((az - c["start"]) % 360.0) > arc] = np.nan
            prof = Profile(elevation_deg=q, sigma_deg=np.where(np.isfinite(q), 0.05, np.nan), frame="body")
            t = time.perf_counter()
            try:
                hf = estimate_heading(prof, dem, c["x"], c["y"], c["yaw"] + c["dh"], 10.0,
                                      prior_pitch_deg=pp, prior_roll_deg=pr)
                err = abs((hf.grid_heading_deg - c["yaw"] + 180) % 360 - 180)
                conf = hf.confidence
                tilt_ok.append(abs(hf.pitch_deg - c["pitch"]) <= 0.5 and abs(hf.roll_deg - c["roll"]) <= 0.5)
            except Exception as e:  # noqa: BLE001 - a refusal counts as a miss
                err, conf = float("inf"), 0.0
                tilt_ok.append(False)
                print(f"  refused: {e}")
            secs.append(time.perf_counter() - t)
            errs.append(err)
            confs.append(conf)
        errs, confs = np.array(errs), np.array(confs)
        hi = confs >= 0.9
        print(f"{arc:7.0f}  {np.mean(errs <= 1):10.0%}  {np.median(errs):14.2f}  "
              f"{int((errs[hi] <= 1).sum()):>3d} of {int(hi.sum()):<3d}      {np.mean(secs):.2f}  "
              f"{np.mean(tilt_ok):.0%}")


if __name__ == "__main__":
    main()
