"""The sky network's training data (``scripts/train_sky_net.py``): the labelled images of the two
dev sets and the simulated frames, the pack they travel in to a training machine, the folds, the
augmentation that makes each training crop, and the batches, made here or in worker processes,
for one member or for the five members side by side. Needs no PyTorch.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
SKY_RGB = (34, 56, 19)
#: MarsScapes' "distant mountain" class: hazy relief the labels call terrain, the sky's lookalike
MOUNTAIN_RGB = (170, 85, 0)
#: label values: 0 terrain, 1 sky, 2 distant mountain (terrain, weighted), 255 unknown
MOUNTAIN = 2
CROP = (224, 320)  # working pixels (h, w)

# --- data -------------------------------------------------------------------------------------------

def _read_rgb(path):
    import cv2

    im = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if im is None:
        raise SystemExit(f"cannot read {path}")
    return cv2.cvtColor(im, cv2.COLOR_BGR2RGB)


def _rows_label(h, rows):
    """(h, W) uint8 labels from a skyline's rows: 1 sky above the row, 0 terrain, 255 unknown
    (columns without a row)."""
    rows = np.array([np.nan if r is None else r for r in rows], float)
    y = np.full((h, rows.size), 255, np.uint8)
    have = np.isfinite(rows)
    lab = (np.arange(h)[:, None] < rows[None, :]).astype(np.uint8)
    y[:, have] = lab[:, have]
    return y


def mars_images(folder):
    """(name, group, kind, RGB image, labels) for each labelled mosaic."""
    for lab_path in sorted(Path(folder).glob("*_label.png")):
        name = lab_path.name[: -len("_label.png")]
        img = _read_rgb(lab_path.with_name(name + ".png"))
        lab = _read_rgb(lab_path)
        sky = np.all(lab == np.array(SKY_RGB, np.uint8), axis=2)
        far = np.all(lab == np.array(MOUNTAIN_RGB, np.uint8), axis=2)
        y = np.where(sky, 1, np.where(far, MOUNTAIN, 0)).astype(np.uint8)
        y[~img.any(axis=2)] = 255
        yield name, "mars:" + name.split("_")[0], "mars", img, y


def web_images(folder):
    for tp in sorted(Path(folder).glob("*.skyline.json")):
        name = tp.name[: -len(".skyline.json")]
        img = _read_rgb(tp.with_name(name + ".png"))
        y = _rows_label(img.shape[0], json.loads(tp.read_text())["rows"])
        y[~img.any(axis=2)] = 255
        yield name, "web:" + name, "web", img, y


def _whole_columns(png: Path) -> tuple[list, list]:
    """The simulator's record of ``png``'s columns that are all ground and all sky (ranges), from
    its ``acquisition.json``; empty where it has none (frames rendered before 2026-11-27)."""
    acq = png.parent / "acquisition.json"
    if not acq.is_file():
        return [], []
    for info in json.loads(acq.read_text()).get("simulation", {}).get("images", []):
        if info.get("image") == png.name:
            return info.get("ground_only_columns", []), info.get("sky_only_columns", [])
    return [], []


def simulated_truths(folder, max_frames):
    """(frame PNG, its skyline truth) for the simulated frames under ``folder`` (the visible
    skyline where the simulator wrote one, else the terrain's), at most ``max_frames`` of them
    spread evenly. The sky classifier's training reads them too."""
    frames = []
    for png in sorted(Path(folder).rglob("*.png")):
        vis = png.with_name(png.stem + ".visible.skyline.json")
        truth = vis if vis.exists() else png.with_name(png.stem + ".skyline.json")
        if truth.exists():
            frames.append((png, truth))
    if len(frames) > max_frames:
        frames = [frames[i] for i in np.linspace(0, len(frames) - 1, max_frames).round().astype(int)]
    return frames


def sim_images(folder, max_frames=60):
    """(name, "sim", "sim", RGB image, labels) for each simulated frame with a truth: sky above
    each column's visible skyline; a column without one is terrain or sky where the simulator
    recorded it wholly so (its skyline above the frame's top, or no terrain in it), else ignored."""
    for png, truth in simulated_truths(folder, max_frames):
        rows = json.loads(truth.read_text())["rows"]
        ground, sky = _whole_columns(png)
        if any(r is not None for r in rows) or ground or sky:
            img = _read_rgb(png)
            y = _rows_label(img.shape[0], rows)
            for (a, b), value in [*((r, 0) for r in ground), *((r, 1) for r in sky)]:
                y[:, a:b] = value
            yield str(png), "sim", "sim", img, y


#: label value in a pack's label image: no image data there (the JPEG's pixels are not exactly 0)
PACK_NO_DATA = 254


def write_pack(images, folder: Path, *, sims=(), quality=90) -> None:
    """The labelled images as one folder small enough to travel to a training machine: each image
    as JPEG, its labels as PNG (with :data:`PACK_NO_DATA` where the image holds no data, which the
    JPEG no longer says exactly), ``index.json`` the names, groups and kinds in order."""
    import cv2

    from skyfix._io import write_json

    folder.mkdir(parents=True, exist_ok=True)
    index = []
    for i, (name, group, kind, img, y) in enumerate(images):
        lab = np.where(img.any(axis=2), y, PACK_NO_DATA).astype(np.uint8)
        if not (cv2.imwrite(str(folder / f"{i:04d}.jpg"), img[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, quality])
                and cv2.imwrite(str(folder / f"{i:04d}.png"), lab)):
            raise SystemExit(f"cannot write into {folder}")
        index.append({"name": name, "group": group, "kind": kind})
    write_json(folder / "index.json", {"jpeg_quality": quality, "sims": list(sims), "images": index})


def pack_images(folder: Path):
    """The images of :func:`write_pack`'s folder, as the readers above give them."""
    import cv2

    for i, e in enumerate(json.loads((folder / "index.json").read_text())["images"]):
        img = _read_rgb(folder / f"{i:04d}.jpg")
        y = cv2.imread(str(folder / f"{i:04d}.png"), cv2.IMREAD_UNCHANGED)
        none = y == PACK_NO_DATA
        img[none] = 0
        y[none] = 255
        yield e["name"], e["group"], e["kind"], img, y


def folds(groups, k):
    """Fold per group name: Mars sols (``mars:SOL``) and Earth photos (``web:NAME``) sorted (sols
    numerically) and dealt round-robin, so every group sits in one fold and neighbouring sols
    spread over the folds; anything else (simulated frames) -1, never held out."""
    out = {}
    for kind in ("mars", "web"):
        gs = sorted({g for g in groups if g.startswith(kind + ":")},
                    key=lambda g: (int(g.split(":")[1]) if kind == "mars" else g))
        out.update({g: i % k for i, g in enumerate(gs)})
    return {g: out.get(g, -1) for g in groups}


# --- augmentation ---------------------------------------------------------------------------------

def _photometric(x, rng, scale):
    """Degradations at full resolution on float RGB in [0, 1]; blur in full-resolution pixels."""
    import cv2

    if rng.random() < 0.2:
        x = np.repeat((x @ np.array([0.299, 0.587, 0.114], np.float32))[..., None], 3, axis=2)
    if rng.random() < 0.8:
        x = x * rng.uniform(0.75, 1.25, 3).astype(np.float32)
    if rng.random() < 0.8:
        x = np.clip(x * rng.uniform(0.5, 1.7), 0, 1) ** rng.uniform(0.65, 1.5)
    if rng.random() < 0.25:
        a = rng.uniform(0.1, 0.5)
        x = (1 - a) * x + a * rng.uniform(0.4, 0.9, 3).astype(np.float32)
    if rng.random() < 0.3:
        x = cv2.GaussianBlur(x, (0, 0), rng.uniform(0.3, 1.5) * 0.4 / max(scale, 0.2))
    if rng.random() < 0.3:
        x = x + rng.normal(0, rng.uniform(0.003, 0.03), x.shape).astype(np.float32)
    x = np.clip(x, 0, 1).astype(np.float32)
    if rng.random() < 0.3:
        ok, buf = cv2.imencode(".jpg", (x[..., ::-1] * 255).astype(np.uint8),
                               [cv2.IMWRITE_JPEG_QUALITY, int(rng.integers(30, 95))])
        x = cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1].astype(np.float32) / 255.0
    return np.ascontiguousarray(x)


def sample(img, y, rng, crop=CROP):
    """One training crop: (x (CHANNELS, h, w) float32, labels (h, w) uint8, 255 = ignore)."""
    import cv2

    from skyfix.detect.image import downscale_factor, trusted
    from skyfix.detect.net import CHANNELS, net_input
    from skyfix.detect.options import NetOptions

    H, W = y.shape
    s = math.exp(rng.uniform(-0.45, 0.45)) / downscale_factor(H, W, NetOptions().net_pixels)
    if rng.random() < 0.3:
        m = cv2.getRotationMatrix2D((W / 2, H / 2), rng.uniform(-6, 6), 1.0)
        img = cv2.warpAffine(img, m, (W, H), flags=cv2.INTER_LINEAR, borderValue=0)
        y = cv2.warpAffine(y, m, (W, H), flags=cv2.INTER_NEAREST, borderValue=255)
    if rng.random() < 0.5:
        img, y = img[:, ::-1], y[:, ::-1]
    ch, cw = crop
    fh, fw = int(round(ch / s)), int(round(cw / s))
    y0 = 0 if rng.random() < 0.5 else int(rng.integers(0, max(1, H - fh + 1)))
    x0 = int(rng.integers(0, max(1, W - fw + 1)))
    sub = np.ascontiguousarray(img[y0:y0 + fh, x0:x0 + fw])
    suby = np.ascontiguousarray(y[y0:y0 + fh, x0:x0 + fw])
    h, w = max(8, int(round(sub.shape[0] * s))), max(8, int(round(sub.shape[1] * s)))
    valid = sub.any(axis=2)
    xf = _photometric(sub.astype(np.float32) / 255.0, rng, s)
    xf[~valid] = 0.0
    x, v = net_input(xf, trusted(valid), (w, h))
    lab = np.where(v, cv2.resize(suby, (w, h), interpolation=cv2.INTER_NEAREST), 255)
    X = np.zeros((CHANNELS, ch, cw), np.float32)
    Y = np.full((ch, cw), 255, np.uint8)
    hh, ww = min(h, ch), min(w, cw)
    X[:, :hh, :ww] = x[:, :hh, :ww]
    Y[:hh, :ww] = lab[:hh, :ww]
    return X, Y



# --- batches ---------------------------------------------------------------------------------------

def _batch(images, p, batch, rng):
    """One training batch (x, labels, index of each crop's image) as arrays, images drawn with
    probabilities ``p``."""
    idx = rng.choice(len(images), batch, p=p)
    xs, ys = zip(*(sample(images[i][3], images[i][4], rng) for i in idx))
    return np.stack(xs), np.stack(ys), idx


_WORKER = {}


def _worker_init(images, p, batch, seed):
    import cv2

    cv2.setNumThreads(1)
    _WORKER.update(images=images, p=p, batch=batch, seed=seed)


def _worker_batch(step):
    w = _WORKER
    return _batch(w["images"], w["p"], w["batch"], np.random.default_rng([w["seed"], step]))


def batches(images, p, batch, seed, steps, workers, *, index=False, keyed=False):
    """The training batches (x, labels; with ``index`` also each crop's image): made here from one
    random stream (``workers`` 0, the shipped recipe), or by ``workers`` processes, batch ``k``
    from the stream ``(seed, k)``, so that a GPU is not kept waiting on the augmentation (~45 ms a
    crop on one core); ``keyed``: batch ``k`` from that stream also with ``workers`` 0. ``steps``
    None: without end. The workers are spawned, not forked: a fork after OpenCV's or PyTorch's
    threads have started can deadlock (it did)."""
    import itertools

    cut = slice(None) if index else slice(2)
    ks = range(steps) if steps is not None else itertools.count()
    if workers <= 0:
        rng = np.random.default_rng(seed)
        for k in ks:
            yield _batch(images, p, batch, np.random.default_rng([seed, k]) if keyed else rng)[cut]
        return
    import collections
    import multiprocessing

    pool = multiprocessing.get_context("spawn").Pool(workers, _worker_init, (images, p, batch, seed))
    try:
        ahead = collections.deque()
        for k in ks:
            left = steps - k if steps is not None else 4 * workers
            while len(ahead) < min(4 * workers, left):  # bounded: batches are 11 MB each
                ahead.append(pool.apply_async(_worker_batch, (k + len(ahead),)))
            yield ahead.popleft().get()[cut]
    finally:
        # Closed and joined (the batches asked ahead, 4 a worker, are finished first), never
        # terminated as the Pool's context manager does: a worker killed while it holds the task
        # queue's lock leaves Pool.terminate waiting for that lock for ever (a test run hung there,
        # its two workers dead, when a stream was dropped after its first batch).
        pool.close()
        pool.join()


def draw_probabilities(images, weights=(0.45, 0.35, 0.2), nosky_boost=2.0, sim_scale=1.0):
    """How often each image is drawn: ``weights`` shared by Mars, Earth and simulated images,
    Mars mosaics without sky ``nosky_boost`` times as often as the others, the simulated images'
    share times ``sim_scale`` before normalising (see :func:`shared_batches`)."""
    kinds = np.array([im[2] for im in images])
    p = np.zeros(len(images))
    for kind, w in zip(("mars", "web", "sim"), weights):
        if (kinds == kind).any():
            p[kinds == kind] = w * (sim_scale if kind == "sim" else 1.0) / (kinds == kind).sum()
    nosky = np.array([im[2] == "mars" and not (im[4] == 1).any() for im in images])
    p[nosky] *= nosky_boost
    return p / p.sum()


def shared_batches(images, fold_of_image, k, *, batch, seed, workers, chunk=8,
                   weights=(0.45, 0.35, 0.2), nosky_boost=2.0):
    """Batches for the ``k`` fold members trained side by side from one stream of crops: a crop
    of an image of fold f goes to every member but f's (a simulated frame, fold -1, to all), so
    each crop is made once for four members instead of once for each: the augmentation, not the
    network, bounds training on a GPU machine. Yields, step after step, a list of ``k`` (x,
    labels). Each member still sees the recipe's mix: a held-out fold takes 1/k of the real images
    away from a member but no simulated frame, so the stream draws those ``1 - 1/k`` as often.
    The crops come in chunks of ``chunk`` from :func:`batches`, so they do not depend on
    ``workers`` either."""
    import collections

    p = draw_probabilities(images, weights, nosky_boost, sim_scale=1.0 - 1.0 / k)
    fold = np.asarray(fold_of_image)
    queues = [collections.deque() for _ in range(k)]
    chunks = batches(images, p, chunk, seed, None, workers, index=True, keyed=True)
    try:
        while True:
            for m in range(k):
                while len(queues[m]) < batch:
                    x, y, idx = next(chunks)
                    for j, i in enumerate(idx):
                        for q in range(k):
                            if fold[i] != q:
                                queues[q].append((x[j], y[j]))
            out = []
            for m in range(k):
                xs, ys = zip(*(queues[m].popleft() for _ in range(batch)))
                out.append((np.stack(xs), np.stack(ys)))
            yield out
    finally:
        chunks.close()
