"""``skyfix heading`` and ``skyfix attitude``: heading, pitch and roll from a rough position.

Imports stay light at module level (the process must fit in 256 MB): numpy, the DEM loader and
the pose solver are imported only when used.
"""

from __future__ import annotations

import sys

import click

from ..errors import ParameterError
from .acqinput import (check_detector, check_source, detector_used, input_files, read_acquisition,
                       read_profile)
from .main import note
from .options import (camera_height, check_point_options, dem_sigma, detector_option, given,
                      point_xy)


@click.command("heading")
@click.argument("acq_dir", required=False, type=click.Path(file_okay=False))
@click.option("--profile", "profile_path", type=click.Path(dir_okay=False),
              help="Body-frame profile JSON instead of an acquisition folder.")
@click.option("--dem", "dem_paths", required=True, multiple=True, type=click.Path(dir_okay=False),
              help="DEM (repeat it for a stack of DEMs of one place).")
@click.option("--x", "x", type=float, help="Rough position x [m] in the work CRS.")
@click.option("--y", "y", type=float, help="Rough position y [m].")
@click.option("--lon", type=float, help="Rough longitude [deg] on the DEM's body, instead of --x/--y.")
@click.option("--lat", type=float, help="Rough latitude [deg].")
@click.option("--heading-prior-deg", type=float,
              help="Heading prior [deg], clockwise from true north (from grid north with "
                   "--prior-north grid). Without one, the full circle is searched.")
@click.option("--prior-north", type=click.Choice(["true", "grid"]), default="true", show_default=True,
              help="Which north the heading prior is measured from.")
@click.option("--window-deg", default=10.0, show_default=True, type=float,
              help="Search +/- this around the prior [deg], within (0, 180] (needs "
                   "--heading-prior-deg; without a prior the whole circle is searched).")
@click.option("--camera-height-m", type=float, callback=camera_height,
              help="Camera height [m] (default: the acquisition's).")
@click.option("--position-sigma-m", type=float, default=None,
              help="How far the rough position may be off [m]: skylines near enough for that to "
                   "move them by degrees weigh less; 0: every bin alike [default: 10].")
@click.option("--dem-sigma-m", type=float, default=None,
              help="The DEM's height error (rms) [m] against the terrain the camera sees, which the "
                   "sigmas of a narrow view (one frame) allow for; 0: the DEM is the world "
                   "[default: 2].")
@detector_option
@click.option("-o", "--out", "--output", "out", type=click.Path(dir_okay=False),
              help="The result's JSON (default stdout).")
@click.option("--overwrite", is_flag=True, help="Replace an existing output.")
def heading(acq_dir, profile_path, dem_paths, x, y, lon, lat, heading_prior_deg, prior_north,
            window_deg, camera_height_m, position_sigma_m, dem_sigma_m, detector, out, overwrite):
    """Find the heading only, from a rough position."""
    import math
    from dataclasses import replace

    import numpy as np

    from .._io import check_outputs, to_json, write_json
    from ..stack import load_dems
    from ..north import grid_heading_from_true, meridian_convergence_deg
    from ..pose import at_window_edge, estimate_heading

    check_source(acq_dir, profile_path)
    check_detector(profile_path, detector)
    # checked with a prior or without: 0, -5, 400 and nan were taken without a word when there
    # was none (the whole circle replaced them)
    if not (math.isfinite(window_deg) and 0 < window_deg <= 180):
        raise ParameterError(f"--window-deg must be within (0, 180] deg, got {window_deg}")
    prior_given = heading_prior_deg
    if heading_prior_deg is None:  # no prior: the whole circle
        if given("window_deg"):
            raise ParameterError("--window-deg needs --heading-prior-deg: without a prior the "
                                 "whole circle is searched (give a prior, or drop --window-deg)")
        if given("prior_north"):  # was taken without a word: it says which north a prior is from
            raise ParameterError("--prior-north needs --heading-prior-deg: it says which north "
                                 "the prior is measured from (give a prior, or drop "
                                 "--prior-north)")
        heading_prior_deg, window_deg = 0.0, 180.0
    check_point_options(x, y, lon, lat)
    if not (math.isfinite(heading_prior_deg) and -360.0 <= heading_prior_deg <= 360.0):
        # 1e12 was wrapped into a heading without a word
        raise ParameterError(f"--heading-prior-deg must be an angle within [-360, 360] deg, "
                             f"clockwise from north, got {heading_prior_deg:g}")
    if position_sigma_m is None:
        from ..pose.heading import HEADING_POSITION_SIGMA_M as position_sigma_m
    if not (math.isfinite(position_sigma_m) and 0 <= position_sigma_m <= 1e5):
        # 1e300 passed as finite and overflowed in the weights
        raise ParameterError(f"--position-sigma-m must be a number of metres from 0 to 1e+05 (a "
                             f"position known to 100 km says nothing of a heading), got "
                             f"{position_sigma_m}")
    dem_sigma_m = dem_sigma(dem_sigma_m)
    acq = read_acquisition(acq_dir)
    check_outputs(overwrite, ("--output", out, None),
                  inputs=input_files(acq, profile_path, dem_paths))
    # the DEM and the position are checked before any image is read (detection is the long part)
    dem_path = " + ".join(dem_paths)
    dem = load_dems(list(dem_paths))
    x, y = point_xy(x, y, lon, lat, dem.crs_wkt)
    # a position given as lon/lat is named so: the x/y it became mean nothing to its giver
    dem.require_inside(np.array([x]), np.array([y]), "rough position" if lon is None else
                       f"rough position lon {lon:g}, lat {lat:g}, which is", lonlat_options="--lon/--lat")
    frames = []  # the frames' detected rows: a narrow view is also solved in the image plane
    prof, pp, pr, cam_h = read_profile(acq, profile_path, frames, detector)
    h = camera_height_m if camera_height_m is not None else (cam_h if cam_h is not None else 1.5)
    notes = []  # each warning printed is in the JSON too, as locate's fix carries its own

    def warn(message):
        note("warning: " + message)
        notes.append(message)

    if camera_height_m is None and cam_h is None:
        warn(f"{profile_path} does not say the camera's height above the ground "
             "(camera_height_m): taken as 1.5 m; give --camera-height-m, or profile the "
             "acquisition again (skyfix profile writes it)")
    conv = meridian_convergence_deg(dem.crs_wkt, x, y)
    if prior_north == "true" and not math.isfinite(conv) and window_deg < 180:
        warn(f"{dem_path} has no CRS that says where true north is: the heading prior is taken "
             "from grid north")
    grid_prior = (grid_heading_from_true(heading_prior_deg, conv) if prior_north == "true"
                  else heading_prior_deg)
    hf = estimate_heading(prof, dem, x, y, grid_prior, window_deg, camera_height_m=h,
                          prior_pitch_deg=pp, prior_roll_deg=pr, frames=frames,
                          dem_sigma_m=dem_sigma_m, position_sigma_m=position_sigma_m,
                          notes=tuple(notes))
    if window_deg < 180 and at_window_edge(hf.grid_heading_deg, grid_prior, window_deg):
        # in the prior's own north: a true heading beside a grid window seemed to lie outside it
        shown = hf.heading_deg if prior_north == "true" else hf.grid_heading_deg
        warn(f"the heading {shown:.1f} deg ({prior_north} north) is on the edge of the window "
             f"{heading_prior_deg:g} +- {window_deg:g} deg: the best match lies outside it "
             "(confidence capped); check the prior or widen --window-deg")
        hf = replace(hf, notes=(*hf.notes, notes[-1]))
    from .provenance import provenance

    d = hf.to_dict()
    d["provenance"] = provenance(
        acq_dir=acq_dir, profile_path=profile_path, dem=dem, dem_path=dem_path, profile=prof,
        options={"heading_prior_deg": prior_given, "prior_north": prior_north,
                 "window_deg": window_deg, "camera_height_m": h, "dem_sigma_m": dem_sigma_m,
                 "position_sigma_m": position_sigma_m,
                 "detector": detector_used(profile_path, detector)},
        estimated=["heading_deg", "pitch_deg", "roll_deg"], echoed=["x", "y"],
        convergence_deg=hf.meridian_convergence_deg)
    if out is not None:
        write_json(out, d)
        # as locate -o ends: what was found and where it went (the JSON is in the file)
        note(f"heading {hf.heading_deg:.2f} deg from true north +- {hf.heading_sigma_deg:.2f}, "
             f"pitch {hf.pitch_deg:.2f}, roll {hf.roll_deg:.2f}, confidence {hf.confidence:.2f} "
             f"-> {out}")
    else:
        click.echo(to_json(d, indent=1))
    sys.stdout.flush()


def _attitude_command() -> click.Command:
    """``skyfix attitude``: the heading search read for all three angles. Its JSON is the heading
    result's: roll, pitch and heading (true north) with their 1-sigmas, which of them the view
    determines, and the confidence; a single frame is enough (one photograph: the NASA Ames use)."""
    import copy

    cmd = copy.copy(heading)
    cmd.name = "attitude"
    cmd.help = ("Find roll, pitch and heading from one frame (or any acquisition) at a known "
                "position: their 1-sigmas and which of them the view determines.")
    cmd.short_help = None
    return cmd


attitude = _attitude_command()
