"""Stage 9: run the board pipeline on simulated cases and measure it against the requirements.

For each robustness set the simulator draws cases (:func:`skyfix.simulate.simulate_set`); each
case goes through the board segment exactly as on the rover (images -> detection -> profile ->
locate / heading) without ever reading ``truth``, which only the scoring here looks at.

Scenarios (``design.md``):
1. after landing: full database search over the area, then DEM refinement; correct = within 5 m
   and 2 deg;
2. end of a traverse: 40 x 40 m prior (drift up to 20 m), DEM only, no database; correct = 1 m;
3. along the traverse: heading only, at a position wrong by 0, 5, 10 or 20 m, heading prior
   within +-5 deg, window +-10 deg; correct = heading within 1 deg.
"""

from __future__ import annotations

import json
import logging
import math
import resource
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import OutputExistsError, ParameterError, SkyfixError
from .report import CaseResult

log = logging.getLogger(__name__)

SETS = ("REF", "HREL", "SCOM", "LREL", "CLUT", "OCCL", "COND", "DEMERR")  # skyfix.simulate.SETS
#: scenario 3's position errors [m], cycled over the cases
HEADING_PRIOR_OFFSETS_M = (0.0, 5.0, 10.0, 20.0)
#: scenario 2's drift [m]: the prior is the truth moved by up to this much
DRIFT_M = 20.0


#: the most cases a set may ask for
MAX_CASES = 10_000


@dataclass(frozen=True)
class EvalConfig:
    """How to evaluate.

    scenario : 1, 2 or 3; sets : robustness set names; cases : per set; seed : reproducibility
    area : (xmin, ymin, xmax, ymax) [m] where cases are drawn (default: the database's grid for
    scenario 1, the simulator's default area otherwise)
    tilt_deg : [deg] mast tilt of the simulated frames (mountain skylines sit 5-30 deg up)
    skylines : ``detect`` (the real pipeline) or ``truth`` (a diagnosis that bypasses detection
    with the simulator's exact terrain skylines, to separate localisation from detection errors)
    detector : the detection method (:data:`skyfix.detect.METHODS`; None: the default)
    """

    scenario: int
    sets: tuple[str, ...] = ("REF",)
    cases: int = 10
    seed: int = 0
    area: tuple[float, float, float, float] | None = None
    camera_height_m: float = 1.5
    planet: str | None = None  # None: the DEM's body
    skylines: str = "detect"
    tilt_deg: float = 15.0
    map_errors: bool = False  # render every set from a world that differs from the map
    dem_sigma_m: float | None = None  # PoseConfig.dem_sigma_m for the cases' fixes
    detector: str | None = None

    def __post_init__(self):
        if self.skylines not in ("detect", "truth"):
            raise ParameterError(f"skylines must be 'detect' or 'truth', got {self.skylines!r}")
        from .detect.options import METHODS

        if self.detector is not None and self.detector not in METHODS:
            raise ParameterError(f"unknown detector {self.detector!r}: choose one of {', '.join(METHODS)}")
        if self.scenario not in (1, 2, 3):
            raise ParameterError(f"scenario must be 1, 2 or 3, got {self.scenario}")
        if not self.sets:
            raise ParameterError(f"no robustness set given: choose from {', '.join(SETS)} "
                                 "(e.g. --sets REF,HREL)")
        bad = [s for s in self.sets if s not in SETS]
        if bad:
            raise ParameterError(f"unknown set(s) {', '.join(bad)}: choose from {', '.join(SETS)}")
        if isinstance(self.cases, bool) or int(self.cases) != self.cases or self.cases < 1:
            raise ParameterError(f"cases must be a whole number >= 1, got {self.cases}")
        if self.cases > MAX_CASES:  # 1e9 started simulating, a few seconds a case, with no end
            raise ParameterError(f"at most {MAX_CASES} cases a set (days of simulation at a few "
                                 f"seconds a case), got {self.cases}")
        from .planets import get_planet
        from .simulate import check_seed

        check_seed(self.seed)
        if not (math.isfinite(self.camera_height_m) and self.camera_height_m >= 0):
            raise ParameterError(f"camera height must be >= 0 m, got {self.camera_height_m}")
        if not (math.isfinite(self.tilt_deg) and abs(self.tilt_deg) <= 90):
            raise ParameterError(f"mast tilt must be within +-90 deg (up positive), got {self.tilt_deg}")
        if self.planet is not None:
            get_planet(self.planet)


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far [MB]."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def db_area(db, margin_m: float = 0.0):
    """(xmin, ymin, xmax, ymax) [m] of a database's position grid, shrunk by ``margin_m``."""
    xs, ys = db.x_coords, db.y_coords
    return (float(xs.min()) + margin_m, float(ys.min()) + margin_m,
            float(xs.max()) - margin_m, float(ys.max()) - margin_m)


def check_area_in_database(area, db) -> None:
    """Refuse an ``area`` [m] (xmin, ymin, xmax, ymax) that reaches outside a database's positions:
    a case drawn there is one the search cannot find (485 m off the grid was scored as the
    localiser's failure)."""
    gx0, gy0, gx1, gy1 = db_area(db)
    x0, y0, x1, y1 = (float(v) for v in area)
    tol = 1e-6 * max(1.0, db.spacing_m)  # the grid's own float coordinates, given back as typed
    if x0 < gx0 - tol or y0 < gy0 - tol or x1 > gx1 + tol or y1 > gy1 + tol:
        raise ParameterError(
            f"--area x {x0:.1f}..{x1:.1f}, y {y0:.1f}..{y1:.1f} reaches outside the database's "
            f"positions (x {gx0:.1f}..{gx1:.1f}, y {gy0:.1f}..{gy1:.1f}): scenario 1 cannot find a "
            "case drawn there; give an --area inside them, or none to draw within the database")


def map_offset_of(case_dir: Path) -> tuple[float, float]:
    """(dx, dy) [m] from a simulated case's truth to where its terrain lies on the map (0, 0 when
    the world was the map): read from the simulator's record, as the truth is."""
    from .simulate.world import recorded_map_offset

    data = json.loads((Path(case_dir) / "acquisition.json").read_text())
    return recorded_map_offset(data.get("simulation"))


def _pose_config(dem_sigma_m):
    """The localiser's settings for ``--dem-sigma-m``: the search weighs bins by that height error
    and the sigmas allow for it (None: the defaults, an unweighted search and 2 m sigmas)."""
    from .pose import PoseConfig

    if dem_sigma_m is None:
        return PoseConfig()
    return PoseConfig(dem_sigma_m=dem_sigma_m, map_sigma_m=dem_sigma_m)


def run_case(case_dir: Path, set_name: str, cfg: EvalConfig, dem, db, rng: np.random.Generator,
             case_index: int) -> tuple[CaseResult, dict]:
    """One case through the board pipeline; returns the result and what the figures need."""
    from .formats import load_acquisition, load_truth
    from .north import meridian_convergence_deg
    from .pose import estimate_heading, locate
    from .profile import acquisition_profile, profile_bins

    truth = load_truth(case_dir)  # scoring only: the pipeline below never sees it
    # the simulator's yaw is from grid north; the report gives the truth from true north beside it
    res = CaseResult(case=case_dir.name, set=set_name, scenario=cfg.scenario, truth_x=truth.x,
                     truth_y=truth.y, truth_yaw_deg=truth.yaw_deg,
                     truth_meridian_convergence_deg=meridian_convergence_deg(dem.crs_wkt, truth.x, truth.y),
                     truth_pitch_deg=truth.pitch_deg, truth_roll_deg=truth.roll_deg)
    res.map_offset_x_m, res.map_offset_y_m = map_offset_of(case_dir)
    if cfg.scenario == 3:  # before anything can fail: a failed case is counted at its offset
        res.prior_offset_m = HEADING_PRIOR_OFFSETS_M[case_index % len(HEADING_PRIOR_OFFSETS_M)]
    extra: dict = {}
    try:
        acq = load_acquisition(case_dir)
        t0 = time.perf_counter()
        profile = acquisition_profile(acq, detector=cfg.detector,
                                      skylines=truth_skylines(acq) if cfg.skylines == "truth" else None,
                                      azimuth_bins=profile_bins(db))
        res.time_profile_s = time.perf_counter() - t0
        extra["profile"] = profile
        extra["prior"] = (acq.prior_pitch_deg, acq.prior_roll_deg)
        t0 = time.perf_counter()
        if cfg.scenario == 3:
            off = HEADING_PRIOR_OFFSETS_M[case_index % len(HEADING_PRIOR_OFFSETS_M)]
            ang = rng.uniform(0, 2 * np.pi)
            x, y = truth.x + off * math.sin(ang), truth.y + off * math.cos(ang)
            head_prior = (truth.yaw_deg + rng.uniform(-5.0, 5.0)) % 360.0
            res.prior_offset_m = off
            hf = estimate_heading(profile, dem, x, y, head_prior, window_deg=10.0,
                                  camera_height_m=acq.camera_height_m, planet=cfg.planet,
                                  prior_pitch_deg=acq.prior_pitch_deg, prior_roll_deg=acq.prior_roll_deg)
            res.fix_x, res.fix_y = x, y
            res.fix_grid_heading_deg = hf.grid_heading_deg
            res.meridian_convergence_deg = hf.meridian_convergence_deg  # at the rough (x, y)
            res.fix_pitch_deg, res.fix_roll_deg = hf.pitch_deg, hf.roll_deg
            res.heading_sigma_deg, res.confidence, res.score = hf.heading_sigma_deg, hf.confidence, hf.score
            extra["features"] = dict(hf.features)
        else:
            kw = {}
            if cfg.scenario == 2:
                r, ang = DRIFT_M * math.sqrt(rng.uniform()), rng.uniform(0, 2 * np.pi)
                kw = {"prior_xy": (truth.x + r * math.sin(ang), truth.y + r * math.cos(ang)),
                      "prior_radius_m": DRIFT_M * 1.25}
                res.prior_offset_m = r
            fix = locate(profile, db=db if cfg.scenario == 1 else None, dem=dem,
                         prior_pitch_deg=acq.prior_pitch_deg, prior_roll_deg=acq.prior_roll_deg,
                         camera_height_m=acq.camera_height_m, planet=cfg.planet,
                         config=_pose_config(cfg.dem_sigma_m), **kw)
            res.fix_x, res.fix_y = fix.x, fix.y
            res.fix_grid_heading_deg = fix.grid_heading_deg
            res.meridian_convergence_deg = fix.meridian_convergence_deg
            res.fix_pitch_deg, res.fix_roll_deg = fix.pitch_deg, fix.roll_deg
            res.position_sigma_m, res.heading_sigma_deg = fix.position_sigma_m, fix.heading_sigma_deg
            res.confidence, res.score = fix.confidence, fix.score
            extra["fix"] = fix
            extra["features"] = dict(fix.features)
        res.time_locate_s = time.perf_counter() - t0
    except SkyfixError as e:
        res.status = f"{type(e).__name__}: {e}"
        log.warning("case %s failed: %s", case_dir.name, e)
    res.peak_rss_mb = peak_rss_mb()
    return res, extra


def truth_skylines(acq):
    """The simulator's exact skylines of an acquisition's images (diagnosis only)."""
    from .formats import read_skyline_json

    names = [f.image for f in acq.frames] if acq.frames else [acq.panorama.image]
    return [read_skyline_json(acq.root / (Path(n).stem + ".skyline.json")) for n in names]


def evaluate(dem_path, cfg: EvalConfig, out, *, db_path=None, overwrite: bool = False,
             progress: bool = True, command: str = "") -> Path:
    """Simulate ``cfg.cases`` cases per set, run them, write results.csv, tables, figures and
    report.html under ``out``. Returns the report's path."""
    from ._io import check_can_write
    from .dem import load_dem
    from .simulate import MapErrors, plan_set, simulate_set

    # Everything that can be refused is checked before ``out`` is created, so a refusal leaves
    # nothing behind.
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{out} exists and is not a folder: choose another --out")
    if out.exists() and any(out.iterdir()) and not overwrite:
        check_can_write(out, overwrite)
    dem = load_dem(dem_path)
    db = None
    area = cfg.area
    if cfg.scenario == 1:
        if db_path is None:
            raise ParameterError("scenario 1 searches a skyline database: give --db DB "
                                 "(build one with `skyfix build-db`)")
        from .database import check_dem_crs, open_database

        db = open_database(db_path)
        check_dem_crs(db, dem, db_path, dem_path)
        if abs(db.camera_height_m - cfg.camera_height_m) > 1e-6:
            raise ParameterError(f"the database was built for a camera {db.camera_height_m} m high, "
                                 f"the cases use {cfg.camera_height_m} m")
        if area is not None:
            check_area_in_database(area, db)
        area = area or db_area(db, margin_m=2 * db.spacing_m)
    for s_i, set_name in enumerate(cfg.sets):  # an area outside the DEM, or mostly void there
        plan_set(dem, set_name, cfg.cases, cfg.seed + s_i, area=area,
                 camera_height_m=cfg.camera_height_m, planet=cfg.planet)
    if overwrite and out.is_dir():
        clear_outputs(out)  # the folder describes one run: no overlay or case of the last one
    out.mkdir(parents=True, exist_ok=True)
    results: list[CaseResult] = []
    features: list[dict] = []
    examples: list[tuple[CaseResult, dict, Path]] = []
    rng = np.random.default_rng(cfg.seed + 1000 * cfg.scenario)
    for s_i, set_name in enumerate(cfg.sets):
        t0 = time.perf_counter()
        case_dirs = simulate_set(dem, set_name, cfg.cases, cfg.seed + s_i, out / "cases" / set_name,
                                 area=area, overwrite=True, tilt_deg=cfg.tilt_deg,
                                 camera_height_m=cfg.camera_height_m, planet=cfg.planet,
                                 map_errors=MapErrors() if cfg.map_errors else None)
        t_sim = (time.perf_counter() - t0) / max(len(case_dirs), 1)
        for k, cdir in enumerate(case_dirs):
            res, extra = run_case(Path(cdir), set_name, cfg, dem, db, rng, k)
            res.time_simulate_s = t_sim
            results.append(res)
            if "features" in extra:
                features.append(calibration_row(res, extra["features"], dem))
            if k < 1:
                examples.append((res, extra, Path(cdir)))
            if progress:
                print(f"{set_name} {k + 1}/{len(case_dirs)}: "
                      + (f"pos err {res.position_error_map_m:.2f} m, " if cfg.scenario != 3 else
                         f"prior off {res.prior_offset_m:.0f} m, ")
                      + f"heading err {res.heading_error_deg:.2f} deg, conf {res.confidence:.2f}"
                      + ("" if res.status == "ok" else f" [{res.status[:60]}]"), flush=True)
    from ._io import write_jsonl

    write_jsonl(out / "calibration.jsonl", features)
    return write_outputs(out, results, examples, cfg, dem, command=command)


#: what an evaluation writes into its folder (and ``overlay_*.png``): all that --overwrite removes
EVAL_OUTPUTS = ("cases", "results.csv", "tables.txt", "tables.md", "report.html", "error_cdf.png",
                "reliability.png", "calibration.jsonl")


def clear_outputs(out: Path) -> None:
    """Remove an earlier evaluation's outputs from ``out`` (and nothing else in it)."""
    import shutil

    for p in [out / n for n in EVAL_OUTPUTS] + sorted(out.glob("overlay_*.png")):
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        elif p.exists() or p.is_symlink():
            p.unlink()


CALIBRATION_KEYS = {1: "locate", 2: "locate_prior", 3: "heading"}


def calibration_row(res: CaseResult, features: dict, dem) -> dict:
    """One line of ``calibration.jsonl``: the localiser's confidence features with the truth's
    verdict, in the form ``scripts/calibrate_confidence.py fit --cases`` reads."""
    # beyond the simulated misregistration, as "correct" counts it: the sigma model is fitted to
    # this error and judged against it
    err = res.heading_error_deg if res.scenario == 3 else res.position_error_map_m
    return {"scenario": CALIBRATION_KEYS[res.scenario], "dem": Path(dem.source).name, "set": res.set,
            "case": res.case, "source": "evaluate", "err": float(err), "correct": bool(res.correct),
            "confidence": float(res.confidence), **{k: float(v) for k, v in features.items()}}


def write_outputs(out: Path, results, examples, cfg: EvalConfig, dem, *, command: str) -> Path:
    from .report import (case_rows, format_table, heading_vs_prior_rows, memory_rows,
                         plot_error_cdfs, plot_reliability, reliability_rows, sigma_coverage_rows,
                         summary_rows, timing_rows, write_report_html, write_results_csv)

    write_results_csv(results, out / "results.csv")
    tables = [("Results per set", summary_rows(results))]
    if cfg.scenario == 3:
        tables.append(("Heading error vs prior position error", heading_vs_prior_rows(results)))
    tables.append(("Confidence reliability", reliability_rows(results)))
    tables.append(("How often the 1-sigmas cover the errors", sigma_coverage_rows(results)))
    tables.append(("Time per stage (rover CPU ~30x slower)", timing_rows(results, cfg.scenario)))
    tables.append(("Memory", memory_rows(results)))
    text = "\n\n".join(f"{h}\n{format_table(rows)}" for h, rows in tables)
    _write_text(out / "tables.txt", text + "\n")
    _write_text(out / "tables.md", "\n\n".join(f"### {h}\n\n{format_table(rows, 'markdown')}"
                                                for h, rows in tables) + "\n")
    figs = [plot_error_cdfs(results, out / "error_cdf.png", cfg.scenario),
            plot_reliability(results, out / "reliability.png")]
    for res, extra, cdir in examples:
        if "profile" in extra:
            try:
                pp, pr = extra["prior"]
                figs.append(plot_skyline_overlay(out / f"overlay_{res.set}_{res.case}.png", res,
                                                 extra["profile"], dem, cfg, prior_pitch_deg=pp,
                                                 prior_roll_deg=pr))
            except SkyfixError as e:
                log.warning("no overlay for %s: %s", res.case, e)
    print(text)
    from .detect.options import DEFAULT_METHOD

    intro = (f"Scenario {cfg.scenario}, sets {', '.join(cfg.sets)}, {cfg.cases} cases per set, seed "
             f"{cfg.seed}, DEM {Path(dem.source).name}, detector {cfg.detector or DEFAULT_METHOD}. "
             "'correct' = within the scenario's tolerance; "
             "confidence is the localiser's own, never told the truth.")
    if cfg.skylines == "truth":
        intro += (" DIAGNOSIS RUN: detection was bypassed with the simulator's exact skylines; these "
                  "numbers measure projection and localisation only, not the whole pipeline.")
    return write_report_html(out, title=f"skyfix evaluation: scenario {cfg.scenario}", intro=intro,
                             sections=[(h, format_table(rows, "html")) for h, rows in tables]
                             + [("Every case", format_table(case_rows(results), "html"))],
                             figures=figs, command=command)


def _write_text(path: Path, text: str) -> None:
    """Write ``text`` atomically: a crash never leaves a truncated table behind."""
    from ._io import atomic_path

    with atomic_path(path) as tmp:
        tmp.write_text(text)


def plot_skyline_overlay(path, res: CaseResult, profile, dem, cfg: EvalConfig, *,
                         prior_pitch_deg: float = 0.0, prior_roll_deg: float = 0.0) -> Path:
    """Measured body-frame profile (levelled with the attitude prior [deg]) vs the DEM's skyline
    rendered at the truth and at the fix and seen through the same levelling."""
    from .horizon import render_horizons
    from .pose import body_profile
    from .optional import pyplot
    from .report import save_figure

    plt = pyplot()
    n = profile.n_bins
    fig, ax = plt.subplots(figsize=(9, 3))
    az = profile.azimuth_deg
    for label, x, y, yaw, pitch, roll, style in (
            ("DEM at truth", res.truth_x, res.truth_y, res.truth_yaw_deg, res.truth_pitch_deg,
             res.truth_roll_deg, dict(color="tab:green", lw=2, alpha=0.6)),
            ("DEM at fix", res.fix_x, res.fix_y, res.fix_grid_heading_deg, res.fix_pitch_deg,
             res.fix_roll_deg, dict(color="tab:red", lw=1, ls="--"))):
        if not all(math.isfinite(v) for v in (x, y, yaw)):
            continue
        world = render_horizons(dem, [x], [y], camera_height_m=cfg.camera_height_m, planet=cfg.planet,
                                azimuth_bins=4 * n).elevation_deg[0]
        body = body_profile(world, yaw, np.nan_to_num(pitch), np.nan_to_num(roll), n_bins=n,
                            prior_pitch_deg=prior_pitch_deg, prior_roll_deg=prior_roll_deg)
        ax.plot(az, body, label=label, **style)
    ax.plot(az, profile.elevation_deg, ".", ms=2, color="k",
            label="measured (exact skylines: detection bypassed)" if cfg.skylines == "truth"
            else "measured (detected)")
    ax.set_xlim(0, 360)
    ax.set_xlabel("azimuth from the rover's forward axis [deg]")
    ax.set_ylabel("elevation [deg]")
    ax.set_title(f"{res.set} {res.case}: position error {res.position_error_map_m:.2f} m, heading error "
                 f"{res.heading_error_deg:.2f} deg, confidence {res.confidence:.2f}", fontsize=9)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    fig.tight_layout()
    return save_figure(fig, path)


def evaluate_detection(images_dir, out=None, *, method: str | None = None) -> list[dict]:
    """Score the detector on every ``NAME.png`` with a ``NAME.skyline.json`` truth in a folder.

    Truth and image are paired by name; a truth whose ``image`` field names another image is
    refused, before any detection."""
    from .detect import DEFAULT_METHOD, combine_scores, detect_skyline, score_skyline
    from .formats import read_skyline_json
    from .profile import read_rgb

    method = method or DEFAULT_METHOD

    images_dir = Path(images_dir)
    if not images_dir.is_dir():
        raise ParameterError(f"{images_dir} is not a folder of images with *.skyline.json truth")
    pairs = []
    no_image = []
    for tpath in sorted(images_dir.glob("*.skyline.json")):
        name = tpath.name[: -len(".skyline.json")]
        img_path = images_dir / f"{name}.png"
        if not img_path.exists():
            no_image.append(tpath.name)
            continue
        truth = read_skyline_json(tpath)
        if truth.image and Path(truth.image).name != img_path.name:
            # swapped or copied labels of one size passed the size check and were scored
            raise ParameterError(
                f"{tpath.name} is the truth of {truth.image!r} (its 'image' field), not of "
                f"{img_path.name} beside it (NAME.skyline.json is scored on NAME.png): rename it "
                f"{Path(truth.image).stem}.skyline.json, or correct its 'image' field")
        pairs.append((name, img_path, tpath, truth))
    rows, spent = [], []
    warm = False
    for name, img_path, tpath, truth in pairs:
        img = read_rgb(img_path)
        if (truth.width, truth.height) != (img.shape[1], img.shape[0]):
            # scoring a truth drawn on another image would be silently meaningless
            raise ParameterError(
                f"{tpath.name} is for a {truth.width} x {truth.height} px image, {img_path.name} is "
                f"{img.shape[1]} x {img.shape[0]} px: give the truth drawn on this image")
        if not warm:  # the first call loads models and compiled kernels: not the image's time
            detect_skyline(img, method=method, name=img_path.name)
            warm = True
        t0 = time.perf_counter()
        pred = detect_skyline(img, method=method, name=img_path.name)
        dt = time.perf_counter() - t0
        sc = score_skyline(pred, truth)
        mpx = img.shape[0] * img.shape[1] / 1e6
        sc = {"image": name, **sc, "ms_per_mpx": 1000 * dt / mpx}
        rows.append(sc)
        spent.append((dt, mpx))
    if no_image:
        log.warning("%d truth file(s) without a NAME.png beside them, not scored: %s",
                    len(no_image), ", ".join(no_image[:5]) + (" ..." if len(no_image) > 5 else ""))
    if not rows:
        raise ParameterError(f"no NAME.png with NAME.skyline.json in {images_dir}")
    total = {"image": "all", **combine_scores([{k: v for k, v in r.items() if k != "image"} for r in rows])}
    # pooled as bench_detect pools it: all the time over all the pixels
    total["ms_per_mpx"] = 1000 * sum(t for t, _ in spent) / sum(m for _, m in spent)
    return rows + [total]
