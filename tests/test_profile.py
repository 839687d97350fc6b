"""Stage 6: acquisition -> body-frame profile.

Known answers: closed-form pinhole geometry; the horizon renderer's profile at the true pose, seen
through the *forward* camera model (``horizon_rows`` projects world directions to pixels with
distortion, the profile code inverts pixels to rays by undistortion: two independent paths).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import gaussian_hills
from skyfix.camera import Camera, Distortion, camera_from_fov, get_camera, r_world_cam
from skyfix.cli.main import cli
from skyfix.dem import Dem
from skyfix.errors import DetectionError
from skyfix.formats import Acquisition, Frame, PanoramaSpec, Skyline, save_acquisition
from skyfix.horizon import render_horizons
from skyfix.profile import (
    DEFAULT_AZIMUTH_BINS, PanRefinement, acquisition_profile, horizon_rows, panorama_profile,
    profile_bins, profile_from_skylines, sample_polyline, skyline_az_el,
)

FINE = 7200  # forward-model horizon sampling (0.05 deg)


@pytest.fixture(scope="module")
def scene():
    return make_scene()


def make_scene():
    """Gaussian hills (relief that keeps the skyline inside a 45-deg camera), the rover near the
    middle; world horizons at 360 bins (truth) and 7200 bins (to draw skylines)."""
    n, sp = 241, 10.0
    z, _, _ = gaussian_hills(n, sp, 25, np.random.default_rng(0))
    dem = Dem.from_array(z, sp)
    x, y = 1200.0, 1200.0
    fine = render_horizons(dem, [x], [y], azimuth_bins=FINE).elevation_deg[0].astype(float)
    truth = render_horizons(dem, [x], [y], azimuth_bins=360).elevation_deg[0].astype(float)
    return fine, truth


def body_truth(truth_world: np.ndarray, yaw: float) -> np.ndarray:
    """``body[az] = world[az + yaw]`` at the bin centres (circular linear interpolation)."""
    n = truth_world.size
    az = (np.arange(n) * 360.0 / n + yaw) % 360.0
    return np.interp(az, np.arange(n + 1) * 360.0 / n, np.r_[truth_world, truth_world[0]])


def make_acq(cam, pans, tilt=0.0, pitch=0.0, roll=0.0, root=Path(".")):
    frames = tuple(Frame(f"frame_{i:03d}.png", float(p), float(tilt)) for i, p in enumerate(pans))
    return Acquisition(root, cam, 1.5, frames, prior_pitch_deg=pitch, prior_roll_deg=roll)


def draw_skylines(cam, fine, yaw, pitch, roll, pans, tilt, pan_errors=None):
    err = np.zeros(len(pans)) if pan_errors is None else pan_errors
    az = np.arange(FINE) * 360.0 / FINE
    return [Skyline(horizon_rows(cam, az, fine, r_world_cam(yaw, pitch, roll, p + e, tilt)), cam.width, cam.height)
            for p, e in zip(pans, err)]


def errors(prof, truth_world, yaw):
    e = np.abs(prof.elevation_deg - body_truth(truth_world, yaw))
    e = e[np.isfinite(e)]
    return float(np.median(e)), float(np.percentile(e, 95)), e.size


# --- closed-form geometry --------------------------------------------------------------------------

def test_pixel_to_az_el_closed_form():
    cam = Camera(1000, 800, 500.0, 500.0, 499.5, 399.5)
    u = np.arange(1000.0)
    # the principal row at pan 30: elevation 0, azimuth 30 + atan((u - cx) / fx)
    az, el = skyline_az_el(cam, np.full(1000, 399.5), pan_deg=30.0)
    np.testing.assert_allclose(el, 0.0, atol=1e-9)
    np.testing.assert_allclose(az, (30.0 + np.degrees(np.arctan((u - 499.5) / 500.0))) % 360.0, atol=1e-9)
    # the centre column at row cy - fy tan(10 deg): elevation 10 deg; tilt adds; pitch (nose up) adds
    rows = np.full(1000, np.nan)
    rows[500] = 399.5 - 500.0 * np.tan(np.radians(10.0))
    cam2 = Camera(1001, 800, 500.0, 500.0, 500.0, 399.5)
    r2 = np.full(1001, np.nan)
    r2[500] = rows[500]
    for tilt, pitch, want in ((0.0, 0.0, 10.0), (5.0, 0.0, 15.0), (0.0, -4.0, 6.0)):
        az, el = skyline_az_el(cam2, r2, pan_deg=0.0, tilt_deg=tilt, pitch_deg=pitch)
        assert el[500] == pytest.approx(want, abs=1e-9)
        assert az[500] == pytest.approx(0.0, abs=1e-9)
        assert np.isnan(el[0])
    # roll right-side-down lowers what a camera panned to the right (pan 90) sees
    az, el = skyline_az_el(cam2, r2, pan_deg=90.0, roll_deg=3.0)
    assert el[500] == pytest.approx(7.0, abs=1e-9) and az[500] == pytest.approx(90.0, abs=1e-9)


def test_sample_polyline_linear_across_north():
    az = np.linspace(350.3, 370.7, 200) % 360.0
    el = 0.5 * np.linspace(350.3, 370.7, 200) - 170.0
    el[100] = np.nan  # a gap breaks the line: the bins in it stay empty
    v, _ = sample_polyline(az, el, 360)
    k = np.arange(360)
    unwrapped = np.where(k < 180, k + 360.0, k)
    covered = np.isfinite(v)
    expect = 0.5 * unwrapped - 170.0
    np.testing.assert_allclose(v[covered], expect[covered], atol=1e-9)
    assert set(np.flatnonzero(covered)) == set(range(351, 360)) | set(range(0, 11))


# --- against the renderer -------------------------------------------------------------------------

def test_profile_bins_are_the_databases_else_the_default():
    """The rule locate, traverse and evaluate each spelled out: a profile searched in a database
    is made in its bins (a store's attribute may be a NumPy integer), else in 360 of 1 deg."""
    class Store:
        azimuth_bins = np.int64(90)

    assert profile_bins(Store()) == 90 and type(profile_bins(Store())) is int
    assert profile_bins(None) == DEFAULT_AZIMUTH_BINS == 360
    import inspect

    default = inspect.signature(acquisition_profile).parameters["azimuth_bins"].default
    assert default == DEFAULT_AZIMUTH_BINS


def test_full_circle_matches_rendered_horizon(scene):
    fine, truth = scene
    cam = get_camera("navcam")
    pans = np.arange(10) * 36.0
    yaw, pitch, roll, tilt = 37.3, 3.0, -2.0, 4.0
    acq = make_acq(cam, pans, tilt, pitch, roll)
    prof = profile_from_skylines(acq, draw_skylines(cam, fine, yaw, pitch, roll, pans, tilt))
    med, p95, n = errors(prof, truth, yaw)
    assert n == 360
    assert med <= 0.01 and p95 <= 0.05  # projection alone: far inside the 0.1 / 0.5 deg budget
    assert prof.frame == "body" and prof.meta["frames_used"] == 10
    assert np.all(np.isfinite(prof.sigma_deg)) and np.all(prof.sigma_deg > 0)
    # overlaps are seen by two frames, the rest by one
    counts = np.array([len(c) for c in prof.meta["contributors"]])
    assert set(counts) == {1, 2}


def test_frames_whose_pans_contradict_each_other_are_flagged(scene, caplog):
    """A frame given the pan of its neighbour (30 deg wrong): the merge's median split the
    difference (bins off by up to 9 deg on a real acquisition) without a word. Agreeing frames
    are not flagged."""
    fine, truth = scene
    cam = get_camera("navcam")
    pans = np.arange(10) * 36.0
    yaw = 37.3
    sky = draw_skylines(cam, fine, yaw, 0.0, 0.0, pans, 0.0)
    good = profile_from_skylines(make_acq(cam, pans), sky)
    assert good.meta["frames_disagree"] == []
    wrong = pans.copy()
    wrong[1] = 20.0  # shown 36 deg, said 20: frames 0, 1 and 2 overlap where they should not
    with caplog.at_level("WARNING"):
        bad = profile_from_skylines(make_acq(cam, wrong), sky)
    pairs = {(d["i"], d["j"]) for d in bad.meta["frames_disagree"]}
    assert (0, 1) in pairs or (1, 2) in pairs
    assert all(1 in p for p in pairs)
    assert "disagree by" in caplog.text and "pan_deg" in caplog.text


def test_partial_coverage_with_distortion(scene):
    fine, truth = scene
    cam = camera_from_fov(640, 480, 90.0, Distortion(k1=-0.05, k2=0.01))
    pans = np.linspace(-76.0, 76.0, 5)  # 152 + 90 = 242 deg
    yaw = 123.0
    acq = make_acq(cam, pans)
    prof = profile_from_skylines(acq, draw_skylines(cam, fine, yaw, 0.0, 0.0, pans, 0.0))
    med, p95, n = errors(prof, truth, yaw)
    assert med <= 0.02 and p95 <= 0.1
    assert 240 <= prof.meta["coverage_deg"] <= 250  # 242 deg, a little more with barrel distortion
    assert np.isnan(prof.elevation_deg[180]) and np.isnan(prof.sigma_deg[180])  # behind the rover


def test_pan_errors_recovered(scene):
    fine, truth = scene
    cam = get_camera("navcam")
    pans = np.arange(10) * 36.0
    err = np.array([1, -1, 0.7, -0.4, 1, -1, -0.8, 0.5, 0.9, -0.9])  # zero mean: the gauge
    yaw, pitch, roll, tilt = 50.0, 2.0, 1.0, 3.0
    acq = make_acq(cam, pans, tilt, pitch, roll)
    sky = draw_skylines(cam, fine, yaw, pitch, roll, pans, tilt, err)
    prof = profile_from_skylines(acq, sky)
    corr = np.array([f["pan_correction_deg"] for f in prof.meta["frames"]])
    assert np.max(np.abs(corr - err)) <= 0.2
    med, p95, _ = errors(prof, truth, yaw)
    assert med <= 0.1 and p95 <= 0.5
    # without refinement the same data is visibly worse: the refinement is what fixes it
    raw = profile_from_skylines(acq, sky, refine=PanRefinement(enabled=False))
    assert errors(raw, truth, yaw)[1] > 2 * p95
    # random errors: relative pans recovered; the common offset is a yaw, fixed by the prior at
    # the mean of the nominal pans
    err2 = np.random.default_rng(3).uniform(-1, 1, 10)
    prof2 = profile_from_skylines(acq, draw_skylines(cam, fine, yaw, pitch, roll, pans, tilt, err2))
    corr2 = np.array([f["pan_correction_deg"] for f in prof2.meta["frames"]])
    res = corr2 - err2
    assert np.max(np.abs(res - res.mean())) <= 0.2
    assert res.mean() == pytest.approx(-err2.mean(), abs=0.05)


@settings(max_examples=12, deadline=None)
@given(yaw=st.floats(0.0, 360.0), pitch=st.floats(-8.0, 8.0), roll=st.floats(-8.0, 8.0))
def test_profile_rotates_with_the_rover(scene, yaw, pitch, roll):
    fine, truth = scene
    cam = get_camera("navcam")
    pans = np.arange(10) * 36.0
    p0 = profile_from_skylines(make_acq(cam, pans), draw_skylines(cam, fine, 0.0, 0.0, 0.0, pans, 0.0))
    acq = make_acq(cam, pans, 0.0, pitch, roll)
    p1 = profile_from_skylines(acq, draw_skylines(cam, fine, yaw, pitch, roll, pans, 0.0))

    def misfit(shift):
        d = p1.elevation_deg - body_truth(p0.elevation_deg, shift)
        return np.nanmedian(np.abs(d))

    assert misfit(yaw) <= 0.01
    assert misfit(yaw + 0.5) > 3 * misfit(yaw)  # the check can tell a wrong rotation


# --- images, detection, failures -----------------------------------------------------------------

def render_two_tone(rows: np.ndarray, h: int, valid: np.ndarray | None = None) -> np.ndarray:
    """RGB image: sky (blue) above the skyline row, ground (brown) below, anti-aliased per pixel."""
    i = np.arange(h)[:, None]
    r = np.where(np.isfinite(rows), rows, -1.0)[None, :]
    sky = np.clip(r - (i - 0.5), 0.0, 1.0)  # fraction of pixel [i - .5, i + .5] above the skyline
    img = sky[..., None] * np.array([90, 140, 230]) + (1 - sky[..., None]) * np.array([120, 80, 50])
    img = img.astype(np.uint8)
    if valid is not None:
        img[:, ~valid] = 0
    return img


def threshold_detector(image, mask=None):
    """Sub-pixel row from the anti-aliased sky fraction (a stand-in for skyfix.detect)."""
    f = np.clip((image[..., 2].astype(float) - 50.0) / 180.0, 0, 1)
    f = (image[..., 2].astype(float) - 50.0) / (230.0 - 50.0)
    f = np.clip(f, 0, 1)
    rows = f.sum(axis=0) - 0.5
    rows[(f[0] < 0.5) | (f[-1] > 0.5)] = np.nan
    if mask is not None:
        rows[~mask.any(axis=0)] = np.nan
    if not np.isfinite(rows).any():
        raise DetectionError("no sky")
    return Skyline(rows, image.shape[1], image.shape[0], confidence=np.ones(image.shape[1]))


def write_frames_acq(root: Path, cam, rows_per_frame, pans):
    import cv2

    root.mkdir(parents=True, exist_ok=True)
    acq = make_acq(cam, pans, root=root)
    for f, rows in zip(acq.frames, rows_per_frame):
        img = render_two_tone(rows, cam.height)
        cv2.imwrite(str(root / f.image), img[..., ::-1])
    save_acquisition(root, acq)
    return acq


def test_images_end_to_end_and_failed_frame(scene, tmp_path):
    fine, truth = scene
    cam = camera_from_fov(320, 240, 60.0)
    pans = np.arange(8) * 45.0
    yaw = 10.0
    sky = draw_skylines(cam, fine, yaw, 0.0, 0.0, pans, 0.0)
    rows = [s.rows for s in sky]
    rows[3] = np.full(cam.width, -5.0)  # an all-ground frame (camera blocked): nothing to detect
    acq = write_frames_acq(tmp_path / "acq", cam, rows, pans)
    prof = acquisition_profile(acq, detector=threshold_detector)
    med, p95, _ = errors(prof, truth, yaw)
    assert med <= 0.1 and p95 <= 0.5
    f3 = prof.meta["frames"][3]
    assert f3["status"] == "dropped" and prof.meta["frames_dropped"] == 1
    assert all(3 not in c for c in prof.meta["contributors"])


def test_no_skyline_anywhere_is_a_clear_error(tmp_path):
    cam = camera_from_fov(64, 48, 60.0)
    acq = write_frames_acq(tmp_path / "acq", cam, [np.full(64, -5.0)] * 3, [0.0, 50.0, 100.0])
    with pytest.raises(DetectionError, match="no skyline in any of the 3 frames"):
        acquisition_profile(acq, detector=threshold_detector)
    with pytest.raises(DetectionError):
        profile_from_skylines(acq, [None, None, None])


def test_equirectangular_panorama(scene, tmp_path):
    import cv2

    fine, truth = scene
    yaw = 75.0
    spec = PanoramaSpec("pano.png", azimuth_left_deg=-180.0, hfov_deg=360.0, elevation_top_deg=25.0,
                        vfov_deg=40.0)
    w, h = 2400, 300
    j = np.arange(w)
    az = spec.azimuth_left_deg + (j + 0.5) * spec.hfov_deg / w
    el = np.interp((az + yaw) % 360.0, np.arange(FINE + 1) * 360.0 / FINE, np.r_[fine, fine[0]])
    rows = (spec.elevation_top_deg - el) * h / spec.vfov_deg - 0.5
    valid = np.ones(w, bool)
    valid[:300] = False  # no data behind the rover (black)
    (tmp_path / "p").mkdir()
    cv2.imwrite(str(tmp_path / "p" / "pano.png"), render_two_tone(rows, h, valid)[..., ::-1])
    acq = Acquisition(tmp_path / "p", None, 1.5, panorama=spec)
    prof = acquisition_profile(acq, detector=threshold_detector)
    med, p95, n = errors(prof, truth, yaw)
    assert med <= 0.05 and p95 <= 0.2
    assert 310 <= n <= 316 and np.isnan(prof.elevation_deg[180])
    # the same skyline given directly
    p2 = panorama_profile(spec, Skyline(np.where(valid, rows, np.nan), w, h))
    assert errors(p2, truth, yaw)[0] <= 0.05


# --- CLI -------------------------------------------------------------------------------------------

def _cli_acq(tmp_path):
    cam = camera_from_fov(64, 48, 60.0)
    rows = [np.full(64, 20.0)] * 2
    root = tmp_path / "acq"
    write_frames_acq(root, cam, rows, [0.0, 40.0])
    return root


def test_cli_missing_image(tmp_path):
    root = _cli_acq(tmp_path)
    (root / "frame_001.png").unlink()
    r = CliRunner().invoke(cli, ["profile", str(root)])
    assert r.exit_code == 2
    assert "frame_001.png" in r.output and "missing" in r.output
    assert "Traceback" not in r.output


def test_cli_bad_field_named(tmp_path):
    root = _cli_acq(tmp_path)
    d = json.loads((root / "acquisition.json").read_text())
    d["frames"][1]["pan_deg"] = "forty"
    (root / "acquisition.json").write_text(json.dumps(d))
    r = CliRunner().invoke(cli, ["profile", str(root)])
    assert r.exit_code == 2 and "frames[1].pan_deg" in r.output


def test_cli_bad_method_and_overwrite(tmp_path):
    root = _cli_acq(tmp_path)
    r = CliRunner().invoke(cli, ["profile", str(root), "--method", "magic"])
    assert r.exit_code == 2
    out = tmp_path / "p.json"
    out.write_text("{}")
    r = CliRunner().invoke(cli, ["profile", str(root), "-o", str(out)])
    assert r.exit_code == 2 and "--overwrite" in r.output
    assert out.read_text() == "{}"


# --- stitching -------------------------------------------------------------------------------------

def test_stitch_fails_clearly_on_featureless_frames():
    from skyfix.stitch import stitch_panorama

    cam = camera_from_fov(200, 150, 60.0)
    acq = make_acq(cam, [0.0, 40.0, 80.0])
    flat = [np.full((150, 200, 3), 128, np.uint8)] * 3
    with pytest.raises(DetectionError, match="stitching failed"):
        stitch_panorama(acq, images=flat)


@pytest.mark.parametrize("pans, full", [([300.0, 330.0, 0.0, 30.0], False),
                                         ([0.0, 45.0, 90.0, 135.0, 180.0, 225.0, 270.0, 315.0],
                                          True)])
def test_stitch_closes_the_loop_only_on_a_full_turn(monkeypatch, pans, full):
    """A 135 deg arc across north (pans 300 .. 30) was taken for a full turn (max - min pans)."""
    import skyfix.profile.stitch as st

    class Seen(Exception):
        pass

    def spy(images, *a, wrap=None, **k):
        raise Seen(wrap)

    monkeypatch.setattr(st, "stitch_rotations", spy)
    cam = camera_from_fov(200, 150, 45.0)
    with pytest.raises(Seen) as got:
        st.stitch_panorama(make_acq(cam, pans), images=[np.zeros((150, 200, 3), np.uint8)] * len(pans))
    assert got.value.args[0] is full


def test_stitch_takes_frames_in_pan_order_however_they_are_listed(tmp_path):
    """Only neighbours in the sequence are matched: frames listed out of pan order were dropped
    as matching none (2 of 4 stitched, 'no good match with its neighbours'). Listed in any
    order, the same frames now make the same panorama."""
    import json
    import shutil

    from skyfix.formats import Truth, load_acquisition
    from skyfix.simulate import simulate_acquisition
    from skyfix.stitch import stitch_panorama

    z, _, _ = gaussian_hills(241, 10.0, 25, np.random.default_rng(3), amp_m=(40.0, 200.0))
    dem = Dem.from_array(z, 10.0)
    c = 120 * 10.0
    acq = simulate_acquisition(dem, Truth(c, c, 100.0), tmp_path / "in_order", frames=4,
                               pan_start_deg=-60.0, tilt_deg=0.0, seed=2)
    shuffled = tmp_path / "shuffled"
    shutil.copytree(acq, shuffled)
    doc = json.loads((shuffled / "acquisition.json").read_text())
    doc["frames"] = [doc["frames"][k] for k in (2, 0, 3, 1)]  # pans 0, -60, 30, -30
    (shuffled / "acquisition.json").write_text(json.dumps(doc))
    pano_a, _, spec_a, info_a = stitch_panorama(load_acquisition(acq))
    pano_b, _, spec_b, info_b = stitch_panorama(load_acquisition(shuffled))
    assert sorted(info_a["frames_stitched"]) == sorted(info_b["frames_stitched"]) == [0, 1, 2, 3]
    assert info_b["frames_dropped"] == []
    # OpenCV's stitching differs by a few hundredths of a degree from run to run (its threads)
    assert spec_b.azimuth_left_deg == pytest.approx(spec_a.azimuth_left_deg, abs=0.3)
    assert spec_b.hfov_deg == pytest.approx(spec_a.hfov_deg, abs=0.6) and pano_b.shape[1] > 0
    # the indices the info gives are the acquisition's own: frame 1 there is the pan of -60 deg
    for k_b, k_a in (("1", "0"), ("3", "1"), ("0", "2"), ("2", "3")):
        assert info_b["pan_estimated_deg"][k_b] == pytest.approx(info_a["pan_estimated_deg"][k_a],
                                                                 abs=0.3)


@pytest.mark.parametrize("left", [-180.0, 0.0, 370.0, -720.0])
@pytest.mark.parametrize("width", [360, 720])
def test_a_full_turn_panorama_observes_every_bin_wherever_its_seam_lies(left, width):
    """The bin between the last column and the first was left empty (bin 180 for a panorama
    whose left edge is -180 deg): a full turn's skyline runs on across its seam."""
    sky = Skyline(rows=np.full(width, 49.5), width=width, height=120)
    p = panorama_profile(PanoramaSpec("p.png", left, 360.0, 30.0, 60.0), sky)
    assert np.isfinite(p.elevation_deg).all()
    np.testing.assert_allclose(p.elevation_deg, 30.0 - 50.0 * 60.0 / 120.0)
    half = panorama_profile(PanoramaSpec("p.png", -90.0, 180.0, 30.0, 60.0),
                            Skyline(rows=np.full(width // 2, 49.5), width=width // 2, height=120))
    assert 178 <= np.isfinite(half.elevation_deg).sum() <= 181  # a half turn is not closed
