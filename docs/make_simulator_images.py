"""Regenerate the example images of docs/simulator.md (PYTHONPATH=src python docs/make_simulator_images.py
[STEM ...]: only those, e.g. ``snow lake``).

Renders from the Sierra Nevada DEM in ../shared/data, two overlapping navcam frames per condition
with the terrain skyline truth drawn in red (and the visible one in yellow where rocks cut it),
downscaled to keep the repository small.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import cv2
import numpy as np

from skyfix.dem import load_dem
from skyfix.formats import Truth, read_skyline_json
from skyfix.simulate import simulate_acquisition

ROOT = Path(__file__).resolve().parents[1]
DEM = ROOT.parent / "shared" / "data" / "dem" / "sierra_nevada_30m.tif"
OUT = ROOT / "docs" / "images"

CASES = [  # file stem, planet, conditions, pitch, roll, tilt
    ("nominal_earth", "earth", None, 0, 0, 0),
    ("nominal_mars", "mars", None, 0, 0, 0),
    ("dust", "mars", "dust:0.6", 0, 0, 0),
    ("clouds", "earth", "clouds:0.8", 0, 0, 0),
    ("snow", "earth", "snow:0.85", 0, 0, 0),
    ("lake", "earth", "lake:0.3", 0, 0, -10),
    ("rocks", "mars", "rocks:0.8", 0, 0, 0),
    ("glare", "earth", "glare:0.8", 0, 0, 0),
    ("overexposed", "earth", "overexposed:0.8", 0, 0, 0),
    ("dark", "mars", "dark:0.8", 0, 0, 0),
    ("blur", "earth", "blur:0.8", 0, 0, 0),
    ("pitch_roll", "mars", None, 6, -8, 0),
    ("skyline_out_of_view", "earth", None, 0, 0, -20),
]


def overlay(img, path, colour):
    if not path.exists():
        return
    rows = read_skyline_json(path).rows
    for c, r in enumerate(rows):
        if np.isfinite(r):
            rr = int(np.ceil(r))
            img[max(rr - 1, 0):rr + 1, c] = colour


def main(only=()):
    OUT.mkdir(parents=True, exist_ok=True)
    dem = load_dem(DEM)
    # A position whose skyline has some shape in the rendered directions (heading 250, two frames).
    from skyfix.horizon import render_horizons
    from skyfix.simulate import default_area

    xmin, ymin, xmax, ymax = default_area(dem)
    rng = np.random.default_rng(5)
    xs, ys = rng.uniform(xmin, xmax, 300), rng.uniform(ymin, ymax, 300)
    el = render_horizons(dem, xs, ys).elevation_deg[:, 228:303]
    score = np.where(el.max(axis=1) < 12, el.std(axis=1), 0)
    k = int(np.argmax(score))
    truth = (xs[k], ys[k])
    with tempfile.TemporaryDirectory() as tmp:
        for stem, planet, cond, pitch, roll, tilt in CASES:
            if only and stem not in only:
                continue
            acq = simulate_acquisition(dem, Truth(truth[0], truth[1], 250.0, pitch, roll), Path(tmp) / stem,
                                       frames=2, pan_start_deg=0, planet=planet, conditions=cond,
                                       tilt_deg=tilt, seed=11)
            tiles = []
            for k in range(2):
                img = cv2.imread(str(acq / f"frame_00{k}.png"))
                overlay(img, acq / f"frame_00{k}.skyline.json", (0, 0, 255))
                overlay(img, acq / f"frame_00{k}.visible.skyline.json", (0, 255, 255))
                tiles.append(cv2.resize(img, (256, 256), interpolation=cv2.INTER_AREA))
            cv2.imwrite(str(OUT / f"sim_{stem}.png"), np.hstack(tiles))
        if only and "panorama_mars" not in only:
            return
        acq = simulate_acquisition(dem, Truth(truth[0], truth[1], 250.0), Path(tmp) / "pano",
                                   mode="panorama", planet="mars", seed=11)
        img = cv2.imread(str(acq / "pano.png"))
        overlay(img, acq / "pano.skyline.json", (0, 0, 255))
        cv2.imwrite(str(OUT / "sim_panorama_mars.png"), cv2.resize(img, (1024, 256), interpolation=cv2.INTER_AREA))


if __name__ == "__main__":
    import sys

    main(set(sys.argv[1:]))
