"""``skyfix build-db``: build (or resume) a skyline database over a search area."""

from __future__ import annotations

import click


@click.command("build-db")
@click.argument("dem", type=click.Path(dir_okay=False))
@click.option("--out", "-o", required=True, type=click.Path(), help="Output zarr store (a folder).")
@click.option("--bounds", nargs=4, type=float, required=True, metavar="XMIN YMIN XMAX YMAX",
              help="Search area [m] in the work CRS (`skyfix info DEM` prints it: the DEM's own when "
                   "projected, else a transverse Mercator on its body); positions at "
                   "xmin + c*spacing, ymax - r*spacing.")
@click.option("--spacing-m", type=float, required=True, help="Grid spacing [m].")
@click.option("--camera-height-m", type=float, default=1.5, show_default=True, help="[m] above ground.")
@click.option("--azimuth-bins", type=int, default=360, show_default=True, help="Bins over 360 deg.")
@click.option("--max-distance-m", type=float, default=None, help="[m] ray limit (default: DEM edge).")
@click.option("--planet", default=None,
              help="earth, mars, moon or a radius [m]; default: the body of the DEM's CRS (an Earth CRS may stand in for any body).")
@click.option("--workers", type=int, default=None,
              help="0: in this process; N: a local Dask cluster of N processes (default: one per core).")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Use an existing Dask cluster (tcp://HOST:PORT) sharing this file system.")
@click.option("--block-positions", type=int, default=64, show_default=True,
              help="Positions per block side: one task and one zarr chunk per block.")
@click.option("--renderer", type=click.Choice(["kernel", "sweep"]), default="kernel", show_default=True,
              help="kernel: every ray traced on its own. sweep: lines of each azimuth shared by "
                   "up to 16 blocks at a time, each position's own ray exact near it and where the "
                   "lines point (about 2x less CPU from 2 x 2 km up; never above the kernel, more "
                   "than 0.01 deg below it in at most 0.05 % of bins, on 24 test blocks at 5 m; "
                   "its lines stay 5 m apart on a coarser grid, which then costs more: from "
                   "10 m up the kernel is as fast or faster; one DEM, no --max-distance-m).")
@click.option("--overwrite", is_flag=True,
              help="Delete an existing database and start afresh (only once every option is checked "
                   "and the workers are up).")
@click.option("--no-progress", is_flag=True, help="No progress bar (nor with -q).")
@click.option("--dem", "more_dems", multiple=True, type=click.Path(dir_okay=False),
              help="Another DEM of the same place (repeatable): a stack, the finest DEM winning "
                   "wherever it has heights (HiRISE inside CTX inside MOLA).")
def build_db(dem, out, bounds, spacing_m, camera_height_m, azimuth_bins, max_distance_m, planet,
             workers, scheduler, block_positions, renderer, overwrite, no_progress, more_dems):
    """Render the skyline at every grid position of BOUNDS from DEM into a zarr store.

    Killed at any point, the same command resumes where it stopped (it also redoes built blocks
    whose data files have gone); run on a complete store it does nothing and succeeds;
    --overwrite starts afresh. A grid of more than 1e9 positions or
    ~500 GB is refused as a likely typo.
    """
    from .._io import check_folder_output, writing_to
    from ..database import build_database
    from ..progress import bars_shown

    check_folder_output(out)
    with writing_to(out):  # an OS error names --out, not a staging folder beside it
        r = build_database([dem, *more_dems] if more_dems else dem, out, bounds, spacing_m,
                           camera_height_m=camera_height_m, azimuth_bins=azimuth_bins,
                           max_distance_m=max_distance_m, planet=planet, workers=workers,
                           scheduler=scheduler, overwrite=overwrite,
                           progress=not no_progress and bars_shown(), block=block_positions,
                           renderer=renderer)
    if r.indexed:
        click.echo(f"{r.path}: coarse index added to {r.indexed} block{'s' * (r.indexed != 1)} built earlier (the search "
                   "now decodes only the blocks it needs)")
    if not r.built and not r.indexed:
        click.echo(f"{r.path}: already complete, {r.n_blocks} block{'s' * (r.n_blocks != 1)}, "
                   f"{r.size_bytes / 1e6:.1f} MB on disk: nothing to do")
    elif r.built or not r.indexed:
        click.echo(f"{r.path}: {r.n_blocks} block{'s' * (r.n_blocks != 1)} ({r.built} built now, {r.resumed_from} already "
                   f"there), {r.positions} skylines in {r.seconds:.1f} s ({r.skylines_per_s:,.0f}/s), "
                   f"{r.size_bytes / 1e6:.1f} MB on disk")
