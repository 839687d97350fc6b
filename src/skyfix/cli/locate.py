"""``skyfix locate``: the board segment's answer, position, heading and attitude.

Imports stay light at module level (the locate process must fit in 256 MB): numpy, the DEM
loader, the database and matplotlib are imported only when used.
"""

from __future__ import annotations

import click

from ..errors import ParameterError
from ..progress import stage
from .acqinput import (check_detector, check_source, check_view_width, detector_used, input_files,
                       read_acquisition, read_profile)
from .main import note
from .options import check_point_options, dem_sigma, detector_option, point_xy


#: this command's options for a prior position in degrees
LONLAT_PRIOR = "--prior-lon/--prior-lat"


#: [m] the largest prior radius that means anything: half the Earth's circumference
MAX_PRIOR_RADIUS_M = 2.0e7


def _check_prior_area(db, dem, prior, radius_m) -> None:
    """Refuse, before any image is read, a prior disc (centre [m], radius [m]) that holds no
    database position, or, searched on the DEM alone, whose centre lies off the DEM."""
    if prior is None:
        return
    import numpy as np

    from ..workcrs import as_typed, lonlat_hint

    if db is not None:
        from ..database import nearest_position_m

        d = nearest_position_m(db, prior[0], prior[1])
        if d > radius_m:
            xs, ys = np.asarray(db.x_coords), np.asarray(db.y_coords)
            span = (xs.min(), ys.min(), xs.max(), ys.max())
            raise ParameterError(
                f"no database position lies inside the prior area ({as_typed(prior[0])}, "
                f"{as_typed(prior[1])}) +- {radius_m:g} m: the nearest is {d:.1f} m away; the database "
                f"spans x {span[0]:.1f}..{span[2]:.1f}, y {span[1]:.1f}..{span[3]:.1f}"
                + lonlat_hint(prior[0], prior[1], span, "DB", LONLAT_PRIOR))
    elif dem is not None:
        dem.require_inside(np.array([prior[0]]), np.array([prior[1]]), "prior position",
                           lonlat_options=LONLAT_PRIOR)
        from ..pose import PoseConfig
        from ..pose.refine import prior_grid

        # too many points for the DEM-only search: said now, not after detecting every frame
        prior_grid(dem, prior, radius_m, PoseConfig().grid_step_m)


def _check_db_dem(db, dem, db_path, dem_path, force) -> list[str]:
    """Refuse a DEM other than the database's (its checksum is in the database), unless forced;
    returns the notes the fix then carries."""
    if db is None or dem is None:
        return []
    from ..database import check_dem_crs

    check_dem_crs(db, dem, db_path, dem_path)  # not forced: another map's coordinates
    if not getattr(db, "dem_sha256", "") or dem.checksum == db.dem_sha256:
        return []
    msg = (f"--dem {dem_path} (sha256 {dem.checksum[:12]}...) is not the DEM the database {db_path} "
           f"was built from (sha256 {db.dem_sha256[:12]}..., {(db.attrs.get('dem') or {}).get('source', 'source not recorded')})")
    if not force:
        raise ParameterError(msg + ": give that DEM, rebuild the database from this one, or pass "
                                   "--force to refine on it anyway")
    note(f"warning: {msg}; going on (--force)")
    return [msg + " (--force)"]


def _check_camera_height(db, db_path, cam_h) -> list[str]:
    """Warn when the acquisition's camera height differs from the database's: the refinement
    renders at the acquisition's; the database search saw the other (the sigma is widened)."""
    if db is None or cam_h is None:
        return []
    built = float(db.camera_height_m)
    if abs(float(cam_h) - built) <= 0.05:
        return []
    msg = (f"the acquisition's camera is {float(cam_h):g} m above the ground, the database {db_path} "
           f"was built for {built:g} m: the search compares skylines seen from another height "
           "(refinement uses the acquisition's; the position sigma is widened by the difference)")
    note("warning: " + msg)
    return [msg]


def _write_outputs(fix, out, geojson, prov=None):
    """The fix as JSON (``out``, else stdout) with its provenance, and GeoJSON (the fix, its
    1-sigma circle and the candidates as features); paths checked before any work."""
    from .._io import to_json, write_json
    from .provenance import fix_geojson, off_earth_warning

    d = fix.to_dict()
    if prov is not None:
        d["provenance"] = prov
    if out is not None:
        write_json(out, d)
    else:
        click.echo(to_json(d, indent=1))
    if geojson is not None:
        write_json(geojson, fix_geojson(fix))
        warning = off_earth_warning(geojson, fix.crs)
        if warning:
            note("warning: " + warning)


def _write_score_map(path, mres, db):
    import numpy as np
    import rasterio
    from rasterio.transform import from_origin

    from .._io import atomic_path

    xs, ys = np.asarray(db.x_coords), np.asarray(db.y_coords)
    s = float(db.spacing_m)
    data = mres.score_map
    if ys[0] < ys[-1]:
        data = data[::-1]
    tr = from_origin(xs.min() - s / 2, ys.max() + s / 2, s, s)
    with atomic_path(path, suffix=".tif") as tmp:
        with rasterio.open(tmp, "w", driver="GTiff", width=data.shape[1], height=data.shape[0],
                           count=1, dtype="float32", crs=db.crs_wkt or None, transform=tr,
                           nodata=float("nan")) as ds:
            ds.write(data.astype("float32"), 1)


def _plot(path, fix, mres, db, dem, profile, truth=None):
    from ..optional import pyplot

    plt = pyplot()
    import numpy as np

    from .._io import save_figure
    from ..pose import body_profile

    fig, axes = plt.subplots(1, 2, figsize=(13, 5.5))
    ax = axes[0]
    if mres is not None:
        xs, ys = np.asarray(db.x_coords), np.asarray(db.y_coords)
        ext = (xs.min(), xs.max(), ys.min(), ys.max())
        if dem is not None:
            r0, c0 = dem.xy_to_colrow(ext[0], ext[3])[::-1]
            r1, c1 = dem.xy_to_colrow(ext[1], ext[2])[::-1]
            z = dem.z[max(0, int(r0)):int(r1) + 1, max(0, int(c0)):int(c1) + 1]
            if z.size > 4:
                gy, gx = np.gradient(z, dem.dy, dem.dx)
                shade = (np.cos(np.radians(45)) - gx * 0.7 + gy * 0.7) / np.sqrt(1 + gx ** 2 + gy ** 2)
                ax.imshow(shade, extent=ext, cmap="gray", origin="upper")
        sm = np.sqrt(mres.score_map if ys[0] > ys[-1] else mres.score_map[::-1])
        im = ax.imshow(sm, extent=ext, origin="upper", cmap="viridis_r", alpha=0.6)
        fig.colorbar(im, ax=ax, label="rms residual [deg]")
    ax.plot(fix.x, fix.y, "r+", ms=14, mew=2, label="fix")
    for c in fix.candidates[1:]:
        ax.plot(c["x"], c["y"], "wx", ms=8)
    if truth is not None:
        ax.plot(truth[0], truth[1], "co", mfc="none", ms=12, label="truth")
    ax.legend(loc="upper right")
    ax.set_title(f"score map, confidence {fix.confidence:.2f}")
    ax = axes[1]
    q = profile.elevation_deg
    az = np.arange(q.size) * 360.0 / q.size
    ax.plot(az, q, "k.", ms=3, label="measured (body)")
    if dem is not None:
        from ..horizon import render_horizons

        w = render_horizons(dem, [fix.x], [fix.y], azimuth_bins=1440).elevation_deg[0]
        ax.plot(az, body_profile(w, fix.grid_heading_deg, fix.pitch_deg, fix.roll_deg, n_bins=q.size),
                "r-", lw=1, label="rendered at fix")
    ax.set_xlabel("azimuth from forward axis [deg]")
    ax.set_ylabel("elevation [deg]")
    ax.legend()
    try:
        save_figure(fig, path, dpi=110, bbox_inches="tight")
    finally:
        plt.close(fig)


@click.command("locate")
@click.argument("acq_dir", required=False, type=click.Path(file_okay=False))
@click.option("--profile", "profile_path", type=click.Path(dir_okay=False),
              help="Body-frame profile JSON instead of an acquisition folder.")
@click.option("--db", "db_path", type=click.Path(), help="Skyline database (zarr).")
@click.option("--dem", "dem_paths", multiple=True, type=click.Path(dir_okay=False),
              help="DEM for sub-spacing refinement and attitude (needed without --db); repeat it "
                   "for a stack of DEMs of one place (the finest wins where it has heights).")
@click.option("--prior-x", type=float, help="Prior position x [m] in the work CRS.")
@click.option("--prior-y", type=float, help="Prior position y [m].")
@click.option("--prior-lon", type=float, help="Prior longitude [deg] on the DEM's body (for --prior-x).")
@click.option("--prior-lat", type=float, help="Prior latitude [deg] (for --prior-y).")
@click.option("--prior-radius-m", type=float, help="Prior search radius [m].")
@click.option("-o", "--out", "--output", "out", type=click.Path(dir_okay=False),
              help="Fix JSON (default stdout).")
@click.option("--geojson", type=click.Path(dir_okay=False), help="Also write the fix as GeoJSON.")
@click.option("--score-map", type=click.Path(dir_okay=False),
              help="Database score map GeoTIFF (.tif; needs --db).")
@click.option("--plot", type=click.Path(dir_okay=False),
              help="Score map and skyline overlay (.png, .jpg, .pdf or .svg).")
@click.option("--preset", type=click.Choice(["fast", "exact", "level"]), default="fast",
              show_default=True,
              help="Database search: fast (a coarse pass on 4-bin averages, then the best share "
                   "exactly), exact (every position scored exactly: slower, for checks), level "
                   "(no tilt harmonic: a camera known to be level, or a narrow view).")
@click.option("--dem-sigma-m", type=float, default=None,
              help="The DEM's height error (rms) [m] against the terrain the camera sees, which "
                   "position_sigma_m (and a narrow view's attitude sigmas) allow for; 0: the DEM "
                   "is the world. The fix itself does not depend on it [default: 2].")
@detector_option
@click.option("--overwrite", is_flag=True, help="Replace existing outputs.")
@click.option("--force", is_flag=True,
              help="Use a --dem other than the one the database was built from. The fix says so, "
                   "and its confidence is capped at 0.45 unless the DEM's skylines at the fix "
                   "match the database's (the same heights in another file).")
def locate(acq_dir, profile_path, db_path, dem_paths, prior_x, prior_y, prior_lon, prior_lat,
           prior_radius_m, out, geojson, score_map, plot, preset, dem_sigma_m, detector, overwrite,
           force):
    """Find position, heading and attitude from an acquisition (or a profile)."""
    import math

    dem_path = " + ".join(dem_paths) if dem_paths else None
    from .._io import GEOTIFF_SUFFIXES, PLOT_FORMATS, check_outputs

    # Everything that can be refused is refused before the search (minutes) and before any
    # output is written.
    check_source(acq_dir, profile_path)
    check_detector(profile_path, detector)
    check_point_options(prior_x, prior_y, prior_lon, prior_lat, xname="--prior-x", yname="--prior-y",
                        lonname="--prior-lon", latname="--prior-lat", required=False)
    have_prior = prior_x is not None or prior_lon is not None
    if prior_radius_m is not None and not (math.isfinite(prior_radius_m) and
                                           0 < prior_radius_m <= MAX_PRIOR_RADIUS_M):
        # 1e300 passed as finite and overflowed in the search, after detection
        raise ParameterError(f"--prior-radius-m must be a number of metres > 0 and at most "
                             f"{MAX_PRIOR_RADIUS_M:g} (half the Earth's circumference), got "
                             f"{prior_radius_m}")
    if db_path is None and dem_path is None:
        raise ParameterError("give --db DB (and optionally --dem) or --dem with a prior area")
    if db_path is None and (not have_prior or prior_radius_m is None):
        raise ParameterError("without --db give --prior-x, --prior-y (or --prior-lon, --prior-lat) "
                             "and --prior-radius-m")
    if db_path is not None and have_prior and prior_radius_m is None:
        raise ParameterError("a prior position needs --prior-radius-m")
    if prior_radius_m is not None and not have_prior:
        # it was ignored, and yet recorded in the fix's provenance as if the search had used it
        raise ParameterError("--prior-radius-m needs the disc's centre: give --prior-x and "
                             "--prior-y (or --prior-lon and --prior-lat)")
    if score_map is not None and db_path is None:
        raise ParameterError("--score-map needs --db (the map is the database's score)")
    dem_sigma_m = dem_sigma(dem_sigma_m)
    acq = read_acquisition(acq_dir)
    check_outputs(overwrite, ("--output", out, None), ("--geojson", geojson, None),
                  ("--score-map", score_map, GEOTIFF_SUFFIXES), ("--plot", plot, PLOT_FORMATS),
                  inputs=input_files(acq, profile_path, dem_paths))
    # The database and the DEM are opened and checked against each other, and the acquisition's
    # description read, before any image is (detection is the long part).
    db = dem = None
    with stage("inputs checked") as st:
        if db_path is not None:
            from ..database import open_database

            db = open_database(db_path)
        if dem_path is not None:
            from ..stack import load_dems

            dem = load_dems(list(dem_paths))
        notes = _check_db_dem(db, dem, db_path, dem_path, force)
        prior = point_xy(prior_x, prior_y, prior_lon, prior_lat,
                         getattr(db, "crs_wkt", "") or (dem.crs_wkt if dem is not None else ""))
        _check_prior_area(db, dem, prior, prior_radius_m)
        if acq is not None:
            notes += _check_camera_height(db, db_path, acq.camera_height_m)
            from ..match import PRESETS

            check_view_width(acq, db, PRESETS[preset].min_observed, "a position search")
        st.result = ", ".join(filter(None, [
            f"database of {len(db.x_coords) * len(db.y_coords):,} positions at {db.spacing_m:g} m"
            if db is not None else "", f"DEM {dem.shape[1]} x {dem.shape[0]} cells of {dem.cell_m:g} m"
            if dem is not None else ""]))
    frames = []  # the frames' detected rows: a narrow view's attitude is also solved in the image
    # the profile in the database's bins: a store of 90 bins made a 360-bin profile it then
    # refused, after detection
    prof, pp, pr, cam_h = read_profile(acq, profile_path, frames, detector, db)
    if profile_path is not None and cam_h is None:
        from ..pose.locate import default_camera_height_m

        cam_h = default_camera_height_m(db, prof)  # as pose.locate would take it
        msg = (f"{profile_path} does not say the camera's height above the ground "
               f"(camera_height_m): taken as {cam_h:g} m"
               + (", the database's" if db is not None else "")
               + "; profile the acquisition again (skyfix profile writes it) or add it")
        note("warning: " + msg)
        notes.append(msg)
    elif profile_path is not None:
        notes += _check_camera_height(db, db_path, cam_h)
    from ..match import PRESETS
    from ..pose import PoseConfig, locate as _locate

    with stage("located") as st:
        fix, mres = _locate(prof, db=db, dem=dem, prior_xy=prior, prior_radius_m=prior_radius_m,
                            prior_pitch_deg=pp, prior_roll_deg=pr, camera_height_m=cam_h,
                            config=PoseConfig(match=PRESETS[preset], map_sigma_m=dem_sigma_m),
                            return_match=True,
                            notes=tuple(notes), frames=frames)
        st.result = (f"({fix.x:.1f}, {fix.y:.1f}) +- {fix.position_sigma_m:.2g} m, heading "
                     f"{fix.heading_deg:.2f} deg from true north, confidence {fix.confidence:.2f}")
    from .provenance import provenance

    prov = provenance(acq_dir=acq_dir, profile_path=profile_path, db=db, db_path=db_path, dem=dem,
                      dem_path=dem_path, profile=prof,
                      options={"preset": preset, "prior_xy": list(prior) if prior else None,
                               "prior_radius_m": prior_radius_m, "force": force,
                               "camera_height_m": cam_h, "dem_sigma_m": dem_sigma_m,
                               "detector": detector_used(profile_path, detector)},
                      estimated=["x", "y", "heading_deg"] + ([] if dem is None else ["pitch_deg", "roll_deg"]),
                      echoed=[] if dem is not None else ["pitch_deg", "roll_deg"],
                      convergence_deg=fix.meridian_convergence_deg)
    _write_outputs(fix, out, geojson, prov)
    if score_map is not None:
        _write_score_map(score_map, mres, db)
    if plot is not None:
        _plot(plot, fix, mres, db, dem, prof)
    if out is not None:
        note(f"fix ({fix.x:.1f}, {fix.y:.1f}) heading {fix.heading_deg:.1f} deg from true "
             f"north, confidence {fix.confidence:.2f} -> {out}")


