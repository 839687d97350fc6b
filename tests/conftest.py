"""Shared fixtures: the reference data folder, tiny synthetic DEMs with known answers and a
synthetic colour scene with a known skyline."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from skyfix.dem import Dem
from skyfix.detect import score_skyline
from skyfix.formats import Skyline

#: ../shared/data beside the repository (CI has it there too)
SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
DEM_DIR = SHARED_DATA / "dem"
SHARED_DEMS = ["sierra_nevada_30m", "south_glacier_20m", "alps_srtm3_n46e008"]


def shared_dem_path(name: str) -> Path:
    path = DEM_DIR / f"{name}.tif"
    if not path.exists():
        pytest.skip(f"shared reference DEM {path} not found (expected ../shared/data beside the repo)")
    return path


def plane_dem(size_m: float, spacing_m: float, z0: float = 100.0, slope_x: float = 0.0,
              slope_y: float = 0.0) -> Dem:
    """A plane z = z0 + slope_x * x + slope_y * y over [0, size] x [0, size]."""
    n = int(round(size_m / spacing_m)) + 1
    xs = np.arange(n) * spacing_m
    ys = xs[::-1]  # row 0 is north
    z = z0 + slope_x * xs[None, :] + slope_y * ys[:, None]
    return Dem.from_array(z, spacing_m)


def gaussian_hills(n: int, cell_m: float, count: int, rng, amp_m=(20.0, 120.0),
                   radius_m=(100.0, 400.0)):
    """Heights [m] (n x n, row 0 first, ``cell_m`` apart) of ``count`` Gaussian hills, each at a
    uniform place with a uniform height in ``amp_m`` and width (sigma) in ``radius_m``, drawn in
    that order from ``rng``: rolling relief whose skyline is neither flat nor one ridge.
    Also the grid's (yy, xx) [m]."""
    yy, xx = np.mgrid[0:n, 0:n] * cell_m
    z = np.zeros((n, n))
    for _ in range(count):
        cx, cy = rng.uniform(0, n * cell_m, 2)
        a, s = rng.uniform(*amp_m), rng.uniform(*radius_m)
        z += a * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * s * s))
    return z, yy, xx


@pytest.fixture
def tmp_dem_file(tmp_path):
    """Write a Dem to a GeoTIFF and return the path."""
    from skyfix.dem import write_dem

    def make(dem: Dem, name: str = "dem.tif") -> Path:
        return write_dem(tmp_path / name, dem)

    return make


def colour_scene(rows, height=200, *, seed=0, clouds=False):
    """Blue sky darkening to the horizon over brown gravel below ``rows`` (the first terrain row
    is ceil(rows)); with ``clouds``, bright soft cumulus in the sky well above the skyline."""
    rng = np.random.default_rng(seed)
    W = len(rows)
    r = np.arange(height)[:, None]
    terrain = r >= np.asarray(rows)[None, :]
    sky = np.stack([120 + 0.3 * r, 160 + 0.3 * r, 230 + 0 * r], -1) * np.ones((1, W, 1))
    if clouds:
        blob = ndimage.gaussian_filter(rng.normal(0, 1, (height, W)), 6.0)
        blob = np.clip((blob / blob.std() - 0.6) * 2.0, 0, 1)
        blob *= (r < np.asarray(rows)[None, :] - 25)  # clouds stay 25 px above the ridge
        sky = (1 - blob[..., None]) * sky + blob[..., None] * np.array([245.0, 245, 248])
    tex = ndimage.gaussian_filter(rng.normal(0, 1, (height, W)), 1.2)
    tex = 35 * tex / tex.std()
    ground = np.stack([130 + tex, 100 + tex, 70 + tex], -1)
    img = np.where(terrain[..., None], ground, sky) + rng.normal(0, 2, (height, W, 3))
    first = np.ceil(np.asarray(rows, float))
    return np.clip(img, 1, 255).astype(np.uint8), np.where(first < height, first, np.nan)


def score_rows(sk, truth):
    """score_skyline of a detection against truth rows (one per column, NaN = no skyline)."""
    return score_skyline(sk, Skyline(rows=truth, width=truth.size, height=sk.height))


@pytest.fixture(autouse=True)
def _opencv_log_level_restored():
    """``skyfix -q`` run in process sets OPENCV_LOG_LEVEL in os.environ (read when OpenCV loads);
    a later test's subprocess inherited it and the test of -q silencing OpenCV passed or failed
    by test order."""
    before = os.environ.get("OPENCV_LOG_LEVEL")
    yield
    if before is None:
        os.environ.pop("OPENCV_LOG_LEVEL", None)
    else:
        os.environ["OPENCV_LOG_LEVEL"] = before


def cli_run(*args):
    """``skyfix ARGS`` in process (click's runner), every argument as a string."""
    from click.testing import CliRunner

    from skyfix.cli.main import cli

    return CliRunner().invoke(cli, [str(a) for a in args])


def assert_one_error_line(result, *needles):
    """Exit status 2, exactly one ``Error:`` line, holding every needle; no traceback."""
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    errors = [ln for ln in result.output.splitlines() if ln.startswith("Error:")]
    assert len(errors) == 1, result.output
    for needle in needles:
        assert needle in errors[0], result.output
