"""Skyline database against damage and bad options: nothing is lost, nothing is read wrong.

A failed option check never costs the database --overwrite would replace; a chunk file deleted or
spoiled, or a zarr.json edited, is named (block, field) by every reader instead of giving a
traceback or a quietly wrong fix; an absurd grid is refused before any work; verify says what it
did not check. Small synthetic builds as in test_database (a tilted plane with two hills).
"""

from __future__ import annotations

import json
import re
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from skyfix.cli.main import cli
from skyfix.database import (MARKER_DIR, Grid, build_database, check_build_size, describe,
                             marker_name, open_database, verify_database)
from skyfix.dem import Dem, write_dem
from skyfix.errors import DatabaseError, ParameterError
from skyfix.match import MatchConfig, match_database

pytestmark = pytest.mark.filterwarnings("ignore:Numcodecs codecs are not in the Zarr")

CELL = 10.0
# 24 x 20 positions at 10 m in blocks of 8 x 8 -> 3 x 3 = 9 blocks (as in test_database).
BOUNDS = (300.0, 300.0, 530.0, 490.0)
SPACING = 10.0
BINS = 72


def _z(x, y):
    hills = (60 * np.exp(-((x - 150) ** 2 + (y - 650) ** 2) / 80**2)
             + 40 * np.exp(-((x - 700) ** 2 + (y - 200) ** 2) / 60**2))
    return 100 + 0.05 * y + hills


@pytest.fixture(scope="module")
def dem_path(tmp_path_factory):
    n = 81
    x = np.arange(n) * CELL
    y = (n - 1 - np.arange(n)) * CELL  # row 0 north
    path = tmp_path_factory.mktemp("dem") / "hills.tif"
    write_dem(path, Dem.from_array(_z(x[None, :], y[:, None]), CELL))
    return path


def _build(dem_path, out, **kw):
    kw = {"workers": 0, "progress": False, "azimuth_bins": BINS, "block": 8, **kw}
    return build_database(dem_path, out, BOUNDS, SPACING, **kw)


@pytest.fixture(scope="module")
def clean_db(dem_path, tmp_path_factory):
    out = tmp_path_factory.mktemp("clean") / "db.zarr"
    _build(dem_path, out)
    return out


def _files(root) -> dict:
    root = Path(root)
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _copy(clean_db, tmp_path, name="db.zarr") -> Path:
    out = tmp_path / name
    shutil.copytree(clean_db, out)
    return out


def _cli(*args):
    res = CliRunner().invoke(cli, [str(a) for a in args])
    assert "Traceback" not in res.output and not (
        res.exception and not isinstance(res.exception, SystemExit)), res.output
    return res


def _profile_file(db, tmp_path, row=10, col=12) -> Path:
    """A body-frame profile JSON: the stored skyline of one position, seen with heading 0."""
    x, y = db.xy_of(row, col)
    prof = db.profiles_at([x], [y])[0]
    p = tmp_path / "p.json"
    p.write_text(json.dumps({"elevation_deg": [round(float(v), 3) for v in prof], "frame": "body"}))
    return p


# --- 1: no option failure costs the database ---------------------------------------------------
@pytest.mark.parametrize("opts, says", [
    (["--workers", "-1"], "--workers must be a whole number >= 0"),
    (["--workers", "0", "--scheduler", "tcp://127.0.0.1:9"], "either --workers or --scheduler"),
    (["--scheduler", "notanaddress"], "not a Dask scheduler address (missing port number"),
    (["--scheduler", "foo://1.2.3.4:5"], "not a Dask scheduler address (unknown address scheme"),
])
def test_overwrite_with_bad_executor_options_keeps_the_database(dem_path, clean_db, tmp_path, opts, says):
    db = _copy(clean_db, tmp_path)
    before = _files(db)
    res = _cli("build-db", dem_path, "-o", db, "--bounds", *BOUNDS, "--spacing-m", SPACING,
               "--azimuth-bins", BINS, "--block-positions", 8, "--overwrite", "--no-progress", *opts)
    assert res.exit_code == 2 and says in res.output, res.output
    assert _files(db) == before  # not one byte deleted
    # A fresh output: refused before a store skeleton is created.
    fresh = tmp_path / "fresh.zarr"
    res = _cli("build-db", dem_path, "-o", fresh, "--bounds", *BOUNDS, "--spacing-m", SPACING,
               "--no-progress", *opts)
    assert res.exit_code == 2 and says in res.output and not fresh.exists()
    assert not list(tmp_path.glob(".fresh.zarr*"))


def test_unreachable_scheduler_keeps_the_database(dem_path, clean_db, tmp_path, monkeypatch):
    """The scheduler is reached before --overwrite deletes anything (a real unreachable one takes
    20 s to time out: the connection failure is simulated)."""
    import dask.distributed

    def refuse(address, **kw):
        raise OSError(f"Timed out trying to connect to {address} after 20 s")

    monkeypatch.setattr(dask.distributed, "Client", refuse)
    db = _copy(clean_db, tmp_path)
    before = _files(db)
    with pytest.raises(ParameterError, match="cannot reach the Dask scheduler at tcp://127.0.0.1:9"):
        _build(dem_path, db, workers=None, scheduler="tcp://127.0.0.1:9", overwrite=True)
    assert _files(db) == before


# --- 2: a chunk file deleted ---------------------------------------------------------------------
def test_deleted_chunk_is_named_by_open_info_search_and_locate_then_resume_rebuilds_it(
        dem_path, clean_db, tmp_path):
    db_path = _copy(clean_db, tmp_path)
    (db_path / "elevation" / "c" / "1" / "1" / "0").unlink()  # block (1, 1) reads as fill values
    says = r"block \(1, 1\) data missing \(no chunk file for elevation\).*skyfix verify.*resumes"
    with pytest.raises(DatabaseError, match=says):
        open_database(db_path)
    # info: described, flagged, exit 2 (it said "9 of 9 blocks (complete)")
    res = _cli("info", db_path)
    assert res.exit_code == 2 and "(complete)" not in res.output
    assert "DAMAGED: 1 of them without their data files" in res.output
    assert "block (1, 1) data missing" in res.output
    d = describe(db_path)
    assert not d["complete"] and d["blocks_data_missing"] == [[1, 1]]
    # The search itself, on a store opened as incomplete, and on the read API
    db = open_database(db_path, allow_incomplete=True)
    assert not db.is_complete and db.blocks_data_missing == [(1, 1)]
    good = open_database(clean_db)
    q = good.profiles_at(*good.xy_of(np.array([10]), np.array([12])))[0]  # a position of block (1, 1)
    with pytest.raises(DatabaseError, match=r"block \(1, 1\) data missing"):
        match_database(db, q, MatchConfig(min_observed=10))
    with pytest.raises(DatabaseError, match=r"block \(1, 1\) data missing"):
        db.read_block(1, 1)
    # locate: a clear refusal (it gave a fix 80 m off without a word)
    res = _cli("locate", "--profile", _profile_file(good, tmp_path), "--db", db_path)
    assert res.exit_code == 2 and "block (1, 1) data missing" in res.output, res.output
    # verify names it; the same build command redoes exactly that block
    rep = verify_database(db_path, samples=0)
    assert dict(rep.corrupt) == {(1, 1): "data missing: no chunk file for elevation"}
    r = _build(dem_path, db_path)
    assert r.built == 1 and r.resumed_from == 8
    assert _files(db_path) == _files(clean_db)


def test_deleted_ground_chunk_is_named_too(clean_db, tmp_path):
    db_path = _copy(clean_db, tmp_path)
    (db_path / "ground_z" / "c" / "2" / "0").unlink()
    with pytest.raises(DatabaseError, match=r"block \(2, 0\) data missing \(no chunk file for ground_z\)"):
        open_database(db_path)
    db = open_database(db_path, allow_incomplete=True)
    x, y = db.xy_of(17, 3)
    with pytest.raises(DatabaseError, match=r"block \(2, 0\) data missing"):
        db.ground_z_at([x], [y])
    np.testing.assert_array_equal(db.read_raw("elevation", 2, 0),
                                  open_database(clean_db).read_raw("elevation", 2, 0))


# --- 3: a chunk file spoiled ---------------------------------------------------------------------
@pytest.mark.parametrize("spoil", ["truncate", "garbage", "empty"])
def test_spoiled_chunk_names_the_block_in_search_and_locate(clean_db, tmp_path, spoil):
    db_path = _copy(clean_db, tmp_path)
    # block (1, 1) holds the query's position: its skylines are scored exactly in every search
    chunk = db_path / "elevation" / "c" / "1" / "1" / "0"
    data = chunk.read_bytes()
    chunk.write_bytes({"truncate": data[:len(data) // 2], "garbage": b"\x00junk" * 50, "empty": b""}[spoil])
    db = open_database(db_path)  # the file is there: only decoding it tells
    says = r"block \(1, 1\) data unreadable \(elevation chunk: .*skyfix verify.*r0001_c0001/zarr.json"
    q = open_database(clean_db).profiles_at(*db.xy_of(np.array([10]), np.array([12])))[0]
    for prefetch, index in ((True, True), (False, True), (True, False), (False, False)):
        with pytest.raises(DatabaseError, match=says):
            match_database(db, q, MatchConfig(min_observed=10, prefetch=prefetch, coarse_index=index))
    with pytest.raises(DatabaseError, match=says):
        db.profiles_at(*db.xy_of(np.array([9]), np.array([9])))
    res = _cli("locate", "--profile", _profile_file(open_database(clean_db), tmp_path), "--db", db_path)
    assert res.exit_code == 2 and "block (1, 1) data unreadable" in res.output, res.output
    rep = verify_database(db_path, samples=0)
    assert [b for b, _ in rep.corrupt] == [(1, 1)]


def test_swapped_chunks_are_named_by_their_checksums_in_search_and_locate(clean_db, tmp_path):
    """Two blocks' elevation chunk files swapped decode without a fault (zstd checks only that a
    file is whole): the search checks each block it decodes against its marker's checksums and
    names the block, where it gave a confident fix (verify alone caught it)."""
    good = open_database(clean_db)
    q = good.profiles_at(*good.xy_of(np.array([10]), np.array([12])))[0]  # block (1, 1)
    best = match_database(good, q, MatchConfig(min_observed=10)).candidates[0]
    assert (best.row, best.col) == (10, 12)  # the undamaged store: the known answer
    db_path = _copy(clean_db, tmp_path)
    a, b = (db_path / "elevation" / "c" / "1" / "1" / "0"), (db_path / "elevation" / "c" / "0" / "1" / "0")
    da, db_ = a.read_bytes(), b.read_bytes()
    a.write_bytes(db_)
    b.write_bytes(da)
    db = open_database(db_path)  # both files there and whole: only their checksums tell
    says = (r"block \((1, 1|0, 1)\) elevation differs from the checksum its marker recorded .*swapped"
            r".*skyfix verify.*r000[01]_c0001/zarr.json\) and rerun the build-db command")
    for prefetch, index in ((True, True), (False, True), (True, False), (False, False)):
        with pytest.raises(DatabaseError, match=says):
            match_database(db, q, MatchConfig(min_observed=10, prefetch=prefetch, coarse_index=index))
    with pytest.raises(DatabaseError, match=r"block \(1, 1\) elevation differs from the checksum"):
        db.profiles_at(*db.xy_of(np.array([9]), np.array([9])))
    res = _cli("locate", "--profile", _profile_file(good, tmp_path), "--db", db_path)
    assert res.exit_code == 2 and re.search(says, res.output), res.output
    rep = verify_database(db_path, samples=0)
    assert sorted(b for b, _ in rep.corrupt) == [(0, 1), (1, 1)]
    # a marker that cannot be read is named as such when its block is decoded
    (db_path / MARKER_DIR / marker_name(1, 1)).write_text("{oops")
    with pytest.raises(DatabaseError, match=r"block \(1, 1\) marker unreadable .*skyfix verify"):
        open_database(db_path).read_block(1, 1)


def test_spoiled_coarse_index_chunk_is_named_and_redone(dem_path, clean_db, tmp_path):
    """The coarse index is derived data: a spoiled chunk of it is named with what to delete, and
    the build command makes it again from the stored skylines (nothing re-rendered)."""
    db_path = _copy(clean_db, tmp_path)
    chunk = db_path / "coarse" / "c" / "1" / "1" / "0"
    chunk.write_bytes(chunk.read_bytes()[:40])
    db = open_database(db_path)
    q = db.profiles_at(*db.xy_of(np.array([10]), np.array([12])))[0]
    with pytest.raises(DatabaseError, match=r"block \(1, 1\) coarse index unreadable .*delete .*"
                                            r"coarse/c/1/1/0 and rerun the build-db command"):
        match_database(db, q, MatchConfig(min_observed=10))
    rep = verify_database(db_path, samples=0)
    assert [b for b, _ in rep.corrupt] == [(1, 1)] and "coarse index" in dict(rep.corrupt)[(1, 1)]
    chunk.unlink()
    assert not open_database(db_path).has_coarse_index
    # without its index the store is searched the older way, with the same answer
    old = match_database(open_database(db_path), q, MatchConfig(min_observed=10))
    new = match_database(open_database(clean_db), q, MatchConfig(min_observed=10))
    assert (old.candidates[0].row, old.candidates[0].col) == (new.candidates[0].row, new.candidates[0].col)
    r = _build(dem_path, db_path)
    assert r.built == 0
    assert _files(db_path) == _files(clean_db)


# --- 4: metadata damaged -------------------------------------------------------------------------
RECORD = "its metadata disagrees with its build record: "


@pytest.mark.parametrize("key, value, says", [
    ("grid.spacing_m", "twenty", "grid.spacing_m must be a number > 0, got 'twenty'"),
    ("grid.spacing_m", 0, "grid.spacing_m must be a number > 0, got 0"),
    ("grid.shape", [20], "grid.shape must be two whole numbers > 0"),
    ("grid.x0", None, "grid.x0 must be a number, got None"),
    ("azimuth_bins", "72", "azimuth_bins must be a whole number > 0, got '72'"),
    ("camera_height_m", "1.5", "camera_height_m must be a number, got '1.5'"),
    ("planet.radius_m", None, "planet.radius_m must be a number > 0"),
    ("elevation.scale_deg", "0.01", "elevation.scale_deg must be a number > 0"),
    ("dem", "hills.tif", "dem must be an object"),
    ("format_version", "1", "format_version must be a whole number"),
    # numbers of the right kind that are not what was built: the search read them as the store's
    # geometry and answered from it (verify --samples 0 passed)
    ("grid.shape", [20, 25], RECORD + "grid.shape [20, 25] (the build made [20, 24])"),
    ("azimuth_bins", 36, RECORD + "azimuth_bins 36 (the build made 72)"),
    ("grid.spacing_m", 20.0, RECORD + "grid.spacing_m 20.0 (the build made 10.0)"),
    ("grid.x0", 400.0, RECORD + "grid.x0 400.0 (the build made 300.0)"),
    ("elevation.scale_deg", 0.02, RECORD + "elevation.scale_deg 0.02 (the build made 0.01)"),
])
def test_damaged_metadata_is_named(clean_db, tmp_path, key, value, says):
    db_path = _copy(clean_db, tmp_path)
    f = db_path / "zarr.json"
    meta = json.loads(f.read_text())
    d = meta["attributes"]
    *parents, last = key.split(".")
    for k in parents:
        d = d[k]
    d[last] = value
    f.write_text(json.dumps(meta))
    with pytest.raises(DatabaseError, match="database metadata damaged: " + re.escape(says)):
        open_database(db_path)
    for args in (["info", db_path], ["verify", db_path, "--samples", "0"],
                 ["locate", "--profile", _profile_file(open_database(clean_db), tmp_path), "--db", db_path]):
        res = _cli(*args)
        assert res.exit_code == 2 and says in res.output, (args, res.output)


@pytest.mark.parametrize("content, says", [
    (b"", r"zarr.json cannot be read \(it is empty\)"),
    (b'{"attributes": {"format": "skyfix-skyline-db", "gr', r"zarr.json cannot be read \(JSONDecodeError"),
    (b"\x00\xff", "zarr.json cannot be read"),
    (b"[1, 2]", "zarr.json holds a JSON list, not an object"),
    (None, "zarr.json is missing"),
])
def test_truncated_or_empty_zarr_json_is_called_damaged(dem_path, clean_db, tmp_path, content, says):
    db_path = _copy(clean_db, tmp_path)
    if content is None:
        (db_path / "zarr.json").unlink()
    else:
        (db_path / "zarr.json").write_bytes(content)
    with pytest.raises(DatabaseError, match=r"database metadata damaged: .*" + says):
        open_database(db_path)
    res = _cli("info", db_path)
    assert res.exit_code == 2 and "metadata damaged" in res.output and "not a skyfix" not in res.output
    # build-db: recognisably ours (its _skyfix folder), so --overwrite may rebuild it
    with pytest.raises(DatabaseError, match="metadata are damaged.*pass --overwrite"):
        _build(dem_path, db_path)
    if content == b"":
        r = _build(dem_path, db_path, overwrite=True)
        assert r.built == 9 and _files(db_path) == _files(clean_db)


# --- 5: absurd grids refused up front -----------------------------------------------------------
def test_oversized_grid_is_refused_before_any_work(dem_path, tmp_path):
    out = tmp_path / "huge.zarr"
    t = time.perf_counter()
    with pytest.raises(ParameterError, match=r"the grid has 43,700,420,001 positions .*, about 9,"
                                             r"\d{3} GB on disk.*raise "
                                             r"--spacing-m or narrow --bounds"):
        build_database(dem_path, out, BOUNDS, 0.001, workers=0, progress=False)
    assert time.perf_counter() - t < 5 and not out.exists()
    with pytest.raises(ParameterError, match="far too small"):
        build_database(dem_path, out, BOUNDS, 1e-320, workers=0, progress=False)
    res = _cli("build-db", dem_path, "-o", out, "--bounds", *BOUNDS, "--spacing-m", "0.001")
    assert res.exit_code == 2 and "raise --spacing-m" in res.output and not out.exists()
    # Many bins make a moderate grid large on disk: refused by the size estimate.
    with pytest.raises(ParameterError, match="GB on disk"):
        check_build_size(Grid.from_bounds((0, 0, 20000, 20000), 1), 65535)
    # The project's own 7 x 7 km area at 5 m (1.96 M skylines, 425 MB) and far larger stay allowed.
    check_build_size(Grid.from_bounds((0, 0, 7000, 7000), 5), 360)
    check_build_size(Grid.from_bounds((0, 0, 100000, 100000), 5), 360)


# --- 6: verify says what it did not check -------------------------------------------------------
def test_verify_reports_skipped_and_clipped_samples(dem_path, clean_db, tmp_path):
    db_path = _copy(clean_db, tmp_path)
    f = db_path / "zarr.json"
    meta = json.loads(f.read_text())
    meta["attributes"]["dem"]["source"] = str(tmp_path / "gone.tif")  # the DEM moved away
    f.write_text(json.dumps(meta))
    res = _cli("verify", db_path)
    assert res.exit_code == 3, res.output
    assert "samples  SKIPPED: the DEM recorded at build time" in res.output and "gone.tif" in res.output
    assert "pass --dem" in res.output and "PARTIAL" in res.output and "\nOK" not in res.output
    rep = verify_database(db_path)
    assert rep.ok and rep.samples == 0 and "not there" in rep.samples_skipped
    res = _cli("verify", db_path, "--samples", "0")  # checksums only, as asked: a full OK
    assert res.exit_code == 0 and "OK (checksums only)" in res.output
    res = _cli("verify", db_path, "--dem", dem_path, "--samples", "3")
    assert res.exit_code == 0 and "3 positions re-rendered" in res.output and "\nOK" in res.output
    # More samples than positions: every position once, and the true count reported.
    res = _cli("verify", db_path, "--dem", dem_path, "--samples", "100000")
    assert res.exit_code == 0 and "480 positions re-rendered" in res.output
    assert "100000 samples asked for, but the intact blocks hold 480 positions" in res.output
    rep = verify_database(clean_db, dem=dem_path, samples=50, seed=4)
    assert rep.ok and rep.samples == 50 and not rep.notes
    res = _cli("verify", db_path, "--samples", "-1")
    assert res.exit_code == 2 and "samples must be a whole number >= 0" in res.output
    with pytest.raises(ParameterError, match="samples must be"):
        verify_database(db_path, samples=2.5)
    # Damage still wins over a skipped sample: exit 2.
    (db_path / MARKER_DIR / marker_name(0, 0)).unlink()
    assert _cli("verify", db_path).exit_code == 2


def test_info_of_a_store_with_nothing_built(dem_path, clean_db, tmp_path):
    """A store whose first block never finished: no made-up bytes-per-skyline figure."""
    db_path = _copy(clean_db, tmp_path)
    for m in (db_path / MARKER_DIR).glob("r*/zarr.json"):
        m.unlink()
    res = _cli("info", db_path)
    assert res.exit_code == 0 and "0 of 9 blocks (INCOMPLETE" in res.output
    assert "no skyline built yet" in res.output
    assert describe(db_path)["bytes_per_skyline"] is None


def test_build_db_out_through_a_file_is_named_before_any_work(tmp_path):
    from click.testing import CliRunner

    from skyfix.cli.main import cli

    plain = tmp_path / "plain.json"
    plain.write_text("{}")
    dem = tmp_path / "missing.tif"  # never read: the output is refused first
    for out in (plain / "db.zarr", plain):
        r = CliRunner().invoke(cli, ["build-db", str(dem), "-o", str(out), "--bounds", "0", "0", "10", "10",
                                     "--spacing-m", "5"])
        assert r.exit_code == 2, r.output
        assert f"{plain} is a file, not a folder" in r.output and "creating" not in r.output
    assert plain.read_text() == "{}"


# --- a second build, an unwritable place, markers that only look like markers ------------------
def test_overwrite_where_the_new_store_cannot_be_staged_keeps_the_old_one(dem_path, clean_db,
                                                                          tmp_path, monkeypatch):
    """--overwrite deleted the store, then failed to stage the new one beside it (a folder the
    user cannot write): all of it lost. Now the place is probed first (EACCES simulated: root
    writes anywhere)."""
    import tempfile

    db = _copy(clean_db, tmp_path)
    before = _files(db)
    real = tempfile.mkstemp

    def refuse(*a, dir=None, **kw):
        if dir is not None and Path(dir) == tmp_path:
            raise PermissionError(13, "Permission denied", str(dir))
        return real(*a, dir=dir, **kw)

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    res = _cli("build-db", dem_path, "-o", db, "--bounds", *BOUNDS, "--spacing-m", SPACING,
               "--azimuth-bins", BINS, "--block-positions", 8, "--overwrite", "--no-progress",
               "--workers", 0, "--camera-height-m", 2)
    assert res.exit_code == 2 and f"cannot write {db}" in res.output, res.output
    assert "not writable" in res.output
    assert _files(db) == before


def test_a_second_build_of_the_same_store_is_refused_while_the_first_runs(dem_path, tmp_path):
    """Two builds of one store at once: the second deleted the first's staging folder, the first
    crashed, and the store was left with neither's parameters."""
    from skyfix.database.build import build_lock

    out = tmp_path / "db.zarr"
    with build_lock(out):  # the first build, holding its lock
        with pytest.raises(DatabaseError, match="another skyfix build-db is writing .*db.zarr"):
            _build(dem_path, out)
        assert not out.exists()
    r = _build(dem_path, out)  # once it is done, the same command runs
    assert r.built == r.n_blocks
    assert sorted(p.name for p in tmp_path.iterdir()) == ["db.zarr"]  # no lock file left


@pytest.mark.parametrize("marker", ["[]", '"x"', '{"zarr_format": 3, "attributes": null}'])
def test_a_marker_that_is_not_a_record_is_corrupt_to_verify_and_rebuilt(dem_path, clean_db,
                                                                        tmp_path, marker):
    """Valid JSON that is not a block's record: verify crashed (a list indexed by a string) or
    called the block missing while build-db called the store complete."""
    db = _copy(clean_db, tmp_path)
    f = db / MARKER_DIR / "r0001_c0001" / "zarr.json"
    f.write_text(marker)
    res = _cli("verify", db, "--samples", 0)
    assert res.exit_code == 2 and "block (1, 1)" in res.output and "marker unreadable" in res.output
    r = _build(dem_path, db)  # redone, not "already complete"
    assert r.built == 1
    assert _cli("verify", db, "--samples", 0).exit_code == 0


def test_a_marker_outside_the_grid_and_arrays_without_metadata(dem_path, clean_db, tmp_path):
    """A block's marker moved to a name outside the grid: build-db said complete while info and
    locate said 8 of 9. An array's metadata gone: build-db said complete, everything else said
    damaged. Now the build redoes the block, and names the damage with what to do."""
    db = _copy(clean_db, tmp_path)
    (db / MARKER_DIR / "r0001_c0001").rename(db / MARKER_DIR / "r0009_c0009")
    assert _build(dem_path, db).built == 1
    (db / "elevation" / "zarr.json").unlink()
    with pytest.raises(DatabaseError, match="arrays cannot be opened .*--overwrite"):
        _build(dem_path, db)
    assert _build(dem_path, db, overwrite=True).built == 9


def test_overwrite_through_a_symbolic_link_is_refused(dem_path, clean_db, tmp_path):
    db = _copy(clean_db, tmp_path)
    link = tmp_path / "link.zarr"
    link.symlink_to(db)
    res = _cli("build-db", dem_path, "-o", link, "--bounds", *BOUNDS, "--spacing-m", SPACING,
               "--azimuth-bins", BINS, "--block-positions", 8, "--overwrite", "--no-progress",
               "--workers", 0)
    assert res.exit_code == 2 and "is a symbolic link" in res.output, res.output
    assert link.is_symlink() and (db / "zarr.json").is_file()
