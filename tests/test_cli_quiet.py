"""``skyfix -q``: only errors on standard error (no stage lines, warnings or progress bars, nor
what OpenCV says on its own past Python's logging)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

from skyfix.cli.main import cli
from skyfix.dem import Dem, write_dem


@pytest.fixture(scope="module")
def hill(tmp_path_factory):
    n = 61
    yy, xx = np.mgrid[0:n, 0:n] * 20.0
    z = 100.0 + 300.0 * np.exp(-((xx - 900.0) ** 2 + (yy - 400.0) ** 2) / (2 * 250.0**2))
    return write_dem(tmp_path_factory.mktemp("dem") / "hill.tif", Dem.from_array(z, 20.0))


@pytest.fixture(scope="module")
def geotiff_image(tmp_path_factory):
    """A photo saved as a GeoTIFF: OpenCV warns of each GeoTIFF tag it does not know."""
    import rasterio
    from rasterio.transform import from_origin

    yy, xx = np.mgrid[0:120, 0:160]
    sky = np.where(yy < 50 + 10 * np.sin(xx / 15.0), 200, 60).astype(np.uint8)
    p = tmp_path_factory.mktemp("img") / "photo.tif"
    with rasterio.open(p, "w", driver="GTiff", width=160, height=120, count=1, dtype="uint8",
                       crs="EPSG:32611", transform=from_origin(500000, 4100000, 1, 1)) as f:
        f.write(sky, 1)
    return p


def skyfix(*args):
    return subprocess.run([sys.executable, "-m", "skyfix.cli.main", *map(str, args)],
                          capture_output=True, text=True, timeout=300)


def test_quiet_simulate_set_draws_no_progress_bar(hill, tmp_path):
    args = ("simulate-set", hill, "--set", "REF", "--cases", 1, "--frames", 1, "--camera", "wide")
    loud = skyfix(*args, "-o", tmp_path / "loud")
    assert loud.returncode == 0 and "set REF" in loud.stderr, loud.stderr  # the bar, without -q
    r = skyfix("-q", *args, "-o", tmp_path / "quiet")
    assert r.returncode == 0, r.stderr
    assert r.stderr == "" and "1 case in" in r.stdout
    assert (tmp_path / "quiet" / "case_000" / "acquisition.json").is_file()


def test_quiet_silences_opencv(geotiff_image, tmp_path):
    loud = skyfix("detect", geotiff_image, "-o", tmp_path / "loud.json")
    assert loud.returncode == 0 and "TIFF_Warning" in loud.stderr, loud.stderr  # the set-up
    r = skyfix("-q", "detect", geotiff_image, "-o", tmp_path / "quiet.json")
    assert r.returncode == 0 and (tmp_path / "quiet.json").is_file(), r.stderr
    assert "WARN" not in r.stderr, r.stderr


def test_quiet_drops_the_summary_lines_on_stderr(geotiff_image, tmp_path):
    """detect, profile, locate, heading, traverse and simulate-traverse say what they wrote on
    stderr (and warn there): with -q that stderr held more than errors."""
    r = skyfix("detect", geotiff_image, "-o", tmp_path / "loud.json")
    assert r.returncode == 0 and "photo.tif: skyline in" in r.stderr, r.stderr
    r = skyfix("-q", "detect", geotiff_image, "-o", tmp_path / "quiet.json")
    assert r.returncode == 0 and (tmp_path / "quiet.json").is_file(), r.stderr
    assert r.stderr == ""
    r = skyfix("-q", "detect", tmp_path / "none.png")
    assert r.returncode == 2 and "Error:" in r.stderr  # errors still are


def test_quiet_silences_opencv_already_loaded(geotiff_image, tmp_path, capfd, monkeypatch):
    """In a process that loaded OpenCV before the command line was read (a program calling the
    CLI), its level is set on the loaded library."""
    cv2 = pytest.importorskip("cv2")
    level = cv2.utils.logging.getLogLevel()
    monkeypatch.delenv("OPENCV_LOG_LEVEL", raising=False)  # put back after the test
    try:
        # the control: loud, OpenCV warns on this GeoTIFF's tags (an earlier -q in this process
        # must not make the test below pass for nothing)
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_WARNING)
        capfd.readouterr()
        r = CliRunner().invoke(cli, ["detect", str(geotiff_image), "-o", str(tmp_path / "l.json")])
        assert r.exit_code == 0, r.output
        assert "WARN" in capfd.readouterr().err
        r = CliRunner().invoke(cli, ["-q", "detect", str(geotiff_image), "-o", str(tmp_path / "s.json")])
        assert r.exit_code == 0, r.output
        assert "WARN" not in capfd.readouterr().err
    finally:
        cv2.utils.logging.setLogLevel(level)


def test_build_db_says_a_dems_warning_once_whatever_its_workers(tmp_path):
    """A DEM read into another CRS is warned about when the build reads it; each Dask worker
    reading it again said it again, unprefixed, through the progress bar (three times with two
    workers)."""
    z = 100.0 + 40.0 * np.sin(np.arange(60)[None, :] / 7.0) * np.cos(np.arange(60)[:, None] / 9.0)
    dem = write_dem(tmp_path / "far.tif", Dem.from_array(z, 10.0, crs="EPSG:32611"))  # 0.27 %
    from skyfix.dem import load_dem

    x0, y0, x1, y1 = load_dem(dem).bounds  # in the work CRS it is read into (UTM 10N)
    cx, cy = round((x0 + x1) / 2), round((y0 + y1) / 2)
    r = skyfix("build-db", dem, "-o", tmp_path / "db.zarr", "--bounds", cx - 100, cy - 100,
               cx + 100, cy + 100,
               "--spacing-m", 10, "--workers", 2, "--azimuth-bins", 36)
    assert r.returncode == 0, r.stderr
    assert r.stderr.count("stretches distances") == 1, r.stderr
