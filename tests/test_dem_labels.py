"""DEMs whose labels do not match their numbers, and coordinates given in the wrong unit: each
is one clear line and exit status 2 (or read right, and said), never a traceback or a message
that sends the user to an option the command lacks.

Most cases are the small shared glacier DEM (UTM 7N, 20 m) written again with another label.
"""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import shared_dem_path
from skyfix.cli.main import cli
from skyfix.dem import load_dem
from skyfix.errors import DemError, SkyfixError


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def assert_clean_error(result, *needles):
    """Exit status 2, one ``Error:`` line holding every needle, no traceback."""
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    errors = [ln for ln in result.output.splitlines() if ln.startswith("Error:")]
    assert len(errors) == 1, result.output
    for needle in needles:
        assert needle in errors[0], result.output


@pytest.fixture
def glacier():
    return shared_dem_path("south_glacier_20m")


def relabel(src, dst, *, crs=None, scale=1.0, transform=None, units=None):
    """A copy of the raster ``src`` at ``dst`` with another CRS label (the numbers unchanged),
    its heights times ``scale``, another ``transform`` or a band unit."""
    import rasterio

    with rasterio.open(src) as s:
        profile = s.profile.copy()
        z = s.read(1, masked=True)
    profile.update(crs=crs if crs is not None else profile["crs"])
    if transform is not None:
        profile.update(transform=transform)
    with rasterio.open(dst, "w", **profile) as d:
        d.write((z * scale).filled(profile["nodata"]).astype(profile["dtype"]), 1)
        if units:
            d.units = (units,)
    return dst


# --- 1. a geographic CRS on coordinates in metres --------------------------------------------------

def test_metres_labelled_degrees_are_one_line_naming_the_coordinates(tmp_path, glacier):
    """EPSG:4326 on UTM coordinates ended in GDAL's "Too many points (441 out of 441) failed to
    transform", a traceback and exit 1."""
    mislabel = relabel(glacier, tmp_path / "mislabel.tif", crs="EPSG:4326")
    r = run("info", mislabel)
    assert_clean_error(r, "mislabel.tif: its CRS EPSG:4326 is geographic",
                       "x 599000..603960, y 6741000..6747000", "not longitudes and latitudes",
                       "gdal_edit.py -a_srs EPSG:XXXX mislabel.tif")
    with pytest.raises(DemError, match="is geographic but its coordinates"):
        load_dem(mislabel)


def test_a_reprojection_gdal_refuses_is_one_line_naming_both_crss(glacier):
    # an orthographic view centred on the far side of the Earth holds no point of Alaska
    far = "+proj=ortho +lat_0=-60 +lon_0=40 +datum=WGS84 +units=m"
    with pytest.raises(DemError, match=r"cannot reproject it from EPSG:32607 to .*ortho.*"
                                       r"\(GDAL: Too many points.*give a --crs that covers"):
        load_dem(glacier, crs=far)
    r = run("horizon", glacier, "--x", 601000, "--y", 6744000, "--crs", far)
    assert_clean_error(r, "cannot reproject it from EPSG:32607")
