"""``skyfix simulate`` and ``skyfix simulate-set``: synthetic acquisitions with exact truth."""

from __future__ import annotations

import click

from .._io import writing_to
from ..errors import ParameterError
from .options import given

CONDITION_HELP = ("Comma-separated degradations, each NAME or NAME:STRENGTH in [0, 1]: dust, clouds "
                  "(Earth), snow (Earth), lake (Earth), rocks, glare, overexposed, dark, blur. "
                  "Example: dust:0.5,rocks.")


#: options that only one --mode reads: given with the other, they were ignored without a word
MODE_OPTIONS = {"frames": ("camera", "frames", "pan_start_deg", "pan_step_deg", "tilt_deg"),
                "panorama": ("pano_size",)}


def _check_mode_options(mode: str) -> None:
    """Refuse an option given on the command line that ``mode`` does not read."""
    named = [name for other, names in MODE_OPTIONS.items() if other != mode for name in names
             if given(name)]
    if named:
        flags = ", ".join("--" + g.replace("_", "-") for g in named)
        many = len(named) > 1
        raise ParameterError(f"{flags}: not read in --mode {mode} ({'they are' if many else 'it is'} "
                             f"for --mode {'frames' if mode == 'panorama' else 'panorama'}): drop "
                             f"{'them' if many else 'it'}")


@click.command("simulate")
@click.argument("dem", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--x", "x", type=float, required=True,
              help="Rover easting [m] in the DEM's work CRS (`skyfix info DEM` prints it).")
@click.option("--y", "y", type=float, required=True, help="Rover northing [m] in the DEM's work CRS.")
@click.option("--yaw-deg", type=float, required=True,
              help="Heading, clockwise from grid north [deg]; written normalised to [0, 360).")
@click.option("--pitch-deg", type=float, default=0.0, show_default=True, help="Nose up positive [deg].")
@click.option("--roll-deg", type=float, default=0.0, show_default=True, help="Right side down positive [deg].")
@click.option("--camera-height-m", type=float, default=1.5, show_default=True, help="Camera above ground [m].")
@click.option("--mode", type=click.Choice(["frames", "panorama"]), default="frames", show_default=True)
@click.option("--camera", type=click.Choice(["navcam", "wide"]), default="navcam", show_default=True,
              help="Camera preset for frames.")
@click.option("--pano-size", type=int, nargs=2, default=(4096, 1024), show_default=True,
              metavar="W H", help="Panorama size [px] (360 x 90 deg).")
@click.option("--frames", type=int, default=None, help="Number of frames (default: a full turn).")
@click.option("--pan-start-deg", type=float, default=None, help="Pan of the first frame [deg].")
@click.option("--pan-step-deg", type=float, default=None,
              help="Pan step [deg] (default: 2/3 of the field of view).")
@click.option("--tilt-deg", type=float, default=15.0, show_default=True,
              help="Mast tilt of every frame, up positive [deg] (the default of evaluate and demo too; "
                   "frames only: a panorama is levelled).")
@click.option("--prior-pitch-deg", type=float, default=None,
              help="Inclinometer pitch to report, within +-60 [deg] (default: true).")
@click.option("--prior-roll-deg", type=float, default=None,
              help="Inclinometer roll to report, within +-60 [deg] (default: true).")
@click.option("--conditions", default=None, help=CONDITION_HELP)
@click.option("--seed", type=int, default=0, show_default=True,
              help="Seed of the looks (sun, texture, noise, rocks), >= 0.")
@click.option("--planet", default=None,
              help="earth, mars, moon or a radius [m]; default: the body of the DEM's CRS (an Earth CRS may stand in for any body).")
@click.option("--crs", default=None, help="Target CRS when the DEM must be reprojected.")
@click.option("-o", "--out", "out", type=click.Path(file_okay=False), required=True, help="Output folder.")
@click.option("--overwrite", is_flag=True,
              help="Replace a non-empty --out, whole, once the new one is complete.")
def simulate(dem, x, y, yaw_deg, pitch_deg, roll_deg, camera_height_m, mode, camera, pano_size, frames,
             pan_start_deg, pan_step_deg, tilt_deg, prior_pitch_deg, prior_roll_deg, conditions, seed,
             planet, crs, out, overwrite):
    """Render an acquisition of DEM seen from (X, Y) with its exact skylines.

    Several DEMs of one place make a stack (a 1 m DTM inside a 20 m one inside a global one): the
    finest that covers a point is the terrain there, as in build-db and locate."""
    from ..stack import load_dems
    from ..formats import Truth
    from ..simulate import (Conditions, check_attitude_prior, check_render_options,
                            simulate_acquisition)

    # Fail on bad options before loading anything (simulate_acquisition checks them all again).
    _check_mode_options(mode)
    cond = Conditions.parse(conditions)
    check_render_options(mode=mode, camera=camera, camera_height_m=camera_height_m, tilt_deg=tilt_deg,
                  planet=planet, seed=seed, frames=frames, pan_start_deg=pan_start_deg,
                  pan_step_deg=pan_step_deg, pano_size=pano_size)
    prior = None
    if prior_pitch_deg is not None or prior_roll_deg is not None:
        prior = check_attitude_prior((pitch_deg if prior_pitch_deg is None else prior_pitch_deg,
                              roll_deg if prior_roll_deg is None else prior_roll_deg))
    for p in dem:
        _check_out(out, overwrite, p)
    d = load_dems(dem, crs=crs)
    with writing_to(out):
        path = simulate_acquisition(
            d, Truth(x, y, yaw_deg, pitch_deg, roll_deg), out, camera=camera, mode=mode, frames=frames,
            pan_start_deg=pan_start_deg, pan_step_deg=pan_step_deg, tilt_deg=tilt_deg,
            camera_height_m=camera_height_m, planet=planet, conditions=cond, seed=seed,
            overwrite=overwrite, attitude_prior=prior, pano_size=pano_size)
    click.echo(acquisition_summary(path))


@click.command("simulate-set")
@click.argument("dem", type=click.Path(dir_okay=False))
@click.option("--set", "name", required=True, help="REF, HREL, SCOM, LREL, CLUT, OCCL, COND or DEMERR.")
@click.option("--cases", type=int, default=10, show_default=True, help="Number of cases.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the draws, >= 0.")
@click.option("--area", type=float, nargs=4, default=None, metavar="XMIN YMIN XMAX YMAX",
              help="Where positions are drawn [m] (default: DEM bounds minus a margin).")
@click.option("--mode", type=click.Choice(["frames", "panorama"]), default="frames", show_default=True)
@click.option("--camera", type=click.Choice(["navcam", "wide"]), default="navcam", show_default=True)
@click.option("--pano-size", type=int, nargs=2, default=(4096, 1024), show_default=True,
              metavar="W H", help="Panorama size [px] (360 x 90 deg).")
@click.option("--frames", type=int, default=None, help="Frames per case (default: a full turn).")
@click.option("--camera-height-m", type=float, default=1.5, show_default=True)
@click.option("--tilt-deg", type=float, default=15.0, show_default=True,
              help="Mast tilt of the frames, up positive [deg] (SCOM sets its own and refuses it; "
                   "the default of simulate, evaluate and demo too).")
@click.option("--planet", default=None,
              help="earth, mars, moon or a radius [m]; default: the body of the DEM's CRS (an Earth CRS may stand in for any body).")
@click.option("--crs", default=None, help="Target CRS when the DEM must be reprojected.")
@click.option("--map-errors", is_flag=True,
              help="Render from a world that differs from the map DEM (DEMERR does by default).")
@click.option("--world-dem", type=click.Path(dir_okay=False), default=None,
              help="Render from this second DEM of the same place instead of DEM (cases are still "
                   "drawn on DEM, the map).")
@click.option("-o", "--out", "out", type=click.Path(file_okay=False), required=True, help="Output folder.")
@click.option("--overwrite", is_flag=True,
              help="Replace a non-empty --out, whole, once the new one is complete.")
def simulate_set(dem, name, cases, seed, area, mode, camera, pano_size, frames, camera_height_m, tilt_deg,
                 planet, crs, map_errors, world_dem, out, overwrite):
    """Render a named robustness set of acquisitions (one subfolder per case)."""
    from ..dem import load_dem
    from ..errors import ParameterError
    from ..progress import bars_shown
    from ..simulate import SETS, check_render_options
    from ..simulate import simulate_set as run_set

    if name.upper() not in SETS:
        raise ParameterError(f"unknown set {name!r}: choose one of {', '.join(SETS)}")
    if cases < 1:
        raise ParameterError(f"cases must be >= 1, got {cases}")
    # Fail on bad options before loading anything (simulate_set checks them all again).
    _check_mode_options(mode)
    if name.upper() == "SCOM" and given("tilt_deg"):
        # SCOM tilts each case's camera itself: --tilt-deg was rendered at another tilt, exit 0
        raise ParameterError("--tilt-deg: not read by --set SCOM (it tilts each case's camera so "
                             "that the skyline leaves the top of the frame): drop it, or choose "
                             "another set")
    check_render_options(mode=mode, camera=camera, camera_height_m=camera_height_m, tilt_deg=tilt_deg,
                  planet=planet, seed=seed, frames=frames, pano_size=pano_size)
    if map_errors and world_dem:
        raise ParameterError("give --map-errors or --world-dem, not both")
    for p in (dem, world_dem):  # --overwrite replaces --out whole: neither may lie inside it
        if p is not None:
            _check_out(out, overwrite, p)
    d = load_dem(dem, crs=crs)
    world = None
    if world_dem is not None:
        world = load_dem(world_dem, crs=d.crs_wkt)  # the map's work CRS, so positions agree
    from ..simulate import MapErrors

    with writing_to(out):
        folders = run_set(d, name, cases, seed, out, area=area or None, camera=camera, mode=mode,
                          frames=frames, camera_height_m=camera_height_m, planet=planet,
                          overwrite=overwrite, tilt_deg=tilt_deg, pano_size=pano_size,
                          progress=bars_shown(),
                          map_errors=MapErrors() if map_errors else None, world=world)
    click.echo(f"{len(folders)} case{'s' * (len(folders) != 1)} in {out}")


def acquisition_summary(folder) -> str:
    """One line on what ``simulate`` wrote in ``folder``, read back from its acquisition.json: the
    images, the pose, and in how many image columns the terrain skyline is there to be found (a
    frame tilted too low, or facing a slope that fills it, holds none)."""
    import json
    from pathlib import Path

    from ..formats import read_skyline_json

    acq = json.loads((Path(folder) / "acquisition.json").read_text())
    t, sim = acq["truth"], acq["simulation"]
    images = sim["images"]
    n = len(images)
    # the widths from the truth skylines beside the images (acquisition.json gives a panorama's
    # field of view, not its pixels)
    widths = [read_skyline_json(Path(folder) / (Path(i["image"]).stem + ".skyline.json")).width
              for i in images]
    if "panorama" in acq:
        what = f"a panorama {widths[0]} px wide"
    else:
        c = acq["camera"]
        what = f"{n} frame{'s' * (n != 1)}, {c['width']} x {c['height']} px"
    found = sum(i["terrain_skyline_columns"] for i in images)
    ground = sum(b - a for i in images for a, b in i["ground_only_columns"])
    sky = sum(b - a for i in images for a, b in i["sky_only_columns"])
    cols = sum(widths)
    return (f"{folder}: {what}, seen from ({t['x']:.1f}, {t['y']:.1f}) at yaw {t['yaw_deg']:.1f} "
            f"deg, pitch {t['pitch_deg']:.1f}, roll {t['roll_deg']:.1f}, the camera "
            f"{acq['camera_height_m']:g} m above the ground at {sim['ground_z_m']:.1f} m; the "
            f"terrain skyline in {found:,} of {cols:,} columns ({100 * found / cols:.0f} %; ground "
            f"only {ground:,}, sky only {sky:,}); the truth in acquisition.json"
            + ("" if found else ": no image shows a skyline to fix from (tilt the camera up, "
               "--tilt-deg, or move it)"))


def _check_out(out, overwrite: bool, dem=None) -> None:
    """Refuse a non-empty --out before any heavy work, and one that holds the DEM (--overwrite
    replaces the folder whole, which would delete the DEM)."""
    from pathlib import Path

    from ..errors import OutputExistsError, ParameterError
    from ..simulate.folders import check_not_current

    p = Path(out)
    check_not_current(p)
    if p.exists() and not p.is_dir():
        raise OutputExistsError(f"{p} exists and is not a folder: choose another --out")
    if p.is_dir() and any(p.iterdir()) and not overwrite:
        raise OutputExistsError(f"{p} is not empty: pass --overwrite to replace it")
    if dem is not None and p.exists():
        d, o = Path(dem).resolve(), p.resolve()
        if o == d.parent or o in d.parents:
            raise ParameterError(f"the DEM {dem} lies inside --out {out}: choose another --out")
