"""A fix says "I don't know" where the search cannot know, and mismatches between the database, the
DEM and the acquisition are refused or reported before any image is read."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
from click.testing import CliRunner

from skyfix.cli.main import cli
from skyfix.database import build_database, open_database
from skyfix.dem import Dem, write_dem
from skyfix.formats import write_profile_json
from skyfix.pose import locate, synthetic_profile
from skyfix.pose.locate import DEGENERATE_CAP

CELL = 10.0


def _z(x, y):
    return (100 + 0.05 * y + 60 * np.exp(-((x - 150) ** 2 + (y - 650) ** 2) / 80**2)
            + 40 * np.exp(-((x - 700) ** 2 + (y - 200) ** 2) / 60**2)
            + 25 * np.sin(x / 70.0) * np.cos(y / 90.0))


def _dem(shift=0.0):
    n = 81
    x = np.arange(n) * CELL
    y = (n - 1 - np.arange(n)) * CELL
    return Dem.from_array(_z(x[None, :] + shift, y[:, None]), CELL)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("maps")
    dem_path = write_dem(d / "map.tif", _dem())
    other = write_dem(d / "other.tif", _dem(shift=35.0))
    db = d / "db.zarr"
    build_database(dem_path, db, (300, 300, 500, 500), 10, workers=0, progress=False,
                   azimuth_bins=180, block=8)
    return dem_path, other, db


def _profile(dem, x=412.0, y=387.0, heading=40.0, **kw):
    return synthetic_profile(dem, x, y, heading, noise_deg=0.03, rng=2, n_bins=180, **kw)


@pytest.mark.parametrize("spacing", [1e6, 150.0])
def test_a_database_of_one_or_two_positions_is_not_confident(tmp_path, files, spacing):
    """The issue's cases: one position (--spacing-m 1e6) answered 539 m off at 0.9994, two 361 m
    off at 0.995. Whatever the scores, a handful of positions cannot support a fix."""
    dem_path, _, _ = files
    db_path = tmp_path / "tiny.zarr"
    build_database(dem_path, db_path, (300, 300, 500, 500), spacing, workers=0, progress=False,
                   azimuth_bins=180, block=8)
    db = open_database(db_path)
    assert len(db.x_coords) * len(db.y_coords) <= 4
    dem = _dem()
    fix = locate(_profile(dem), db=db, dem=dem)
    assert fix.confidence < 0.5
    assert any("database position" in n for n in fix.notes)


def test_a_fix_on_the_edge_of_the_searched_area_is_not_confident(files):
    """The rover stands 5 m beyond the database's last column (x 300..500): within half a grid
    step of it, on its edge."""
    dem_path, _, db_path = files
    dem = _dem()
    fix = locate(_profile(dem, x=505.0, y=450.0), db=open_database(db_path), dem=dem)
    assert np.hypot(fix.x - 505.0, fix.y - 450.0) < 1.0
    assert fix.confidence < 0.5 and any("within one grid step (10 m) of the searched area's edge"
                                        in n for n in fix.notes), fix.notes
    # the cap says the rover may lie outside the area, not in another basin inside it: the
    # sigma is the basin's (spread over the area it was 183 m for a fix 0.2 m off)
    assert fix.position_sigma_m == pytest.approx(fix.features["position_sigma_basin_m"], rel=0.1)
    assert not any("another basin" in n for n in fix.notes)


def test_a_fix_refined_out_of_the_database_is_kept_and_said_to_lie_outside(files):
    """The rover stands 40 m beyond the database's area: the database's best match is on its
    edge, and refinement on the DEM walks out to the rover. The fix stays where the skyline says
    (clamped to x = 500 it would be 40 m off with a sigma of metres); it is not confident, since
    nothing beyond the edge was searched, and says so with the distance (it said "within one grid
    step of the edge")."""
    dem_path, _, db_path = files
    dem = _dem()
    fix = locate(_profile(dem, x=540.0, y=420.0), db=open_database(db_path), dem=dem)
    assert np.hypot(fix.x - 540.0, fix.y - 420.0) < 1.0
    assert fix.confidence <= DEGENERATE_CAP
    assert any(re.search(r"the answer lies (39\.\d|40\.\d) m outside the searched area \(the "
                         r"database's positions, x 300\.0\.\.500\.0 and y 300\.0\.\.500\.0 m\)", n)
               for n in fix.notes), fix.notes
    assert not any("within one grid step" in n for n in fix.notes)


def test_a_fix_refined_off_a_one_column_database_is_not_confident(tmp_path, files):
    """A strip of 51 positions along x = 400 (a database along a planned route), the rover 25 m
    east of it: refinement walks to the rover. A grid one position wide has no edge in x to be
    near, so the fix went out at confidence 0.95 with no note."""
    dem_path, _, _ = files
    strip = tmp_path / "strip.zarr"
    build_database(dem_path, strip, (400, 300, 400, 500), 4, workers=0, progress=False,
                   azimuth_bins=180, block=8)
    db = open_database(strip)
    assert (len(db.x_coords), len(db.y_coords)) == (1, 51)
    dem = _dem()
    fix = locate(_profile(dem, x=425.0, y=400.0), db=db, dem=dem)
    assert np.hypot(fix.x - 425.0, fix.y - 400.0) < 1.0
    assert fix.confidence <= DEGENERATE_CAP
    assert any("25.0 m outside the searched area" in n for n in fix.notes), fix.notes


def test_a_fix_refined_out_of_the_prior_disc_says_how_far(files):
    """Without a database: a prior disc of 10 m around (412, 387), the rover at (430, 387). The
    refinement walks 8 m past the disc to the rover; the note said "within one grid step (2 m)
    of the searched area's edge"."""
    dem = _dem()
    fix = locate(_profile(dem, x=430.0, y=387.0), dem=dem, prior_xy=(412.0, 387.0),
                 prior_radius_m=10.0)
    assert np.hypot(fix.x - 430.0, fix.y - 387.0) < 1.0
    assert fix.confidence <= DEGENERATE_CAP
    assert any("8.0 m outside the searched area (the prior disc of 10 m around (412.0, 387.0))"
               in n and "--prior-radius-m" in n for n in fix.notes), fix.notes


def test_a_fix_inside_a_healthy_search_keeps_its_confidence(files):
    dem_path, _, db_path = files
    dem = _dem()
    fix = locate(_profile(dem), db=open_database(db_path), dem=dem)
    assert np.hypot(fix.x - 412.0, fix.y - 387.0) < 1.0
    assert fix.confidence > 0.5 and not any("capped" in n for n in fix.notes)


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.fixture
def detection_forbidden(monkeypatch):
    """Fail loudly if any image is decoded or detected."""
    import skyfix.detect
    import skyfix.profile.frames

    def boom(*a, **k):
        raise AssertionError("an image was read before the checks")

    monkeypatch.setattr(skyfix.detect, "detect_skyline", boom)
    monkeypatch.setattr(skyfix.profile.frames, "read_rgb", boom)


def _acquisition(tmp_path, camera_height_m=1.5):
    """An acquisition folder whose images would take long to detect (never read here)."""
    from skyfix.camera import get_camera
    from skyfix.formats import Acquisition, Frame, save_acquisition

    acq = tmp_path / "acq"
    acq.mkdir()
    (acq / "f0.png").write_bytes(b"not read")
    save_acquisition(acq, Acquisition(root=acq, camera=get_camera("navcam"),
                                      camera_height_m=camera_height_m,
                                      frames=(Frame("f0.png", 0.0, 0.0),)))
    return acq


def test_a_dem_other_than_the_databases_is_refused_before_detection(tmp_path, files,
                                                                     detection_forbidden):
    dem_path, other, db_path = files
    acq = _acquisition(tmp_path)
    r = _run("locate", acq, "--db", db_path, "--dem", other)
    assert r.exit_code == 2, r.output
    assert "is not the DEM the database" in r.output and str(other) in r.output
    assert "Traceback" not in r.output


def test_a_database_built_in_another_work_crs_is_refused_even_forced(tmp_path, monkeypatch,
                                                                     detection_forbidden):
    """The same DEM file, read into another work CRS than the database's: skyfix before
    2026-11-28 kept a DEM projected with 0.1-1 % scale error (here UTM 11N 500 km off its
    meridian, 0.27 %) in its own CRS; it is now read into its UTM zone (10N), and the database's
    positions would be taken for coordinates of that other map. Refused, --force or not."""
    import skyfix.dem

    z = _dem().z
    dem_path = write_dem(tmp_path / "utm_far.tif", Dem.from_array(z, CELL, crs="EPSG:32611"))
    db_path = tmp_path / "old.zarr"
    with monkeypatch.context() as m:  # the rule of before: a 0.27 % stretch kept, as the file's
        m.setattr(skyfix.dem, "scale_error", lambda *a, **k: 0.0)
        build_database(dem_path, db_path, (300, 300, 500, 500), 10, workers=0, progress=False,
                       azimuth_bins=180, block=8)
    assert open_database(db_path).attrs["crs_name"] == "EPSG:32611"
    acq = _acquisition(tmp_path)
    for extra in ((), ("--force",)):
        r = _run("locate", acq, "--db", db_path, "--dem", dem_path, *extra)
        assert r.exit_code == 2, r.output
        assert "was built in EPSG:32611" in r.output and "read in EPSG:32610" in r.output
        assert "Rebuild the database" in r.output and "Traceback" not in r.output


def test_a_database_built_on_another_reading_of_the_same_dem_is_refused(tmp_path, monkeypatch,
                                                                      detection_forbidden):
    """The same DEM file, the same work CRS, another grid: skyfix before 2026-11-28 cropped a
    reprojected DEM to the largest rectangle inside its footprint and now keeps all of it, so a
    database built then misses terrain the crop cut. The checksum cannot tell: refused by the grid
    recorded, --force or not."""
    import skyfix.stack

    z = _dem().z
    dem_path = write_dem(tmp_path / "geo_like.tif", Dem.from_array(z, CELL))
    db_path = tmp_path / "old.zarr"

    def cropped(path, **kw):  # the reading of before: two rows and columns less
        d = load(path, **kw)
        return Dem(d.z[1:-1, 1:-1], d.x0 + d.dx, d.y0 - d.dy, d.dx, d.dy, d.crs_wkt, d.crs_name,
                   source=d.source, checksum=d.checksum, body=d.body)

    load = skyfix.stack.load_dem
    with monkeypatch.context() as m:
        m.setattr(skyfix.stack, "load_dem", cropped)
        build_database(dem_path, db_path, (300, 300, 500, 500), 10, workers=0, progress=False,
                       azimuth_bins=180, block=8)
    assert open_database(db_path).attrs["dem"]["shape"] == [z.shape[0] - 2, z.shape[1] - 2]
    acq = _acquisition(tmp_path)
    for extra in ((), ("--force",)):
        r = _run("locate", acq, "--db", db_path, "--dem", dem_path, *extra)
        assert r.exit_code == 2, r.output
        assert f"read as a {z.shape[1] - 2} x {z.shape[0] - 2} grid" in r.output, r.output
        assert "rebuild the database" in r.output and "Traceback" not in r.output


def test_a_forced_other_dem_is_said_in_the_fix(tmp_path, files):
    dem_path, other, db_path = files
    prof = tmp_path / "p.json"
    write_profile_json(prof, _profile(_dem()))
    r = _run("locate", "--profile", prof, "--db", db_path, "--dem", other, "--force",
             "-o", tmp_path / "fix.json")
    assert r.exit_code == 0, r.output
    fix = json.loads((tmp_path / "fix.json").read_text())
    assert any("--force" in n and "not the DEM" in n for n in fix["notes"])


def test_a_camera_height_other_than_the_databases_is_used_and_widens_the_sigma(tmp_path, files):
    """Database at 1.5 m, rover camera 4 m up: refinement renders at 4 m (the fix lands on the
    truth), a warning says so, and the position sigma is at least the 2.5 m difference."""
    dem_path, _, db_path = files
    dem = _dem()
    prof = _profile(dem, camera_height_m=4.0)
    prof.meta["camera_height_m"] = 4.0
    path = tmp_path / "p.json"
    write_profile_json(path, prof)
    r = _run("locate", "--profile", path, "--db", db_path, "--dem", dem_path, "-o", tmp_path / "fix.json")
    assert r.exit_code == 0, r.output
    assert "4 m above the ground" in r.output and "built for 1.5 m" in r.output
    fix = json.loads((tmp_path / "fix.json").read_text())
    assert np.hypot(fix["x"] - 412.0, fix["y"] - 387.0) < 1.0
    assert fix["position_sigma_m"] >= 2.5
    assert any("camera" in n for n in fix["notes"])


def test_dem_sigma_sizes_the_position_sigma_not_the_fix(tmp_path, files, detection_forbidden):
    """``locate --dem-sigma-m``: refused when negative, before any image is read; otherwise the
    same fix, with a position sigma that holds the map's share (default 2 m) or not (0)."""
    dem_path, _, db_path = files
    r = _run("locate", _acquisition(tmp_path), "--db", db_path, "--dem", dem_path,
             "--dem-sigma-m", -1)
    assert r.exit_code == 2 and "--dem-sigma-m" in r.output and "Traceback" not in r.output
    path = tmp_path / "p.json"
    write_profile_json(path, _profile(_dem()))
    fixes = []
    for extra in ((), ("--dem-sigma-m", 0)):
        out = tmp_path / f"fix{len(fixes)}.json"
        r = _run("locate", "--profile", path, "--db", db_path, "--dem", dem_path, "-o", out, *extra)
        assert r.exit_code == 0, r.output
        fixes.append(json.loads(out.read_text()))
    wide, exact = fixes
    assert (wide["x"], wide["y"], wide["heading_deg"]) == (exact["x"], exact["y"], exact["heading_deg"])
    assert wide["position_sigma_m"] > exact["position_sigma_m"] + 0.5
    assert wide["provenance"]["options"]["dem_sigma_m"] == 2.0
    assert exact["provenance"]["options"]["dem_sigma_m"] == 0.0


def test_a_prior_area_off_the_database_is_refused_before_detection(tmp_path, files,
                                                                   detection_forbidden):
    """It was refused only after every image had been detected."""
    dem_path, _, db_path = files
    acq = _acquisition(tmp_path)
    r = _run("locate", acq, "--db", db_path, "--prior-x", 0, "--prior-y", 0, "--prior-radius-m", 50)
    assert r.exit_code == 2, r.output
    assert "no database position lies inside the prior area" in r.output
    assert "spans x 300.0..500.0" in r.output and "Traceback" not in r.output
    # a radius without a centre was ignored, yet recorded in the provenance as if used
    r = _run("locate", acq, "--db", db_path, "--prior-radius-m", 50)
    assert r.exit_code == 2 and "--prior-radius-m needs the disc's centre" in r.output, r.output
    # a disc between grid positions that holds none (the grid is 10 m)
    r = _run("locate", acq, "--db", db_path, "--prior-x", 405, "--prior-y", 405, "--prior-radius-m", 3)
    assert r.exit_code == 2 and "the nearest is 7.1 m away" in r.output, r.output


@pytest.mark.parametrize("where", [("--x", -500, "--y", 400), ("--lon", 500, "--lat", 0),
                                   ("--lon", 0, "--lat", 95), ("--lon", -100, "--lat", 40)])
def test_a_heading_position_off_the_dem_is_refused_before_detection(tmp_path, files,
                                                                    detection_forbidden, where):
    dem_path, _, _ = files
    r = _run("heading", _acquisition(tmp_path), "--dem", dem_path, *where)
    assert r.exit_code == 2, r.output
    bad_lonlat = where[0] == "--lon" and (abs(where[1]) > 180 or abs(where[3]) > 90)
    assert ("must be within" if bad_lonlat else "outside the DEM") in r.output
    if where[0] == "--lon" and "outside the DEM" in r.output:  # named as the user gave it
        assert f"lon {where[1]}, lat {where[3]}" in r.output
    assert "Traceback" not in r.output


def test_an_acquisition_is_profiled_in_the_databases_bins(tmp_path, files):
    """A store of 180 bins: the acquisition's profile was made with 360 and refused, after
    every image had been detected."""
    from skyfix.formats import Truth
    from skyfix.simulate import simulate_acquisition

    dem_path, _, db_path = files
    acq = simulate_acquisition(_dem(), Truth(412.0, 387.0, 40.0, 0.0, 0.0), tmp_path / "acq",
                               frames=12, seed=3)
    r = _run("locate", acq, "--db", db_path, "-o", tmp_path / "fix.json")
    assert r.exit_code == 0, r.output
    fix = json.loads((tmp_path / "fix.json").read_text())
    assert math.hypot(fix["x"] - 412.0, fix["y"] - 387.0) < 10.0


def test_evaluate_profiles_in_the_databases_bins(tmp_path, files):
    """Every scenario-1 case on a 180-bin store failed ('the profile has 360 azimuth bins')."""
    import csv

    dem_path, _, db_path = files
    r = _run("evaluate", "--dem", dem_path, "--scenario", 1, "--db", db_path, "--sets", "REF",
             "--cases", 1, "--seed", 2, "-o", tmp_path / "ev")
    assert r.exit_code == 0, r.output
    (row,) = list(csv.DictReader((tmp_path / "ev" / "results.csv").open()))
    assert row["status"] == "ok", row
    assert math.hypot(float(row["fix_x"]) - float(row["truth_x"]),
                      float(row["fix_y"]) - float(row["truth_y"])) < 10.0


def test_observable_bins_of_a_level_frame_and_a_panorama():
    """Closed form: a level pinhole frame of field of view H panned to p covers the azimuths
    p +- H/2 (every row of a level frame spans them: the widest is the horizon row), widened by
    the margin; a panorama covers its stated range."""
    from skyfix.camera import camera_from_fov
    from skyfix.formats import Acquisition, Frame, PanoramaSpec
    from skyfix.profile import observable_bins
    from skyfix.profile.acquisition import OBSERVABLE_MARGIN_DEG as m

    cam = camera_from_fov(640, 480, 30.0)
    one = Acquisition(root=".", camera=cam, camera_height_m=1.5, frames=(Frame("a", 100.0),))
    # centres 100 +- (15 + m) deg at 1 deg bins
    assert observable_bins(one, 360) == int(2 * (15 + m)) + 1
    two = Acquisition(root=".", camera=cam, camera_height_m=1.5,
                      frames=(Frame("a", 350.0), Frame("b", 10.0)))
    assert observable_bins(two, 360) == int(20 + 2 * (15 + m)) + 1  # 335 - m .. 25 + m
    pano = Acquisition(root=".", camera=None, camera_height_m=1.5,
                       panorama=PanoramaSpec("p", azimuth_left_deg=-30.0, hfov_deg=60.0))
    assert observable_bins(pano, 180) == int((60 + 2 * m) / 2) + 1  # -30 - m .. 30 + m, 2 deg
    assert observable_bins(replace_pano(pano, 359.0), 90) == 90


def replace_pano(acq, hfov):
    from dataclasses import replace

    return replace(acq, panorama=replace(acq.panorama, hfov_deg=hfov))


def test_a_view_too_narrow_to_search_is_refused_before_detection(tmp_path, files,
                                                                 detection_forbidden):
    """A 12 deg lens in one frame can fill at most 11 of 180 bins (20 deg with the margins for
    the pan refinement): the search needs 20. Said before any image is read (detection is the
    long part)."""
    from skyfix.camera import camera_from_fov
    from skyfix.formats import Acquisition, Frame, save_acquisition

    dem_path, _, db_path = files
    acq = tmp_path / "acq"
    acq.mkdir()
    (acq / "f0.png").write_bytes(b"not read")
    save_acquisition(acq, Acquisition(root=acq, camera=camera_from_fov(1024, 768, 12.0),
                                      camera_height_m=1.5, frames=(Frame("f0.png", 0.0, 0.0),)))
    r = _run("locate", acq, "--db", db_path, "--dem", dem_path)
    assert r.exit_code == 2, r.output
    assert "can observe at most 11 of the profile's 180 azimuth bins" in r.output
    assert "needs at least 20" in r.output and "Traceback" not in r.output


def test_a_forced_dem_of_other_terrain_caps_the_confidence_and_the_same_heights_do_not(tmp_path,
                                                                                     files):
    """``locate --force`` with another map (the same hills 35 m east) gave a confident fix on
    terrain the search never compared; the same heights in another file (a checksum apart, here
    0.1 mm) must keep their confidence. Told apart by re-rendering the database positions at the
    fix from the DEM given."""
    from skyfix.dem import load_dem
    from skyfix.pose.other_map import map_agreement

    dem_path, other_path, db_path = files
    db = open_database(db_path)
    prof = _profile(_dem())
    shifted = load_dem(other_path)
    assert shifted.checksum != db.dem_sha256
    fix = locate(prof, db=db, dem=shifted)
    assert fix.confidence <= DEGENERATE_CAP
    assert any("another map's terrain" in n for n in fix.notes), fix.notes
    same = load_dem(write_dem(tmp_path / "same.tif", Dem.from_array(_dem().z + 1e-4, CELL)))
    assert same.checksum != db.dem_sha256
    reason, note = map_agreement(db, same, 412.0, 387.0)
    assert reason is None and "the same terrain" in note
    fix = locate(prof, db=db, dem=same)
    assert np.hypot(fix.x - 412.0, fix.y - 387.0) < 1.0
    assert fix.confidence > 0.5 and any("the same terrain" in n for n in fix.notes), fix.notes
    assert map_agreement(db, load_dem(dem_path), 412.0, 387.0) == (None, None)


def test_every_candidate_of_a_fix_carries_the_same_kind_of_score(tmp_path):
    """Unrefined database candidates were listed with the search's unclipped mean of squares
    beside the refined ones' clipped cost (3.0 beside 0.17 deg^2 for a rival closer than that).
    A clipped cost is at most the clip squared (0.25 deg^2), and the unrefined ones' equal the
    clipped cost of their stored skyline at their heading, taken here directly."""
    from conftest import shared_dem_path
    from skyfix.dem import load_dem
    from skyfix.pose import PoseConfig
    from skyfix.pose.scoring import clipped_costs

    dem_path = shared_dem_path("south_glacier_20m")
    build_database(dem_path, tmp_path / "db.zarr", (601000, 6743000, 601630, 6743630), 10,
                   workers=0, progress=False, block=32)
    db, dem = open_database(tmp_path / "db.zarr"), load_dem(dem_path)
    prof = synthetic_profile(dem, 601312.3, 6743287.1, 40.0, noise_deg=0.1, rng=1, n_bins=360)
    fix = locate(prof, db=db, dem=dem, config=PoseConfig(refine_candidates=1))
    assert len(fix.candidates) >= 3
    assert all(0 <= c["score"] <= 0.25 for c in fix.candidates)
    q = prof.elevation_deg
    on_grid = [c for c in fix.candidates[1:]  # the unrefined ones stand on database positions
               if np.isin(c["x"], db.x_coords) and np.isin(c["y"], db.y_coords)]
    assert on_grid
    from skyfix.north import meridian_convergence_deg

    for c in on_grid:  # headings from true north, as the fix's: the grid's is the shift
        grid = c["heading_deg"] - meridian_convergence_deg(db.crs_wkt, c["x"], c["y"])
        want = clipped_costs(db.profiles_at([c["x"]], [c["y"]]), q, [grid * q.size / 360.0])[0]
        assert c["score"] == pytest.approx(want, rel=1e-6)
