"""``skyfix evaluate`` and ``skyfix evaluate-detect``."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

import click

from ..detect.options import DEFAULT_METHOD, METHODS
from ..errors import OutputExistsError, ParameterError
from .options import dem_sigma, detector_option, given, overwrite_option, traverse_path_options


#: flag -> why a scenario does not read it, for an option given with a scenario that ignores it
#: (each was once ignored without a word: a traverse evaluated with --map-errors ran without any)
NOT_READ = {
    "traverse": {
        "sets": "simulates one traverse, it draws no robustness sets",
        "cases": "simulates one traverse (--length-m, --stop-spacing-m), not sets of cases",
        "db_path": "fixes positions on the DEM, it reads no database",
        "area": "plans its path over the DEM from --seed, it draws nothing in an area",
        "camera_height_m": "renders its stops at the traverse simulator's camera height",
        "tilt_deg": "renders levelled panoramas, not tilted frames",
        "skylines": "detects every stop's skyline, it has no truth bypass",
        "dem_sigma_m": "fixes its stops with the localiser's default DEM error",
        "overwrite": "resumes its own earlier output, it replaces nothing (choose another -o to "
                     "start afresh)",
    },
    **{s: {"length_m": "simulates no traverse (--scenario traverse does)",
           "stop_spacing_m": "simulates no traverse (--scenario traverse does)",
           "stop_conditions": "simulates no traverse (--scenario traverse does)"}
       for s in ("1", "2", "3")},
}
NOT_READ["2"]["db_path"] = "searches the DEM around a prior, it reads no database"
NOT_READ["3"]["db_path"] = "finds the heading at a rough position, it reads no database"
# estimate_heading takes a DEM error only for a narrow view's image-plane solve, which the
# evaluation's cases never reach: the weights and sigmas of its profile fit take none
NOT_READ["3"]["dem_sigma_m"] = "solves the heading on the profile, which takes no DEM error"

#: the flags of parameters whose name is not the flag's
FLAGS = {"db_path": "--db"}


def check_scenario_options(scenario: str) -> None:
    """Refuse an option given on the command line that ``scenario`` does not read (call inside
    the command: :func:`skyfix.cli.options.given` reads click's context)."""
    named = [(FLAGS.get(n, "--" + n.replace("_", "-")), why)
             for n, why in NOT_READ[scenario].items() if given(n)]
    if not named:
        return
    by_why: dict[str, list[str]] = {}  # one reason once, with every flag it covers
    for flag, why in named:
        by_why.setdefault(why, []).append(flag)
    flags = [f for f, _ in named]
    drop = flags[0] if len(flags) == 1 else ", ".join(flags[:-1]) + " and " + flags[-1]
    raise ParameterError("; ".join(f"{', '.join(fs)}: scenario {scenario} {why}"
                                   for why, fs in by_why.items()) + f"; drop {drop}")


@click.command()
@click.option("--dem", "dem_path", required=True, type=click.Path(dir_okay=False), help="DEM: any raster GDAL reads (GeoTIFF, PDS3 .IMG, ...).")
@click.option("--scenario", type=click.Choice(["1", "2", "3", "traverse"]), required=True,
              help="1: 7x7 km database search; 2: 40x40 m prior, DEM only; 3: heading only; "
                   "traverse: a simulated traverse fused with odometry (--length-m, --stop-spacing-m, "
                   "--stop-conditions).")
@click.option("--sets", default="REF", show_default=True,
              help="Comma-separated robustness sets: REF,HREL,SCOM,LREL,CLUT,OCCL,COND,DEMERR "
                   "(scenarios 1-3).")
@click.option("--cases", type=int, default=10, show_default=True, help="Cases per set (scenarios 1-3).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the draws, >= 0.")
@click.option("--db", "db_path", type=click.Path(file_okay=False), default=None,
              help="Skyline database (scenario 1); cases are drawn inside its grid.")
@click.option("--area", type=float, nargs=4, default=None, metavar="XMIN YMIN XMAX YMAX",
              help="Where cases are drawn [m]; scenario 1: within the database's positions (default: "
                   "the database grid, or the simulator's default).")
@click.option("--camera-height-m", type=float, default=1.5, show_default=True,
              help="Camera above the ground in the simulated cases (and the database's) [m].")
@click.option("--tilt-deg", type=float, default=15.0, show_default=True,
              help="Mast tilt of the simulated frames [deg] (SCOM sets its own).")
@click.option("--skylines", type=click.Choice(["detect", "truth"]), default="detect", show_default=True,
              help="'truth' bypasses detection with the simulator's exact skylines (diagnosis only).")
@click.option("--map-errors", is_flag=True,
              help="Render every set (or the traverse's stops) from a world that differs from "
                   "the map (as DEMERR does); position errors are then counted beyond the "
                   "simulated misregistration.")
@click.option("--dem-sigma-m", type=float, default=None,
              help="The DEM's height error [m]: the localiser weighs bins by it and its sigmas "
                   "allow for it (PoseConfig.dem_sigma_m and map_sigma_m) [default: unweighted, "
                   "sigmas for 2 m].")
@detector_option
@traverse_path_options
@click.option("-o", "--out", required=True, type=click.Path(file_okay=False), help="Output folder.")
@overwrite_option
def evaluate(dem_path, scenario, sets, cases, seed, db_path, area, camera_height_m, tilt_deg, skylines,
             map_errors, dem_sigma_m, detector, length_m, stop_spacing_m, stop_conditions, out,
             overwrite):
    """Simulate cases, run the board pipeline, and write results.csv, tables, figures and
    report.html to OUT."""
    from ..evaluate import EvalConfig
    from ..evaluate import evaluate as run
    from .._io import writing_to
    from ..optional import require

    check_scenario_options(scenario)
    require("matplotlib", "skyfix evaluate (its figures and report)")
    if dem_sigma_m is not None:  # None keeps the localiser's defaults (an unweighted search)
        dem_sigma(dem_sigma_m)
    args = sys.argv[sys.argv.index("evaluate") + 1:] if "evaluate" in sys.argv else []
    if scenario == "traverse":
        if detector is not None:
            raise ParameterError("--detector does not reach the simulated traverse of evaluate "
                                 "(its stops are detected with the default method): drop it, or "
                                 "run skyfix traverse --detector on the traverse")
        from ..simulate import MapErrors, check_seed
        from ..traverse.evaluation import evaluate_traverse
        from ..traverse.simulate import parse_stop_conditions

        check_seed(seed)
        conds = parse_stop_conditions(stop_conditions)
        o = Path(out)
        if o.exists() and (not o.is_dir() or (any(o.iterdir()) and not (
                (o / "traverse").is_dir() or (o / "result").is_dir()))):
            # a rerun into its own output resumes (traverse/ and result/ record what made them);
            # any other folder is someone else's, and report.html would land in it
            raise OutputExistsError(f"{out} is not an earlier `evaluate --scenario traverse` output "
                                    "and not an empty folder: choose another -o")
        with writing_to(out):
            report = evaluate_traverse(dem_path, out, length_m=length_m, stop_spacing_m=stop_spacing_m,
                                       seed=seed, stop_conditions=conds,
                                       map_errors=MapErrors() if map_errors else None,
                                       command="skyfix evaluate " + " ".join(shlex.quote(a) for a in args))
        click.echo(f"wrote {report}")
        return
    scenario = int(scenario)
    set_names = tuple(s.strip().upper() for s in sets.split(",") if s.strip())
    if set(set_names) == {"SCOM"} and given("tilt_deg"):
        # SCOM tilts each case's camera itself: the run would say nothing and ignore it
        raise ParameterError("--tilt-deg: not read by the set SCOM (it tilts each case's camera so "
                             "that the skyline leaves the top of the frame): drop it, or add a set "
                             "that reads it")

    cfg = EvalConfig(scenario=scenario, sets=set_names,
                     cases=cases, seed=seed, area=tuple(area) if area else None,
                     camera_height_m=camera_height_m, skylines=skylines,
                     tilt_deg=tilt_deg, map_errors=map_errors, dem_sigma_m=dem_sigma_m,
                     detector=detector)
    # The command that regenerates the report, as typed (for the report's own footer).
    command = "skyfix evaluate " + " ".join(shlex.quote(a) for a in args)
    with writing_to(out):
        report = run(dem_path, cfg, out, db_path=db_path, overwrite=overwrite, command=command)
    click.echo(f"wrote {report}")


@click.command("evaluate-detect")
@click.option("--images", "images_dir", required=True, type=click.Path(file_okay=False),
              help="Folder of NAME.png with NAME.skyline.json truth, paired by name (as "
                   "../shared/data/marsscapes-dev); a truth whose 'image' names another image is refused.")
@click.option("--method", type=click.Choice(METHODS), default=DEFAULT_METHOD, show_default=True)
@click.option("-o", "--out", "--output", "output", type=click.Path(dir_okay=False), default=None,
              help="Write the table as CSV.")
@overwrite_option
def evaluate_detect(images_dir, method, output, overwrite):
    """Score skyline detection on labelled images: mean row error, share within 3 / 10 px,
    false- and missed-skyline rates, milliseconds per megapixel."""
    from .._io import atomic_path, check_outputs
    from ..evaluate import evaluate_detection
    from ..report import format_table

    from pathlib import Path

    folder = Path(images_dir)
    # --overwrite onto a truth file of the folder replaced it with the table
    ins = [*folder.glob("*.png"), *folder.glob("*.skyline.json")] if folder.is_dir() else []
    check_outputs(overwrite, ("--output", output, None), inputs=ins)
    rows = evaluate_detection(images_dir, method=method)
    # the rates as percentages on screen (0.45 % printed as 0.00 of 1, hiding the 1 % bars);
    # the CSV keeps the fractions
    rates = ("within_3px", "within_10px", "false_rate", "missed_rate")
    click.echo(format_table([{(f"{k}_pct" if k in rates else k): (100.0 * v if k in rates else v)
                              for k, v in r.items()} for r in rows]))
    if output:
        import csv

        with atomic_path(output, suffix=".csv") as tmp:
            with open(tmp, "w", newline="") as f:
                w = csv.DictWriter(f, fieldnames=list(rows[0]))
                w.writeheader()
                w.writerows(rows)
        click.echo(f"wrote {output}")
