"""The sky network's training data (scripts/sky_net_data.py, used by train_sky_net.py) as it
travels to a training machine (--write-pack / --pack) and the crops made in worker processes:
what arrives is what was written, the batches do not depend on how many workers made them, and
members trained side by side never see their held-out fold. PyTorch is not needed."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))
import sky_net_data as T  # noqa: E402


def _images():
    rng = np.random.default_rng(3)
    out = []
    for k, kind in enumerate(("mars", "web", "sim")):
        h, w = 180, 400
        img = np.zeros((h, w, 3), np.uint8)
        img[: h // 3] = (90, 120, 200)  # sky
        img[h // 3:] = rng.integers(40, 120, (h - h // 3, w, 3))  # textured ground
        img[:, :25] = 0  # a mosaic's no-data border
        y = np.where(np.arange(h)[:, None] < h // 3, 1, 0).repeat(w, 1).astype(np.uint8)
        y[:, :25] = 255
        y[h // 3 + 10: h // 3 + 20, 200:260] = T.MOUNTAIN
        y[:, 390:] = 255  # a column without a drawn skyline: valid image, no label
        out.append((f"im{k}", f"{kind}:{k}", kind, img, y))
    return out


def test_a_pack_gives_back_the_labels_and_the_no_data_exactly(tmp_path):
    images = _images()
    T.write_pack(images, tmp_path / "pack", sims=["set_a"])
    back = list(T.pack_images(tmp_path / "pack"))
    assert [b[:3] for b in back] == [i[:3] for i in images]
    for (_, _, _, img, y), (_, _, _, img2, y2) in zip(images, back):
        assert np.array_equal(y2, y)  # labels lossless, 255 both for no data and for no label
        none = ~img.any(axis=2)
        assert np.array_equal(~img2.any(axis=2), none)  # the JPEG's near-black border is zeroed
        diff = np.abs(img2.astype(int) - img.astype(int))
        assert np.max(diff[5:40, 48:380]) <= 3  # the smooth sky, off JPEG blocks that hold an edge
        assert np.mean(diff[~none]) < 15  # and the ground, uniform noise, JPEG's worst case


def test_batches_are_the_same_whatever_the_number_of_workers():
    images = _images()
    p = np.full(len(images), 1 / len(images))
    one = list(T.batches(images, p, 2, 7, 3, workers=1))
    two = list(T.batches(images, p, 2, 7, 3, workers=2))
    assert len(one) == len(two) == 3
    for (x1, y1), (x2, y2) in zip(one, two):
        assert x1.shape[0] == 2 and x1.shape[2:] == T.CROP and y1.shape == (2, *T.CROP)
        assert np.array_equal(x1, x2) and np.array_equal(y1, y2)
    # and the crops hold labelled pixels of both kinds, from the images drawn
    ys = np.stack([y for _, y in one])
    assert (ys == 1).any() and (ys == 0).any()


def test_members_side_by_side_never_see_their_held_out_fold_and_keep_the_recipes_mix():
    images = _images() * 4  # 12 images: mars, web, sim, four times over
    fold_of = [0, 1, -1, 1, 2, -1, 2, 0, -1, 0, 2, -1]  # sims (every third) are never held out
    k, batch = 3, 4
    stream = T.shared_batches(images, fold_of, k, batch=batch, seed=5, workers=0, chunk=3)
    drawn = {m: [] for m in range(k)}
    p = T.draw_probabilities(images, sim_scale=1 - 1 / k)
    for _ in range(60):
        step = next(stream)
        assert len(step) == k
        for m, (x, y) in enumerate(step):
            assert x.shape[0] == batch and y.shape == (batch, *T.CROP)
            drawn[m].append(x)
    stream.close()
    # the crops a member got are the stream's, minus its fold: compare with the stream itself
    chunks = T.batches(images, p, 3, 5, 200, 0, index=True, keyed=True)
    made = [(x[j], i) for x, _, idx in chunks for j, i in enumerate(idx)]
    for m in range(k):
        mine = [(xx, i) for xx, i in made if fold_of[i] != m][: 60 * batch]
        got = np.concatenate(drawn[m])
        assert all(np.array_equal(a, b) for a, (b, _) in zip(got, mine))  # in stream order
        kinds = [images[i][2] for _, i in mine]
        assert all(fold_of[i] != m for _, i in mine)
        # the simulated share stays near the recipe's 0.2 (0.2 exactly in expectation)
        assert 0.1 < kinds.count("sim") / len(kinds) < 0.3
    # and a worker pool gives the same chunks
    one = next(T.shared_batches(images, fold_of, k, batch=batch, seed=5, workers=2, chunk=3))
    for (x1, y1), x0 in zip(one, (drawn[m][0] for m in range(k))):
        assert np.array_equal(x1, x0)


def test_simulated_columns_without_a_skyline_are_labelled_as_the_simulator_recorded_them(tmp_path):
    """A column without a skyline row is terrain where the simulator recorded it all ground (the
    skyline above the frame), sky where it recorded it all sky, and ignored where it recorded
    nothing (frames rendered before it did)."""
    import json

    import cv2

    h, w = 40, 10
    cv2.imwrite(str(tmp_path / "frame_000.png"), np.full((h, w, 3), 120, np.uint8))
    rows = [None, None, None, 20.0, 20.0, None, None, None, None, None]
    (tmp_path / "frame_000.skyline.json").write_text(json.dumps({"rows": rows, "width": w,
                                                                  "height": h}))
    sim = {"images": [{"image": "frame_000.png", "ground_only_columns": [[0, 3]],
                       "sky_only_columns": [[8, 10]]}]}
    (tmp_path / "acquisition.json").write_text(json.dumps({"simulation": sim}))
    (_, _, kind, _, y), = list(T.sim_images(tmp_path))
    assert kind == "sim"
    assert (y[:, :3] == 0).all() and (y[:, 8:] == 1).all()  # recorded: terrain, sky
    assert (y[:, 5:8] == 255).all()  # not recorded: ignored
    assert (y[:20, 3:5] == 1).all() and (y[20:, 3:5] == 0).all()  # a skyline row as before
    # without the record, the same frame is what it was: rows only, the rest ignored
    (tmp_path / "acquisition.json").unlink()
    (_, _, _, _, y0), = list(T.sim_images(tmp_path))
    assert (y0[:, :3] == 255).all() and (y0[:, 8:] == 255).all()
