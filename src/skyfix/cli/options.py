"""Click options shared by several subcommands (one definition, one help text)."""

from __future__ import annotations

import click

from ..detect.options import DEFAULT_METHOD, METHODS
from ..errors import ParameterError
from ..planets import get_planet


def given(name: str) -> bool:
    """Whether the option ``name`` was given on the command line (not its default)."""
    source = click.get_current_context().get_parameter_source(name)
    return source is click.core.ParameterSource.COMMANDLINE


def _planet(ctx, param, value):
    if value is None:
        return None
    try:
        return get_planet(value)
    except ParameterError as e:
        raise click.BadParameter(str(e)) from None


def camera_height(ctx, param, value):
    """Click callback: a camera height [m] that is finite and within 0 .. MAX_CAMERA_HEIGHT_M."""
    import math

    from ..formats import MAX_CAMERA_HEIGHT_M

    if value is None:
        return None
    if not (math.isfinite(value) and 0 <= value <= MAX_CAMERA_HEIGHT_M):
        why = (" (higher up, the skyline is the planet's limb, not the DEM's terrain)"
               if value > MAX_CAMERA_HEIGHT_M else "")
        raise click.BadParameter(
            f"camera height must be within 0 to {MAX_CAMERA_HEIGHT_M:g} m above the ground, "
            f"got {value:g}{why}")
    return value


#: [m] the largest DEM height error a sigma may allow for: beyond, the DEM says nothing
MAX_DEM_SIGMA_M = 1000.0


def dem_sigma(value):
    """``--dem-sigma-m`` checked before any work [m]: finite and >= 0 (0: the DEM is the world);
    None gives the sigmas' usual allowance, :data:`skyfix.pose.map_error.MAP_DEM_SIGMA_M`."""
    import math

    if value is None:
        from ..pose.map_error import MAP_DEM_SIGMA_M

        return MAP_DEM_SIGMA_M
    if not (math.isfinite(value) and 0 <= value <= MAX_DEM_SIGMA_M):
        # 1e300 passed as finite and overflowed in the sigmas' model
        raise ParameterError(f"--dem-sigma-m must be a number of metres from 0 (the DEM is taken "
                             f"as the world) to {MAX_DEM_SIGMA_M:g}, got {value}")
    return value


camera_height_option = click.option(
    "--camera-height-m", type=float, default=1.5, show_default=True, callback=camera_height,
    help="Camera centre above the ground [m].")
planet_option = click.option(
    "--planet", default=None, callback=_planet,
    help="earth, mars, moon, or a planet radius in metres (curvature; refraction 0.13 with "
         "'earth', none with a radius alone, Earth's included); "
         "default: the body of the DEM's CRS (an Earth CRS may stand in for any body).")
azimuth_bins_option = click.option(
    "--azimuth-bins", type=int, default=360, show_default=True,
    help="Number of azimuth bins over 360 degrees.")
max_distance_option = click.option(
    "--max-distance-m", type=float, default=None,
    help="Longest ray [m] (default: to the DEM edge).")
crs_option = click.option(
    "--crs", default=None, help="Metric CRS to read the DEM in (default: its own if projected within "
    "0.1 % of true distances, else its UTM zone or a transverse Mercator on its body; `skyfix info` "
    "prints it).")
overwrite_option = click.option("--overwrite", is_flag=True, help="Replace existing outputs.")
detector_option = click.option(
    "--detector", type=click.Choice(METHODS), default=None,
    help=f"Skyline detection method for the acquisition's images [default: {DEFAULT_METHOD}]; "
         "fuse (dp with the learned sky network) is the better on real photographs, dp on "
         "skyfix's own simulated frames; see README, skyline detection.")


def check_point_options(x, y, lon, lat, *, xname="--x", yname="--y", lonname="--lon",
                        latname="--lat", required=True) -> None:
    """A point given as x/y [m] or lon/lat [deg], each pair whole and finite (checked before any
    file is read); with ``required`` one of the two pairs."""
    import math

    # both kinds at once is said first: "give both --x and --y" misled a user who had given
    # --lon/--lat and one stray --x
    if (x is not None or y is not None) and (lon is not None or lat is not None):
        raise ParameterError(f"give {xname}/{yname} or {lonname}/{latname}, not both")
    for a, b, na, nb in ((x, y, xname, yname), (lon, lat, lonname, latname)):
        if (a is None) != (b is None):
            raise ParameterError(f"give both {na} and {nb}")
        for n, v in ((na, a), (nb, b)):
            if v is not None and not math.isfinite(v):
                raise ParameterError(f"{n} must be a finite number, got {v}")
    if lat is not None and not -90.0 <= lat <= 90.0:
        raise ParameterError(f"{latname} must be within [-90, 90] deg, got {lat}")
    # east longitudes 0-360, as Mars's are often given, as well as -180-180
    if lon is not None and not -180.0 <= lon <= 360.0:
        raise ParameterError(f"{lonname} must be within [-180, 360] deg, got {lon}")
    if x is not None and lon is not None:
        raise ParameterError(f"give {xname}/{yname} or {lonname}/{latname}, not both")
    if required and x is None and lon is None:
        raise ParameterError(f"give {xname} and {yname} [m] (or {lonname} and {latname} [deg])")


def point_xy(x, y, lon, lat, crs_wkt):
    """(x, y) [m] in the work CRS: the given x/y, or lon/lat [deg] on the CRS's body; None when
    neither was given."""
    if lon is None:
        return (x, y) if x is not None else None
    from ..workcrs import lonlat_to_xy

    if not crs_wkt:
        raise ParameterError("--lon/--lat need a DEM or database with a CRS")
    return lonlat_to_xy(crs_wkt, lon, lat)


def traverse_path_options(f):
    """``--length-m``, ``--stop-spacing-m`` and ``--stop-conditions`` of a simulated traverse
    (``simulate-traverse`` and ``evaluate --scenario traverse``)."""
    f = click.option("--stop-conditions", multiple=True, metavar="STOP=CONDITIONS",
                     help="Simulated traverse: conditions at one stop, e.g. 12=clouds:1 or "
                          "20=overexposed:1 (repeatable).")(f)
    f = click.option("--stop-spacing-m", type=float, default=50.0, show_default=True,
                     help="Simulated traverse: between stops [m].")(f)
    return click.option("--length-m", type=float, default=3000.0, show_default=True,
                        help="Simulated traverse: path length [m].")(f)
