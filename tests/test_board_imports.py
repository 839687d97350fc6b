"""The board segment imports only what it uses: each board command, run in a fresh process, must
not import scikit-learn, matplotlib, Dask or PyTorch (hundreds of MB of a 256 MB budget)."""

from __future__ import annotations

import subprocess
import sys

import pytest

HEAVY = ("sklearn", "matplotlib", "dask", "distributed", "torch")

RUNNER = """
import atexit, sys
def report():
    got = sorted({m.split('.')[0] for m in sys.modules} & set(%r))
    sys.stderr.write('HEAVY:' + ','.join(got) + '\\n')
atexit.register(report)
from skyfix.cli.main import cli
cli(sys.argv[1:], prog_name='skyfix')
""" % (HEAVY,)


@pytest.fixture(scope="module")
def board_inputs(tmp_path_factory):
    from skyfix.dem import fractal_dem, write_dem
    from skyfix.formats import Truth
    from skyfix.simulate import simulate_acquisition

    d = tmp_path_factory.mktemp("board")
    dem = fractal_dem(160, 30.0, relief_m=900.0, seed=6)
    dem_path = write_dem(d / "dem.tif", dem)
    xmin, ymin, xmax, ymax = dem.bounds
    x, y = (xmin + xmax) / 2, (ymin + ymax) / 2
    acq = simulate_acquisition(dem, Truth(x, y, 40.0, 0.0, 0.0), d / "acq", camera="wide",
                               frames=4, tilt_deg=10.0, seed=1)
    return d, dem_path, acq, x, y


@pytest.mark.parametrize("command", ["detect", "profile", "locate", "heading"])
def test_board_commands_stay_lean(board_inputs, command):
    d, dem_path, acq, x, y = board_inputs
    args = {
        "detect": ["detect", str(acq / "frame_000.png"), "-o", str(d / "sky.json"), "--overwrite"],
        "profile": ["profile", str(acq), "-o", str(d / "prof.json"), "--overwrite"],
        "locate": ["locate", str(acq), "--dem", str(dem_path), "--prior-x", str(x + 3),
                   "--prior-y", str(y - 2), "--prior-radius-m", "10", "-o", str(d / "fix.json"),
                   "--overwrite"],
        "heading": ["heading", str(acq), "--dem", str(dem_path), "--x", str(x), "--y", str(y),
                    "--heading-prior-deg", "40", "--prior-north", "grid", "-o",
                    str(d / "heading.json"), "--overwrite"],
    }[command]
    r = subprocess.run([sys.executable, "-c", RUNNER, *args], capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr
    heavy = [ln for ln in r.stderr.splitlines() if ln.startswith("HEAVY:")]
    assert heavy == ["HEAVY:"], f"{command} imported {heavy}"
