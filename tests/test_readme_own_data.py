"""The README's "Your own data" section, run command by command as a user would: its `skyfix`
lines, with the variables filled in, on a real DEM and a folder of plain images (simulated, with
the truth kept aside where the commands cannot see it)."""

from __future__ import annotations

import json
import math
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import shared_dem_path

README = Path(__file__).resolve().parents[1] / "README.md"


def _commands() -> list[str]:
    text = README.read_text()
    sec = text[text.index("## Your own data"):]
    block = sec[sec.index("```bash") + len("```bash"):]
    block = block[:block.index("```")]
    lines = [ln.split("  #")[0].strip() for ln in block.splitlines()]
    return [ln for ln in lines if ln.startswith("skyfix ")]


def test_the_section_holds_the_path_from_dem_and_images_to_a_fix():
    cmds = [c.split()[1] for c in _commands()]
    assert cmds == ["info", "build-db", "acquisition-init", "detect", "locate", "heading"]


@pytest.mark.slow
def test_readme_own_data_section_runs_and_locates(tmp_path):
    from skyfix.dem import load_dem
    from skyfix.formats import Truth
    from skyfix.simulate import simulate_acquisition

    dem_path = shared_dem_path("south_glacier_20m")
    dem = load_dem(dem_path)
    # "my images": 12 navcam frames (45 deg wide, 30 deg apart, mast tilted 10 deg), of which the
    # user folder gets the PNGs alone
    truth = Truth(601_530.0, 6_743_960.0, 115.0, 0.0, 0.0)  # README prior 120 is true north
    sim = simulate_acquisition(dem, truth, tmp_path / "sim", camera="navcam", frames=12,
                               pan_start_deg=0.0, pan_step_deg=30.0, tilt_deg=10.0, seed=3)
    images = tmp_path / "my_images"
    images.mkdir()
    for png in sorted(sim.glob("frame_*.png")):
        (images / png.name).write_bytes(png.read_bytes())
    lon, lat = _lonlat(dem.crs_wkt, truth.x + 6.0, truth.y - 4.0)  # known to a few metres
    env = {"DEM": str(dem_path), "IMAGES": str(images), "XMIN": "601300", "YMIN": "6743700",
           "XMAX": "601800", "YMAX": "6744200", "LON": f"{lon:.7f}", "LAT": f"{lat:.7f}"}
    for cmd in _commands():
        line = re.sub(r"\$(\w+)", lambda m: env[m.group(1)], cmd)
        args = shlex.split(line)
        r = subprocess.run([sys.executable, "-m", "skyfix.cli.main", *args[1:]], cwd=tmp_path,
                           capture_output=True, text=True)
        assert r.returncode == 0, f"{line}\n{r.stdout}\n{r.stderr}"
    fix = json.loads((tmp_path / "fix.json").read_text())
    assert math.hypot(fix["x"] - truth.x, fix["y"] - truth.y) < 2.0
    assert abs((fix["grid_heading_deg"] - truth.yaw_deg + 180) % 360 - 180) < 0.5
    assert fix["confidence"] > 0.5 and fix["provenance"]["frames"]
    heading = json.loads((tmp_path / "heading.json").read_text())
    assert abs((heading["grid_heading_deg"] - truth.yaw_deg + 180) % 360 - 180) < 1.0
    conv = heading["meridian_convergence_deg"]
    assert abs((heading["heading_deg"] - heading["grid_heading_deg"] - conv + 180) % 360 - 180) < 1e-6
    gj = json.loads((tmp_path / "fix.geojson").read_text())
    assert {f["properties"]["role"] for f in gj["features"]} >= {"fix", "1-sigma", "candidate"}
    sky = json.loads((tmp_path / "skyline.json").read_text())
    assert np.isfinite(np.array(sky["rows"], float)).mean() > 0.5
    assert (tmp_path / "skyline.png").stat().st_size > 1000


def _lonlat(crs_wkt, x, y):
    from pyproj import CRS, Transformer

    c = CRS.from_user_input(crs_wkt)
    return Transformer.from_crs(c, "EPSG:4326", always_xy=True).transform(x, y)
