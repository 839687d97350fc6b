"""``skyfix locate`` and ``skyfix heading``: the board segment's answer.

Imports stay light at module level (the locate process must fit in 256 MB): numpy, the DEM
loader, the database and matplotlib are imported only when used.
"""

from __future__ import annotations

import sys

import click

from ..errors import ParameterError


def _read_profile(acq_dir, profile_path):
    """Profile from ``--profile`` JSON, else from the acquisition folder (prior attitude too)."""
    from ..formats import load_acquisition, read_profile_json

    if profile_path is not None:
        prof = read_profile_json(profile_path)
        if prof.frame != "body":
            raise ParameterError(f"{profile_path}: locate needs a body-frame profile (frame 'body'), "
                                 f"got '{prof.frame}'")
        prior = prof.meta.get("attitude_prior") or {}
        return prof, float(prior.get("pitch_deg", 0.0)), float(prior.get("roll_deg", 0.0)), \
            prof.meta.get("camera_height_m")
    if acq_dir is None:
        raise ParameterError("give an acquisition folder or --profile PROFILE.json")
    acq = load_acquisition(acq_dir)
    try:
        from ..profile import acquisition_profile
    except ImportError:
        raise ParameterError("this build has no skyfix.profile stage yet: pass --profile "
                             "PROFILE.json (made by 'skyfix profile')") from None
    prof = acquisition_profile(acq)
    return prof, acq.prior_pitch_deg, acq.prior_roll_deg, acq.camera_height_m


def _write_outputs(fix, out, geojson, overwrite):
    from .._io import check_can_write, to_json, write_json

    for p in (out, geojson):
        if p is not None:
            check_can_write(p, overwrite)
    if out is not None:
        write_json(out, fix.to_dict())
    else:
        click.echo(to_json(fix.to_dict(), indent=1))
    if geojson is not None:
        write_json(geojson, {"type": "FeatureCollection", "features": [fix.to_geojson()]})


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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from .._io import atomic_path
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
        ax.plot(az, body_profile(w, fix.heading_deg, fix.pitch_deg, fix.roll_deg, n_bins=q.size),
                "r-", lw=1, label="rendered at fix")
    ax.set_xlabel("azimuth from forward axis [deg]")
    ax.set_ylabel("elevation [deg]")
    ax.legend()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight", format="png")
    plt.close(fig)


@click.command("locate")
@click.argument("acq_dir", required=False, type=click.Path(file_okay=False))
@click.option("--profile", "profile_path", type=click.Path(dir_okay=False),
              help="Body-frame profile JSON instead of an acquisition folder.")
@click.option("--db", "db_path", type=click.Path(), help="Skyline database (zarr).")
@click.option("--dem", "dem_path", type=click.Path(dir_okay=False),
              help="DEM for sub-spacing refinement and attitude (needed without --db).")
@click.option("--prior-x", type=float, help="Prior position x [m] in the DEM's CRS.")
@click.option("--prior-y", type=float, help="Prior position y [m].")
@click.option("--prior-radius-m", type=float, help="Prior search radius [m].")
@click.option("-o", "--output", "out", type=click.Path(dir_okay=False), help="Fix JSON (default stdout).")
@click.option("--geojson", type=click.Path(dir_okay=False), help="Also write the fix as GeoJSON.")
@click.option("--score-map", type=click.Path(dir_okay=False), help="Database score map GeoTIFF.")
@click.option("--plot", type=click.Path(dir_okay=False), help="Score map and skyline overlay PNG.")
@click.option("--preset", type=click.Choice(["fast", "exact", "level"]), default="fast",
              show_default=True, help="Matcher preset.")
@click.option("--overwrite", is_flag=True, help="Replace existing outputs.")
def locate(acq_dir, profile_path, db_path, dem_path, prior_x, prior_y, prior_radius_m, out,
           geojson, score_map, plot, preset, overwrite):
    """Find position, heading and attitude from an acquisition (or a profile)."""
    from .._io import check_can_write

    for p in (out, geojson, score_map, plot):
        if p is not None:
            check_can_write(p, overwrite)
    if (prior_x is None) != (prior_y is None):
        raise ParameterError("give both --prior-x and --prior-y")
    if prior_radius_m is not None and not prior_radius_m > 0:
        raise ParameterError(f"--prior-radius-m must be > 0, got {prior_radius_m}")
    if db_path is None and dem_path is None:
        raise ParameterError("give --db DB (and optionally --dem) or --dem with a prior area")
    prof, pp, pr, cam_h = _read_profile(acq_dir, profile_path)
    from ..match import PRESETS
    from ..pose import PoseConfig, locate as _locate

    db = dem = None
    if db_path is not None:
        from ..database import open_database

        db = open_database(db_path)
    if dem_path is not None:
        from ..dem import load_dem

        dem = load_dem(dem_path)
    if db is None and (prior_x is None or prior_radius_m is None):
        raise ParameterError("without --db give --prior-x, --prior-y and --prior-radius-m")
    prior = (prior_x, prior_y) if prior_x is not None else None
    if prior is not None and prior_radius_m is None and db is not None:
        raise ParameterError("--prior-x/--prior-y need --prior-radius-m")
    fix, mres = _locate(prof, db=db, dem=dem, prior_xy=prior, prior_radius_m=prior_radius_m,
                        prior_pitch_deg=pp, prior_roll_deg=pr,
                        camera_height_m=None if db is not None else cam_h,
                        config=PoseConfig(match=PRESETS[preset]), return_match=True)
    _write_outputs(fix, out, geojson, overwrite=True)
    if score_map is not None:
        if mres is None:
            raise ParameterError("--score-map needs --db (the map is the database's score)")
        _write_score_map(score_map, mres, db)
    if plot is not None:
        _plot(plot, fix, mres, db, dem, prof)
    if out is not None:
        click.echo(f"fix ({fix.x:.1f}, {fix.y:.1f}) heading {fix.heading_deg:.1f} deg "
                   f"confidence {fix.confidence:.2f} -> {out}", err=True)


@click.command("heading")
@click.argument("acq_dir", required=False, type=click.Path(file_okay=False))
@click.option("--profile", "profile_path", type=click.Path(dir_okay=False),
              help="Body-frame profile JSON instead of an acquisition folder.")
@click.option("--dem", "dem_path", required=True, type=click.Path(dir_okay=False))
@click.option("--x", "x", required=True, type=float, help="Rough position x [m].")
@click.option("--y", "y", required=True, type=float, help="Rough position y [m].")
@click.option("--heading-prior-deg", required=True, type=float, help="Heading prior [deg].")
@click.option("--window-deg", default=10.0, show_default=True, type=float,
              help="Search +/- this around the prior [deg].")
@click.option("--camera-height-m", type=float, help="Camera height [m] (default: the acquisition's).")
@click.option("-o", "--output", "out", type=click.Path(dir_okay=False))
@click.option("--overwrite", is_flag=True)
def heading(acq_dir, profile_path, dem_path, x, y, heading_prior_deg, window_deg,
            camera_height_m, out, overwrite):
    """Find the heading only, from a rough position."""
    from .._io import check_can_write, to_json, write_json
    from ..dem import load_dem
    from ..pose import estimate_heading

    if out is not None:
        check_can_write(out, overwrite)
    prof, pp, pr, cam_h = _read_profile(acq_dir, profile_path)
    dem = load_dem(dem_path)
    h = camera_height_m if camera_height_m is not None else (cam_h if cam_h is not None else 1.5)
    hf = estimate_heading(prof, dem, x, y, heading_prior_deg, window_deg, camera_height_m=h,
                          prior_pitch_deg=pp, prior_roll_deg=pr)
    if out is not None:
        write_json(out, hf.to_dict())
    else:
        click.echo(to_json(hf.to_dict(), indent=1))
    sys.stdout.flush()
