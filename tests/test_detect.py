"""Skyline detection on synthetic images with known skylines, and on real Mars mosaics."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from skyfix.cli.main import cli
from skyfix.detect import combine_scores, detect_skyline, score_skyline
from skyfix.errors import ParameterError
from skyfix.formats import Skyline, read_skyline_json


from conftest import SHARED_DATA, colour_scene, score_rows

DEV = SHARED_DATA / "marsscapes-dev"
METHODS = ["dp", "bayes"]


def synth(sky_rows, height=160, *, seed=0, noise=2.0, rgb=True):
    """An image whose column c is sky above ``sky_rows[c]`` and textured terrain from there on.

    sky_rows : float per column [px]; terrain where row >= sky_rows[c] (so the first terrain
    row is ceil(sky_rows[c])); <= 0 means all terrain, >= height all sky.
    Returns (image uint8, truth rows with NaN where there is no skyline).
    """
    from scipy import ndimage

    rng = np.random.default_rng(seed)
    W = len(sky_rows)
    rows = np.arange(height)[:, None]
    terrain = rows >= np.asarray(sky_rows)[None, :]
    sky = 200 - 0.15 * rows + rng.normal(0, noise, (height, W))
    # gravel: blobs of +-40 grey levels at a few-pixel scale
    tex = ndimage.gaussian_filter(rng.normal(0, 1, (height, W)), 1.2)
    ter = 120 + 40 * tex / tex.std() + rng.normal(0, noise, (height, W))
    g = np.clip(np.where(terrain, ter, sky), 1, 255).astype(np.uint8)
    first = np.ceil(np.asarray(sky_rows, float))
    truth = np.where((first > 0) & (first < height), first, np.nan)
    if rgb:
        img = np.stack([g, (g * 0.85).astype(np.uint8), (g * 0.7).astype(np.uint8)], axis=-1)
        img = np.maximum(img, 1)  # keep away from the no-data colour
    else:
        img = g
    return img, truth


def _score(sk, truth, valid=None):
    t = Skyline(rows=truth, width=truth.size, height=sk.height, valid=valid)
    return score_skyline(sk, t)


@pytest.mark.parametrize("method", METHODS)
def test_step_skyline(method):
    c = np.arange(240)
    rows = np.where(c < 120, 50.0, 90.0)  # a 40 px cliff
    img, truth = synth(rows)
    sk = detect_skyline(img, method=method)
    s = _score(sk, truth)
    # dp cuts the cliff's foot diagonally over 9 columns (rows 10-30 px off); their confidence
    # is ~0, so they are reported as unknown rather than wrong: missed 5 %
    assert s["false_rate"] == 0 and s["missed_rate"] <= (0.06 if method == "dp" else 0.01)
    assert s["within_3px"] >= 0.95  # measured 0.974 (dp)
    assert s["mean_abs_err_px"] < 1.0  # measured 0.72 (dp)
    if method == "dp":
        assert s["within_10px"] >= 0.99  # measured 0.996
    assert sk.confidence.shape == (240,) and np.all((sk.confidence >= 0) & (sk.confidence <= 1))


@pytest.mark.parametrize("method", METHODS)
def test_steep_slope(method):
    c = np.arange(240, dtype=float)
    # a ridge rising 3 rows per column (72 deg) then a flat top
    rows = np.clip(130 - 3.0 * (c - 60), 40, 130)
    img, truth = synth(rows, height=180, seed=1)
    sk = detect_skyline(img, method=method)
    s = _score(sk, truth)
    # dp: the flank's foot (rows 8-13 px off at confidence < 0.15) is reported as unknown
    assert s["false_rate"] == 0 and s["missed_rate"] <= (0.08 if method == "dp" else 0.02)
    assert s["within_3px"] >= (0.95 if method == "dp" else 0.9)  # measured 0.96 (both)
    if method == "dp":
        assert s["within_10px"] == 1.0
    steep = (rows < 130) & (rows > 40)
    err = np.abs(sk.rows[steep] - truth[steep])
    # dp follows the 72 deg flank through moves within a column (measured median 1.42 px),
    # bayes through its smoothness window, held to the edge by its boundary term (1.32 px; ~9 px
    # without it, cutting the corner)
    assert np.nanmedian(err) <= 2.1


@pytest.mark.parametrize("method", METHODS)
def test_skyline_leaving_frame(method):
    c = np.arange(300, dtype=float)
    # the ridge climbs out of the top of the frame: columns >= 200 are all terrain
    rows = 80 - 0.8 * (c - 100).clip(0)
    img, truth = synth(rows, seed=2)
    sk = detect_skyline(img, method=method)
    s = _score(sk, truth)
    assert s["false_rate"] <= 0.06  # near the exit only a few sky rows remain
    assert s["missed_rate"] <= 0.06  # measured 0.047: the last columns hold only a few sky rows
    assert s["within_3px"] >= 0.9
    assert np.isnan(sk.rows[215:]).all()


@pytest.mark.parametrize("method", METHODS)
def test_sky_filling_most_of_the_frame(method):
    """Sky over three quarters of the frame: its own noise is then the image's median texture.
    bayes's old prior (edge density over 0.4 x the median is terrain) called every column all
    sky (missed 100 %)."""
    c = np.arange(300, dtype=float)
    img, truth = synth(120 + 10 * np.sin(c / 30.0), height=160, seed=4)
    s = _score(detect_skyline(img, method=method), truth)
    assert s["false_rate"] == 0 and s["missed_rate"] <= 0.02
    assert s["within_3px"] >= 0.8  # measured 0.86 (bayes)
    assert s["within_10px"] == 1.0


@pytest.mark.parametrize("method", METHODS)
def test_no_sky_at_all(method):
    img, truth = synth(np.full(300, -1.0), seed=3)
    assert np.isnan(truth).all()
    sk = detect_skyline(img, method=method)
    assert np.isnan(sk.rows).all()
    assert sk.valid.all()


@pytest.mark.parametrize("method", METHODS)
def test_no_data_border(method):
    c = np.arange(320)
    rows = 70 + 10 * np.sin(c / 25.0)
    img, truth = synth(rows, height=200, seed=4)
    # mosaic-like black border: tiles whose top edges step, plus 20 empty columns on the left
    top = np.where(c < 110, 30, np.where(c < 220, 12, 40))
    img[np.arange(200)[:, None] < top[None, :]] = 0
    img[:, :20] = 0
    img[170:, 150:] = 0
    sk = detect_skyline(img, method=method)
    assert not sk.valid[:20].any() and sk.valid[20:].all()
    assert np.isnan(sk.rows[:20]).all()
    s = _score(sk, truth, valid=sk.valid)
    # the columns within the trusted margin (3 px) of the empty ones hold no trusted pixel: at
    # most 4 of the 300 valid columns missed (measured 4 with dp at a 3 px margin, 0 false)
    assert s["false_rate"] == 0 and s["missed_rate"] <= 4 / 300
    assert s["within_3px"] >= 0.95
    # never on the border itself
    near = np.abs(sk.rows[20:] - top[20:]) <= 2
    assert not near.any()


@pytest.mark.parametrize("method", METHODS)
def test_no_sky_with_border(method):
    img, _ = synth(np.full(300, -1.0), seed=5)
    c = np.arange(300)
    top = np.where(c < 150, 25, 5)
    img[np.arange(160)[:, None] < top[None, :]] = 0
    sk = detect_skyline(img, method=method)
    assert np.isnan(sk.rows).all()


@pytest.mark.parametrize("method", METHODS)
def test_noise_and_grey(method):
    c = np.arange(260, dtype=float)
    rows = 60 + 20 * np.abs(np.sin(c / 40.0))
    img, truth = synth(rows, noise=6.0, rgb=False, seed=6)
    sk = detect_skyline(img, method=method)
    s = _score(sk, truth)
    assert s["false_rate"] == 0 and s["missed_rate"] <= 0.02
    assert s["within_3px"] >= 0.9


def test_noisy_sky_over_smooth_ground():
    """A noisy camera over ground barely rougher than the noise (as in many simulated frames):
    relative to the image's median texture the sky looks rough; only a noise-aware threshold
    calls it sky. Without the noise floor (noise_ratio=0) the skyline lands ~95 px inside the
    terrain."""
    from scipy import ndimage

    rng = np.random.default_rng(3)
    H, W, noise = 480, 800, 3.0
    c = np.arange(W)
    sky_rows = 150 + 30 * np.sin(c / 90.0) + 10 * np.sin(c / 23.0)
    rows = np.arange(H)[:, None]
    sky = 190 - 0.08 * rows + rng.normal(0, noise, (H, W))
    blobs = ndimage.gaussian_filter(rng.normal(0, 1, (H, W)), 2.0)
    ter = 105 + 0.05 * rows + 8 * blobs / blobs.std() + rng.normal(0, noise, (H, W))
    g = np.clip(np.where(rows >= sky_rows[None, :], ter, sky), 1, 255)
    img = np.stack([g, g * 0.9, g * 0.8], -1).astype(np.uint8)
    s = _score(detect_skyline(img), np.ceil(sky_rows))
    assert s["missed_rate"] <= 0.02 and s["false_rate"] == 0
    assert s["within_3px"] >= 0.95


def test_mask_excludes_region():
    img, truth = synth(np.full(240, 60.0), seed=7)
    mask = np.ones(img.shape[:2], bool)
    mask[:, 100:140] = False
    sk = detect_skyline(img, mask=mask)
    assert np.isnan(sk.rows[100:140]).all() and not sk.valid[100:140].any()
    keep = np.r_[0:100, 140:240]
    err = np.abs(sk.rows[keep] - truth[keep])
    # a few columns (the mask's edges, faint patches) are reported as unknown, none as wrong
    known = np.isfinite(err)
    assert known.mean() >= 0.93 and np.nanmax(err) <= 5 and np.mean(err[known] <= 3) >= 0.95


def test_short_isolated_runs_are_dropped():
    from skyfix.detect.runs import drop_short_runs as _drop_short_runs

    rows = np.full(30, np.nan)
    rows[2:5] = 10.0     # 3 columns: dropped
    rows[10:22] = 20.0   # 12 columns: kept
    rows[27:30] = 5.0    # 3 columns at the edge: dropped
    conf = np.where(np.isfinite(rows), 0.8, 0.0)
    _drop_short_runs(rows, conf, 8)
    assert np.flatnonzero(np.isfinite(rows)).tolist() == list(range(10, 22))
    assert np.all(conf[np.isnan(rows)] == 0) and np.all(conf[10:22] == 0.8)


def test_weak_runs_survive_only_as_a_skylines_continuation():
    from skyfix.detect.runs import drop_unanchored_runs as _drop_unanchored_runs

    rows = np.full(2000, np.nan)
    conf = np.zeros(2000)
    spans = {(0, 200): 0.8,      # confident: an anchor
             (230, 260): 0.2,    # weak, 30 columns from the anchor: kept
             (900, 930): 0.25,   # weak, alone (640 and 370 columns from the others): dropped
             (1300, 1600): 0.2}  # weak but 15 % of the width: an anchor by itself
    for (a, b), c in spans.items():
        rows[a:b] = 40.0
        conf[a:b] = c
    _drop_unanchored_runs(rows, conf, 0.5, 300, 200)
    kept = np.flatnonzero(np.isfinite(rows))
    assert kept.tolist() == [*range(0, 200), *range(230, 260), *range(1300, 1600)]
    assert np.all(conf[900:930] == 0) and np.all(conf[230:260] == 0.2)
    empty = np.full(10, np.nan)
    _drop_unanchored_runs(empty, np.zeros(10), 0.5, 3, 2)  # no run at all: nothing to do
    assert np.isnan(empty).all()


@pytest.mark.shared_data
def test_no_slivers_along_a_hazy_mountains_foot():
    # 432_2: Mount Sharp's hazy flank fills the top of the mosaic; the skyline is out of frame
    # in most columns. Without the run hysteresis, 14 columns (276 with a model that did not
    # see this image) of short weak runs along the flank's foot came out as skyline
    img, truth = _dev_case("432_2")
    s = score_skyline(detect_skyline(img), truth)
    assert s["n_false"] == 0
    assert score_skyline(detect_skyline(img, anchor_conf=0), truth)["n_false"] > 0


def test_bad_input():
    with pytest.raises(ParameterError, match="method"):
        detect_skyline(np.zeros((50, 50), np.uint8) + 9, method="nope")
    with pytest.raises(ParameterError, match="shape"):
        detect_skyline(np.zeros((50, 50, 2), np.uint8))
    with pytest.raises(ParameterError, match="mask"):
        detect_skyline(np.ones((50, 50), np.uint8), mask=np.ones((10, 10), bool))
    with pytest.raises(ParameterError, match="option"):
        detect_skyline(np.ones((50, 50), np.uint8), bogus=1)


@pytest.mark.parametrize("method, option, value, says", [
    ("dp", "anchor_gap", -0.1, ">= 0"),          # would link nothing, silently
    ("dp", "w_grad", float("nan"), "finite"),
    ("dp", "min_confidence", 1.5, r"\[0, 1\]"),  # would drop every column, silently
    ("dp", "work_pixels", 0, ">= 1"),
    ("dp", "min_run", 2.5, "whole number"),
    ("dp", "no_data_black", "yes", "True or False"),
    ("bayes", "window", 0, ">= 1"),
    ("bayes", "seed", -3, ">= 0"),
    ("bayes", "jump_cost", -1.0, ">= 0"),
])
def test_options_out_of_range_are_refused_by_name(method, option, value, says):
    with pytest.raises(ParameterError, match=f"{option}=.*{says}"):
        detect_skyline(np.ones((50, 50), np.uint8), method=method, **{option: value})


def test_score_skyline_known_values():
    truth = Skyline(rows=np.array([10.0, 10.0, np.nan, np.nan, 20.0, 5.0]), width=6, height=30,
                    valid=np.array([True, True, True, True, True, False]))
    pred = Skyline(rows=np.array([11.0, 22.0, 3.0, np.nan, np.nan, 5.0]), width=6, height=30)
    s = score_skyline(pred, truth)
    assert s["n_valid"] == 5 and s["n_both"] == 2
    assert s["mean_abs_err_px"] == pytest.approx(6.5)
    assert s["within_3px"] == pytest.approx(0.5) and s["within_10px"] == pytest.approx(0.5)
    assert s["false_rate"] == pytest.approx(1 / 5) and s["missed_rate"] == pytest.approx(1 / 5)
    tot = combine_scores([s, s])
    assert tot["mean_abs_err_px"] == pytest.approx(6.5) and tot["n_valid"] == 10


def test_cli_writes_json_and_plot(tmp_path):
    import cv2

    img, truth = synth(np.full(200, 50.0), seed=8)
    p = tmp_path / "im.png"
    cv2.imwrite(str(p), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    out, plot = tmp_path / "sky.json", tmp_path / "sky.png"
    r = CliRunner().invoke(cli, ["detect", str(p), "-o", str(out), "--plot", str(plot)])
    assert r.exit_code == 0, r.output
    sk = read_skyline_json(out)
    assert sk.width == 200 and sk.height == 160 and sk.image == "im.png"
    err = np.abs(sk.rows - truth)
    known = np.isfinite(err)
    assert known.mean() >= 0.93 and np.median(err[known]) <= 1.0 and np.mean(err[known] <= 3) >= 0.95
    assert plot.stat().st_size > 1000
    r = CliRunner().invoke(cli, ["detect", str(p), "-o", str(out)])
    assert r.exit_code == 2 and "--overwrite" in r.output
    r = CliRunner().invoke(cli, ["detect", str(p), "-o", str(out), "--overwrite", "--method", "bayes"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(cli, ["detect", str(tmp_path / "missing.png")])
    assert r.exit_code == 2 and "does not exist" in r.output
    mask = tmp_path / "mask.png"
    cv2.imwrite(str(mask), np.full((10, 10), 255, np.uint8))
    r = CliRunner().invoke(cli, ["detect", str(p), "--mask", str(mask)])
    assert r.exit_code == 2 and "mask" in r.output


def _with_exif_orientation(jpeg: bytes, orientation: int) -> bytes:
    """A JPEG with an EXIF APP1 segment holding only the orientation tag (0x0112), as a camera
    held on its side writes it (TIFF little-endian, one IFD entry)."""
    import struct

    tiff = (b"II*\x00" + struct.pack("<IH", 8, 1) + struct.pack("<HHIHH", 0x0112, 3, 1, orientation, 0)
            + struct.pack("<I", 0))
    payload = b"Exif\x00\x00" + tiff
    return jpeg[:2] + b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload + jpeg[2:]


@pytest.mark.parametrize("orientation, turn", [(6, 1), (8, -1), (3, 2)])
def test_a_photo_stored_on_its_side_is_read_upright(tmp_path, orientation, turn):
    """Pixels stored turned, with the EXIF tag that turns them back (every viewer does): detect
    and acquisition-init read the image upright. Read as stored, the sky lay at the side: no
    skyline in any column."""
    import cv2

    from skyfix.formats import load_acquisition

    img, truth = synth(np.full(200, 50.0), seed=8)
    stored = np.ascontiguousarray(np.rot90(cv2.cvtColor(img, cv2.COLOR_RGB2BGR), turn))
    ok, buf = cv2.imencode(".jpg", stored, [cv2.IMWRITE_JPEG_QUALITY, 95])
    p = tmp_path / "f0.jpg"
    p.write_bytes(_with_exif_orientation(buf.tobytes(), orientation))
    r = CliRunner().invoke(cli, ["detect", str(p), "-o", str(tmp_path / "sky.json")])
    assert r.exit_code == 0, r.output
    sk = read_skyline_json(tmp_path / "sky.json")
    assert (sk.width, sk.height) == (200, 160)
    err = np.abs(sk.rows - truth)
    known = np.isfinite(err)
    assert known.mean() >= 0.9 and np.median(err[known]) <= 1.0
    r = CliRunner().invoke(cli, ["acquisition-init", str(tmp_path), "--images", "*.jpg",
                                 "--hfov-deg", 60, "--pan-step-deg", 30, "--tilt-deg", 0,
                                 "--camera-height-m", 1.5])
    assert r.exit_code == 0, r.output
    cam = load_acquisition(tmp_path).camera
    assert (cam.width, cam.height) == (200, 160)


def _dev_case(name):
    import cv2

    if not DEV.is_dir():
        pytest.skip(f"real dev set not found at {DEV} (../shared/data/marsscapes-dev)")
    img = cv2.cvtColor(cv2.imread(str(DEV / f"{name}.png")), cv2.COLOR_BGR2RGB)
    return img, read_skyline_json(DEV / f"{name}.skyline.json")


@pytest.mark.shared_data
@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("name", ["412_1", "437_1"])
def test_real_mosaic_with_sky(name, method):
    img, truth = _dev_case(name)
    s = score_skyline(detect_skyline(img, method=method), truth)
    # measured: 0.33-0.61 px mean error, 95.6-100 % within 3 px, no false column, either method
    # (the shipped sky model saw these images in training: the held-out figures are
    # bench_detect.py --cv's); bayes was 8-10 px off before its boundary term and row-wise edge
    # density. The false-skyline bound is the project's requirement on the dev set
    assert s["mean_abs_err_px"] <= 1.0
    assert s["within_3px"] >= 0.93
    # bayes leaves more columns unknown where the edge is faint (412_1: 6.2 % missed)
    assert s["false_rate"] <= 0.02 and s["missed_rate"] <= (0.05 if method == "dp" else 0.1)


@pytest.mark.shared_data
@pytest.mark.parametrize("method", METHODS)
def test_real_mosaic_without_sky(method):
    # 385_1 looks down at the ground: no column has a skyline (measured: none found, either method)
    img, truth = _dev_case("385_1")
    assert not np.isfinite(truth.rows).any()
    s = score_skyline(detect_skyline(img, method=method), truth)
    assert s["false_rate"] <= 0.02


# --- the learned sky classifier (region term of dp) ----------------------------------------------

def test_shipped_model_loads_and_is_small():
    from skyfix.detect.skymodel import DEFAULT_GREY_MODEL, DEFAULT_MODEL, FEATURE_NAMES, load_sky_model

    for m, path in ((load_sky_model(), DEFAULT_MODEL), (load_sky_model(grey=True), DEFAULT_GREY_MODEL)):
        assert m.feature_names == FEATURE_NAMES and m.roots.size > 0
        assert path.stat().st_size < 2 * 1024 * 1024
        # every node index points inside the table, and trees end in leaves
        assert m.left.max() < m.feat.size and m.right.max() < m.feat.size and m.leaf.any()


def test_tree_export_matches_sklearn():
    # the numba evaluator against scikit-learn's own prediction on the same fitted model
    from sklearn.ensemble import HistGradientBoostingClassifier

    from skyfix.detect.skymodel import N_FEATURES, from_sklearn

    rng = np.random.default_rng(0)
    X = rng.normal(size=(3000, N_FEATURES)).astype(np.float32)
    y = (X[:, 0] + X[:, 3] * X[:, 5] + 0.3 * rng.normal(size=3000)) > 0
    clf = HistGradientBoostingClassifier(max_iter=30, max_depth=4, random_state=0).fit(X, y)
    m = from_sklearn(clf)
    Xt = rng.normal(size=(500, N_FEATURES)).astype(np.float32)
    np.testing.assert_allclose(m.log_odds_sky(Xt), clf.decision_function(Xt), atol=1e-9)


def _model_llr(img):
    from skyfix.detect.image import fill_invalid, to_float_gray, trusted, valid_mask
    from skyfix.detect.skymodel import load_sky_model, sky_log_odds

    valid = trusted(valid_mask(img, None, True))
    gray = fill_invalid(to_float_gray(img), valid)
    lo, v, fm = sky_log_odds(img, valid, gray, load_sky_model(), 250_000)
    assert fm == 1
    return lo


def test_shipped_model_separates_synthetic_sky_from_terrain():
    # trained on Mars mosaics only; a smooth bright sky over gravel is the case it must get right
    c = np.arange(300, dtype=float)
    rows = 70 + 15 * np.sin(c / 30.0)
    img, truth = synth(rows, height=200, seed=11)
    lo = _model_llr(img)
    r = np.arange(200)[:, None]
    sky = r < rows[None, :] - 3
    ter = r > rows[None, :] + 3
    acc = 0.5 * ((lo[sky] > 0).mean() + (lo[ter] < 0).mean())
    assert acc >= 0.9


def test_skyline_under_a_cloud():
    """A bright, softly textured cloud fills the sky down to 8 px above the skyline in half the
    columns. Its texture looks like terrain; the classifier calls it sky. Measured, seeds 0-3:
    0.68-0.93 of the cloud's columns within 3 px; without the cloud rule 0 (the skyline there
    is called missing or put on the cloud's lower edge)."""
    from scipy import ndimage

    W, H = 320, 200
    c = np.arange(W)
    rows = 120 + 10 * np.sin(c / 40.0)
    img, truth = synth(rows, height=H, seed=40)
    rng = np.random.default_rng(0)
    r = np.arange(H)[:, None]
    inside = (c[None] > 80) & (c[None] < 240) & (r > 30) & (r < rows[None] - 8)
    blob = ndimage.gaussian_filter(rng.normal(0, 1, (H, W)), 3.0)
    cloud = np.clip(235 + 15 * blob / blob.std(), 0, 255)
    alpha = ndimage.gaussian_filter(inside.astype(float), 6.0)[..., None]  # a soft outline
    img = np.clip(alpha * cloud[..., None] + (1 - alpha) * img, 1, 255).astype(np.uint8)
    under = (c > 80) & (c < 240)
    err = np.abs(detect_skyline(img).rows - truth)[under]
    assert np.mean(err <= 3) >= 0.8
    err = np.abs(detect_skyline(img, cloud_llr=0.0).rows - truth)[under]
    assert np.mean(err <= 3) <= 0.1


def test_cloud_rule_needs_a_representative_clear_sky():
    """The cloud rule compares a pixel with the smooth ("unmistakable") sky. When that is a small
    remnant of what the classifier calls sky, it stands down: the remnant is the dark corner of a
    wide field's sky, and sunlit ground is brighter than it in every channel."""
    from skyfix.detect.dp import _cloud_like

    h, w = 60, 80
    valid = np.ones((h, w), bool)
    lo = np.full((h, w), 3.0)                    # the classifier: all sky
    rgb = np.full((h, w, 3), 120.0, np.float32)  # clear sky level
    tex = np.full((h, w), -0.5)                  # smooth
    tex[:, 40:] = 0.5                            # textured right half ...
    rgb[:, 40:] = 200.0                          # ... brighter in every channel: cloud-like
    got = _cloud_like(tex, lo, rgb, valid, 1.0, min_share=0.4)
    assert got[:, 40:].all() and not got[:, :40].any()   # smooth sky is half of the sky
    tex[:, 20:] = 0.5                                     # now the smooth sky is a quarter
    rgb[:, 20:40] = 125.0                                 # (textured sky just above its level)
    assert not _cloud_like(tex, lo, rgb, valid, 1.0, min_share=0.4).any()
    assert _cloud_like(tex, lo, rgb, valid, 1.0, min_share=0.0)[:, 20:].all()


def test_wide_camera_clear_sky_is_not_taken_for_cloud(tmp_path):
    """A simulated wide-camera (90 deg) Earth frame under a clear sky: the steep zenith-to-
    horizon gradient makes the texture term call most of the sky textured, and without the
    sky-share gate the cloud rule took the sunlit ground under the horizon for cloud. Measured:
    0.17 px, 100 % within 3 px with the gate; 16 px, 70 % without it."""
    from skyfix.dem import fractal_dem
    from skyfix.formats import Truth
    from skyfix.profile import read_rgb
    from skyfix.simulate import simulate_acquisition

    dem = fractal_dem(400, 30.0, seed=2)
    out = simulate_acquisition(dem, Truth(506640.8, 4192912.7, 14.75), tmp_path / "a",
                               camera="wide", frames=1, seed=0)
    png = sorted(out.glob("frame_*.png"))[0]
    truth = read_skyline_json(png.with_name(png.stem + ".skyline.json"))
    img = read_rgb(png)
    assert score_skyline(detect_skyline(img), truth)["within_3px"] >= 0.95
    assert score_skyline(detect_skyline(img, cloud_sure_share=0.0), truth)["within_3px"] < 0.9


def test_wide_camera_sky_survives_jpeg(tmp_path):
    """The same kind of wide-camera frame, JPEG-compressed (quality 70): the compression wipes
    out the sensor noise whose floor had kept the sky's steep gradient from reading as texture.
    The sky's threshold from the classifier's sure sky (``sure_sky_q``) finds the whole skyline
    again. Measured: 100 % within 3 px, none missed; without it, none found."""
    import cv2

    from skyfix.dem import fractal_dem
    from skyfix.formats import Truth
    from skyfix.profile import read_rgb
    from skyfix.simulate import simulate_acquisition

    out = simulate_acquisition(fractal_dem(400, 30.0, seed=2), Truth(506640.8, 4192912.7, 14.75),
                               tmp_path / "a", camera="wide", frames=1, seed=0)
    png = sorted(out.glob("frame_*.png"))[0]
    truth = read_skyline_json(png.with_name(png.stem + ".skyline.json"))
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(read_rgb(png), cv2.COLOR_RGB2BGR),
                           [cv2.IMWRITE_JPEG_QUALITY, 70])
    img = cv2.cvtColor(cv2.imdecode(buf, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    s = score_skyline(detect_skyline(img), truth)
    assert s["within_3px"] >= 0.95 and s["missed_rate"] <= 0.02 and s["false_rate"] == 0
    assert score_skyline(detect_skyline(img, sure_sky_q=0), truth)["missed_rate"] > 0.5


def test_grey_wide_camera_frame_uses_the_grey_sky_model(tmp_path):
    """The wide-camera frame in grey (a camera without colour): the texture term alone reads the
    sky's gradient as texture and misses the skyline; the classifier trained on grey copies
    finds it, whether the grey image comes as H x W or as RGB with R = G = B. Measured: 100 %
    within 3 px, none missed; texture alone: all missed."""
    import cv2

    from skyfix.dem import fractal_dem
    from skyfix.formats import Truth
    from skyfix.profile import read_rgb
    from skyfix.simulate import simulate_acquisition

    out = simulate_acquisition(fractal_dem(400, 30.0, seed=2), Truth(506640.8, 4192912.7, 14.75),
                               tmp_path / "a", camera="wide", frames=1, seed=0)
    png = sorted(out.glob("frame_*.png"))[0]
    truth = read_skyline_json(png.with_name(png.stem + ".skyline.json"))
    grey = cv2.cvtColor(read_rgb(png), cv2.COLOR_RGB2GRAY)
    sk = detect_skyline(grey)
    s = score_skyline(sk, truth)
    assert s["within_3px"] >= 0.95 and s["missed_rate"] <= 0.05 and s["false_rate"] == 0
    as_rgb = detect_skyline(np.dstack([grey, grey, grey]))
    np.testing.assert_array_equal(as_rgb.rows, sk.rows)
    assert score_skyline(detect_skyline(grey, region="texture"), truth)["missed_rate"] > 0.5


def test_bayes_on_a_wide_camera_needs_the_sure_sky_threshold(tmp_path):
    """bayes's prior reads a wide (90 deg) sky's steep gradient as texture and calls no column a
    skyline; with the sure sky's texture as its threshold (opt-in) it finds the skyline."""
    from skyfix.dem import fractal_dem
    from skyfix.formats import Truth
    from skyfix.profile import read_rgb
    from skyfix.simulate import simulate_acquisition

    out = simulate_acquisition(fractal_dem(400, 30.0, seed=2), Truth(506640.8, 4192912.7, 14.75),
                               tmp_path / "a", camera="wide", frames=1, seed=0)
    png = sorted(out.glob("frame_*.png"))[0]
    truth = read_skyline_json(png.with_name(png.stem + ".skyline.json"))
    img = read_rgb(png)
    s = score_skyline(detect_skyline(img, method="bayes", sure_sky_q=90), truth)
    assert s["within_3px"] >= 0.95 and s["missed_rate"] <= 0.05 and s["false_rate"] == 0
    assert score_skyline(detect_skyline(img, method="bayes"), truth)["missed_rate"] > 0.5


def test_training_recipe_learns_synthetic_sky(tmp_path):
    # train on synthetic images only, then classify a held-out one (no dev data needed)
    from skyfix.detect.skymodel import fit_sky_model, load_sky_model, training_pixels

    parts = []
    for seed in range(3):
        rows = 60 + 20 * np.sin(np.arange(200) / (20.0 + seed))
        img, _ = synth(rows, seed=20 + seed)
        sky = np.arange(160)[:, None] < rows[None, :]
        parts.append(training_pixels(img, sky))
    model, _ = fit_sky_model(parts, per_image=5000, max_iter=20)
    # saved and read back as scripts/train_sky_model.py and the detector do (the save had
    # imported skyfix.detect._io, which does not exist: no model could be written)
    model.save(tmp_path / "sky.npz")
    model = load_sky_model(tmp_path / "sky.npz")
    rows = 90 - 0.2 * np.arange(260)
    img, _ = synth(rows, seed=30)
    from skyfix.detect.image import fill_invalid, to_float_gray, trusted, valid_mask
    from skyfix.detect.skymodel import sky_log_odds

    valid = trusted(valid_mask(img, None, True))
    gray = fill_invalid(to_float_gray(img), valid)
    lo, _, _ = sky_log_odds(img, valid, gray, model, 250_000)
    r = np.arange(160)[:, None]
    assert (lo[r < rows[None, :] - 3] > 0).mean() >= 0.95
    assert (lo[r > rows[None, :] + 3] < 0).mean() >= 0.95
    # and the detector follows it
    sk = detect_skyline(img, model=model)
    first = np.ceil(rows)
    assert np.mean(np.abs(sk.rows - first) <= 3) >= 0.85  # measured 0.89: the flat end wanders


def test_texture_region_term_still_available():
    c = np.arange(240)
    img, truth = synth(np.where(c < 120, 50.0, 90.0))
    s = _score(detect_skyline(img, region="texture"), truth)
    assert s["false_rate"] == 0 and s["within_3px"] >= 0.95
    with pytest.raises(ParameterError, match="region"):
        detect_skyline(img, region="magic")


def test_bayes_model_init_runs_and_checks_its_option():
    img, truth = synth(np.full(200, 50.0), seed=12)
    sk = detect_skyline(img, method="bayes", init="model")
    s = _score(sk, truth)  # a flat skyline: found, in the right place, in (nearly) every column
    assert s["within_3px"] >= 0.9 and s["false_rate"] == 0 and s["missed_rate"] <= 0.02
    with pytest.raises(ParameterError, match="init"):
        detect_skyline(img, method="bayes", init="guess")


def test_subpixel_row_is_the_edge_position():
    """An antialiased edge at known fractional rows (each pixel the area-weighted mix of sky
    and ground, pixel centres at integer rows): the detected row is the edge itself, within a
    tenth of a pixel -- not the step peak half a pixel below it."""
    rng = np.random.default_rng(5)
    H, W = 200, 400
    c = np.arange(W)
    edge = 80.3 + 12 * np.sin(c / 45.0)
    v = np.arange(H)[:, None]
    ground_frac = np.clip(v + 0.5 - edge[None, :], 0.0, 1.0)  # pixel v spans [v - 0.5, v + 0.5]
    ground = 90 + 30 * np.sin(v / 3.0 + c[None, :] / 5.0)  # textured, so the sky is the smooth side
    g = 200 * (1 - ground_frac) + ground * ground_frac + rng.normal(0, 0.5, (H, W))
    img = np.stack([g, g * 0.9, g * 0.8], -1).clip(1, 255).astype(np.uint8)
    sk = detect_skyline(img)
    err = sk.rows - edge
    assert np.isfinite(err).mean() > 0.98
    assert abs(np.nanmedian(err)) < 0.1 and np.nanmedian(np.abs(err)) < 0.15


@pytest.mark.parametrize("method", ["dp", "fuse", "net", "bayes"])
def test_non_finite_pixels_of_a_float_image_are_no_data(method):
    """A float image marking no data with NaN (a mosaic's corner) or holding an infinite pixel
    block: those pixels are left out, the skyline elsewhere is found (one NaN used to make every
    column's cost NaN, and no skyline came back at all)."""
    rows = 60 + 8 * np.sin(np.arange(240) / 25.0)
    img, truth = colour_scene(rows, height=150, seed=6)
    f = img / 255.0
    f[:20, :30] = np.nan
    f[100:, 200:] = np.inf
    sk = detect_skyline(f, method=method)
    s = score_rows(sk, truth)
    assert s["missed_rate"] < 0.05 and s["within_3px"] > 0.9 and s["false_rate"] == 0, s


def test_a_12_bit_camera_in_a_16_bit_file_is_read_at_its_own_depth(tmp_path):
    """12-bit data (0-4095) in a 16-bit PNG was taken as 0-65535: a sixteenth as bright, the
    network's skyline in 212 of 1388 columns of a real photo (1388 at 8 bits), an acquisition's
    frames shifted to near black (>> 8). It reads as the 8-bit image it came from; and a 16-bit
    mask of 0 and 1 holds data where it is 1 (it was refused as all zero)."""
    import cv2

    c = np.arange(240)
    img, truth = synth(100 + 20 * np.sin(c / 25.0))
    twelve = (img.astype(np.uint16) * 16)  # the same picture on 12 bits
    from skyfix.formats.images import to_8bit

    assert np.abs(to_8bit(twelve).astype(int) - img).max() <= 1
    full = img.astype(np.uint16) * 257  # a full-range 16-bit copy reads as before
    assert np.abs(to_8bit(full).astype(int) - img).max() <= 1
    dark = np.ones_like(twelve)
    dark[0, 0] = 4095
    assert to_8bit(dark)[1:].min() == 1  # a dark pixel is not made black (no data)
    for method in METHODS:
        a = score_rows(detect_skyline(img, method=method), truth)
        b = score_rows(detect_skyline(twelve, method=method), truth)
        assert a["within_3px"] > 0.8 and b["within_3px"] == pytest.approx(a["within_3px"], abs=0.02)
    # through the CLI: the file and a 16-bit mask of 0 and 1 (the right half)
    cv2.imwrite(str(tmp_path / "im.png"), cv2.cvtColor(twelve, cv2.COLOR_RGB2BGR))
    mask = np.zeros(img.shape[:2], np.uint16)
    mask[:, 120:] = 1
    cv2.imwrite(str(tmp_path / "mask.png"), mask)
    r = CliRunner().invoke(cli, ["detect", str(tmp_path / "im.png"), "--mask",
                                 str(tmp_path / "mask.png"), "-o", str(tmp_path / "sk.json")])
    assert r.exit_code == 0, r.output
    sk = read_skyline_json(tmp_path / "sk.json")
    got = np.asarray(sk.rows, float)
    assert np.isnan(got[:120]).all() and np.isfinite(got[125:]).mean() > 0.95
    assert np.nanmean(np.abs(got[125:] - truth[125:])) < 1.0


def test_filling_holes_around_their_columns_equals_the_whole_image_transform():
    """fill_invalid runs the nearest-valid transform only around the columns still holding a
    hole (the whole image's was five arrays of its size: a 3.9-MP mosaic peaked at 384 MB); the
    answer is the whole-image transform's, on random interior holes and bands of empty columns
    (every column with data holds its top and bottom rows, so the mirroring above and below a
    column's data, the first step, leaves them all)."""
    from skyfix.detect.image import fill_invalid
    from skyfix.nearest import nearest_valid

    rng = np.random.default_rng(0)
    for _ in range(100):
        h, w = rng.integers(5, 60, 2)
        arr = rng.normal(size=(h, w)).astype(np.float32)
        valid = rng.random((h, w)) > rng.uniform(0.0, 0.6)
        valid[0], valid[-1] = True, True
        for _ in range(rng.integers(1, 3)):
            c = rng.integers(0, w - 1)
            valid[:, c:c + rng.integers(1, 12)] = False
        valid[:, -1] = True  # some data (an image of no-data alone is returned as it is)
        _, rr, cc = nearest_valid(valid, 1.0, 64.0)
        assert np.array_equal(fill_invalid(arr, valid), arr[rr, cc])
        rgb = np.stack([arr, -arr, 2 * arr], axis=2)  # colour: no mirroring, the transform alone
        _, rr, cc = nearest_valid(valid, 1.0, 64.0)
        assert np.array_equal(fill_invalid(rgb, valid), rgb[rr, cc])


def test_a_cliff_in_the_skyline_is_followed_at_full_resolution():
    """A skyline flat at row 250.5, then at 210.5 from column 200 on: the full-resolution band
    allowed no move within a column and only a few rows between columns, so a 40-row step left
    no allowed path and the right half was lost (0 of 200 columns)."""
    h = w = 400
    rng = np.random.default_rng(0)
    edge = np.where(np.arange(w) < 200, 250.5, 210.5)
    frac = np.clip(np.arange(h)[:, None] + 0.5 - edge, 0, 1)[..., None]  # each pixel's terrain
    ground = np.array([120, 90, 60.0]) + 20 * rng.standard_normal((h, w, 1))
    sky = np.array([240, 225, 205.0]) + 1.5 * rng.standard_normal((h, w, 1))
    img = np.clip(sky * (1 - frac) + ground * frac, 1, 255).round().astype(np.uint8)
    rows = np.asarray(detect_skyline(img, method="dp").rows, float)
    want = edge
    found = np.isfinite(rows)
    assert found[:200].sum() >= 190 and found[200:].sum() >= 190
    off = np.flatnonzero(found & (np.abs(rows - want) > 3.0))
    # the step itself lies between two columns: the one holding the path's climb may read
    # either row
    assert set(off) <= {199, 200}, off


@pytest.mark.parametrize("dtype", [np.int16, np.int32, np.uint32])
def test_images_of_other_integer_types_are_read_at_their_depth(dtype):
    """A grey 0-10000 image as int16 was clipped to 255 (all sky: skyline in 0 of 80 columns);
    read at its effective depth like a 16-bit one it gives the 8-bit image's skyline. Negative
    values are refused."""
    from skyfix.errors import ParameterError
    from skyfix.formats.images import to_8bit

    rng = np.random.default_rng(0)
    yy = np.arange(120)[:, None] * np.ones((1, 160))
    grey8 = np.clip(np.where(yy < 60, 220 + 1.5 * rng.standard_normal(yy.shape),
                             90 + 20 * rng.standard_normal(yy.shape)), 1, 255).astype(np.uint8)
    big = (grey8.astype(np.int64) * 10000 // 255).astype(dtype)
    want = np.asarray(detect_skyline(grey8, method="dp").rows, float)
    got = np.asarray(detect_skyline(big, method="dp").rows, float)
    assert np.isfinite(want).sum() >= 150
    np.testing.assert_allclose(got, want, atol=0.05)
    if np.dtype(dtype).kind == "i":
        with pytest.raises(ParameterError, match="negative values"):
            to_8bit(big - 1000)


@pytest.mark.parametrize("edge", [150.5, 195.5, 196.5])
def test_an_edge_near_the_bottom_is_reported_where_the_conventions_put_it(edge):
    """A crisp edge between rows k - 1 and k is reported at k - 0.5 (conventions.md). Within 5
    rows of the image's bottom the half-level crossing is skipped and the step's peak was kept,
    half a row low (196.5 read 197.0)."""
    h, w = 200, 300
    rng = np.random.default_rng(0)
    frac = np.clip(np.arange(h)[:, None] + 0.5 - edge, 0, 1)[..., None] * np.ones((1, w, 1))
    ground = np.array([120, 90, 60.0]) + 20 * rng.standard_normal((h, w, 1))
    sky = np.array([240, 225, 205.0]) + 1.5 * rng.standard_normal((h, w, 1))
    img = np.clip(sky * (1 - frac) + ground * frac, 1, 255).round().astype(np.uint8)
    rows = np.asarray(detect_skyline(img, method="dp").rows, float)
    assert np.isfinite(rows).sum() >= 290
    assert abs(np.nanmedian(rows) - edge) < 0.1


def test_bayes_is_sure_of_a_column_that_is_all_sky():
    """Its no-skyline confidence was 1 - the largest sky probability: near 0 for a column surely
    all sky (0.12 over a clear sky image), though sure."""
    rng = np.random.default_rng(1)
    sky = np.clip(np.array([200, 170, 140.0]) + 1.5 * rng.standard_normal((200, 400, 1)), 1,
                  255).astype(np.uint8)
    s = detect_skyline(sky, method="bayes")
    assert not np.isfinite(np.asarray(s.rows, float)).any()
    assert s.confidence.mean() > 0.5


def test_a_skyline_across_an_image_narrower_than_the_shortest_run_is_kept():
    """Runs shorter than 4 columns are dropped as specks; an image 3 px wide lost its whole
    skyline so (dp found it at 30.53 with min_run 1)."""
    from skyfix.detect.runs import drop_short_runs

    rows, conf = np.array([30.5, 30.6, 30.4]), np.ones(3)
    drop_short_runs(rows, conf, 4)
    assert np.isfinite(rows).all()
    rows = np.array([np.nan, 30.5, 30.6, 30.4, np.nan, 12.0])
    drop_short_runs(rows, np.ones(6), 4)
    assert not np.isfinite(rows).any()  # within a wider image, a 3-column run is still a speck
