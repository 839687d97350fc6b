"""``skyfix horizon``: the skyline a DEM predicts from one point."""

from __future__ import annotations

import sys

import click
import numpy as np

from ..errors import ParameterError
from .options import (azimuth_bins_option, camera_height_option, check_point_options, crs_option,
                      max_distance_option, overwrite_option, planet_option, point_xy)


@click.command()
@click.argument("dem_path", metavar="DEM", type=click.Path(dir_okay=False))
@click.option("--x", "x", type=float, help="Easting [m] in the work CRS (see skyfix info DEM).")
@click.option("--y", "y", type=float, help="Northing [m] in the work CRS.")
@click.option("--lon", type=float, help="Longitude [deg] on the DEM's body, instead of --x/--y.")
@click.option("--lat", type=float, help="Latitude [deg] on the DEM's body.")
@camera_height_option
@planet_option
@azimuth_bins_option
@max_distance_option
@crs_option
@click.option("--json", "as_json", is_flag=True, help="Print the profile as JSON.")
@click.option("--plot", type=click.Path(dir_okay=False), default=None,
              help="Draw the profile to this file (.png, .jpg, .pdf or .svg).")
@overwrite_option
@click.option("--dem", "more_dems", multiple=True, type=click.Path(dir_okay=False),
              help="Another DEM of the same place (repeatable): a stack, the finest DEM winning "
                   "wherever it has heights.")
def horizon(dem_path, x, y, lon, lat, camera_height_m, planet, azimuth_bins, max_distance_m, crs,
            as_json, plot, overwrite, more_dems):
    """Render the skyline a DEM predicts from (X, Y).

    Elevation angles [deg] per azimuth bin (bin k centred on k*360/bins deg, clockwise from grid
    north), with the planet's curvature and refraction. Rays stop at the DEM edge or
    --max-distance-m; their lengths are reported.
    """
    from .._io import PLOT_FORMATS, check_outputs, to_json
    from ..dem import load_dem
    from ..stack import load_dems
    from ..horizon import render_horizon

    check_point_options(x, y, lon, lat)
    if not 1 <= azimuth_bins <= 65535:  # 1e8 bins ran for 88 s; a database holds at most 65535
        raise ParameterError(f"azimuth bins must be 1 to 65535, got {azimuth_bins}")
    check_outputs(overwrite, ("--plot", plot, PLOT_FORMATS))
    dem = load_dems([dem_path, *more_dems], crs=crs) if more_dems else load_dem(dem_path, crs=crs)
    x, y = point_xy(x, y, lon, lat, dem.crs_wkt)
    # checked here, not only in the renderer: this command can tell degrees typed for --x/--y
    dem.require_inside(np.array([x]), np.array([y]), "point", lonlat_options="--lon/--lat")
    hb = render_horizon(dem, x, y, camera_height_m=camera_height_m, planet=planet,
                        azimuth_bins=azimuth_bins, max_distance_m=max_distance_m)
    el = hb.elevation_deg[0].astype(float)
    length = hb.ray_length_m[0].astype(float)
    az = hb.azimuth_deg
    if as_json:
        click.echo(to_json({
            "x": x, "y": y, "crs": dem.crs_name or dem.crs_wkt, **_lonlat(dem.crs_wkt, x, y),
            "ground_z_m": float(hb.ground_z_m[0]),
            "camera_height_m": camera_height_m, "planet": hb.planet.to_attr(),
            "azimuth_deg": np.round(az, 6), "elevation_deg": np.round(el, 4),
            # conventions.md's profile format; a render from the DEM carries no noise estimate
            "sigma_deg": np.full(el.size, np.nan),
            "ray_length_m": np.round(length, 2),
        }))
    else:
        _summary(dem, x, y, hb, el, length, az, max_distance_m)
    if plot:
        _plot(plot, az, el, length, x, y, dem, max_distance_m)
        click.echo(f"wrote {plot}", err=as_json)


def _summary(dem, x, y, hb, el, length, az, max_distance_m):
    # Bins whose ray finds no terrain (pointing off the DEM from its edge or corner) are NaN:
    # statistics skip them, and a sector without any terrain says so instead of "+nan".
    seen = np.isfinite(el)
    edge = length < (max_distance_m or np.inf) * (1 - 1e-6)
    out = sys.stdout
    print(dem.describe(), file=out)
    print(f"point ({x:.1f}, {y:.1f}), ground {hb.ground_z_m[0]:.1f} m, camera {hb.camera_height_m:g} m "
          f"above, planet {hb.planet.name}", file=out)
    if seen.any():
        k = int(np.flatnonzero(seen)[np.argmax(el[seen])])
        print(f"skyline over {az.size} bins ({int(seen.sum())} with terrain): mean {el[seen].mean():.2f} "
              f"deg, min {el[seen].min():.2f} deg, max {el[k]:.2f} deg at azimuth {az[k]:.1f} deg",
              file=out)
    else:
        print(f"skyline over {az.size} bins: no terrain in any direction (the point is on the DEM's "
              "edge and every ray leaves it)", file=out)
    print(f"rays reaching the DEM edge: {int(edge.sum())} of {az.size} (shortest {length.min():.0f} m)",
          file=out)
    names = ["N", "NE", "E", "SE", "S", "SW", "W", "NW"]
    sector = np.round(az / 45.0).astype(int) % 8  # sector i spans 45 i +- 22.5 deg
    cells = []
    for i, n in enumerate(names):
        in_sector = sector == i
        if not in_sector.any():
            cells.append(f"{n} no bin")  # fewer than 8 --azimuth-bins
        elif not (in_sector & seen).any():
            cells.append(f"{n} no terrain")
        else:
            cells.append(f"{n} {el[in_sector & seen].max():+.1f}")
    print("highest per sector [deg]: " + ", ".join(cells), file=out)


def _plot(path, az, el, length, x, y, dem, max_distance_m):
    from ..optional import pyplot

    plt = pyplot()

    from .._io import save_figure

    fig, ax = plt.subplots(figsize=(10, 3.2))
    seen = np.isfinite(el)
    if seen.any():  # NaN bins (no terrain) are gaps in the line, not a warning
        low = float(el[seen].min())
        ax.fill_between(az, np.where(seen, el, low), low - 1, where=seen, color="0.45")
        ax.plot(az, el, color="k", lw=1)
    else:
        ax.text(0.5, 0.5, "no terrain in any direction", transform=ax.transAxes, ha="center")
    # Without --max-distance-m every ray runs to the DEM edge by design: nothing to flag.
    edge = length < max_distance_m * (1 - 1e-6) if max_distance_m else np.zeros(az.size, bool)
    if edge.any():
        ax.plot(az[edge], el[edge], ".", ms=2, color="tab:red",
                label="ray stopped at the DEM edge before max distance")
        ax.legend(loc="upper right", fontsize=8)
    ax.set_xlim(0, 360)
    ax.set_xticks(range(0, 361, 45))
    ax.set_xlabel("azimuth from grid north [deg]")
    ax.set_ylabel("elevation [deg]")
    ax.set_title(f"skyline at ({x:.0f}, {y:.0f}) {dem.crs_name}", fontsize=9)
    fig.tight_layout()
    try:
        save_figure(fig, path, dpi=120)
    finally:
        plt.close(fig)


def _lonlat(crs_wkt, x, y) -> dict:
    from ..pose.fix import crs_and_lonlat

    _, lon, lat = crs_and_lonlat(crs_wkt, x, y)
    return {"lon": lon, "lat": lat}
