"""``skyfix traverse`` (odometry fused with skyline fixes along a traverse) and
``skyfix simulate-traverse`` (a traverse folder from the simulator)."""

from __future__ import annotations

import logging

import click

from ..errors import ParameterError
from .main import note
from .options import dem_sigma, detector_option, traverse_path_options

log = logging.getLogger("skyfix.stage")  # one line per stop at the default verbosity


@click.command("traverse")
@click.argument("traverse_dir", type=click.Path(file_okay=False))
@click.option("--dem", "dem_paths", required=True, multiple=True, type=click.Path(dir_okay=False),
              help="DEM (repeat for a stack of DEMs of one place).")
@click.option("--db", "db_path", type=click.Path(), help="Skyline database for the position fixes "
              "(without it they search the DEM in a disc about the prediction).")
@click.option("-o", "--out", "out", required=True, type=click.Path(file_okay=False),
              help="Output folder: stops.jsonl, track.geojson, track.png.")
@click.option("--leg-length-m", type=float, default=None,
              help="A position fix after this many metres driven [m] (default: traverse.json's, else 1000).")
@click.option("--min-confidence", type=float, default=0.5, show_default=True,
              help="Updates below it are retried once, then not used.")
@click.option("--max-rejections", type=int, default=3, show_default=True,
              help="Stops in a row without an accepted update before the operator is asked.")
@click.option("--dem-sigma-m", type=float, default=None,
              help="The DEM's height error (rms) [m] against the terrain, which the position "
                   "fixes' sigmas allow for (so the track leans on them as far as such a map "
                   "allows); 0: the DEM is the world [default: 2].")
@detector_option
@click.option("--no-plot", is_flag=True, help="Do not draw track.png.")
@click.option("--overwrite", is_flag=True,
              help="Start afresh in an -o that an earlier traverse run wrote (its stops.jsonl, "
                   "track.geojson, track.png and run.json are deleted, once every input is checked).")
def traverse(traverse_dir, dem_paths, db_path, out, leg_length_m, min_confidence, max_rejections,
             dem_sigma_m, detector, no_plot, overwrite):
    """Fuse a traverse's odometry with skyline headings and position fixes.

    Rerun with the same -o to resume at the first stop not yet written: -o/run.json records the
    inputs and options that made the output, and a rerun with others is refused (--overwrite
    starts afresh).
    """
    import math
    from pathlib import Path

    from .._io import check_folder_output
    from ..detect.options import DEFAULT_METHOD
    from ..progress import stage
    from ..traverse import TraverseConfig, convergence_function, read_traverse, run_traverse
    from ..traverse.inputs import check_start, check_stops
    from ..traverse.output import digest
    from ..traverse.run import check_output
    from ..traverse.measure import acquisition_measure

    if not (0.0 <= min_confidence <= 1.0):
        raise ParameterError(f"--min-confidence must be within [0, 1], got {min_confidence}")
    if max_rejections < 1:
        raise ParameterError(f"--max-rejections must be >= 1, got {max_rejections}")
    if not no_plot:  # refused now, not after the whole traverse
        from ..optional import require

        require("matplotlib", "the track figure (track.png)", "--no-plot")
    if leg_length_m is not None and not (math.isfinite(leg_length_m) and leg_length_m > 0):
        raise ParameterError(f"--leg-length-m must be a number of metres > 0, got {leg_length_m}")
    dem_sigma_m = dem_sigma(dem_sigma_m)
    out = check_folder_output(out)
    with stage("inputs checked") as st:
        trav = read_traverse(traverse_dir)
        check_stops(trav)
        db = None
        if db_path is not None:
            from ..database import open_database

            db = open_database(db_path)
        elif trav.start is None:
            raise ParameterError("the traverse has no start (traverse.json 'start'): give --db so "
                                 "that the first stop can be located without a prior")
        from ..stack import load_dems

        dem = load_dems(list(dem_paths))
        if db is not None:
            from ..database import check_dem_crs

            check_dem_crs(db, dem, db_path, " ".join(map(str, dem_paths)))
        check_start(trav, dem)
        cfg = TraverseConfig(min_confidence=min_confidence, max_rejections=max_rejections,
                             leg_length_m=leg_length_m)
        # what the measurements depend on beyond the traverse and cfg; the DEM and the database
        # by content, so that a moved file still resumes and a replaced one does not
        inputs = {"dem_sha256": dem.checksum,
                  "database_sha256": None if db is None else digest(db.attrs.get("build") or db.attrs),
                  "detector": detector or DEFAULT_METHOD, "dem_sigma_m": dem_sigma_m}
        about = {"traverse": str(traverse_dir), "dem": [str(p) for p in dem_paths],
                 "database": None if db_path is None else str(db_path)}
        action = check_output(trav, out, config=cfg, inputs=inputs, overwrite=overwrite)
        st.result = f"{len(trav.stops)} stops" + {"resume": ", resuming",
                                                   "replace": ", starting afresh"}.get(action, "")

    convergence = convergence_function(dem.crs_wkt)

    def progress(k, d):
        req = " OPERATOR REQUEST" if d["operator_request"] else ""
        conf = "" if d["confidence"] is None else f", confidence {d['confidence']:.2f}"
        log.info("stop %d/%d %s: %s%s; +-%.1f m, +-%.2f deg%s", k + 1, len(trav.stops), d["stop"],
                 d["update"] if d["update"] != d["attempted"] or d["update"] == "rejected"
                 else f"{d['update']} update", conf, d["position_sigma_m"], d["heading_sigma_deg"], req)

    from ..pose import PoseConfig

    measure = acquisition_measure(trav, dem, db=db, pose_config=PoseConfig(map_sigma_m=dem_sigma_m),
                                  detector=detector)
    rows = run_traverse(trav, measure, out, config=cfg, convergence=convergence, on_stop=progress,
                        inputs=inputs, about=about, overwrite=overwrite)
    write_track(Path(out), rows, dem.crs_wkt)
    if not no_plot:
        from ..traverse.plots import plot_track

        plot_track(Path(out) / "track.png", rows, trav, dem, convergence)
    asked = sum(r["operator_request"] is not None for r in rows)
    note(f"{len(rows)} stops: {sum(r['update'] == 'heading' for r in rows)} heading and "
         f"{sum(r['update'] == 'position' for r in rows)} position updates, "
         f"{sum(r['update'] == 'rejected' for r in rows)} rejected, {asked} operator "
         f"request{'s' * (asked != 1)} -> {out}")


def write_track(out, rows, crs_wkt) -> None:
    """``track.geojson``: the fused track as a LineString (from two stops: GeoJSON has no line of
    one position) and a Point per stop (lon/lat WGS 84 on Earth, the body's own geodetic
    coordinates elsewhere) whose properties are the stop's record in ``stops.jsonl`` but its
    filter state: work-CRS x, y, the heading from true north with its grid heading and
    convergence (the conventions ask all three of every heading), why and what was measured."""
    from .._io import write_json
    from ..pose.fix import crs_and_lonlat
    from .provenance import with_body

    feats, line = [], []
    for r in rows:
        _, lon, lat = crs_and_lonlat(crs_wkt, r["x"], r["y"])
        line.append([lon, lat])
        props = {k: v for k, v in r.items() if k != "filter"}
        feats.append({"type": "Feature", "geometry": {"type": "Point", "coordinates": [lon, lat]},
                      "properties": props})
    if len(line) >= 2:
        feats.insert(0, {"type": "Feature", "geometry": {"type": "LineString", "coordinates": line},
                         "properties": {"name": "fused track", "stops": len(rows)}})
    write_json(out / "track.geojson", with_body({"type": "FeatureCollection", "features": feats},
                                                crs_wkt))


@click.command("simulate-traverse")
@click.argument("dem", type=click.Path(dir_okay=False))
@click.option("-o", "--out", "out", required=True, type=click.Path(file_okay=False),
              help="Traverse folder to write (rerun with the same options to resume: rendered "
                   "stops are kept; -o/simulation.json records the options).")
@traverse_path_options
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--distance-drift", type=float, default=0.02, show_default=True,
              help="Odometry's 1-sigma error per step, as a share of the step.")
@click.option("--heading-drift-deg-per-100m", type=float, default=0.5, show_default=True,
              help="Odometry's heading 1-sigma error over 100 m [deg], a random walk (per step: "
                   "this times the square root of the step over 100 m).")
@click.option("--mode", type=click.Choice(["frames", "panorama"]), default="frames", show_default=True)
@click.option("--pano-size", type=int, nargs=2, default=(2048, 512), show_default=True, metavar="W H")
@click.option("--leg-length-m", type=float, default=1000.0, show_default=True,
              help="Written to traverse.json: a position fix after this many metres.")
@click.option("--no-start", is_flag=True, help="Write no start fix (the first stop is located).")
@click.option("--map-errors", is_flag=True,
              help="Render the stops from a world that differs from the map DEM (refined, height "
                   "error, spikes, a 3 m misregistration; see skyfix.simulate.world).")
@click.option("--world-dem", type=click.Path(dir_okay=False), default=None,
              help="Render the stops from this second DEM of the same place instead of DEM (the "
                   "path is still planned on DEM, the map).")
@click.option("--overwrite", is_flag=True,
              help="Start afresh in an -o that an earlier simulate-traverse wrote with other options "
                   "(its stops, odometry, truth and traverse.json are deleted, once every option is "
                   "checked).")
def simulate_traverse(dem, out, length_m, stop_spacing_m, seed, distance_drift,
                      heading_drift_deg_per_100m, stop_conditions, mode, pano_size, leg_length_m,
                      no_start, map_errors, world_dem, overwrite):
    """Simulate a traverse: stops with acquisitions, odometry with drift, and the truth.

    Rerun with the same options to resume; other options into the same -o are refused (the stops
    on disk are another simulation's), unless --overwrite.
    """
    import math

    from .._io import check_folder_output, writing_to
    from ..dem import load_dem
    from ..simulate import MapErrors, check_render_options, check_seed
    from ..traverse.simulate import parse_stop_conditions, simulate_traverse as _simulate

    check_seed(seed)
    if not (0 <= distance_drift < 1) or not (math.isfinite(heading_drift_deg_per_100m)
                                             and heading_drift_deg_per_100m >= 0):
        raise ParameterError(f"--distance-drift must be a share in [0, 1) and "
                             f"--heading-drift-deg-per-100m a number >= 0, got {distance_drift} "
                             f"and {heading_drift_deg_per_100m}")
    if not (math.isfinite(leg_length_m) and leg_length_m > 0):
        raise ParameterError(f"--leg-length-m must be a number of metres > 0, got {leg_length_m}")
    # refused before the DEM is read (the simulation checks them all again)
    check_render_options(mode=mode, camera="navcam", camera_height_m=1.5, tilt_deg=15.0,
                         planet=None, seed=seed, pano_size=pano_size)
    conds = parse_stop_conditions(stop_conditions)
    if map_errors and world_dem:
        raise ParameterError("give --map-errors or --world-dem, not both")
    check_folder_output(out)
    d = load_dem(dem)
    world = load_dem(world_dem, crs=d.crs_wkt) if world_dem else None  # the map's CRS: positions agree

    def progress(k, n):
        if (k + 1) % 10 == 0 or k + 1 == n:
            log.info("stop %d/%d rendered", k + 1, n)

    with writing_to(out):
        path = _simulate(d, out, length_m=length_m, stop_spacing_m=stop_spacing_m, seed=seed,
                         distance_drift=distance_drift,
                         heading_drift_deg_per_100m=heading_drift_deg_per_100m,
                         stop_conditions=conds, mode=mode, pano_size=pano_size,
                         with_start=not no_start, leg_length_m=leg_length_m, on_stop=progress,
                         world=world, map_errors=MapErrors() if map_errors else None,
                         overwrite=overwrite)
    note(f"traverse -> {path}")
