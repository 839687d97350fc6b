"""Train the sky-vs-terrain pixel classifier used by the ``dp`` detector's region term.

Reads every labelled mosaic of the dev set (``NAME.png`` + ``NAME_label.png``, sky = RGB
(34, 56, 19), black = no data), extracts :func:`skyfix.skymodel.training_pixels`, fits
:func:`skyfix.skymodel.fit_sky_model` on all of them and writes the tree arrays (.npz, no pickle).

    PYTHONPATH=src python scripts/train_sky_model.py \\
        --data ../shared/data/marsscapes-dev --out src/skyfix/models/sky_hgb.npz [--overwrite] \\
        [--sim FOLDER ...] [--grey]

``--sim`` adds simulated acquisitions (``skyfix simulate-set`` output), labelled exactly from the
simulator's visible skylines, so that the classifier also knows skies the real dev set lacks
(Earth's blue, clouds, glare). Each image also enters as a crop cut just below its skyline, so
that sky dominates it (:func:`sky_dominant_crop`; ``--no-sky-crops`` to skip). The shipped model was trained with the sets that
``scripts/make_sky_sims.sh`` renders (seeds 901-905, never used for evaluation), as the simulator
rendered them before commit ac76fd1 (shaded ground: sky-view light, +-20 % metre-scale albedo);
frames rendered now differ in their shaded ground, so retraining gives a slightly different model.

The held-out (leave-one-image-out) accuracy of this recipe is printed by
``benchmarks/bench_detect.py --cv``.

``--grey`` trains the model for images without colour on grey copies of the same images (the
chroma features are then 0, as they are for a grey input). The shipped grey model was trained by
``scripts/make_sky_sims.sh SIMS && python scripts/train_sky_model.py --grey --sim SIMS/*
--sim-max-frames 10`` (sims rendered by the simulator as of this model); its held-out accuracy:
``benchmarks/bench_detect.py --methods dp --no-all --cv --cv-sim SIMS --degrade grey``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def read_labelled(folder):
    """Yield (name, RGB image, sky mask) for each NAME.png with a NAME_label.png."""
    import cv2

    from skyfix.detect.skymodel import sky_label_mask

    for lab_path in sorted(Path(folder).glob("*_label.png")):
        name = lab_path.name[: -len("_label.png")]
        im = cv2.imread(str(lab_path.with_name(name + ".png")), cv2.IMREAD_COLOR)
        lab = cv2.imread(str(lab_path), cv2.IMREAD_COLOR)
        if im is None or lab is None:
            raise SystemExit(f"cannot read {name}.png or its label in {folder}")
        yield name, cv2.cvtColor(im, cv2.COLOR_BGR2RGB), sky_label_mask(
            cv2.cvtColor(lab, cv2.COLOR_BGR2RGB))


def read_simulated(folder, max_frames):
    """Yield (name, RGB image, sky mask) for simulated frames under ``folder``.

    Pixel rows above a column's visible skyline row are sky, the rest terrain; columns without a
    skyline (all terrain or all sky: the truth file does not say which) are blanked to no-data.
    At most ``max_frames`` frames, spread evenly, so the real dev set keeps its weight.
    """
    import cv2

    from skyfix.formats import read_skyline_json

    from sky_net_data import simulated_truths

    for png, truth in simulated_truths(folder, max_frames):
        sky = read_skyline_json(truth)
        if not np.isfinite(sky.rows).any():
            continue
        img = cv2.cvtColor(cv2.imread(str(png), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        h = img.shape[0]
        rows = np.arange(h)[:, None]
        # pixel centre v lies above the skyline (sky) when v < r
        mask = rows < np.where(np.isfinite(sky.rows), sky.rows, -1)[None, :]
        img[:, ~np.isfinite(sky.rows)] = 0
        yield f"{png.parent.parent.name}/{png.parent.name}/{png.stem}", img, mask


def sky_dominant_crop(img, sky, sky_share=0.7):
    """The image cut just below its skyline, so that about ``sky_share`` of the kept valid
    pixels are sky: (image, sky mask), or None when there is too little sky.

    The classifier's features are relative to image-wide medians. The dev mosaics are mostly
    terrain, so a frame that is mostly sky (a mast tilted up, a panorama's upper half) puts the
    median in the sky and, untrained on that, the classifier called such skies terrain."""
    valid = np.any(img > 0, axis=2) if img.ndim == 3 else img > 0
    n_sky = int((sky & valid).sum())
    if n_sky < 2000:
        return None
    cols = np.flatnonzero(sky.any(axis=0))
    last_sky = np.array([np.flatnonzero(sky[:, c])[-1] for c in cols])
    r0 = int(np.percentile(last_sky, 90)) + 1
    terr_per_row = (valid & ~sky).sum(axis=1)
    want = n_sky * (1 - sky_share) / sky_share  # terrain pixels to keep
    cum = np.cumsum(terr_per_row)
    r1 = int(np.searchsorted(cum, cum[min(r0, len(cum) - 1)] + want))
    r1 = max(r0 + 8, min(r1, img.shape[0]))
    if r1 >= img.shape[0] - 8:
        return None
    return img[:r1].copy(), sky[:r1].copy()


def simulated_frames(folders, max_frames):
    """:func:`read_simulated` over several folders, ``max_frames`` in all, shared evenly."""
    for k, folder in enumerate(folders):
        share = max_frames // len(folders) + (k < max_frames % len(folders))
        yield from read_simulated(folder, share)


def as_grey(img):
    """An RGB training image as the grey image a camera without colour would deliver."""
    import cv2

    return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img


def training_views(img, sky, sky_crops=True):
    """The (tag, image, sky mask) views one labelled image contributes: itself and, with
    ``sky_crops``, its :func:`sky_dominant_crop`."""
    views = [("", img, sky)]
    if sky_crops:
        crop = sky_dominant_crop(img, sky)
        if crop is not None:
            views.append((" (sky-dominant crop)", *crop))
    return views


def main(argv=None):
    from skyfix.detect.skymodel import fit_sky_model, training_pixels

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "marsscapes-dev"))
    ap.add_argument("--out", default=str(ROOT / "src" / "skyfix" / "models" / "sky_hgb.npz"))
    ap.add_argument("--overwrite", action="store_true")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--sim", action="append", default=[],
                    help="folder of simulated acquisitions to add (repeatable)")
    ap.add_argument("--sim-max-frames", type=int, default=24,
                    help="at most this many simulated frames in all")
    ap.add_argument("--no-sky-crops", dest="sky_crops", action="store_false",
                    help="do not add a sky-dominant crop of each image (see sky_dominant_crop)")
    ap.add_argument("--grey", action="store_true",
                    help="train on grey copies of every image: the model for images without "
                         "colour (default --out src/skyfix/models/sky_hgb_grey.npz)")
    args = ap.parse_args(argv)
    if args.grey and args.out == ap.get_default("out"):
        args.out = str(ROOT / "src" / "skyfix" / "models" / "sky_hgb_grey.npz")
    out = Path(args.out)
    if out.exists() and not args.overwrite:
        raise SystemExit(f"{out} exists: pass --overwrite to replace it")
    t0 = time.perf_counter()
    parts = []
    import itertools

    for name, img, sky in itertools.chain(read_labelled(args.data),
                                          simulated_frames(args.sim, args.sim_max_frames)):
        for tag, im, sk in training_views(img, sky, args.sky_crops):
            X, y = training_pixels(as_grey(im) if args.grey else im, sk)
            parts.append((X, y))
            print(f"{name}{tag}: {len(y)} pixels, {100 * y.mean():.1f} % sky", file=sys.stderr)
    if not parts:
        raise SystemExit(f"no labelled images in {args.data}")
    model, clf = fit_sky_model(parts, seed=args.seed)
    model.save(out)
    print(f"wrote {out} ({out.stat().st_size / 1024:.0f} KiB, {model.roots.size} trees, "
          f"{model.feat.size} nodes) from {len(parts)} images in "
          f"{time.perf_counter() - t0:.0f} s", file=sys.stderr)
    Xa = np.concatenate([p[0] for p in parts])
    ref = clf.decision_function(Xa[:2000])
    mine = model.log_odds_sky(Xa[:2000])
    print(f"export check: max |sklearn - arrays| log-odds = {np.abs(ref - mine).max():.2e}",
          file=sys.stderr)


if __name__ == "__main__":
    main()
