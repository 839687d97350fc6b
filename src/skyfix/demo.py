"""The README's main job: DEM -> small database -> simulated acquisition -> fix, with figures.

Uses ``sierra_nevada_30m.tif`` from ``../shared/data`` when present, else generates a fractal
mountain DEM, so it runs on a fresh machine with nothing but the package.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from .formats import Truth

#: where the shared reference data sits relative to the current folder and to the source tree
_SHARED_CANDIDATES = (Path.cwd().parent / "shared" / "data" / "dem" / "sierra_nevada_30m.tif",
                      Path(__file__).resolve().parents[3] / "shared" / "data" / "dem" / "sierra_nevada_30m.tif")


#: what a demo run writes into its folder; nothing else is ever replaced without --overwrite
DEMO_OUTPUTS = frozenset({"skylines.zarr", "acquisition", "fix.json", "summary.json",
                          "skyline_overlay.png", "fix_map.png", "frame_skyline.png",
                          "generated_dem.tif"})
#: written first into a folder the demo creates or finds empty, so a rerun knows the folder is its own
DEMO_MARKER = ".skyfix-demo"


def is_demo_output(out: Path) -> bool:
    """Whether folder ``out`` holds only what an earlier demo wrote (and so may be rebuilt).

    It must carry the marker (or, from before the marker, the demo's own ``summary.json`` beside
    its ``skylines.zarr``) and nothing but the demo's own outputs and hidden temporary files: a
    user's folder that merely contains an ``acquisition/``, or a ``summary.json`` and a
    ``fix.json`` of their own, is not a demo output.
    """
    names = {p.name for p in out.iterdir()}
    if not all(n in DEMO_OUTPUTS or n == DEMO_MARKER or n.startswith(".") for n in names):
        return False
    return DEMO_MARKER in names or ("skylines.zarr" in names and _demo_summary(out / "summary.json"))


def _demo_summary(path: Path) -> bool:
    """Whether ``path`` is a summary the demo wrote (its keys), not a user's file of that name."""
    import json

    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and {"fix", "truth", "timings_s", "files"} <= set(data)


def check_demo_out(out: Path, overwrite: bool) -> None:
    """Refuse an ``out`` that is a file, or a non-empty folder that is not an earlier demo's
    output unless ``overwrite`` (which replaces only the demo's own outputs in it)."""
    from .errors import OutputExistsError

    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{out} exists and is not a folder: choose another --out")
    if out.is_dir() and any(out.iterdir()) and not overwrite and not is_demo_output(out):
        raise OutputExistsError(
            f"{out} is not empty and is not an earlier skyfix demo's output: choose another --out, "
            f"or pass --overwrite to replace the demo's files in it ({', '.join(sorted(DEMO_OUTPUTS))})")


def find_demo_dem(out: Path, say=print) -> Path:
    for p in _SHARED_CANDIDATES:
        if p.exists():
            say(f"DEM: {p} (real terrain, Sierra Nevada)")
            return p
    from .dem import fractal_dem, write_dem

    path = out / "generated_dem.tif"
    if not path.exists():
        write_dem(path, fractal_dem(640, 30.0, seed=11))
    say(f"DEM: no ../shared/data found, generated fractal mountains at {path}")
    return path


def run_demo(out, *, area_m: float = 1500.0, spacing_m: float = 10.0, seed: int = 4,
             overwrite: bool = False, say=print, tell=None, progress: bool = True) -> dict:
    """Run the whole pipeline once; returns the fix, its error and the files written.

    area_m : [m] side of the square search area (database grid) at the DEM's centre
    spacing_m : [m] database grid spacing
    seed : whole number >= 0, where the rover is hidden
    overwrite : replace the demo's files in a non-empty ``out`` that is not an earlier demo's
        output (an earlier demo's output is rebuilt without it, so the quick start can be rerun)
    say, tell : where the stage lines and the result lines (the fix, the truth) go; ``tell``
        defaults to ``say``
    progress : draw the database build's progress bar
    """
    from ._io import write_json
    from .database import build_database, open_database
    from .dem import load_dem
    from .evaluate import EvalConfig, plot_skyline_overlay
    from .formats import load_acquisition
    from .pose import locate
    from .profile import acquisition_profile
    from .report import CaseResult
    from .north import meridian_convergence_deg
    from .errors import ParameterError
    from .simulate import check_seed, simulate_acquisition

    # Checked before anything is built or written (the database alone takes 15 s).
    seed = check_seed(seed)
    if not (math.isfinite(area_m) and math.isfinite(spacing_m) and 0 < spacing_m < area_m):
        raise ParameterError(f"need 0 < spacing_m < area_m, got {spacing_m} and {area_m}")
    out = Path(out)
    check_demo_out(out, overwrite)
    fresh = not out.exists() or not any(out.iterdir())
    out.mkdir(parents=True, exist_ok=True)
    if fresh or is_demo_output(out):
        (out / DEMO_MARKER).write_text("written by `skyfix demo`: a rerun may replace this folder's "
                                       "demo outputs\n")
    timings = {}
    dem_path = find_demo_dem(out, say)
    dem = load_dem(dem_path)
    xmin, ymin, xmax, ymax = dem.bounds
    cx, cy = (xmin + xmax) / 2, (ymin + ymax) / 2
    bounds = (cx - area_m / 2, cy - area_m / 2, cx + area_m / 2, cy + area_m / 2)

    t0 = time.perf_counter()
    say(f"1/4 building a skyline database: {area_m:.0f} x {area_m:.0f} m at {spacing_m:g} m "
        f"({(int(area_m / spacing_m) + 1) ** 2} skylines x 360 azimuths)")
    db_path = out / "skylines.zarr"
    build_database(dem_path, db_path, bounds, spacing_m, workers=0, overwrite=True,
                   progress=progress)
    timings["build_db_s"] = time.perf_counter() - t0

    rng = np.random.default_rng(seed)
    m = area_m * 0.3
    truth = Truth(x=float(rng.uniform(bounds[0] + m, bounds[2] - m)),
                  y=float(rng.uniform(bounds[1] + m, bounds[3] - m)),
                  yaw_deg=float(rng.uniform(0, 360)), pitch_deg=float(rng.uniform(-3, 3)),
                  roll_deg=float(rng.uniform(-3, 3)))
    t0 = time.perf_counter()
    say("2/4 simulating a 360 deg navcam frame set, mast tilted 15 deg up, at a hidden position")
    acq_dir = simulate_acquisition(dem, truth, out / "acquisition", camera="navcam", seed=seed,
                                   tilt_deg=15.0, overwrite=True)
    timings["simulate_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    say("3/4 detecting the skyline in each frame and building the angular profile")
    acq = load_acquisition(acq_dir)
    profile = acquisition_profile(acq)
    timings["profile_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    say("4/4 locating: full database search, then refinement against the DEM")
    fix = locate(profile, db=open_database(db_path), dem=dem, prior_pitch_deg=acq.prior_pitch_deg,
                 prior_roll_deg=acq.prior_roll_deg, camera_height_m=acq.camera_height_m)
    timings["locate_s"] = time.perf_counter() - t0

    write_json(out / "fix.json", fix.to_dict())
    res = CaseResult(case="demo", set="REF", scenario=1, truth_x=truth.x, truth_y=truth.y,
                     truth_yaw_deg=truth.yaw_deg,
                     truth_meridian_convergence_deg=meridian_convergence_deg(dem.crs_wkt, truth.x, truth.y),
                     truth_pitch_deg=truth.pitch_deg, truth_roll_deg=truth.roll_deg, fix_x=fix.x,
                     fix_y=fix.y, fix_grid_heading_deg=fix.grid_heading_deg,
                     meridian_convergence_deg=fix.meridian_convergence_deg, fix_pitch_deg=fix.pitch_deg,
                     fix_roll_deg=fix.roll_deg, confidence=fix.confidence, score=fix.score)
    overlay = plot_skyline_overlay(out / "skyline_overlay.png", res, profile, dem,
                                   EvalConfig(scenario=1), prior_pitch_deg=acq.prior_pitch_deg,
                                   prior_roll_deg=acq.prior_roll_deg)
    from .detect import detect_skyline
    from .figures import plot_fix_map, plot_frame_skyline
    from .profile.frames import read_rgb

    fix_map = plot_fix_map(out / "fix_map.png", fix, dem, area=bounds, truth=(truth.x, truth.y))
    # the first frame whose skyline spans most of its width (frame 0 may look at a near slope)
    best = None
    for frame in acq.frames:
        rgb = read_rgb(acq.root / frame.image)
        sky = detect_skyline(rgb)
        share = float(np.mean(np.isfinite(np.asarray(sky.rows, float))))
        if best is None or share > best[0]:
            best = (share, frame, rgb, sky)
        if share >= 0.9:
            break
    _, frame, rgb, sky = best
    frame_fig = plot_frame_skyline(out / "frame_skyline.png", rgb, sky,
                                   title=f"{frame.image}: pan {frame.pan_deg:.0f} deg, tilt "
                                         f"{frame.tilt_deg:.0f} deg, detected skyline")
    summary = {
        "fix": fix.to_dict(),
        # headings as the fix gives them (conventions.md): from true north, the grid's beside it
        "truth": {"x": truth.x, "y": truth.y, "heading_deg": res.truth_heading_deg,
                  "grid_heading_deg": truth.yaw_deg,
                  "meridian_convergence_deg": res.truth_meridian_convergence_deg,
                  "yaw_deg": truth.yaw_deg, "pitch_deg": truth.pitch_deg,
                  "roll_deg": truth.roll_deg},
        "position_error_m": res.position_error_m, "heading_error_deg": res.heading_error_deg,
        "timings_s": timings,
        "files": [str(out / "fix.json"), str(overlay), str(fix_map), str(frame_fig), str(db_path),
                  str(acq_dir)],
    }
    write_json(out / "summary.json", summary)
    tell = say if tell is None else tell
    tell(f"fix: x {fix.x:.1f} m, y {fix.y:.1f} m ({fix.crs}), heading {fix.heading_deg:.2f} deg from "
        f"true north (grid {fix.grid_heading_deg:.2f}), pitch {fix.pitch_deg:.2f}, roll "
        f"{fix.roll_deg:.2f}, confidence {fix.confidence:.2f}")
    tell(f"truth: x {truth.x:.1f} m, y {truth.y:.1f} m, heading {res.truth_heading_deg:.2f} deg from true north "
        f"-> position error {res.position_error_m:.2f} m, heading error {res.heading_error_deg:.2f} deg")
    say("times: " + ", ".join(f"{k[:-2]} {v:.1f} s" for k, v in timings.items()))
    say(f"wrote {out / 'fix.json'}, {out / 'summary.json'} and the figures {overlay.name}, "
        f"{fix_map.name}, {frame_fig.name}")
    return summary
