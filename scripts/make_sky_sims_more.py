"""More simulated training frames for the sky network's next retraining (not in the shipped recipe,
whose frames ``scripts/make_sky_sims.sh`` renders): the cases the dev sets hold few of.

    python scripts/make_sky_sims_more.py OUT      # then train_sky_net.py ... --sims OUT/earth_snow ...

- ``earth_snow``: snow (0.4-1) on the Sierra Nevada and the Alps, bright summits against the sky;
- ``earth_lake``: a lake (0.2-1) under the ridges, the sky mirrored below the skyline;
- ``mars_haze_nosky``: Mars in dust (0.5-1) with the mast tilted down until the skyline leaves the
  frame's top over part or all of it: hazy relief with nothing behind it, which the simulator
  records as all-ground columns and the training labels terrain (what the no-sky mosaics teach).

Seeds 911-913, never used to evaluate; positions drawn in each DEM's default area, headings
uniform. Every frame comes with its exact skyline as ``skyfix simulate`` writes it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEMS = ROOT.parent / "shared" / "data" / "dem"

#: set name: (seed, DEM files, planet, condition name, strength range, tilt range [deg])
SETS = {
    "earth_snow": (911, ("sierra_nevada_30m.tif", "alps_srtm3_n46e008.tif"), "earth", "snow",
                   (0.4, 1.0), (0.0, 15.0)),
    "earth_lake": (912, ("sierra_nevada_30m.tif", "alps_srtm3_n46e008.tif"), "earth", "lake",
                   (0.2, 1.0), (-10.0, 5.0)),
    "mars_haze_nosky": (913, ("alps_srtm3_n46e008.tif", "south_glacier_20m.tif"), "mars", "dust",
                        (0.5, 1.0), (-25.0, -12.0)),
}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="folder to write one sub-folder per set into")
    ap.add_argument("--cases", type=int, default=3, help="acquisitions per set and DEM (default 3)")
    ap.add_argument("--frames", type=int, default=4, help="frames per acquisition (default 4)")
    ap.add_argument("--overwrite", action="store_true")
    args = ap.parse_args(argv)
    missing = [d for s in SETS.values() for d in s[1] if not (DEMS / d).is_file()]
    if missing:
        raise SystemExit(f"no {missing[0]} in {DEMS}: these frames are rendered from the shared DEMs")
    from skyfix.dem import load_dem
    from skyfix.formats import Truth
    from skyfix.simulate import default_area, simulate_acquisition

    out = Path(args.out)
    for name, (seed, dems, planet, cond, (lo, hi), (t_lo, t_hi)) in SETS.items():
        rng = np.random.default_rng(seed)
        for dem_name in dems:
            dem = load_dem(DEMS / dem_name)
            x0, y0, x1, y1 = default_area(dem)
            for k in range(args.cases):
                truth = Truth(float(rng.uniform(x0, x1)), float(rng.uniform(y0, y1)),
                              float(rng.uniform(0, 360)))
                folder = out / name / f"{Path(dem_name).stem}_{k:02d}"
                simulate_acquisition(dem, truth, folder, frames=args.frames,
                                     tilt_deg=float(rng.uniform(t_lo, t_hi)), planet=planet,
                                     conditions=f"{cond}:{rng.uniform(lo, hi):.2f}",
                                     seed=int(rng.integers(0, 2**31)), overwrite=args.overwrite)
                print(f"wrote {folder}", file=sys.stderr)


if __name__ == "__main__":
    main()
