"""One photograph: roll, pitch and heading from a single navcam frame at a known position
(``skyfix attitude``), a frame seeing its skyline over a third of its width, a camera 30 m above
the DEM, and a frame with no skyline refused."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import shared_dem_path
from skyfix.cli.main import cli
from skyfix.dem import load_dem
from skyfix.formats import Truth
from skyfix.simulate import simulate_acquisition

X, Y = 601500.0, 6743500.0  # glacier DEM, a valley with ridges around


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.fixture(scope="module")
def dem_path():
    return shared_dem_path("south_glacier_20m")


def _frame(dem_path, out, *, yaw, pan, height=1.5, tilt=10.0, pitch=2.0, roll=-1.5, prior=None):
    dem = load_dem(dem_path)
    return simulate_acquisition(dem, Truth(X, Y, yaw, pitch, roll), out, frames=1, pan_start_deg=pan,
                                tilt_deg=tilt, camera_height_m=height, seed=3,
                                attitude_prior=prior)


def _angle(a):
    return abs((a + 180.0) % 360.0 - 180.0)


@pytest.mark.parametrize("height", [1.5, 30.0])
def test_one_frame_gives_roll_pitch_and_heading(dem_path, tmp_path, height):
    """The inclinometer off by (1.5, -1) deg and the heading prior 6 deg off; the camera 1.5 m or
    30 m above the DEM surface (taken from the acquisition)."""
    acq = _frame(dem_path, tmp_path / "acq", yaw=40.0, pan=0.0, height=height, prior=(3.5, -2.5))
    r = run("attitude", acq, "--dem", dem_path, "--x", X, "--y", Y, "--heading-prior-deg", 46.0,
            "--prior-north", "grid")
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout)
    assert _angle(d["grid_heading_deg"] - 40.0) < 1.0
    assert abs(d["pitch_deg"] - 2.0) < 0.5 and abs(d["roll_deg"] + 1.5) < 0.5
    assert set(d["determined"]) == {"heading", "pitch", "roll"} and d["determined"]["heading"]
    assert 0 < d["heading_sigma_deg"] < 1.0 and np.isfinite(d["pitch_sigma_deg"])
    assert d["confidence"] >= 0.5


def test_a_frame_looking_at_the_ground_is_refused_clearly(dem_path, tmp_path):
    acq = _frame(dem_path, tmp_path / "acq", yaw=40.0, pan=0.0, tilt=-60.0)
    r = run("attitude", acq, "--dem", dem_path, "--x", X, "--y", Y, "--heading-prior-deg", 46.0)
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output and "no skyline" in r.output and "sky visible?" in r.output
