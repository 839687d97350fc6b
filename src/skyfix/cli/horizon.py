"""``skyfix horizon``: the skyline a DEM predicts from one point."""

from __future__ import annotations

import sys

import click
import numpy as np

from .options import (azimuth_bins_option, camera_height_option, crs_option, max_distance_option,
                      overwrite_option, planet_option)


@click.command()
@click.argument("dem_path", metavar="DEM", type=click.Path(dir_okay=False))
@click.option("--x", "x", type=float, required=True, help="Easting [m] in the DEM's (projected) CRS.")
@click.option("--y", "y", type=float, required=True, help="Northing [m] in the DEM's (projected) CRS.")
@camera_height_option
@planet_option
@azimuth_bins_option
@max_distance_option
@crs_option
@click.option("--json", "as_json", is_flag=True, help="Print the profile as JSON.")
@click.option("--plot", type=click.Path(dir_okay=False), default=None, help="Draw the profile to a PNG.")
@overwrite_option
def horizon(dem_path, x, y, camera_height_m, planet, azimuth_bins, max_distance_m, crs, as_json,
            plot, overwrite):
    """Render the skyline a DEM predicts from (X, Y).

    Elevation angles [deg] per azimuth bin (bin k centred on k*360/bins deg, clockwise from grid
    north), with the planet's curvature and refraction. Rays stop at the DEM edge or
    --max-distance-m; their lengths are reported.
    """
    from .._io import check_can_write, to_json
    from ..dem import load_dem
    from ..horizon import render_horizon

    if plot:
        check_can_write(plot, overwrite)
    dem = load_dem(dem_path, crs=crs)
    hb = render_horizon(dem, x, y, camera_height_m=camera_height_m, planet=planet,
                        azimuth_bins=azimuth_bins, max_distance_m=max_distance_m)
    el = hb.elevation_deg[0].astype(float)
    length = hb.ray_length_m[0].astype(float)
    az = hb.azimuth_deg
    if as_json:
        click.echo(to_json({
            "x": x, "y": y, "crs": dem.crs_name or dem.crs_wkt, "ground_z_m": float(hb.ground_z_m[0]),
            "camera_height_m": camera_height_m, "planet": planet.to_attr(),
            "azimuth_deg": np.round(az, 6), "elevation_deg": np.round(el, 4),
            "ray_length_m": np.round(length, 2),
        }))
    else:
        _summary(dem, x, y, hb, el, length, az, max_distance_m)
    if plot:
        _plot(plot, az, el, length, x, y, dem, max_distance_m)
        click.echo(f"wrote {plot}", err=as_json)


def _summary(dem, x, y, hb, el, length, az, max_distance_m):
    k = int(np.nanargmax(el)) if np.isfinite(el).any() else 0
    edge = length < (max_distance_m or np.inf) * (1 - 1e-6)
    out = sys.stdout
    print(dem.describe(), file=out)
    print(f"point ({x:.1f}, {y:.1f}), ground {hb.ground_z_m[0]:.1f} m, camera {hb.camera_height_m:g} m "
          f"above, planet {hb.planet.name}", file=out)
    print(f"skyline over {az.size} bins: mean {np.nanmean(el):.2f} deg, min {np.nanmin(el):.2f} deg, "
          f"max {el[k]:.2f} deg at azimuth {az[k]:.1f} deg", file=out)
    print(f"rays reaching the DEM edge: {int(edge.sum())} of {az.size} (shortest {length.min():.0f} m)",
          file=out)
    names = ["N", "NE", "E", "SE", "S", "SW", "W", "NW"]
    sector = np.round(az / 45.0).astype(int) % 8  # sector i spans 45 i +- 22.5 deg
    cells = [f"{n} {np.nanmax(el[sector == i]) if np.any(sector == i) else np.nan:+.1f}"
             for i, n in enumerate(names)]
    print("highest per sector [deg]: " + ", ".join(cells), file=out)


def _plot(path, az, el, length, x, y, dem, max_distance_m):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .._io import atomic_path

    fig, ax = plt.subplots(figsize=(10, 3.2))
    ax.fill_between(az, np.nan_to_num(el, nan=np.nanmin(el)), np.nanmin(el) - 1, color="0.45")
    ax.plot(az, el, color="k", lw=1)
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
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)
