"""A Mars case shaped as missions publish their DEMs, built from this project's reference data.

    python scripts/make_mars_case.py OUT [--locate N] [--detect N] [--detector dp|net]

Writes, in IAU_2015:49900 (Mars 2015 sphere, geographic), centred on Jezero (77.5 E, 18.4 N):
- ``OUT/mola_like_200m.tif``: a ~200 km, 200 m "MOLA-like" DEM: the Alps SRTM tile's relief
  (../shared/data/dem), mirrored 2 x 2 to cover 200 km, resampled to 200 m;
- ``OUT/hirise_like_1m.tif``: a 3 km, 1 m "HiRISE-like" DTM in its middle: the same terrain
  (bicubic from the Alps tile) with metre-scale fractal detail the coarse DEM cannot hold.
Then builds a 2 x 2 km database at 20 m over the stack (``skyfix build-db HIRISE --dem MOLA``) and
locates N rovers from exact skylines of the stack (noise 0.02 deg, off-grid, random heading),
printing each position error and the heading error against TRUE north (from the fix's
``heading_deg``, the truth's grid yaw plus the CRS's meridian convergence). With ``--detect N``,
N acquisitions are also rendered from the stack (``skyfix simulate HIRISE MOLA``: navcam frames
on a mast tilted 15 deg, a full turn, light dust) and located from the skylines skyfix detects in
them (``skyfix profile ACQ --detector D``, then ``skyfix locate --profile P --db DB --dem HIRISE
--dem MOLA``), with the same two errors. A rerun
keeps the DEMs, the database and rendered acquisitions already in OUT.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ALPS = ROOT.parent / "shared" / "data" / "dem" / "alps_srtm3_n46e008.tif"
R_MARS = 3_396_190.0
LAT0, LON0 = 18.4, 77.5


def _write_geo(path, z, cell_m):
    """``z`` (row 0 north) as a Mars geographic GeoTIFF centred on (LON0, LAT0), cells of
    ``cell_m`` metres on the ground."""
    import rasterio
    from rasterio.transform import from_origin

    ny, nx = z.shape
    dlat = math.degrees(cell_m / R_MARS)
    dlon = math.degrees(cell_m / (R_MARS * math.cos(math.radians(LAT0))))
    t = from_origin(LON0 - dlon * nx / 2, LAT0 + dlat * ny / 2, dlon, dlat)
    with rasterio.open(path, "w", driver="GTiff", width=nx, height=ny, count=1, dtype="float32",
                       crs="IAU_2015:49900", transform=t, compress="deflate", predictor=3,
                       tiled=True) as d:
        d.write(z.astype("float32"), 1)
    return path


def make(out: Path) -> tuple[Path, Path]:
    import cv2

    from skyfix.dem import load_dem
    from skyfix.simulate.world import fractal_noise

    alps = load_dem(ALPS)
    z = np.where(np.isfinite(alps.z), alps.z, np.nanmean(alps.z)).astype(np.float32)
    big = np.block([[z, z[:, ::-1]], [z[::-1], z[::-1, ::-1]]])  # continuous at the seams
    cell = alps.cell_m
    # MOLA-like: 200 m cells over 200 km
    n = int(200_000 // 200)
    k = 200.0 / cell
    cy, cx = big.shape[0] / 2, big.shape[1] / 2
    ys = (cy + (np.arange(n) - n / 2 + 0.5) * k).astype(np.float32)
    xs = (cx + (np.arange(n) - n / 2 + 0.5) * k).astype(np.float32)
    mx, my = np.meshgrid(xs, ys)
    mola = cv2.remap(big, mx, my, cv2.INTER_AREA if k > 1 else cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REFLECT)
    mola_p = _write_geo(out / "mola_like_200m.tif", mola, 200.0)
    # HiRISE-like: 1 m over 3 km, the same terrain plus detail
    m = 3000
    ys = (cy + (np.arange(m) - m / 2 + 0.5) / cell).astype(np.float32)
    xs = (cx + (np.arange(m) - m / 2 + 0.5) / cell).astype(np.float32)
    mx, my = np.meshgrid(xs, ys)
    hi = cv2.remap(big, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT).astype(np.float64)
    rng = np.random.default_rng(7)
    hi += 0.8 * fractal_noise(hi.shape, 1.0, 2.0, 150.0, rng)
    hi_p = _write_geo(out / "hirise_like_1m.tif", hi, 1.0)
    return hi_p, mola_p


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("--locate", type=int, default=5, help="rovers to locate (0: build only)")
    ap.add_argument("--spacing-m", type=float, default=20.0)
    ap.add_argument("--detect", type=int, default=0,
                    help="acquisitions to render from the stack and locate from detected skylines")
    ap.add_argument("--detector", default="dp", choices=("dp", "bayes", "net"))
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    hi_p, mola_p = out / "hirise_like_1m.tif", out / "mola_like_200m.tif"
    if not (hi_p.is_file() and mola_p.is_file()):
        hi_p, mola_p = make(out)
        print(f"wrote {hi_p} and {mola_p} ({time.time() - t0:.0f} s)", flush=True)
    from skyfix.stack import load_dems

    stack = load_dems([hi_p, mola_p])
    print(f"stack: {[s['cell_m'] for s in stack.sources]} m cells in {stack.crs_name}, body "
          f"{stack.body.name}", flush=True)
    db = out / "mars_2km_db.zarr"
    half = 1000.0
    cmd = [sys.executable, "-m", "skyfix.cli.main", "build-db", str(hi_p), "--dem", str(mola_p),
           "-o", str(db), "--bounds", str(-half), str(-half), str(half), str(half),
           "--spacing-m", str(args.spacing_m), "--workers", "0", "--no-progress"]
    t0 = time.time()
    r = subprocess.run(cmd, capture_output=True, text=True)  # resumes an interrupted build
    print((r.stdout + r.stderr).strip().splitlines()[-1], f"({time.time() - t0:.0f} s)", flush=True)
    if r.returncode and "already a complete database" not in r.stderr:
        raise SystemExit(r.stderr)
    from skyfix.formats import write_profile_json
    from skyfix.north import meridian_convergence_deg, true_heading_deg
    from skyfix.pose import synthetic_profile

    rng = np.random.default_rng(1)
    errs = []
    for i in range(args.locate):
        tx, ty = rng.uniform(-half + 100, half - 100, 2)
        th = float(rng.uniform(0, 360))
        prof = synthetic_profile(stack, tx, ty, th, noise_deg=0.02, rng=i)
        p = out / f"profile_{i}.json"
        write_profile_json(p, prof)
        fx = out / f"fix_{i}.json"
        t0 = time.time()
        r = subprocess.run([sys.executable, "-m", "skyfix.cli.main", "-q", "locate", "--profile", str(p),
                            "--db", str(db), "--dem", str(hi_p), "--dem", str(mola_p), "-o", str(fx),
                            "--overwrite"], capture_output=True, text=True)
        if r.returncode:
            print(r.stderr)
            continue
        fix = json.loads(fx.read_text())
        true_h = true_heading_deg(th, meridian_convergence_deg(stack.crs_wkt, tx, ty))
        pe = math.hypot(fix["x"] - tx, fix["y"] - ty)
        he = abs((fix["heading_deg"] - true_h + 180) % 360 - 180)
        errs.append((pe, he))
        print(f"rover {i}: position error {pe:.3f} m, heading error vs true north {he:.4f} deg, "
              f"confidence {fix['confidence']:.2f}, convergence {fix['meridian_convergence_deg']:.4f} "
              f"deg ({time.time() - t0:.0f} s)", flush=True)
    if errs:
        pe, he = np.array(errs).T
        print(f"{len(errs)} rovers: position error max {pe.max():.3f} m, heading error max "
              f"{he.max():.4f} deg (targets 1 m, 0.05 deg)")
    if args.detect:
        detect_and_locate(out, stack, hi_p, mola_p, db, args.detect, half, args.detector)


def detect_and_locate(out, stack, hi_p, mola_p, db, n, half, detector="dp"):
    """Render ``n`` acquisitions from the stack and locate each from its detected skylines."""
    from skyfix.north import meridian_convergence_deg, true_heading_deg

    sky = [sys.executable, "-m", "skyfix.cli.main", "-q"]
    rng = np.random.default_rng(2)
    errs = []
    for i in range(n):
        tx, ty = rng.uniform(-half + 100, half - 100, 2)
        th = float(rng.uniform(0, 360))
        acq = out / f"acq_{i}"
        if not (acq / "acquisition.json").is_file():
            r = subprocess.run(sky + ["simulate", str(hi_p), str(mola_p), "--x", str(tx), "--y", str(ty),
                                      "--yaw-deg", str(th), "--conditions", "dust:0.3", "--seed", str(i),
                                      "-o", str(acq), "--overwrite"], capture_output=True, text=True)
            if r.returncode:
                print(r.stderr)
                continue
        prof, fx = out / f"profile_{detector}_{i}.json", out / f"fix_{detector}_{i}.json"
        t0 = time.time()
        r = subprocess.run(sky + ["profile", str(acq), "--detector", detector, "-o", str(prof),
                                  "--overwrite"], capture_output=True, text=True)
        if r.returncode == 0:
            r = subprocess.run(sky + ["locate", "--profile", str(prof), "--db", str(db), "--dem", str(hi_p),
                                      "--dem", str(mola_p), "-o", str(fx), "--overwrite"],
                               capture_output=True, text=True)
        if r.returncode:
            print(f"acquisition {i}: {r.stderr.strip().splitlines()[-1]}")
            continue
        fix = json.loads(fx.read_text())
        true_h = true_heading_deg(th, meridian_convergence_deg(stack.crs_wkt, tx, ty))
        pe = math.hypot(fix["x"] - tx, fix["y"] - ty)
        he = abs((fix["heading_deg"] - true_h + 180) % 360 - 180)
        errs.append((pe, he, fix["confidence"]))
        print(f"{detector} {i}: position error {pe:.3f} m, heading error vs true north {he:.4f} deg, "
              f"confidence {fix['confidence']:.2f} ({time.time() - t0:.0f} s)", flush=True)
    if errs:
        pe, he, c = np.array(errs).T
        print(f"{len(errs)} acquisitions, skylines detected by {detector}: position error median {np.median(pe):.2f} m, "
              f"max {pe.max():.2f} m; heading error median {np.median(he):.3f} deg, max "
              f"{he.max():.3f} deg; within 1 m {int(np.sum(pe <= 1))}/{len(errs)}")


if __name__ == "__main__":
    main()
