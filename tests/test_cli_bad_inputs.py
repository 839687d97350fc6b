"""Bad input at the CLI's edges: one clear line and exit status 2, never a traceback, a silent
wrong answer or a half-written set of outputs.

The slow stages (detection, the profile, the search) are replaced by stubs where a test is about
what happens around them: each test here is about refusing before the work, or about a reader.
"""

from __future__ import annotations

import errno
import json
import os
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest

from conftest import cli_run as run, plane_dem, shared_dem_path
from skyfix.errors import SkyfixError
from skyfix.formats import Profile, Skyline, load_acquisition, read_profile_json, read_skyline_json


def assert_clean_error(result, *needles):
    """Exit status 2, one ``Error:`` line holding every needle, no traceback."""
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    for needle in needles:
        assert needle in result.output, result.output


# --- fixtures and stubs ----------------------------------------------------------------------------

@pytest.fixture
def image(tmp_path):
    """A 64 x 48 px RGB PNG."""
    import cv2

    path = tmp_path / "img.png"
    cv2.imwrite(str(path), np.full((48, 64, 3), 120, np.uint8))
    return path


@pytest.fixture
def stub_detect(monkeypatch):
    """detect_skyline without the detector: a flat skyline at row 10."""
    import skyfix.detect

    calls = []

    def fake(img, *, mask=None, method="dp", name="", **kw):
        calls.append(name)
        h, w = img.shape[:2]
        return Skyline(np.full(w, 10.0), w, h, name, np.ones(w), np.ones(w, bool))

    monkeypatch.setattr(skyfix.detect, "detect_skyline", fake)
    return calls


def body_profile_dict(n=360, **extra):
    el = 5.0 + 3.0 * np.sin(np.radians(np.arange(n) * 3.0))
    d = {"azimuth_deg": list(np.arange(n) * 360.0 / n), "elevation_deg": list(el),
         "sigma_deg": [0.1] * n, "frame": "body"}
    d.update(extra)
    return d


@pytest.fixture
def profile_json(tmp_path):
    def make(name="p.json", **fields):
        path = tmp_path / name
        path.write_text(json.dumps(body_profile_dict(**fields)))
        return path

    return make


@pytest.fixture
def stub_profile(monkeypatch):
    """acquisition_profile without detection: the body profile of ``body_profile_dict``."""
    import skyfix.profile

    d = body_profile_dict()
    prof = Profile(np.array(d["elevation_deg"]), np.array(d["sigma_deg"]), "body", {"method": "stub"})
    monkeypatch.setattr(skyfix.profile, "acquisition_profile", lambda acq, **kw: prof)


class _Fix:
    x, y, heading_deg, pitch_deg, roll_deg, confidence = 500.0, 500.0, 10.0, 0.0, 0.0, 0.5
    candidates = ()

    def to_dict(self):
        return {"x": self.x, "y": self.y, "heading_deg": self.heading_deg}

    def to_geojson(self):
        return {"type": "Feature", "geometry": {"type": "Point", "coordinates": [self.x, self.y]},
                "properties": {}}


@pytest.fixture
def stub_locate(monkeypatch):
    """pose.locate without the search; records its calls."""
    import skyfix.pose

    calls = []

    def fake(profile, **kw):
        calls.append(kw)
        return (_Fix(), None) if kw.get("return_match") else _Fix()

    monkeypatch.setattr(skyfix.pose, "locate", fake)
    return calls


@pytest.fixture
def dem_file(tmp_dem_file):
    return tmp_dem_file(plane_dem(1_000, 10, slope_x=0.05))


def write_acq(root: Path, **changes) -> Path:
    """A one-frame acquisition (its image a placeholder); ``changes`` replace top-level fields,
    ``camera__cx=...`` style keys a camera field, ``frame__tilt_deg`` the frame's."""
    root.mkdir(parents=True, exist_ok=True)
    (root / "f.png").write_bytes(b"placeholder")
    d = {"camera": {"width": 1024, "height": 1024, "fx": 1236.0, "fy": 1236.0, "cx": 511.5,
                    "cy": 511.5, "distortion": {"k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "k3": 0.0}},
         "camera_height_m": 1.5, "frames": [{"image": "f.png", "pan_deg": 0.0, "tilt_deg": 0.0}],
         "attitude_prior": {"pitch_deg": 0.0, "roll_deg": 0.0}}
    for key, v in changes.items():
        if key.startswith("camera__dist__"):
            d["camera"]["distortion"][key[len("camera__dist__"):]] = v
        elif key.startswith("camera__"):
            d["camera"][key[len("camera__"):]] = v
        elif key.startswith("frame__"):
            d["frames"][0][key[len("frame__"):]] = v
        elif key.startswith("pano__"):
            d.pop("frames", None)
            d.pop("camera", None)
            d.setdefault("panorama", {"image": "f.png"})[key[len("pano__"):]] = v
        else:
            d[key] = v
    (root / "acquisition.json").write_text(json.dumps(d))
    return root


# --- 1. unwritable outputs --------------------------------------------------------------------------

@pytest.fixture
def a_file(tmp_path):
    f = tmp_path / "plain.json"
    f.write_text("{}")
    return f


def test_output_under_a_file_is_one_line_in_every_command(tmp_path, a_file, image, dem_file,
                                                          profile_json, stub_detect, stub_profile,
                                                          stub_locate):
    bad = a_file / "out.json"
    plot = a_file / "out.png"
    acq = write_acq(tmp_path / "acq")
    prof = profile_json()
    cases = [
        ("detect", image, "-o", bad),
        ("detect", image, "--plot", plot),
        ("horizon", dem_file, "--x", 500, "--y", 500, "--plot", plot),
        ("profile", acq, "-o", bad),
        ("profile", acq, "--plot", plot),
        ("locate", "--profile", prof, "--dem", dem_file, "--prior-x", 500, "--prior-y", 500,
         "--prior-radius-m", 4, "-o", bad),
        ("locate", "--profile", prof, "--dem", dem_file, "--prior-x", 500, "--prior-y", 500,
         "--prior-radius-m", 4, "--geojson", bad),
        ("locate", "--profile", prof, "--dem", dem_file, "--prior-x", 500, "--prior-y", 500,
         "--prior-radius-m", 4, "--plot", plot),
        ("heading", "--profile", prof, "--dem", dem_file, "--x", 500, "--y", 500,
         "--heading-prior-deg", 0, "-o", bad),
        ("evaluate-detect", "--images", tmp_path, "-o", a_file / "t.csv"),
    ]
    for args in cases:
        assert_clean_error(run(*args), "cannot write", f"{a_file} is a file, not a folder")
    assert stub_detect == [] and stub_locate == []  # refused before any work


def test_read_only_folder_is_one_line(tmp_path, image, stub_detect, monkeypatch):
    ro = tmp_path / "ro"
    ro.mkdir()
    real = tempfile.mkstemp

    def mkstemp(*a, dir=None, **kw):  # a read-only file system, which even root cannot write
        if dir is not None and Path(dir) == ro:
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(dir))
        return real(*a, dir=dir, **kw)

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp)
    assert_clean_error(run("detect", image, "-o", ro / "s.json"), f"cannot write {ro / 's.json'}",
                       "Read-only file system")
    assert stub_detect == []


def test_unwritable_folder_is_one_line(tmp_path, image, stub_detect, monkeypatch):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    real = tempfile.mkstemp

    def mkstemp(*a, dir=None, **kw):  # what a user without root is told (root writes anywhere)
        if dir is not None and Path(dir) == ro:
            raise OSError(errno.EACCES, os.strerror(errno.EACCES), str(dir))
        return real(*a, dir=dir, **kw)

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp)
    try:
        assert_clean_error(run("detect", image, "-o", ro / "s.json"), "cannot write",
                           f"folder {ro} is not writable", "Permission denied")
    finally:
        ro.chmod(0o755)
    assert stub_detect == []


def test_a_write_that_fails_late_is_a_clear_error_and_keeps_the_old_file(tmp_path, monkeypatch):
    """A failure after the checks (disk full, the folder turned read-only): SkyfixError, the
    previous file untouched, no temporary file left behind."""
    from skyfix import _io

    out = tmp_path / "fix.json"
    out.write_text('{"old": 1}\n')

    def no_replace(src, dst):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(src))

    monkeypatch.setattr(_io.os, "replace", no_replace)
    with pytest.raises(SkyfixError, match=r"cannot write .*fix\.json: No space left"):
        _io.write_json(out, {"new": 2})
    assert json.loads(out.read_text()) == {"old": 1}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fix.json"]


def test_os_error_escaping_a_command_is_one_line(tmp_path, a_file, dem_file):
    """build-db's store is created by skyfix.database: an OS error there still gets a line."""
    r = run("build-db", dem_file, "-o", a_file / "db.zarr", "--bounds", 400, 400, 600, 600,
            "--spacing-m", 100, "--workers", 0, "--no-progress")
    assert_clean_error(r, "Error:")


def test_missing_output_folder_is_refused_not_created(tmp_path, dem_file, image, stub_detect):
    missing = tmp_path / "no" / "such"
    assert_clean_error(run("horizon", dem_file, "--x", 500, "--y", 500, "--plot", missing / "p.png"),
                       f"folder {missing} does not exist")
    assert_clean_error(run("detect", image, "-o", missing / "s.json"), "does not exist")
    assert not (tmp_path / "no").exists()


# --- 2. an output that is a folder -----------------------------------------------------------------

def test_output_that_is_a_folder_says_so(tmp_path, stub_profile):
    acq = write_acq(tmp_path / "acq")
    adir = tmp_path / "adir"
    adir.mkdir()
    for extra in ((), ("--overwrite",)):
        r = run("profile", acq, "-o", adir, *extra)
        assert_clean_error(r, f"cannot write {adir}: it is a folder")
        assert "--overwrite" not in r.output


# --- 3. every output checked before any work --------------------------------------------------------

def test_no_output_is_written_when_another_cannot_be(tmp_path, a_file, image, dem_file, profile_json,
                                                     stub_detect, stub_profile, stub_locate):
    first = tmp_path / "first.json"
    acq = write_acq(tmp_path / "acq")
    prof = profile_json()
    loc = ("locate", "--profile", prof, "--dem", dem_file, "--prior-x", 500, "--prior-y", 500,
           "--prior-radius-m", 4, "-o", first)
    for args in [("detect", image, "-o", first, "--plot", a_file / "x.png"),
                 ("profile", acq, "-o", first, "--plot", a_file / "p.png"),
                 (*loc, "--geojson", a_file / "f.geojson"),
                 (*loc, "--score-map", a_file / "s.tif"),
                 (*loc, "--plot", a_file / "p.png")]:
        assert_clean_error(run(*args), "Error:")
        assert not first.exists(), args
    assert stub_detect == [] and stub_locate == []


def test_score_map_without_db_is_refused_before_the_search(tmp_path, dem_file, profile_json,
                                                          stub_locate):
    out = tmp_path / "fix.json"
    r = run("locate", "--profile", profile_json(), "--dem", dem_file, "--prior-x", 500, "--prior-y",
            500, "--prior-radius-m", 4, "-o", out, "--score-map", tmp_path / "s.tif")
    assert_clean_error(r, "--score-map needs --db")
    assert stub_locate == [] and not out.exists()


def test_two_options_naming_one_file_are_refused(tmp_path, dem_file, profile_json, stub_locate):
    same = tmp_path / "fix.json"
    r = run("locate", "--profile", profile_json(), "--dem", dem_file, "--prior-x", 500, "--prior-y",
            500, "--prior-radius-m", 4, "-o", same, "--geojson", same)
    assert_clean_error(r, "--output and --geojson both name")
    assert stub_locate == []


def test_plot_and_score_map_suffixes(tmp_path, dem_file, profile_json, stub_locate):
    prof = profile_json()
    assert_clean_error(run("locate", "--profile", prof, "--db", tmp_path / "db.zarr", "--score-map",
                           tmp_path / "s.png"), "end it with .tif")
    assert_clean_error(run("locate", "--profile", prof, "--dem", dem_file, "--prior-x", 500,
                           "--prior-y", 500, "--prior-radius-m", 4, "--plot", tmp_path / "p.gif"),
                       "end it with .png")
    assert stub_locate == []


# --- 4. impossible acquisition values -------------------------------------------------------------

@pytest.mark.parametrize("changes, field", [
    ({"pano__elevation_top_deg": 200}, "panorama.elevation_top_deg"),
    ({"pano__elevation_top_deg": -80, "pano__vfov_deg": 60}, "below the nadir"),
    ({"frame__tilt_deg": 400}, "frames[0].tilt_deg"),
    ({"camera__cx": 5000}, "camera.cx"),
    ({"camera__cy": -900}, "camera.cy"),
    ({"camera__dist__k1": 50}, "camera.distortion k1=50"),
    ({"camera__dist__k1": -3}, "camera.distortion k1=-3"),  # folds the image over
    # folds beyond the corner's distorted radius, short of its undistorted one (was accepted:
    # corner pixels got directions 90 deg apart)
    ({"camera__fx": 640.0, "camera__fy": 640.0, "camera__dist__k1": -0.15}, "fold the image"),
    ({"camera__dist__p2": 1.0}, "camera.distortion.p2"),
    ({"camera_height_m": 1e9}, "camera_height_m"),
    ({"camera_height_m": "tall"}, "camera_height_m"),
    ({"attitude_prior": {"pitch_deg": 80}}, "attitude_prior.pitch_deg"),
    ({"attitude_prior": {"pitch_deg": None}}, "attitude_prior.pitch_deg"),
    ({"attitude_prior": {"roll_deg": "a"}}, "attitude_prior.roll_deg"),
    ({"attitude_prior": 5}, "attitude_prior must be an object"),
    # misspelt fields were ignored and their values silently replaced by the defaults: one that
    # looks like a known field (case, underscores, unit suffix, or close spelling) is refused
    ({"camera__dist__K1": -0.2}, "camera.distortion: unknown field 'K1' (like 'k1')"),
    ({"camera__k1": -0.2}, "camera: unknown field 'k1' (like 'camera.distortion.k1')"),
    ({"attitude_prior": {"pitch": 5, "roll": 3}},
     "attitude_prior: unknown fields 'pitch' (like 'pitch_deg'), 'roll' (like 'roll_deg')"),
    ({"attitude_prior": {"Pitch_deg": 5}}, "attitude_prior: unknown field 'Pitch_deg' (like 'pitch_deg')"),
    ({"attitude_prior": {"pich_deg": 5}}, "unknown field 'pich_deg' (like 'pitch_deg')"),
    ({"frame__tilt": 10}, "frames[0]: unknown field 'tilt' (like 'tilt_deg')"),
    ({"frame__tilt_rad": 0.2}, "frames[0]: unknown field 'tilt_rad' (like 'tilt_deg')"),
    ({"camera__heigth": 1024}, "camera: unknown field 'heigth' (like 'height')"),
    ({"pano__hfov": 90}, "panorama: unknown field 'hfov' (like 'hfov_deg')"),
    # at the top level too: the prior was silently 0, 0
    ({"attitude_priors": {"pitch_deg": 8.0}}, "unknown field 'attitude_priors' (like 'attitude_prior')"),
    ({"camera_height": 3.0}, "unknown field 'camera_height' (like 'camera_height_m')"),
    # a coefficient of OpenCV's beyond the five skyfix models, non-zero: undistorted wrongly
    ({"camera__dist__k4": 0.02}, "camera.distortion: k4 = 0.02: skyfix models OpenCV's five"),
])
def test_impossible_acquisition_values_name_the_field(tmp_path, changes, field):
    root = write_acq(tmp_path / "acq", **changes)
    with pytest.raises(SkyfixError) as e:
        load_acquisition(root)
    assert field in str(e.value)


@pytest.mark.parametrize("changes", [
    {},
    {"frame__tilt_deg": 90.0},
    {"frame__tilt_deg": -35.0, "frame__pan_deg": 400.0},  # a pan past 360 is the same direction
    {"camera__cx": 540.0, "camera__cy": 470.0},  # a few per cent off centre
    {"camera__dist__k1": -0.3, "camera__dist__k2": 0.1, "camera__dist__p1": 1e-3,
     "camera__dist__k3": -0.02},
    {"camera__fx": 300.0, "camera__fy": 300.0, "camera__dist__k1": -0.25, "camera__dist__k2": 0.05},  # 120 deg
    {"camera__fx": 5000.0, "camera__fy": 5000.0, "camera__dist__k3": 100.0},  # narrow: r**6 is tiny
    {"pano__elevation_top_deg": 90.0, "pano__vfov_deg": 180.0},
    {"pano__elevation_top_deg": -10.0, "pano__vfov_deg": 40.0},
    {"attitude_prior": {"pitch_deg": -12.5, "roll_deg": 59.0}},
    {"attitude_prior": None},
    {"camera_height_m": 0.0},
    {"simulation": {"seed": 3}, "mission": "MSL"},  # a producer's own top-level fields
])
def test_plausible_acquisitions_still_load(tmp_path, changes):
    """... and load as written: every changed field holds its value, the rest the default's."""
    a = load_acquisition(write_acq(tmp_path / "acq", **changes))
    prior = changes.get("attitude_prior") or {"pitch_deg": 0.0, "roll_deg": 0.0}
    assert (a.prior_pitch_deg, a.prior_roll_deg) == (prior["pitch_deg"], prior["roll_deg"])
    assert a.camera_height_m == changes.get("camera_height_m", 1.5)
    pano = {k[len("pano__"):]: v for k, v in changes.items() if k.startswith("pano__")}
    if pano:
        assert a.panorama is not None and not a.frames
        for k, v in pano.items():
            assert getattr(a.panorama, k) == v
        return
    frame = {"pan_deg": 0.0, "tilt_deg": 0.0}
    frame.update({k[len("frame__"):]: v for k, v in changes.items() if k.startswith("frame__")})
    assert [(f.image, f.pan_deg, f.tilt_deg) for f in a.frames] == \
        [("f.png", frame["pan_deg"], frame["tilt_deg"])]
    cam = {"fx": 1236.0, "fy": 1236.0, "cx": 511.5, "cy": 511.5}
    cam.update({k[len("camera__"):]: v for k, v in changes.items()
                if k.startswith("camera__") and not k.startswith("camera__dist__")})
    assert {k: getattr(a.camera, k) for k in cam} == cam
    for k, v in changes.items():
        if k.startswith("camera__dist__"):
            assert getattr(a.camera.distortion, k[len("camera__dist__"):]) == v


@pytest.mark.parametrize("changes, name", [
    ({"frame__exposure_ms": 12.5}, "frames[0]: field 'exposure_ms'"),
    ({"camera__model": "navcam-left"}, "camera: field 'model'"),
    ({"camera__dist__k4": 0.0}, "camera.distortion: field 'k4'"),  # a model skyfix lacks, not a typo
    ({"attitude_prior": {"pitch_deg": 2.0, "roll_deg": -1.0, "source": "imu"}}, "attitude_prior: field 'source'"),
    ({"pano__exposure_ms": 4.0}, "panorama: field 'exposure_ms'"),
])
def test_an_outside_tools_own_fields_are_ignored_with_a_warning(tmp_path, caplog, changes, name):
    """conventions.md lists the fields without forbidding others: a field unlike any known one is
    a producer's metadata, read past with a warning naming it, and changes nothing."""
    import logging

    base = {"pano__hfov_deg": 360.0} if any(k.startswith("pano__") for k in changes) else {}
    if "attitude_prior" in changes:
        base = {"attitude_prior": {"pitch_deg": 2.0, "roll_deg": -1.0}}
    plain = load_acquisition(write_acq(tmp_path / "acq", **base))
    assert not caplog.records
    with caplog.at_level(logging.WARNING, logger="skyfix"):
        extended = load_acquisition(write_acq(tmp_path / "acq", **{**base, **changes}))
    assert extended == plain
    assert name in caplog.text and "ignored" in caplog.text


def test_a_field_on_every_frame_is_one_warning(tmp_path, caplog):
    import logging

    root = write_acq(tmp_path / "acq")
    d = json.loads((root / "acquisition.json").read_text())
    for i in (1, 2):
        (root / f"f{i}.png").write_bytes(b"placeholder")
        d["frames"].append({"image": f"f{i}.png", "pan_deg": 40.0 * i, "tilt_deg": 0.0})
    for f in d["frames"]:
        f["exposure_ms"] = 10.0
    (root / "acquisition.json").write_text(json.dumps(d))
    with caplog.at_level(logging.WARNING, logger="skyfix"):
        assert len(load_acquisition(root).frames) == 3
    assert [r.getMessage().split(":")[0] for r in caplog.records] == ["frames"]
    assert "'exposure_ms'" in caplog.text


def test_the_profile_command_reads_past_an_outside_tools_field(tmp_path, stub_profile):
    r = run("profile", write_acq(tmp_path / "a", frame__exposure_ms=12.5))
    assert r.exit_code == 0, r.output
    assert "frames[0]: field 'exposure_ms' not read by skyfix" in r.output


def test_profile_command_names_the_bad_field(tmp_path, stub_profile):
    assert_clean_error(run("profile", write_acq(tmp_path / "a", frame__tilt_deg=400)), "frames[0].tilt_deg")
    assert_clean_error(run("profile", write_acq(tmp_path / "b", pano__elevation_top_deg=200)),
                       "panorama.elevation_top_deg")


# --- 5. skyline JSON --------------------------------------------------------------------------------

def _skyline(tmp_path, **changes):
    d = {"image": "a.png", "width": 4, "height": 10, "rows": [1.0, 2.5, None, 9.4]}
    d.update(changes)
    for k in [k for k, v in d.items() if v is Ellipsis]:
        del d[k]
    path = tmp_path / "a.skyline.json"
    path.write_text(json.dumps(d))
    return path


@pytest.mark.parametrize("changes, needle", [
    ({"valid": "yes"}, "'valid' must be a list of 4 true/false values"),
    ({"valid": [True, False]}, "it has 2"),
    ({"valid": [1, 0, 1, 1]}, "valid[0] is 1"),
    ({"rows": [1.0, 2.0, 11.0, 3.0]}, "rows[2] = 11"),
    ({"rows": [1.0, -5.0, 2.0, 3.0]}, "rows[1] = -5"),
    ({"rows": [1.0, "x", 2.0, 3.0]}, "rows[1] must be a finite number"),
    ({"width": 5}, "'width' is 5 but 'rows' has 4 entries"),
    ({"height": 0}, "'height' must be a whole number"),
    ({"height": Ellipsis}, "missing field 'height'"),
    ({"confidence": [0.5, 2.0, None, 1.0]}, "confidence[1] = 2"),
    ({"confidence": [0.5]}, "'confidence' has 1 entries"),
    ({"rows": "1,2,3,4"}, "'rows' must be a non-empty list"),
])
def test_bad_skyline_json_names_the_field(tmp_path, changes, needle):
    with pytest.raises(SkyfixError) as e:
        read_skyline_json(_skyline(tmp_path, **changes))
    assert needle in str(e.value)


def test_good_skyline_json_reads(tmp_path):
    sk = read_skyline_json(_skyline(tmp_path, valid=[True, True, False, True],
                                    confidence=[1.0, 0.5, None, 0.0]))
    assert sk.width == 4 and sk.height == 10 and np.isnan(sk.rows[2]) and sk.valid.sum() == 3
    assert read_skyline_json(_skyline(tmp_path, width=Ellipsis)).width == 4  # width optional


# --- 6. profile JSON --------------------------------------------------------------------------------

@pytest.mark.parametrize("changes, needle", [
    ({"attitude_prior": {"pitch_deg": None, "roll_deg": 0}}, "attitude_prior.pitch_deg must be a finite"),
    ({"attitude_prior": {"pitch_deg": "a", "roll_deg": 0}}, "attitude_prior.pitch_deg must be a finite"),
    ({"attitude_prior": 3}, "attitude_prior must be an object"),
    ({"camera_height_m": "tall"}, "camera_height_m must be a finite number"),
    ({"camera_height_m": -1}, "camera_height_m must be within 0"),
    ({"elevation_deg": [1.0] * 359 + [200.0]}, "elevation_deg[359] = 200"),
    ({"sigma_deg": [0.1] * 10}, "'sigma_deg' has 10 entries, must have 360"),
    ({"sigma_deg": [0.0] * 360}, "sigma_deg[0] = 0"),
    ({"azimuth_deg": [0.0, 1.0]}, "'azimuth_deg' has 2 entries"),
    ({"frame": "up"}, "'frame' must be 'body'"),
])
def test_bad_profile_json_names_the_field(tmp_path, profile_json, changes, needle):
    with pytest.raises(SkyfixError) as e:
        read_profile_json(profile_json(**changes))
    assert needle in str(e.value)


def test_heading_and_locate_with_a_bad_profile_field(tmp_path, dem_file, profile_json, stub_locate):
    bad = profile_json(attitude_prior={"pitch_deg": "a", "roll_deg": 0.0})
    assert_clean_error(run("heading", "--profile", bad, "--dem", dem_file, "--x", 500, "--y", 500,
                           "--heading-prior-deg", 10), "attitude_prior.pitch_deg")
    tall = profile_json("tall.json", camera_height_m="tall")
    assert_clean_error(run("heading", "--profile", tall, "--dem", dem_file, "--x", 500, "--y", 500,
                           "--heading-prior-deg", 10), "camera_height_m")
    world = tmp_path / "world.json"
    world.write_text(json.dumps({k: v for k, v in body_profile_dict().items() if k != "frame"}))
    assert_clean_error(run("locate", "--profile", world, "--dem", dem_file, "--prior-x", 500,
                           "--prior-y", 500, "--prior-radius-m", 4), "has no 'frame' field",
                       "'body'-frame profile")
    assert stub_locate == []


# --- 7. priors --------------------------------------------------------------------------------------

def test_prior_radius_too_large_or_not_finite(dem_file, profile_json):
    prof = profile_json()
    base = ("locate", "--profile", prof, "--dem", dem_file, "--prior-x", 500, "--prior-y", 500)
    assert_clean_error(run(*base, "--prior-radius-m", 1e7), "build a database", "--prior-radius-m")
    for v in ("inf", "nan", "1e300"):  # 1e300 overflowed in the search, after detection
        assert_clean_error(run(*base, "--prior-radius-m", v), "--prior-radius-m must be a number")
    # so did a DEM error of 1e300 m in the sigmas' model
    assert_clean_error(run(*base, "--prior-radius-m", 4, "--dem-sigma-m", "1e300"),
                       "--dem-sigma-m must be a number of metres from 0")
    assert_clean_error(run("locate", "--profile", prof, "--dem", dem_file, "--prior-x", "nan",
                           "--prior-y", 500, "--prior-radius-m", 4), "--prior-x must be a finite")


def test_prior_area_is_clipped_to_the_dem():
    """A radius reaching past the DEM searches the DEM's part only (no cost beyond it)."""
    from skyfix.pose.refine import prior_grid as _prior_grid

    dem = plane_dem(100, 10)
    gx, gy = _prior_grid(dem, (50.0, 50.0), 1e6, 2.0)
    assert gx.min() >= 0 and gx.max() <= 100 and gy.min() >= 0 and gy.max() <= 100
    assert gx.size == 51 * 51


@pytest.mark.parametrize("v", ["nan", "inf", "-inf", "400", "-361", "1e12"])
def test_heading_prior_must_be_an_angle(dem_file, profile_json, v):
    """400 and 1e12 were wrapped into a heading without a word (1e12 gave 280 deg)."""
    assert_clean_error(run("heading", "--profile", profile_json(), "--dem", dem_file, "--x", 500,
                           "--y", 500, "--heading-prior-deg", v),
                       "--heading-prior-deg must be an angle within [-360, 360] deg")


@pytest.mark.parametrize("cmd", ["heading", "attitude"])
@pytest.mark.parametrize("v", ["0", "-5", "400", "nan"])
def test_window_must_be_within_half_a_turn_with_a_prior_or_without(dem_file, profile_json, cmd, v):
    """Without a prior these were taken without a word (the whole circle replaced them)."""
    base = (cmd, "--profile", profile_json(), "--dem", dem_file, "--x", 500, "--y", 500,
            "--window-deg", v)
    assert_clean_error(run(*base), f"--window-deg must be within (0, 180] deg, got {float(v)}")
    assert_clean_error(run(*base, "--heading-prior-deg", 10), "--window-deg must be within (0, 180]")


@pytest.mark.parametrize("cmd", ["heading", "attitude"])
def test_a_north_without_a_prior_is_refused(dem_file, profile_json, cmd):
    """``--prior-north grid`` with no prior was taken without a word, as a window was."""
    assert_clean_error(run(cmd, "--profile", profile_json(), "--dem", dem_file, "--x", 500, "--y",
                           500, "--prior-north", "grid"), "--prior-north needs --heading-prior-deg")


@pytest.mark.parametrize("cmd", ["heading", "attitude"])
def test_a_window_without_a_prior_is_refused(dem_file, profile_json, cmd, tmp_path):
    """The window is about the prior: without one the whole circle is searched and a window
    given was dropped without a word. Refused before any output is written."""
    r = run(cmd, "--profile", profile_json(), "--dem", dem_file, "--x", 500, "--y", 500,
            "--window-deg", 20, "-o", tmp_path / "h.json")
    assert_clean_error(r, "--window-deg needs --heading-prior-deg: without a prior the whole "
                          "circle is searched")
    assert not (tmp_path / "h.json").exists()


def test_heading_stays_in_its_window():
    """Truth 15 deg from the prior, window +-10: the answer is the window's edge, not the truth
    outside it (it was), and its confidence says the best lies beyond."""
    from skyfix import pose
    from skyfix.dem import load_dem

    dem = load_dem(shared_dem_path("south_glacier_20m"))
    x, y = 601_500.0, 6_744_000.0
    prof = pose.synthetic_profile(dem, x, y, 80.0, noise_deg=0.05, rng=1)
    h = pose.estimate_heading(prof, dem, x, y, 95.0, 10.0)
    d = (h.grid_heading_deg - 95.0 + 180.0) % 360.0 - 180.0  # the prior and the window are grid
    assert -10.0 - 1e-6 <= d <= 10.0 + 1e-6  # was -15: the truth, outside the window
    assert h.confidence <= pose.PINNED_HEADING_CONFIDENCE
    inside = pose.estimate_heading(prof, dem, x, y, 86.0, 10.0)  # truth inside: found, not capped
    assert abs(inside.grid_heading_deg - 80.0) < 0.5 and inside.confidence > pose.PINNED_HEADING_CONFIDENCE


def test_heading_json_carries_the_warnings_it_prints(tmp_path, dem_file, profile_json,
                                                    monkeypatch):
    """A warning on stderr is in the JSON's ``notes`` too, as locate's fix carries its own: they
    were on stderr only, lost once the JSON was filed. ``notes`` is there, empty, without one."""
    from skyfix import pose
    from skyfix.dem import load_dem
    from skyfix.formats import write_profile_json

    path = shared_dem_path("south_glacier_20m")
    x, y = 601_500.0, 6_744_000.0
    prof = pose.synthetic_profile(load_dem(path), x, y, 80.0, noise_deg=0.05, rng=1)
    prof.meta["camera_height_m"] = 1.5  # as skyfix profile writes it: no note for its absence
    write_profile_json(tmp_path / "p.json", prof)
    base = ("--profile", tmp_path / "p.json", "--dem", path, "--x", x, "--y", y, "--prior-north",
            "grid", "--heading-prior-deg")
    for cmd in ("heading", "attitude"):
        r = run(cmd, *base, 95)  # truth 15 deg off, window +-10: pinned to the window's edge
        assert r.exit_code == 0, r.output
        # the edge, and (its confidence at most 0.05) the sigmas allowing for another basin
        notes = json.loads(r.stdout)["notes"]
        assert len(notes) == 2 and any("another basin of the +-10 deg window" in n for n in notes)
        (said,) = [n for n in notes if "another basin" not in n]
        assert said.startswith("the heading ") and "is on the edge of the window 95 +- 10" in said
        # in the window's own north: the grid edge is 85 or 105, not a true heading beside it
        shown = float(said.split()[2])
        assert "(grid north)" in said and min(abs(shown - 85.0), abs(shown - 105.0)) < 0.1
        assert f"warning: {said}" in r.stderr
        r = run(cmd, *base, 86)  # truth inside the window: nothing to say
        assert r.exit_code == 0 and json.loads(r.stdout)["notes"] == [], r.output
    # a CRS that does not say where true north is: the prior is taken from grid north, and the
    # JSON says so. Stubbed: every DEM load_dem takes has a true north (one without a CRS is
    # given a local transverse Mercator, an engineering grid refused), so the CLI's branch is
    # reached through the convergence it reads
    import skyfix.north

    monkeypatch.setattr(skyfix.north, "meridian_convergence_deg", lambda crs, x, y: float("nan"))
    r = run("heading", "--profile", profile_json(), "--dem", dem_file, "--x", 500, "--y", 500,
            "--heading-prior-deg", 10, "-o", tmp_path / "h.json")
    assert r.exit_code == 0, r.output
    notes = json.loads((tmp_path / "h.json").read_text())["notes"]
    assert any("has no CRS that says where true north is" in n for n in notes), notes
    assert all(f"warning: {n}" in r.stderr for n in notes)


# --- 8. plot formats --------------------------------------------------------------------------------

def test_plot_is_written_in_the_format_its_suffix_names(tmp_path, dem_file):
    jpg = tmp_path / "p.jpg"
    r = run("horizon", dem_file, "--x", 500, "--y", 500, "--plot", jpg)
    assert r.exit_code == 0, r.output
    assert jpg.read_bytes()[:2] == b"\xff\xd8"  # JPEG, not PNG bytes under a .jpg name
    gif = tmp_path / "p.gif"
    assert_clean_error(run("horizon", dem_file, "--x", 500, "--y", 500, "--plot", gif), "'.gif'")
    assert not gif.exists()


# --- 9. smaller ones --------------------------------------------------------------------------------

def test_locate_refuses_a_folder_and_a_profile(tmp_path, dem_file, profile_json, stub_locate):
    acq = write_acq(tmp_path / "acq")
    assert_clean_error(run("locate", acq, "--profile", profile_json(), "--dem", dem_file, "--prior-x",
                           500, "--prior-y", 500, "--prior-radius-m", 4), "not both")
    assert_clean_error(run("heading", acq, "--profile", profile_json(), "--dem", dem_file, "--x", 500,
                           "--y", 500, "--heading-prior-deg", 0), "not both")
    assert stub_locate == []


def test_a_detector_is_refused_with_a_profile(dem_file, profile_json, stub_locate):
    """A profile holds no images: a --detector there would be silently ignored."""
    assert_clean_error(run("locate", "--profile", profile_json(), "--dem", dem_file, "--prior-x", 500,
                           "--prior-y", 500, "--prior-radius-m", 4, "--detector", "fuse"),
                       "--detector fuse", "holds none")
    assert_clean_error(run("heading", "--profile", profile_json(), "--dem", dem_file, "--x", 500,
                           "--y", 500, "--detector", "net"), "--detector net", "holds none")
    assert stub_locate == []


def test_detect_sizes_are_width_x_height(tmp_path, stub_detect):
    import cv2

    wide = tmp_path / "wide.png"
    cv2.imwrite(str(wide), np.full((3, 500, 3), 100, np.uint8))
    assert_clean_error(run("detect", wide), "500 x 3 px (width x height)", "at least 2 x 8 px")


def test_detect_refuses_an_all_zero_mask(tmp_path, image, stub_detect):
    import cv2

    mask = tmp_path / "mask.png"
    cv2.imwrite(str(mask), np.zeros((48, 64), np.uint8))
    assert_clean_error(run("detect", image, "--mask", mask), "no non-zero pixel")
    assert stub_detect == []


def test_horizon_at_a_dem_corner_has_no_nan_and_no_warning(tmp_dem_file, tmp_path):
    path = tmp_dem_file(plane_dem(1_000, 10, slope_x=0.2, slope_y=0.2))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy's "All-NaN slice" was leaking
        r = run("horizon", path, "--x", 0, "--y", 0, "--plot", tmp_path / "c.png")
        r1 = run("horizon", path, "--x", 500, "--y", 500, "--azimuth-bins", 1)
    assert r.exit_code == 0, r.output
    assert "nan" not in r.output and "no terrain" in r.output
    assert r1.exit_code == 0, r1.output
    assert "nan" not in r1.output and "NE no bin" in r1.output


def test_horizon_refuses_an_absurd_camera_height(dem_file):
    assert_clean_error(run("horizon", dem_file, "--x", 500, "--y", 500, "--camera-height-m", 1e9),
                       "camera height must be within 0 to 100000 m")
    r = run("horizon", dem_file, "--x", 500, "--y", 500, "--camera-height-m", 1e5, "--json")
    assert r.exit_code == 0, r.output


@pytest.mark.parametrize("bins", [7, 18])
def test_a_store_too_coarse_to_search_is_refused_before_building(tmp_path, dem_file, bins):
    """A profile needs 20 observed bins to be searched: a store of fewer was built, then no
    command could use it."""
    out = tmp_path / "db.zarr"
    r = run("build-db", dem_file, "-o", out, "--bounds", 400, 400, 600, 600, "--spacing-m", 100,
            "--workers", 0, "--no-progress", "--azimuth-bins", bins)
    assert_clean_error(r, f"got {bins}", "at least 20 azimuth bins")
    assert not out.exists()


@pytest.mark.parametrize("bins", [20, 90])
def test_a_store_of_few_or_odd_bins_is_built_and_searched(tmp_path, dem_file, bins):
    """The fewest bins allowed, and a count the coarse pass's 4 does not divide (it averages 3
    then): each store is searched with the default settings."""
    from skyfix.database import open_database
    from skyfix.database.layout import dequantise
    from skyfix.match import match_database

    out = tmp_path / "db.zarr"
    r = run("build-db", dem_file, "-o", out, "--bounds", 400, 400, 600, 600, "--spacing-m", 100,
            "--workers", 0, "--no-progress", "--azimuth-bins", bins)
    assert r.exit_code == 0, r.output
    db = open_database(out)
    assert db.azimuth_bins == bins
    blk = next(db.iter_blocks())
    k = blk.x.size // 2
    stored = dequantise(blk.elevation[k]).astype(float)
    # the stored skyline of one position as a rover turned two bins left of north sees it
    best = match_database(db, np.roll(stored, 2)).candidates[0]
    assert (best.x, best.y) == (blk.x[k], blk.y[k])
    assert best.heading_deg % 360 == pytest.approx(360 - 2 * 360 / bins, abs=0.1) and best.score < 1e-3


# --- outputs that would destroy something ----------------------------------------------------------

def test_an_output_naming_an_input_is_refused_and_the_input_kept(tmp_path, image, dem_file,
                                                                 stub_detect, stub_profile):
    """--overwrite replaced an image with its skyline's JSON, or a DEM with the heading."""
    img_bytes, dem_bytes = image.read_bytes(), dem_file.read_bytes()
    assert_clean_error(run("detect", image, "-o", image, "--overwrite"),
                       "is one of this command's inputs")
    acq = write_acq(tmp_path / "acq")
    assert_clean_error(run("heading", acq, "--dem", dem_file, "--x", 500, "--y", 500, "-o", dem_file,
                           "--overwrite"), "is one of this command's inputs")
    # the same file by another path: a link to the acquisition's image
    (tmp_path / "alias.png").symlink_to(acq / "f.png")
    assert_clean_error(run("profile", acq, "-o", tmp_path / "alias.png", "--overwrite"),
                       "is one of this command's inputs")
    assert image.read_bytes() == img_bytes and dem_file.read_bytes() == dem_bytes
    assert (acq / "f.png").read_bytes() == b"placeholder"
    assert stub_detect == []


def test_a_device_pipe_or_standard_output_is_refused(tmp_path, image, stub_detect):
    """A pipe (or /dev/null, as root) was replaced by a regular file under --overwrite."""
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    for out in (fifo, "/dev/null"):
        assert_clean_error(run("detect", image, "-o", out, "--overwrite"), "not a regular file")
    assert_clean_error(run("detect", image, "-o", "-"), "not to standard output")
    import stat

    assert stat.S_ISFIFO(os.stat(fifo).st_mode) and not (tmp_path / "-").exists()
    assert stub_detect == []


def test_an_output_through_a_link_replaces_the_file_it_points_at(tmp_path, image, stub_detect):
    target = tmp_path / "target.json"
    target.write_text("{}")
    link = tmp_path / "link.json"
    link.symlink_to(target)
    r = run("detect", image, "-o", link, "--overwrite")
    assert r.exit_code == 0, r.output
    assert link.is_symlink() and read_skyline_json(target).rows[0] == 10.0


@pytest.mark.parametrize("step, msg", [(0, "not 0"), (400, "span more than 360 deg"),
                                       (float("nan"), "finite")])
def test_acquisition_init_refuses_pans_that_cannot_be(tmp_path, step, msg):
    """A zero step put every image at pan 0, as simulate already refused."""
    import cv2

    for k in range(3):
        cv2.imwrite(str(tmp_path / f"f{k}.png"), np.full((48, 64, 3), 120, np.uint8))
    assert_clean_error(run("acquisition-init", tmp_path, "--hfov-deg", 45, "--pan-step-deg", step,
                           "--camera-height-m", 1.5, "--tilt-deg", 0), msg)
    assert not (tmp_path / "acquisition.json").exists()
    r = run("acquisition-init", tmp_path, "--hfov-deg", 45, "--pan-step-deg", -30,
            "--camera-height-m", 1.5, "--tilt-deg", 0)
    assert r.exit_code == 0, r.output
    assert [f.pan_deg for f in load_acquisition(tmp_path).frames] == [0.0, -30.0, -60.0]


def test_a_panorama_too_large_to_render_is_refused_before_any_work(tmp_path, dem_file):
    """100000 x 50000 px died of a MemoryError, with a traceback, asking for 56 GiB."""
    out = tmp_path / "sim"
    assert_clean_error(run("simulate", dem_file, "--x", 500, "--y", 500, "--yaw-deg", 0, "--mode",
                           "panorama", "--pano-size", 100000, 50000, "-o", out), "64 MP")
    assert not out.exists()


@pytest.mark.parametrize("changes, field", [
    ({"camera__fx": 1e-6}, "camera.fx = 1e-06 px gives a field of view of 180.0 deg"),
    ({"camera__fy": 8.0}, "camera.fy = 8 px gives a field of view of 178.2 deg"),
    ({"frame__pan_deg": 1e20}, "frames[0].pan_deg must be within -3600 to 3600"),
    ({"frames": [{"image": "f.png", "pan_deg": 0.0, "tilt_deg": 0.0},
                 {"image": "f.png", "pan_deg": 30.0, "tilt_deg": 0.0}]},
     "frames[1] and frames[0] both name f.png"),
    ({"frames": [{"image": "f.png", "pan_deg": 0.0, "tilt_deg": 0.0},
                 {"image": "./f.png", "pan_deg": 40.0, "tilt_deg": 0.0}]},
     "frames[1] and frames[0] both name f.png ('f.png' and './f.png')"),
])
def test_a_focal_length_pan_or_frame_that_cannot_be_is_refused(tmp_path, changes, field):
    """fx = 1e-6 px (a focal length in metres) made a profile of no observed bins, exit 0; a pan
    of 1e20 deg keeps no direction; one image named by two frames made a profile of copies."""
    with pytest.raises(SkyfixError) as e:
        load_acquisition(write_acq(tmp_path / "acq", **changes))
    assert field in str(e.value)


@pytest.mark.parametrize("planet, says", [("1", "at least 100 m"), ("-5", "at least 100 m"),
                                          ("nan", "at least 100 m"), ("jupiterish", "unknown planet")])
def test_a_planet_no_body_could_be_is_refused(dem_file, planet, says):
    """--planet 1 rendered horizons on a 1 m world without a word."""
    assert_clean_error(run("horizon", dem_file, "--x", 500, "--y", 500, "--planet", planet), says)


def test_build_and_verify_options_that_could_not_work_are_one_line(tmp_path, dem_file):
    """--block-positions 100000 asked zarr for 6.5 TiB (a traceback, a half-made store); verify
    --seed -3 died in NumPy's generator."""
    out = tmp_path / "db.zarr"
    base = ("build-db", dem_file, "-o", out, "--bounds", 400, 400, 600, 600, "--spacing-m", 100,
            "--workers", 0, "--no-progress")
    assert_clean_error(run(*base, "--block-positions", 100000), "at most 256 positions a side")
    assert not out.exists()
    assert run(*base).exit_code == 0
    assert_clean_error(run("verify", out, "--samples", 1, "--seed", -3), "seed must be a whole number")


@pytest.mark.parametrize("args, says", [
    (("--frames", 1, "--pan-start-deg", 1e12), "pan start must be within +-3600"),
    (("--mode", "panorama", "--pano-size", 64, 4), "at least 2 x 8 px"),
    (("--conditions", "dust,dust:0.3"), "given twice"),
    (("--conditions", "dust:"), "strength after ':' is missing"),
    (("--conditions", ",,"), "empty item"),
])
def test_simulate_writes_only_what_skyfix_reads_back(tmp_path, dem_file, args, says):
    """Each of these was written (exit 0), then refused by profile or silently read otherwise."""
    out = tmp_path / "sim"
    assert_clean_error(run("simulate", dem_file, "--x", 500, "--y", 500, "--yaw-deg", 0, *args,
                           "-o", out), says)
    assert not out.exists()


def test_a_truncated_jpeg_is_refused_naming_it(tmp_path):
    """OpenCV decoded the first eighth of a JPEG and filled the rest with grey (libjpeg only
    warned on stderr): fuse found a skyline in every column, exit 0."""
    import cv2

    yy, xx = np.mgrid[0:240, 0:320]
    sky = np.where(yy < 100 + 20 * np.sin(xx / 30.0), 200, 60).astype(np.uint8)
    ok, data = cv2.imencode(".jpg", np.dstack([sky, sky, (xx % 256).astype(np.uint8)]))
    whole, cut = tmp_path / "whole.jpg", tmp_path / "cut.jpg"
    whole.write_bytes(data.tobytes())
    cut.write_bytes(data.tobytes()[: len(data) // 8])
    assert run("detect", whole, "-o", tmp_path / "w.json").exit_code == 0
    assert_clean_error(run("detect", cut, "-o", tmp_path / "c.json"), "cut.jpg is damaged or truncated",
                       "Premature end of JPEG file")
    assert not (tmp_path / "c.json").exists()


def test_an_image_too_small_to_search_is_named(tmp_path):
    """Among many images (evaluate-detect) the refusal did not say which."""
    import cv2

    from skyfix.detect import detect_skyline

    with pytest.raises(SkyfixError, match=r"^tiny.png: image of 1 x 1 px"):
        detect_skyline(np.zeros((1, 1, 3), np.uint8), name="tiny.png")
    cv2.imwrite(str(tmp_path / "tiny.png"), np.zeros((1, 1, 3), np.uint8))
    (tmp_path / "tiny.skyline.json").write_text(json.dumps({"image": "tiny.png", "width": 1,
                                                            "height": 1, "rows": [None]}))
    assert_clean_error(run("evaluate-detect", "--images", tmp_path), "tiny.png: image of 1 x 1 px")


def test_a_frame_without_its_tilt_is_refused_not_read_as_level(tmp_path):
    """A missing tilt_deg was read as 0: on a mast tilted 10-25 deg every skyline moved that far
    and the attitude solve reported the tilt as roll, 15 deg off at confidence 1.0."""
    root = write_acq(tmp_path / "acq")
    d = json.loads((root / "acquisition.json").read_text())
    del d["frames"][0]["tilt_deg"]
    (root / "acquisition.json").write_text(json.dumps(d))
    with pytest.raises(SkyfixError) as e:
        load_acquisition(root)
    assert "frames[0]: missing field 'tilt_deg'" in str(e.value)


def test_acquisition_init_needs_the_tilt_and_warns_of_a_view_given_in_radians(tmp_path):
    """--tilt-deg had a default of 0 (a level mast); a field of view or pan step in radians was
    written without a word."""
    import cv2

    for k in range(3):
        cv2.imwrite(str(tmp_path / f"f{k}.png"), np.full((48, 64, 3), 120, np.uint8))
    r = run("acquisition-init", tmp_path, "--hfov-deg", 45, "--pan-step-deg", 30, "--camera-height-m", 1.5)
    assert r.exit_code == 2 and "--tilt-deg" in r.output
    r = run("acquisition-init", tmp_path, "--hfov-deg", 0.785, "--pan-step-deg", 30,
            "--camera-height-m", 1.5, "--tilt-deg", 0)
    assert r.exit_code == 0, r.output
    assert "was it given in radians (45.0 deg)?" in r.output and "leave gaps" in r.output
    r = run("acquisition-init", tmp_path, "--hfov-deg", 45, "--pan-step-deg", 0.5236,
            "--camera-height-m", 1.5, "--tilt-deg", 0, "--overwrite")
    assert r.exit_code == 0 and "were the pans given in radians?" in r.output
    r = run("acquisition-init", tmp_path, "--hfov-deg", 45, "--pan-step-deg", 40,
            "--camera-height-m", 1.5, "--tilt-deg", 10, "--overwrite")
    assert r.exit_code == 0 and "warning" not in r.output
    assert [f.tilt_deg for f in load_acquisition(tmp_path).frames] == [10.0] * 3


def test_a_refused_acquisition_init_overwrite_keeps_the_file_that_was_there(tmp_path):
    """--overwrite replaced acquisition.json, then deleted it when the new one failed its checks
    (a focal length in mm, images of two sizes): a hand-edited acquisition lost. The new one is
    now checked before anything is written."""
    import cv2

    for k in range(3):
        cv2.imwrite(str(tmp_path / f"f{k}.png"), np.full((48, 64, 3), 120, np.uint8))
    good = ("--hfov-deg", 45, "--pan-step-deg", 30, "--camera-height-m", 1.5, "--tilt-deg", 10)
    assert run("acquisition-init", tmp_path, *good).exit_code == 0
    before = (tmp_path / "acquisition.json").read_bytes()
    r = run("acquisition-init", tmp_path, "--focal-px", 0.035, "--pan-step-deg", 30,
            "--camera-height-m", 1.5, "--tilt-deg", 0, "--overwrite")
    assert_clean_error(r, "focal")
    assert (tmp_path / "acquisition.json").read_bytes() == before
    cv2.imwrite(str(tmp_path / "f3.png"), np.full((40, 64, 3), 120, np.uint8))
    r = run("acquisition-init", tmp_path, *good, "--overwrite")
    assert_clean_error(r, "is not a 64 x 48 image like f0.png")
    assert (tmp_path / "acquisition.json").read_bytes() == before
