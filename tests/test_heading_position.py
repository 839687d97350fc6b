"""Scenario 3 from a rough position: a skyline near the camera, which the position's error moves
by degrees, must not pull the heading (``skyfix heading --position-sigma-m``)."""

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import shared_dem_path
from skyfix.cli.main import cli
from skyfix.dem import load_dem
from skyfix.formats import Truth
from skyfix.pose.heading import position_weights
from skyfix.simulate import simulate_acquisition


def test_position_weights_closed_form():
    """noise^2 / (noise^2 + (sigma / d)^2), deg: a ridge 100 m away under a 10 m position error
    moves by 5.73 deg; one at 50 km by 0.0115 deg; a bin without a skyline distance weighs 1."""
    w = position_weights(np.array([100.0, 50e3, np.nan]), 10.0, 0.1)
    e = math.degrees(0.1)
    np.testing.assert_allclose(w[0], 0.01 / (0.01 + e * e), rtol=1e-12)
    np.testing.assert_allclose(w[1], 0.01 / (0.01 + math.degrees(10.0 / 50e3) ** 2), rtol=1e-12)
    assert w[2] == 1.0
    assert np.all(position_weights(np.array([100.0, 5e3]), 0.0, 0.1) == 1.0)


def test_heading_from_a_position_20_m_off_beside_near_terrain(tmp_path):
    """A full turn in the Sierra where much of the skyline lies within 300 m; the rough position
    20 m west of the truth (scenario 3 allows metres). Weighing each bin by how far the position
    error can move it: 0.09 deg off (measured; fuse 0.003); every bin alike: 1.95 deg off, the
    near slopes dragging the fit. (The Albers coordinates of before, 3.4 deg then, read into UTM
    11N, the same place and true heading.)"""
    dem_path = shared_dem_path("sierra_nevada_30m")
    tx, ty, yaw = 308769.7598, 4148327.7565, 271.6868
    acq = simulate_acquisition(load_dem(dem_path), Truth(tx, ty, yaw, 0.0, 0.0), tmp_path / "acq",
                               frames=12, seed=1)
    base = ["heading", str(acq), "--dem", str(dem_path), "--x", str(tx - 20.0), "--y", str(ty),
            "--heading-prior-deg", str(yaw + 3.0), "--prior-north", "grid"]

    def error(*extra):
        r = CliRunner().invoke(cli, base + list(extra))
        assert r.exit_code == 0, r.output
        d = json.loads(r.stdout)
        return abs((d["grid_heading_deg"] - yaw + 180.0) % 360.0 - 180.0), d

    weighted, d = error()
    assert weighted < 0.3 and d["provenance"]["options"]["position_sigma_m"] == 10.0
    assert d["provenance"]["options"]["detector"] == "dp"
    # the same frames through the fuse detector: the same heading, and the answer says how
    fused, d = error("--detector", "fuse")
    assert fused < 0.3 and d["provenance"]["options"]["detector"] == "fuse"
    alike, _ = error("--position-sigma-m", "0")
    assert alike > 1.0
    # a position known to kilometres: the sigma is that of a heading not known at all (it was
    # 7.8 M deg at confidence 0.9999997), and the confidence says the heading is not likely right
    _, d = error("--position-sigma-m", "1e9")
    assert d["heading_sigma_deg"] == pytest.approx(360.0 / math.sqrt(12.0)) and d["confidence"] < 0.05
    r = CliRunner().invoke(cli, base + ["--position-sigma-m", "-5"])
    assert r.exit_code == 2 and "--position-sigma-m" in r.output and "Traceback" not in r.output


def test_position_heading_sigma_closed_form():
    """A skyline equally far all round does not turn under a translation; one ridge alone,
    ``d`` away, turns by ``sigma / d``; two equal ridges 90 deg apart by ``sigma / (sqrt(2) d)``."""
    from skyfix.pose.heading import position_heading_sigma_deg

    n = 360
    d = np.full(n, 2000.0)
    assert position_heading_sigma_deg(d, np.ones(n), 10.0) < 1e-12
    one = np.full(n, np.nan)
    one[40] = 500.0
    np.testing.assert_allclose(position_heading_sigma_deg(one, np.ones(n), 10.0),
                               math.degrees(10.0 / 500.0), rtol=1e-12)
    two = np.full(n, np.nan)
    two[[0, 90]] = 500.0
    w = np.zeros(n)
    w[[0, 90]] = 1.0
    np.testing.assert_allclose(position_heading_sigma_deg(two, w, 10.0),
                               math.degrees(10.0 / 500.0) / math.sqrt(2.0), rtol=1e-12)
