"""``-v`` and ``-q`` mean the same after the subcommand as before it, for every subcommand, and
``-v`` says what ``locate``, ``heading`` and ``detect`` did (candidates, refinement, detection
coverage) while the default output stays as it was."""

from __future__ import annotations

import re

import numpy as np
import pytest
from click.testing import CliRunner

from skyfix.cli.main import COMMANDS, cli
from skyfix.database import build_database
from skyfix.dem import Dem, write_dem
from skyfix.formats import write_profile_json
from skyfix.pose import synthetic_profile

CELL = 10.0


def _z(x, y):
    return (100 + 0.05 * y + 60 * np.exp(-((x - 150) ** 2 + (y - 650) ** 2) / 80**2)
            + 40 * np.exp(-((x - 700) ** 2 + (y - 200) ** 2) / 60**2)
            + 25 * np.sin(x / 70.0) * np.cos(y / 90.0))


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A DEM, a 21 x 21 database at 10 m inside it and a profile seen from (412, 387)."""
    d = tmp_path_factory.mktemp("verbosity")
    n = 81
    x, y = np.arange(n) * CELL, (n - 1 - np.arange(n)) * CELL
    dem = Dem.from_array(_z(x[None, :], y[:, None]), CELL)
    dem_path = write_dem(d / "map.tif", dem)
    db = d / "db.zarr"
    build_database(dem_path, db, (300, 300, 500, 500), 10, workers=0, progress=False,
                   azimuth_bins=180, block=8)
    prof = d / "profile.json"
    write_profile_json(prof, synthetic_profile(dem, 412.0, 387.0, 40.0, noise_deg=0.03, rng=2,
                                               n_bins=180))
    import cv2

    # a blue sky over textured brown ground, a skyline 40-60 rows down
    rng = np.random.default_rng(0)
    rows, cols = np.mgrid[0:120, 0:160]
    sky = rows < 50 + 10 * np.sin(cols / 15.0)
    rgb = np.stack([np.where(sky, 110 + 40 * rows / 120, 120 + rng.normal(0, 12, rows.shape)),
                    np.where(sky, 160 + 40 * rows / 120, 90 + rng.normal(0, 12, rows.shape)),
                    np.where(sky, 230, 60 + rng.normal(0, 12, rows.shape))], axis=2)
    image = d / "photo.png"
    cv2.imwrite(str(image), rgb.clip(0, 255).astype(np.uint8)[..., ::-1])
    return dict(dem=dem_path, db=db, profile=prof, image=image, dir=d)


def _run(*args):
    r = CliRunner().invoke(cli, [str(a) for a in args])
    return r


def _messages(stderr):
    """The log lines without their times (two runs differ in nothing else)."""
    return [re.sub(r"\d+\.\d+ s\b", "T s", line) for line in stderr.splitlines()]


@pytest.mark.parametrize("name", list(COMMANDS))
def test_every_subcommand_takes_v_and_q_after_its_name(name):
    r = _run(name, "-v", "-q", "--help")
    assert r.exit_code == 0, r.output
    assert "-v, --verbose" in r.stdout and "-q, --quiet" in r.stdout


@pytest.mark.parametrize("args", [("-v", "-q", "info", "{dem}"), ("-q", "info", "{dem}", "-v"),
                                  ("info", "{dem}", "-vv", "-q"), ("-v", "info", "{dem}", "-q")])
def test_v_and_q_together_are_refused_wherever_given(scene, args):
    """-q silenced whatever -v asked for, without a word: they do not count against each other."""
    r = _run(*(a.format(dem=scene["dem"]) for a in args))
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert r.stderr.strip() == "Error: give -v or -q, not both (-v: more log output, -q: errors only)"
    assert r.stdout == ""  # refused before the command ran
    assert _run("-q", "info", scene["dem"], "-q").exit_code == 0  # each alone, twice, still runs
    assert _run("-v", "info", scene["dem"], "-v").exit_code == 0


def test_locate_v_after_the_subcommand_is_v_before_it(scene, tmp_path):
    args = ("--profile", scene["profile"], "--db", scene["db"], "--dem", scene["dem"])
    after = _run("locate", *args, "-o", tmp_path / "after.json", "-v")
    assert after.exit_code == 0, after.output  # click refused it: "No such option: -v"
    before = _run("-v", "locate", *args, "-o", tmp_path / "before.json")
    assert before.exit_code == 0, before.output
    assert _messages(after.stderr) == [m.replace("before.json", "after.json")
                                       for m in _messages(before.stderr)]
    # what -v adds: the candidates the search kept, where refinement took them, the decision
    assert "INFO skyfix.pose.locate: database search: " in after.stderr
    assert re.search(r"refined \([\d.]+, [\d.]+\) -> \(41[12]\.\d, 38[78]\.\d\), moved", after.stderr)
    assert "confidence" in after.stderr and "before caps" in after.stderr
    plain = _run("locate", *args, "-o", tmp_path / "plain.json")
    assert plain.exit_code == 0 and "INFO" not in plain.stderr and "located:" in plain.stderr
    loud = _run("locate", *args, "-o", tmp_path / "loud.json", "-vvv")  # everyone's debug
    assert loud.exit_code == 0 and "DEBUG rasterio" in loud.stderr, loud.stderr


def test_locate_vv_split_around_the_subcommand_is_debug(scene, tmp_path):
    r = _run("-v", "locate", "--profile", scene["profile"], "--db", scene["db"], "--dem",
             scene["dem"], "-o", tmp_path / "fix.json", "-v")
    assert r.exit_code == 0, r.output
    assert "DEBUG skyfix.pose.locate: confidence features: log_ratio" in r.stderr


def test_q_after_the_subcommand_leaves_errors_only(scene, tmp_path):
    r = _run("locate", "--profile", scene["profile"], "--db", scene["db"], "--dem", scene["dem"],
             "-o", tmp_path / "fix.json", "-q")
    assert r.exit_code == 0, r.output
    assert r.stderr == "" and (tmp_path / "fix.json").is_file()
    r = _run("detect", tmp_path / "none.png", "-q")
    assert r.exit_code == 2 and "Error:" in r.stderr  # errors still are


def test_heading_v_says_what_the_search_saw(scene, tmp_path):
    r = _run("heading", "--profile", scene["profile"], "--dem", scene["dem"], "--x", 412,
             "--y", 387, "--heading-prior-deg", 45, "-o", tmp_path / "h.json", "-v")
    assert r.exit_code == 0, r.output
    assert re.search(r"heading search at \(412\.0, 387\.0\): grid 45\.0 \+- 10 deg, \d+ of 180 "
                     r"bins observed", r.stderr), r.stderr
    assert "INFO skyfix.pose.heading: attitude fit: yaw 40." in r.stderr
    plain = _run("heading", "--profile", scene["profile"], "--dem", scene["dem"], "--x", 412,
                 "--y", 387, "--heading-prior-deg", 45, "-o", tmp_path / "h2.json")
    assert plain.exit_code == 0 and "INFO" not in plain.stderr


def test_detect_v_gives_method_coverage_and_time(scene, tmp_path):
    r = _run("detect", scene["image"], "-o", tmp_path / "s.json", "-v")
    assert r.exit_code == 0, r.output
    assert re.search(r"INFO skyfix\.detect\.skyline: photo\.png: dp, 160 x 120 px colour, 100 % of "
                     r"pixels valid: skyline in 160 of 160 columns, median confidence [\d.]+ "
                     r"\([\d.]+ s\)", r.stderr), r.stderr
    plain = _run("detect", scene["image"], "-o", tmp_path / "s2.json")
    assert plain.exit_code == 0 and "INFO" not in plain.stderr
