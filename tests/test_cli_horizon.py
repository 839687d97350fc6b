"""`skyfix horizon` and the CLI's shared behaviour: JSON output, plot, one-line errors."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from conftest import cli_run as run, plane_dem, shared_dem_path


def assert_clean_error(result, needle):
    assert result.exit_code != 0
    assert needle in result.output
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)


def test_json_output_has_the_documented_fields(tmp_dem_file):
    path = tmp_dem_file(plane_dem(4_000, 20, z0=100))
    r = run("horizon", path, "--x", 2_000, "--y", 2_000, "--azimuth-bins", 36, "--json")
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout)
    assert set(d) >= {"x", "y", "crs", "ground_z_m", "camera_height_m", "azimuth_deg", "elevation_deg",
                      "ray_length_m"}
    assert d["crs"] == plane_dem(4_000, 20).crs_name and d["ground_z_m"] == pytest.approx(100.0)
    assert len(d["elevation_deg"]) == 36 and d["azimuth_deg"][9] == 90.0
    # conventions.md's profile format, sigma_deg included (null: a render has no noise estimate)
    assert d["sigma_deg"] == [None] * 36
    np.testing.assert_allclose(d["ray_length_m"][0], 2_000.0, rtol=1e-4)  # north edge 2 km away
    assert all(e < 0 for e in d["elevation_deg"])  # a plane's skyline dips below the horizontal


def test_summary_and_plot(tmp_dem_file, tmp_path):
    path = tmp_dem_file(plane_dem(4_000, 20))
    png = tmp_path / "p.png"
    r = run("horizon", path, "--x", 1_000, "--y", 1_500, "--planet", "mars", "--plot", png)
    assert r.exit_code == 0, r.output
    assert "planet mars" in r.output and "highest per sector" in r.output
    assert png.read_bytes()[:4] == b"\x89PNG"
    r2 = run("horizon", path, "--x", 1_000, "--y", 1_500, "--plot", png)
    assert_clean_error(r2, "--overwrite")


def test_real_dem_point_reports_its_crs():
    path = shared_dem_path("south_glacier_20m")
    r = run("horizon", path, "--x", 601_500, "--y", 6_744_000, "--json")
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout)
    assert d["crs"] == "EPSG:32607" and 1_600 < d["ground_z_m"] < 3_200


def test_bad_input_gives_one_line_errors(tmp_path, tmp_dem_file):
    good = tmp_dem_file(plane_dem(1_000, 10))
    assert_clean_error(run("horizon", tmp_path / "missing.tif", "--x", 0, "--y", 0), "does not exist")
    notes = tmp_path / "notes.txt"
    notes.write_text("hello")
    assert_clean_error(run("horizon", notes, "--x", 0, "--y", 0), "cannot read")
    assert_clean_error(run("horizon", good, "--x", 5_000, "--y", 0), "outside the DEM")
    assert_clean_error(run("horizon", good, "--x", 500, "--y", 500, "--camera-height-m", -2), "camera height")
    assert_clean_error(run("horizon", good, "--x", 500, "--y", 500, "--azimuth-bins", 0), "azimuth bins")
    # 1e8 bins ran for 88 s before answering
    assert_clean_error(run("horizon", good, "--x", 500, "--y", 500, "--azimuth-bins", 10**8),
                       "azimuth bins must be 1 to 65535")
    assert_clean_error(run("horizon", good, "--x", 500, "--y", 500, "--planet", "venus"), "unknown planet")

    import rasterio
    from rasterio.transform import from_origin

    nocrs = tmp_path / "nocrs.tif"
    with rasterio.open(nocrs, "w", driver="GTiff", width=4, height=4, count=1, dtype="float32",
                       transform=from_origin(0, 40, 10, 10)) as dst:
        dst.write(np.ones((4, 4), np.float32), 1)
    assert_clean_error(run("horizon", nocrs, "--x", 10, "--y", 10), "no CRS")


def test_help_and_version_do_not_import_heavy_modules():
    code = ("import sys; from click.testing import CliRunner; from skyfix.cli.main import cli; "
            "r = CliRunner().invoke(cli, ['--help']); assert r.exit_code == 0, r.output; "
            "heavy = [m for m in ('numba', 'cv2', 'dask', 'matplotlib', 'zarr', 'rasterio') if m in sys.modules]; "
            "print(','.join(heavy))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""
    r = run("--version")
    assert r.exit_code == 0 and "skyfix, version" in r.output


def test_a_point_given_both_ways_is_refused_as_both():
    """--lon/--lat with one stray --x was answered "give both --x and --y"."""
    from skyfix.cli.options import check_point_options
    from skyfix.errors import ParameterError

    with pytest.raises(ParameterError, match="give --x/--y or --lon/--lat, not both"):
        check_point_options(5.0, None, 8.0, 46.0)
    with pytest.raises(ParameterError, match="give both --x and --y"):
        check_point_options(5.0, None, None, None)
