"""The ``net`` detector: the shipped network loads from the installed package and runs on the CPU
through OpenCV alone; it finds known skylines, keeps clouds above a ridge out of the skyline, says
"no skyline" over hazy relief it did not train on, is deterministic, and turns bad input into a
clear error or a documented conversion."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from skyfix.detect import detect_skyline
from skyfix.detect.net import DEFAULT_NET, load_sky_net, net_input
from skyfix.errors import ParameterError
from skyfix.formats import read_skyline_json

from conftest import colour_scene, score_rows

DEV = Path(__file__).resolve().parents[2] / "shared" / "data" / "marsscapes-dev"


def test_the_shipped_network_loads_from_the_installed_package():
    from importlib.resources import files

    path = Path(str(files("skyfix") / "models" / "sky_net.onnx"))
    assert path == DEFAULT_NET and path.is_file() and path.stat().st_size < 10e6
    net = load_sky_net()
    assert net.meta["channels"] == 5 and net.cal_x.size >= 2  # calibrated confidence shipped


def test_net_runs_without_training_dependencies():
    """A fresh process detects with net and never imports PyTorch, onnx or scikit-learn."""
    code = ("import sys, numpy as np; from skyfix.detect import detect_skyline; "
            "img = np.zeros((120, 200, 3), np.uint8) + 90; img[:50] = 200; "
            "sk = detect_skyline(img, method='net'); "
            "print(sorted({'torch', 'onnx', 'sklearn'} & {m.split('.')[0] for m in sys.modules}))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"


def test_a_known_skyline_is_found():
    c = np.arange(420)
    img, truth = colour_scene(80 + 25 * np.sin(c / 40.0))
    s = score_rows(detect_skyline(img, method="net"), truth)
    assert s["missed_rate"] < 0.02 and s["mean_abs_err_px"] < 1.5 and s["within_3px"] > 0.95


def test_clouds_above_a_ridge_stay_out_of_the_skyline():
    """Five cloud fields (not one, which a model can pass by luck): pooled, few columns missed and
    nearly all within 3 px. The network shipped before 2026-11-27 lost one scene whole (seed 5:
    half the columns missed), 9.8 % missed pooled; the current one 1.5 %."""
    c = np.arange(420)
    rows = 120 + 15 * np.sin(c / 35.0)
    missed, within = [], []
    for seed in (3, 4, 5, 6, 7):
        img, truth = colour_scene(rows, height=240, seed=seed, clouds=True)
        s = score_rows(detect_skyline(img, method="net"), truth)
        missed.append(s["missed_rate"])
        within.append(s["within_3px"])
    assert np.mean(missed) < 0.04 and np.mean(within) > 0.95
    assert max(missed) < 0.2  # no scene lost


def test_the_same_image_gives_the_same_rows():
    img, _ = colour_scene(70 + 10 * np.cos(np.arange(300) / 30.0), seed=4)
    a = detect_skyline(img, method="net")
    b = detect_skyline(img.copy(), method="net")
    assert np.array_equal(a.rows, b.rows, equal_nan=True)
    assert np.array_equal(a.confidence, b.confidence)


@pytest.mark.shared_data
def test_hazy_relief_without_sky_is_no_skyline_for_a_member_that_never_saw_it():
    """The no-sky mosaics of the Mars dev set (the upper part hazy relief of a distant mountain,
    labelled terrain), each by the ensemble member that held its sol out in training: the share
    of their columns claimed as skyline stays at what the cross-validated benchmark measured."""
    if not DEV.is_dir():
        pytest.skip(f"no Mars dev set at {DEV}")
    import cv2

    claimed = total = 0
    for name, k in sorted(load_sky_net().held_out_members().items()):
        truth = DEV / f"{name}.skyline.json"
        if not truth.exists() or np.isfinite(np.asarray(read_skyline_json(truth).rows, float)).any():
            continue  # a mosaic with sky (or an Earth photo)
        img = cv2.cvtColor(cv2.imread(str(DEV / f"{name}.png")), cv2.COLOR_BGR2RGB)
        sk = detect_skyline(img, method="net", member=k)
        valid = np.asarray(sk.valid, bool)
        claimed += int(np.isfinite(sk.rows[valid]).sum())
        total += int(valid.sum())
    assert total > 0
    assert claimed / total <= NO_SKY_CLAIMED_MAX


#: the share of the no-sky mosaics' columns claimed, held out (benchmarks/bench_detect.py --cv-net)
#: plus a margin; see the README's detection row
NO_SKY_CLAIMED_MAX = 0.16  # measured 0.113 at the shipped min_confidence 0.3 (target 0.01: not
#                            met; 388_2 97 %, 404_2 31 %); the network before 2026-11-27: 0.194


def test_image_conversions_and_refusals():
    img, truth = colour_scene(60 + 8 * np.sin(np.arange(240) / 25.0), height=150, seed=6)
    base = detect_skyline(img, method="net").rows
    # 16-bit: the same image scaled to 0..65535 gives the same skyline
    sk16 = detect_skyline(img.astype(np.uint16) * 257, method="net").rows
    both = np.isfinite(base) & np.isfinite(sk16)
    assert both.mean() > 0.95 and np.abs(base - sk16)[both].max() < 1.0
    # RGBA: the alpha channel is dropped
    rgba = np.dstack([img, np.full(img.shape[:2], 255, np.uint8)])
    assert np.array_equal(detect_skyline(rgba, method="net").rows, base, equal_nan=True)
    # grey: taken as one channel
    grey = img.mean(axis=2).astype(np.uint8)
    s = score_rows(detect_skyline(grey, method="net"), truth)
    assert s["within_3px"] >= 0.95 and s["false_rate"] == 0
    with pytest.raises(ParameterError, match="too small"):
        detect_skyline(img[:5, :5], method="net")
    with pytest.raises(ParameterError, match="H x W x 3"):
        detect_skyline(np.zeros((50, 50, 2), np.uint8), method="net")
    with pytest.raises(ParameterError, match="net_pixels"):
        detect_skyline(img, method="net", net_pixels=0)


def test_net_input_channels():
    """Colour normalised per image, the validity mask, and the texture channel's median is 0."""
    img, _ = colour_scene(np.full(200, 80.0), seed=8)
    valid = np.ones(img.shape[:2], bool)
    valid[:, :20] = False
    x, v = net_input(img, valid, (100, 100))
    assert x.shape == (5, 100, 100) and v.shape == (100, 100)
    assert np.array_equal(x[3], v.astype(np.float32)) and not v[:, :9].any()
    assert abs(float(np.median(x[4][v]))) < 1e-6
    lum = x[:3].mean(axis=0)[v]
    assert abs(float(np.median(lum))) < 0.05
