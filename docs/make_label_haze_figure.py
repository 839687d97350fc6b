"""Regenerate docs/images/dev_label_haze.jpg and dev_label_haze_48.jpg
(PYTHONPATH=src python docs/make_label_haze_figure.py).

Why the dev set's last 2 % of false skyline is not the detector's to remove: three crops of the top
of Curiosity mosaics in ../shared/data/marsscapes-dev, each shown as is and contrast-stretched
(CLAHE), with the label's skyline (green; a green bar along the top where the label says the
terrain runs out of the frame) and what `skyfix detect` finds (red dashes). In all three a faint
band of Mount Sharp's flank, textured under the stretch, lies above the near ground. 404_1's label
calls the band sky in its middle and terrain to its right (a vertical cut, the same band on both
sides); 412_1's and 385_2's labels call like bands sky throughout.

The second figure (the 48-mosaic set): the same kind of band, Mount Sharp's flank in haze filling
the frame's top, is labelled sky above a near-edge skyline in 477_1 and in 344_1's right part,
and terrain (no sky in the mosaic) in 388_2 and 463_1. Red dashes are the sky network alone
(``--method net``) run with the ensemble member that held the image's fold out.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from skyfix.detect import detect_skyline  # noqa: E402
from skyfix.formats import read_skyline_json  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "data" / "marsscapes-dev"
IMAGES = ROOT / "docs" / "images"

CROPS = [  # image, first column, last column, rows shown, caption
    ("404_1", 1500, 4203, 100, "404_1: band labelled sky (middle), then terrain (right): 990 'false' columns"),
    ("412_1", 2100, 4248, 120, "412_1: a like band, labelled sky"),
    ("385_2", 0, 1700, 290, "385_2: a fainter band above the near ridge, labelled sky"),
]
CROPS_48 = [
    ("477_1", 1300, 2364, 210, "477_1: Mount Sharp's flank above the near ground, labelled sky"),
    ("344_1", 650, 1359, 220, "344_1 (right part): a like band with relief in it, labelled sky"),
    ("388_2", 1100, 2300, 200, "388_2: a like band, labelled terrain (no sky in the mosaic)"),
    ("463_1", 300, 1480, 110, "463_1: a like band, labelled terrain (no sky in the mosaic)"),
]


def held_out_member(name: str) -> int:
    """The sky network's ensemble member that was trained without ``name``'s fold."""
    meta = json.loads((ROOT / "src" / "skyfix" / "models" / "sky_net.json").read_text())
    for member, names in meta["held_out_by_member"].items():
        if name in names:
            return int(member.split("_")[1])
    raise SystemExit(f"{name} is in no fold of the shipped network")


def figure(crops, out: Path, held_out_net: bool, legend: str):
    fig, axes = plt.subplots(2 * len(crops), 1, figsize=(12, 10 * len(crops) / 3), dpi=80)
    for k, (name, c0, c1, nrow, caption) in enumerate(crops):
        bgr = cv2.imread(str(DEV / f"{name}.png"), cv2.IMREAD_COLOR)
        rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        truth = read_skyline_json(DEV / f"{name}.skyline.json")
        det = (detect_skyline(rgb, name=name, method="net", member=held_out_member(name))
               if held_out_net else detect_skyline(rgb, name=name))
        grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
        # a tall narrow CLAHE tile: the stretch follows the band's brightness along the mosaic
        stretched = cv2.createCLAHE(clipLimit=6.0, tileGridSize=(2, 16)).apply(grey)
        cols = np.arange(c0, c1)
        valid = truth.valid[c0:c1] if truth.valid is not None else np.ones(c1 - c0, bool)
        no_sky = valid & ~np.isfinite(truth.rows[c0:c1])
        for j, (pic, cmap) in enumerate(((rgb, None), (stretched, "gray"))):
            ax = axes[2 * k + j]
            ax.imshow(pic[:nrow, c0:c1], cmap=cmap, extent=(c0, c1, nrow, 0), aspect="auto",
                      interpolation="antialiased")
            ax.plot(cols, truth.rows[c0:c1], color="lime", lw=1.2)
            ax.plot(cols, det.rows[c0:c1], color="red", lw=1.0, ls=(0, (4, 3)))
            ax.fill_between(cols, 0, nrow * 0.04, where=no_sky, color="lime", lw=0)
            ax.set_xlim(c0, c1)
            ax.set_ylim(nrow, 0)
            ax.set_yticks([])
            ax.tick_params(labelsize=7)
            if j == 0:
                ax.set_title(caption, fontsize=9, loc="left")
    axes[0].plot([], [], color="lime", label="label's skyline (bar: terrain to the top)")
    axes[0].plot([], [], color="red", ls=(0, (4, 3)), label=legend)
    axes[0].legend(loc="lower right", fontsize=7, framealpha=0.8)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, pil_kwargs={"quality": 85})
    print(f"wrote {out}")


def main():
    figure(CROPS, IMAGES / "dev_label_haze.jpg", False, "skyfix detect")
    figure(CROPS_48, IMAGES / "dev_label_haze_48.jpg", True, "skyfix detect --method net (held-out member)")


if __name__ == "__main__":
    main()
