"""``skyfix info``: what a skyline database holds, how complete it is, its size on disk; or what a
DEM is (its CRS, body, work CRS, extent, cells, voids and distortion)."""

from __future__ import annotations

import click


#: suffixes of the DEM files users give (GeoTIFF, Erdas, VRT, SRTM .hgt, ASCII grid, netCDF, ...)
RASTER_SUFFIXES = (".tif", ".tiff", ".img", ".vrt", ".hgt", ".dem", ".asc", ".nc", ".jp2", ".bil",
                   ".flt", ".grd", ".dt0", ".dt1", ".dt2")


@click.command("info")
@click.argument("db", type=click.Path())
@click.option("--json", "as_json", is_flag=True, help="Print the description as JSON.")
def info(db, as_json):
    """Describe the skyline database DB (complete or not), or the DEM file DB.

    Exit status 0, or 2 if built blocks have lost their data files (described, then named).
    """
    from pathlib import Path

    from .._io import to_json
    from ..database import describe
    from ..errors import DatabaseError

    path = Path(db)
    if not path.exists() and path.suffix.lower() != ".zarr":
        # Only a .zarr path is taken for a database that is yet to be built; anything else that is
        # not there may have been either, so the message assumes neither.
        from ..errors import SkyfixError

        raise SkyfixError(f"DEM file {db} does not exist" if path.suffix.lower() in RASTER_SUFFIXES
                          else f"no such file or folder: {db} (give a DEM or a skyline database)")
    if path.is_file():
        d = describe_dem(db)
        click.echo(to_json(d, indent=1) if as_json else "\n".join(f"{k:12s} {v}" for k, v in _dem_lines(d)))
        return
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
    blocks = f"{d['n_blocks']} block{'s' * (d['n_blocks'] != 1)}"
    lines = [
        f"database     {d['path']} ({d['format']}, skyfix {d['software_version']})",
        f"crs          {d['crs']}",
        f"grid         {g['nx']} x {g['ny']} positions at {g['spacing_m']:g} m "
        f"(x {xmin:.1f}..{xmax:.1f}, y {ymin:.1f}..{ymax:.1f}; row 0 north), "
        f"blocks of {g['block_shape'][0]} x {g['block_shape'][1]}",
        f"skylines     {d['azimuth_bins']} azimuth bins, camera {d['camera_height_m']:g} m above ground, "
        f"rays to {maxd}, planet {p['name']} (R {p['radius_m']:.0f} m, k {p['refraction_k']:g}), "
        f"stored in steps of {d['scale_deg']:g} deg, rendered by the {d['renderer']}",
        f"dem          {d['dem']['source']} (sha256 {d['dem']['sha256'][:16]}...)",
        f"completeness {d['blocks_done']} of {blocks}"
        + (f" built, DAMAGED: {len(d['blocks_data_missing'])} of them without their data files"
           if d["blocks_data_missing"] else
           " (complete)" if d["complete"] else " (INCOMPLETE: rerun the build command to finish)"),
        f"coarse index {d['coarse_index_blocks']} of {blocks}"
        + (" (the search decodes only the blocks its coarse pass keeps)"
           if d["coarse_index_blocks"] == d["n_blocks"] else
           " (rerun the build command to add it: the search then decodes only the blocks it needs)"
           if d["coarse_index_possible"] else " (not possible: odd block side or bins not a multiple of 4)"),
        f"size         {d['size_bytes'] / 1e6:.1f} MB on disk, "
        + (f"{d['bytes_per_skyline']:.0f} bytes per built skyline" if d["bytes_per_skyline"] is not None
           else "no skyline built yet"),
    ]
    click.echo("\n".join(lines))


def describe_dem(path) -> dict:
    """What ``skyfix`` makes of a DEM file: its own CRS and body, the work CRS it is read into,
    extent [m], cell size [m], height range [m], voids (a sentence, and ``void_cells``: counts of
    cells) and the work CRS's scale error (a fraction: 0.001 stretches distances by 0.1 %)."""
    import numpy as np
    import rasterio
    from pyproj import CRS

    from ..dem import load_dem
    from ..workcrs import crs_label, geographic_bounds, scale_error

    dem = load_dem(path)  # first: it refuses what is no DEM with one clear line
    with rasterio.open(path) as src:
        native = CRS.from_user_input(src.crs.to_wkt()) if src.crs else None
        native_bounds = list(src.bounds)
        native_size = [src.width, src.height]
        native_res = [abs(src.transform.a), abs(src.transform.e)]
    body = dem.body
    b = dem.bounds
    native_err = (scale_error(native, native_bounds) if native is not None and native.is_projected
                  else float("nan"))
    return {
        "path": str(path),
        "native_crs": (native.to_string() if native is not None else None),
        "native_crs_name": native.name if native is not None else None,
        # one line for people: a code, a name, or a PROJ string, never a WKT of many lines
        "native_crs_label": crs_label(native) if native is not None else None,
        "native_size_px": native_size, "native_cell": native_res,
        "native_scale_error": native_err,
        "body": body.to_attr() if body is not None else None,
        "work_crs": dem.crs_name or dem.crs_wkt,
        "reprojected": bool(native is None or dem.crs_wkt != native.to_wkt()),
        "bounds_m": [float(v) for v in b],
        "size_m": [float(b[2] - b[0]), float(b[3] - b[1])],
        "lonlat_bounds": [float(v) for v in geographic_bounds(dem.crs_wkt, b)],
        "cell_m": [dem.dx, dem.dy], "shape": list(dem.z.shape),
        "height_m": [float(np.nanmin(dem.z)), float(np.nanmax(dem.z))],
        "voids": str(dem.voids),
        # the same as numbers, for a program: the sentence above is for people
        "void_cells": {"void": dem.voids.n_void, "filled": dem.voids.n_filled,
                       "left_masked": dem.voids.n_remaining, "outside_data": dem.voids.n_outside},
        "scale_error": dem.scale_error,
        "checksum_sha256": dem.checksum,
    }


def _dem_lines(d: dict):
    body = d["body"] or {"name": "unknown (Earth assumed)", "radius_m": float("nan"), "refraction_k": 0}
    w, s, e, n = d["lonlat_bounds"]
    yield "dem", d["path"]
    code = d["native_crs_label"]
    named = d["native_crs_name"] not in (None, "", "unknown", code)
    yield "native crs", (f"{d['native_crs_name'] + ' (' + code + ')' if named else code}, "
                         f"{d['native_size_px'][0]} x "
                         f"{d['native_size_px'][1]} px of {d['native_cell'][0]:g} x {d['native_cell'][1]:g}"
                         + (f", scale error {100 * d['native_scale_error']:.3f} %"
                            if d["native_scale_error"] == d["native_scale_error"] else ""))
    yield "body", f"{body['name']} (R {body['radius_m']:.0f} m, refraction k {body['refraction_k']:g})"
    yield "work crs", (f"{d['work_crs']}" + (" (reprojected)" if d["reprojected"] else " (the DEM's own)"))
    yield "extent", (f"x {d['bounds_m'][0]:.1f}..{d['bounds_m'][2]:.1f}, y {d['bounds_m'][1]:.1f}.."
                     f"{d['bounds_m'][3]:.1f} m ({d['size_m'][0] / 1000:.2f} x {d['size_m'][1] / 1000:.2f} km "
                     "between the outer cells' centres, where heights are defined); "
                     f"lon {w:.5f}..{e:.5f}, lat {s:.5f}..{n:.5f} deg")
    yield "cells", f"{d['shape'][1]} x {d['shape'][0]} of {d['cell_m'][0]:.3f} x {d['cell_m'][1]:.3f} m"
    yield "heights", f"{d['height_m'][0]:.1f} .. {d['height_m'][1]:.1f} m; {d['voids']}"
    err = d["scale_error"]
    yield "distortion", (f"scale error up to {100 * err:.4f} % over the DEM"
                         + (" (over the 0.1 % a horizon can take: reproject it to a conformal CRS, "
                            "its UTM zone, with gdalwarp -t_srs)"
                            if err > 1e-3 else ""))
