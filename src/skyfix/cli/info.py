"""``skyfix info``: what a skyline database holds, how complete it is, its size on disk."""

from __future__ import annotations

import click


@click.command("info")
@click.argument("db", type=click.Path())
@click.option("--json", "as_json", is_flag=True, help="Print the description as JSON.")
def info(db, as_json):
    """Describe the skyline database DB (complete or not).

    Exit status 0, or 2 if built blocks have lost their data files (described, then named).
    """
    from .._io import to_json
    from ..database import describe
    from ..errors import DatabaseError

    d = describe(db)
    if as_json:
        click.echo(to_json(d, indent=1))
    else:
        _print(d)
    if d["damage"]:  # after the description: what the store is helps decide what to do
        raise DatabaseError(d["damage"])


def _print(d: dict) -> None:
    g = d["grid"]
    p = d["planet"]
    xmin, ymin, xmax, ymax = g["bounds"]
    maxd = "DEM edge" if d["max_distance_m"] is None else f"{d['max_distance_m']:g} m"
    lines = [
        f"database     {d['path']} ({d['format']}, skyfix {d['software_version']})",
        f"crs          {d['crs']}",
        f"grid         {g['nx']} x {g['ny']} positions at {g['spacing_m']:g} m "
        f"(x {xmin:.1f}..{xmax:.1f}, y {ymin:.1f}..{ymax:.1f}; row 0 north), "
        f"blocks of {g['block_shape'][0]} x {g['block_shape'][1]}",
        f"skylines     {d['azimuth_bins']} azimuth bins, camera {d['camera_height_m']:g} m above ground, "
        f"rays to {maxd}, planet {p['name']} (R {p['radius_m']:.0f} m, k {p['refraction_k']:g}), "
        f"stored in steps of {d['scale_deg']:g} deg",
        f"dem          {d['dem']['source']} (sha256 {d['dem']['sha256'][:16]}...)",
        f"completeness {d['blocks_done']} of {d['n_blocks']} blocks"
        + (f" built, DAMAGED: {len(d['blocks_data_missing'])} of them without their data files"
           if d["blocks_data_missing"] else
           " (complete)" if d["complete"] else " (INCOMPLETE: rerun the build command to finish)"),
        f"size         {d['size_bytes'] / 1e6:.1f} MB on disk, "
        + (f"{d['bytes_per_skyline']:.0f} bytes per built skyline" if d["bytes_per_skyline"] is not None
           else "no skyline built yet"),
    ]
    click.echo("\n".join(lines))
