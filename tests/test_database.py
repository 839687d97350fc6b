"""Skyline database: grid, storage, resume after a crash, reading API, verify, errors.

All builds run on a small synthetic DEM (a tilted plane with two hills) so they take seconds;
the renderer itself is tested against its slow reference in test_horizon.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zarr
from click.testing import CliRunner

from skyfix.cli.main import cli
from skyfix.database import (MARKER_DIR, MISSING, SCALE_DEG, SKIP_TOL_DEG, Grid, build_database,
                             marker_name, open_database, quantise, verify_database)
from skyfix.database.chunks import chunk_reader
from skyfix.database.layout import coarse_of
from skyfix.database.tasks import tasks_of
from skyfix.dem import Dem, file_checksum, load_dem, write_dem
from skyfix.errors import DatabaseError, OutputExistsError, OutsideDemError, ParameterError
from skyfix.horizon import render_horizons
from skyfix.planets import MARS

pytestmark = pytest.mark.filterwarnings("ignore:Numcodecs codecs are not in the Zarr")

SRC = Path(__file__).resolve().parents[1] / "src"
CELL = 10.0
SLOPE = 0.05  # ground rises 5 m per 100 m northwards
# The build area: 24 x 20 positions at 10 m, cut into 8 x 8 blocks -> 3 x 3 = 9 blocks.
BOUNDS = (300.0, 300.0, 530.0, 490.0)
SPACING = 10.0


def _z(x, y):
    hills = (60 * np.exp(-((x - 150) ** 2 + (y - 650) ** 2) / 80**2)
             + 40 * np.exp(-((x - 700) ** 2 + (y - 200) ** 2) / 60**2))
    return 100 + SLOPE * y + hills


@pytest.fixture(scope="module")
def dem_path(tmp_path_factory):
    n = 81
    x = np.arange(n) * CELL
    y = (n - 1 - np.arange(n)) * CELL  # row 0 north
    z = _z(x[None, :], y[:, None])
    path = tmp_path_factory.mktemp("dem") / "hills.tif"
    write_dem(path, Dem.from_array(z, CELL))
    return path


def _build(dem_path, out, **kw):
    kw = {"workers": 0, "progress": False, "azimuth_bins": 72, "block": 8, **kw}
    return build_database(dem_path, out, BOUNDS, SPACING, **kw)


def _files(root) -> dict:
    root = Path(root)
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def clean_db(dem_path, tmp_path_factory):
    out = tmp_path_factory.mktemp("clean") / "db.zarr"
    _build(dem_path, out)
    return out


# --- grid and content --------------------------------------------------------------------------
def test_grid_convention():
    g = Grid.from_bounds((0, 0, 7000, 7000), 5)
    assert g.shape == (1401, 1401)  # both edges included when the spacing divides the extent
    g = Grid.from_bounds((100, 50, 125, 62), 5, block=4)
    assert g.shape == (3, 6) and g.n_blocks == (1, 2)
    np.testing.assert_array_equal(g.x_coords, [100, 105, 110, 115, 120, 125])
    np.testing.assert_array_equal(g.y_coords, [62, 57, 52])  # row 0 north, from ymax down
    x, y = g.block_xy(0, 1)  # columns 4, 5; row-major within the block
    np.testing.assert_array_equal(x, [120, 125, 120, 125, 120, 125])
    np.testing.assert_array_equal(y, [62, 62, 57, 57, 52, 52])


def test_quantise_rounds_to_nearest_step_and_marks_missing():
    q = quantise(np.array([0.004, 0.006, -0.016, 12.3449, 12.3451, -89.996, np.nan], np.float32))
    np.testing.assert_array_equal(q, [0, 1, -2, 1234, 1235, -9000, MISSING])


def test_stored_skylines_match_the_renderer_and_ground_is_the_plane(clean_db, dem_path):
    db = open_database(clean_db)
    dem = load_dem(dem_path)
    assert db.is_complete and db.shape == (20, 24)
    seen = 0
    for blk in db.iter_blocks():
        assert blk.rows * blk.cols == blk.elevation.shape[0] <= 64  # one block at a time
        hb = render_horizons(dem, blk.x, blk.y, camera_height_m=1.5, azimuth_bins=72,
                             skip_tol_deg=db.attrs["build"]["skip_tol_deg"])
        ok = np.isfinite(hb.elevation_deg)
        assert ok.all()  # hills and slope: every ray sees terrain here
        stored = blk.elevation.astype(float) * db.scale_deg
        assert np.abs(stored - hb.elevation_deg).max() <= SCALE_DEG / 2 + 1e-6
        # Ground height: the closed form of the synthetic surface (bilinear error is tiny here).
        np.testing.assert_allclose(blk.ground_z_m, _z(blk.x, blk.y), atol=0.05)
        seen += blk.rows * blk.cols
    assert seen == 20 * 24


def test_positions_and_profiles_at(clean_db, dem_path):
    db = open_database(clean_db)
    np.testing.assert_array_equal(db.x_coords, 300 + 10 * np.arange(24))
    np.testing.assert_array_equal(db.y_coords, 490 - 10 * np.arange(20))
    row, col = db.index_of([303.0, 529.0], [487.0, 301.0])
    np.testing.assert_array_equal(row, [0, 19])
    np.testing.assert_array_equal(col, [0, 23])
    x, y = db.xy_of(row, col)
    np.testing.assert_array_equal(x, [300, 530])
    np.testing.assert_array_equal(y, [490, 300])
    # Points spread over several blocks, asked for in a scrambled order.
    rng = np.random.default_rng(3)
    r, c = rng.integers(0, 20, 30), rng.integers(0, 24, 30)
    x, y = db.xy_of(r, c)
    prof = db.profiles_at(x + 2.0, y - 2.0)  # nearest position
    hb = render_horizons(load_dem(dem_path), x, y, azimuth_bins=72, skip_tol_deg=SKIP_TOL_DEG)
    assert prof.dtype == np.float32 and prof.shape == (30, 72)
    assert np.abs(prof - hb.elevation_deg).max() <= SCALE_DEG / 2 + 1e-6
    np.testing.assert_allclose(db.ground_z_at(x, y), hb.ground_z_m, atol=1e-3)
    with pytest.raises(ParameterError, match="outside the database grid"):
        db.profiles_at([0.0], [0.0])


def test_attributes_round_trip(dem_path, tmp_path):
    out = tmp_path / "mars.zarr"
    _build(dem_path, out, planet="mars", camera_height_m=2.0, max_distance_m=300.0, azimuth_bins=36)
    db = open_database(out)
    dem = load_dem(dem_path)
    assert db.planet == MARS
    assert db.camera_height_m == 2.0 and db.max_distance_m == 300.0 and db.azimuth_bins == 36
    assert db.spacing_m == SPACING and db.scale_deg == SCALE_DEG and db.missing == MISSING
    assert db.crs_wkt == dem.crs_wkt and db.attrs["crs_name"] == dem.crs_name
    a = db.attrs
    assert a["dem"]["sha256"] == file_checksum(dem_path)
    assert a["grid"]["x0"] == 300.0 and a["grid"]["y0"] == 490.0 and a["grid"]["shape"] == [20, 24]
    assert a["build"]["bounds"] == list(BOUNDS) and a["software_version"]
    np.testing.assert_array_equal(db.azimuth_deg, np.arange(36) * 10.0)
    # Rays capped at 300 m inside an 800 m DEM: the edge count is 0 where the DEM edge is further.
    blk = next(db.iter_blocks())
    assert np.all(blk.min_ray_m <= 300.0 + 1e-3)
    # Zarr metadata carry dimension names for xarray-style readers.
    meta = json.loads((out / "elevation" / "zarr.json").read_text())
    assert meta["dimension_names"] == ["y", "x", "azimuth"]


def test_the_store_is_a_clean_zarr_hierarchy(clean_db):
    """zarr opens the store and walks every node without calling anything unknown (the block
    markers are groups whose attributes hold the checksums); the one warning left is zarr's
    notice that the numcodecs delta and shuffle codecs are outside the v3 core spec."""
    import warnings

    import zarr

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        g = zarr.open_group(str(clean_db), mode="r")
        names = sorted(k for k, _ in g.members(max_depth=None))
        marker = g[f"{MARKER_DIR}/r0000_c0000"].attrs.asdict()
        elev = g["elevation"][:2, :2]
    msgs = [str(w.message) for w in caught]
    assert not [m for m in msgs if "not recognized" in m], msgs
    assert all("Numcodecs codecs" in m for m in msgs), msgs
    assert "elevation" in names and f"{MARKER_DIR}/r0000_c0000" in names
    assert marker["block"] == [0, 0] and set(marker["sha256"]) >= {"elevation"}
    assert elev.shape[:2] == (2, 2)


def test_xarray_opens_the_store_with_its_dimensions(clean_db):
    """``xarray.open_zarr`` reads the data arrays with named dimensions and the same values as
    skyfix's own reader; zarr's numcodecs notice is the one warning (a documented choice: the
    delta codec makes the database 38 % smaller)."""
    import warnings

    xr = pytest.importorskip("xarray")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ds = xr.open_zarr(str(clean_db), consolidated=False)
        elev = ds["elevation"].values
    msgs = [str(w.message) for w in caught]
    assert all("Numcodecs codecs" in m for m in msgs), msgs
    assert ds["elevation"].dims == ("y", "x", "azimuth")
    db = open_database(clean_db)
    raw = db.profiles_at(db.x_coords[:3], np.full(3, db.y_coords[1]))
    got = elev[1, :3].astype(np.float32) * np.float32(SCALE_DEG)
    got[elev[1, :3] == MISSING] = np.nan
    np.testing.assert_array_equal(got, raw)


def test_a_store_with_the_older_marker_files_still_opens_and_verifies(clean_db, tmp_path):
    """Stores built before markers were zarr groups hold rRRRR_cCCCC.json files: still read."""
    import shutil

    old = tmp_path / "old.zarr"
    shutil.copytree(clean_db, old)
    for mp in sorted((old / MARKER_DIR).glob("r*_c*/zarr.json")):
        (mp.parent.parent / f"{mp.parent.name}.json").write_text(
            json.dumps(json.loads(mp.read_text())["attributes"]))
        shutil.rmtree(mp.parent)
    assert open_database(old).n_blocks == open_database(clean_db).n_blocks
    assert verify_database(old).ok


def test_edge_bins_count_rays_that_hit_the_dem_edge(dem_path, tmp_path):
    # Without a distance limit every ray stops at the DEM edge; with a short one, none does.
    out = tmp_path / "short.zarr"
    _build(dem_path, out, max_distance_m=50.0, azimuth_bins=36)
    blk = next(open_database(out).iter_blocks())
    assert np.all(blk.edge_bins == 0) and np.allclose(blk.min_ray_m, 50.0)
    out2 = tmp_path / "full.zarr"
    _build(dem_path, out2, azimuth_bins=36)
    blk = next(open_database(out2).iter_blocks())
    assert np.all(blk.edge_bins == 36)
    # The north-west position (300, 490) is 300 m from the west edge (x = 0) of the DEM.
    assert blk.min_ray_m[0] == pytest.approx(300.0, abs=0.01)


# --- executors and resume ----------------------------------------------------------------------
def test_local_cluster_build_equals_in_process(dem_path, clean_db, tmp_path):
    out = tmp_path / "cluster.zarr"
    environ = dict(os.environ)
    r = _build(dem_path, out, workers=2)
    assert r.built == 9 and r.positions == 480
    assert _files(out) == _files(clean_db)
    # Dask puts its workers' malloc settings into this process's environment; the build takes
    # them out again, or every later child process (a test's, a pipeline's) inherits them.
    assert dict(os.environ) == environ



def _worker_env(_):
    return {k: os.environ.get(k) for k in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_",
                                           "OMP_NUM_THREADS")}


def test_cluster_workers_keep_render_buffers_on_the_heap():
    """The workers start with glibc's mmap threshold at 16 MiB, not Dask's 128 KiB (every render
    buffer a fresh mapping); Dask's thread caps stay."""
    from skyfix.database.executors import make_executor

    with make_executor(workers=1) as (ex, slots, _):
        env = ex.submit(_worker_env, 0).result()
    assert slots == 1
    assert env == {"MALLOC_MMAP_THRESHOLD_": str(16 << 20),
                   "MALLOC_TRIM_THRESHOLD_": str(64 << 20), "OMP_NUM_THREADS": "1"}

def test_killed_build_resumes_to_an_identical_store(dem_path, tmp_path):
    """kill -9 a real build mid-way, rerun the same command: byte-identical to a clean build."""
    out = tmp_path / "killed.zarr"
    # Many small, slow blocks (1440 bins) so the kill lands mid-build.
    args = [str(dem_path), "--out", str(out), "--bounds", *map(str, BOUNDS), "--spacing-m", "10",
            "--azimuth-bins", "1440", "--block-positions", "4", "--workers", "0", "--no-progress"]
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    proc = subprocess.Popen([sys.executable, "-m", "skyfix.cli.main", "build-db", *args], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    markers = out / MARKER_DIR
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        if markers.is_dir() and len(list(markers.glob("r*/zarr.json"))) >= 3:
            break
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    n_done = len(list(markers.glob("r*/zarr.json")))
    assert 3 <= n_done < 30, f"the kill should land mid-build ({n_done} of 30 blocks done)"
    with pytest.raises(DatabaseError, match="incomplete"):
        open_database(out)
    res = CliRunner().invoke(cli, ["build-db", *args])
    assert res.exit_code == 0, res.output
    assert "already there" in res.output
    clean = tmp_path / "clean.zarr"
    build_database(dem_path, clean, BOUNDS, 10, azimuth_bins=1440, block=4, workers=0, progress=False)
    assert _files(out) == _files(clean)


def test_resume_redoes_blocks_without_markers(dem_path, clean_db, tmp_path):
    """Crash states: chunks written but no marker (garbage inside), zarr's temporary files."""
    import shutil

    import zarr

    out = tmp_path / "crashed.zarr"
    shutil.copytree(clean_db, out)
    g = zarr.open_group(str(out), mode="r+")
    g["elevation"][8:16, 8:16] = 7  # half-written block: wrong data, then died before the marker
    (out / MARKER_DIR / marker_name(1, 1)).unlink()
    (out / MARKER_DIR / marker_name(2, 0)).unlink()
    (out / "elevation" / "c" / "1" / "1" / "0.abc.partial").write_bytes(b"junk")
    r = _build(dem_path, out)
    assert r.built == 2 and r.resumed_from == 7
    assert _files(out) == _files(clean_db)


# --- the sweep renderer --------------------------------------------------------------------------
@pytest.fixture(scope="module")
def sweep_db(dem_path, tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep") / "db.zarr"
    r = _build(dem_path, out, renderer="sweep")
    assert r.built == 9 and r.positions == 480
    return out


def test_sweep_build_stores_the_kernels_skylines_and_verifies(dem_path, clean_db, sweep_db):
    a = zarr.open_group(str(clean_db), mode="r")
    b = zarr.open_group(str(sweep_db), mode="r")
    for name in ("ground_z", "min_ray_m", "edge_bins"):
        np.testing.assert_array_equal(b[name][:], a[name][:])
    k = np.asarray(a["elevation"][:], np.int32)
    w = np.asarray(b["elevation"][:], np.int32)
    assert ((k == MISSING) == (w == MISSING)).all()
    # True points of each ray: never above the kernel beyond its skip tolerance and rounding.
    assert (w - k).max() <= 1
    assert np.mean(np.abs(w - k) > 1) < 0.005
    np.testing.assert_array_equal(b["coarse"][:], coarse_of(b["elevation"][:]))
    rep = verify_database(sweep_db, dem=dem_path, samples=20)
    assert rep.ok, rep.sample_failures
    assert any("sweep renderer" in n for n in rep.notes)
    res = CliRunner().invoke(cli, ["info", str(sweep_db)])
    assert res.exit_code == 0 and "rendered by the sweep" in res.output


def test_sweep_build_resumes_to_an_identical_store_and_keeps_its_renderer(dem_path, sweep_db, tmp_path):
    import shutil

    out = tmp_path / "resumed.zarr"
    shutil.copytree(sweep_db, out)
    for br, bc in ((0, 1), (2, 2)):  # the resume renders two lone blocks of the group
        (out / MARKER_DIR / marker_name(br, bc)).unlink()
    with pytest.raises(DatabaseError, match="renderer: the store has 'sweep', this build asks for 'kernel'"):
        _build(dem_path, out)
    r = _build(dem_path, out, renderer="sweep")
    assert r.built == 2 and r.resumed_from == 7
    assert _files(out) == _files(sweep_db)


def test_sweep_groups_shrink_to_keep_every_slot_busy():
    """Groups of up to 4 x 4 blocks, halved while fewer than two tasks a slot remain; one process
    (one slot) keeps the largest."""
    grid = [(r, c) for r in range(4) for c in range(4)]  # a 1 x 1 km build at 5 m
    assert [len(t) for t in tasks_of(grid, "sweep", 1)] == [16]
    assert sorted(len(t) for t in tasks_of(grid, "sweep", 2)) == [4, 4, 4, 4]
    assert sorted(len(t) for t in tasks_of(grid, "sweep", 8)) == [1] * 16
    big = [(r, c) for r in range(22) for c in range(22)]  # 7 x 7 km
    assert max(len(t) for t in tasks_of(big, "sweep", 2)) == 16
    assert sorted(b for t in tasks_of(big, "sweep", 2) for b in t) == big
    assert tasks_of(grid, "kernel", 2) == [[b] for b in grid]
    # larger blocks, smaller groups: at most 256 positions a side a task (4 x 4 blocks of 256
    # were a million positions, 9-16 GB a worker)
    assert max(len(t) for t in tasks_of(big, "sweep", 1, block=128)) == 4
    assert max(len(t) for t in tasks_of(big, "sweep", 1, block=256)) == 1
    assert max(len(t) for t in tasks_of(big, "sweep", 1, block=32)) == 16


def test_sweep_store_is_the_same_however_its_blocks_are_grouped(dem_path, sweep_db, tmp_path):
    from concurrent.futures import ThreadPoolExecutor

    out = tmp_path / "two_slots.zarr"
    # A given executor counts as two slots: 3 x 3 blocks go as four groups, not one. One thread
    # runs them (numba's workqueue layer, where it is the one, takes no concurrent launches).
    with ThreadPoolExecutor(1) as ex:
        r = _build(dem_path, out, renderer="sweep", executor=ex)
    assert r.built == 9
    assert _files(out) == _files(sweep_db)


def test_sweep_build_refuses_what_it_cannot_render(dem_path, tmp_path):
    with pytest.raises(ParameterError, match="renderer must be one of kernel, sweep"):
        _build(dem_path, tmp_path / "a.zarr", renderer="raytrace")
    with pytest.raises(ParameterError, match="max-distance-m"):
        _build(dem_path, tmp_path / "a.zarr", renderer="sweep", max_distance_m=300.0)
    with pytest.raises(ParameterError, match="stack of DEMs"):
        build_database([dem_path, dem_path], tmp_path / "a.zarr", BOUNDS, SPACING, workers=0,
                       progress=False, renderer="sweep")
    assert not (tmp_path / "a.zarr").exists()
    res = CliRunner().invoke(cli, ["build-db", str(dem_path), "--out", str(tmp_path / "c.zarr"),
                                   "--bounds", *map(str, BOUNDS), "--spacing-m", "10", "--workers",
                                   "0", "--renderer", "sweep", "--max-distance-m", "300"])
    assert res.exit_code == 2 and "--renderer kernel" in res.output


# --- verify --------------------------------------------------------------------------------------
def test_verify_passes_a_good_store_and_catches_corrupt_and_missing_blocks(dem_path, clean_db, tmp_path):
    import shutil

    import zarr

    runner = CliRunner()
    res = runner.invoke(cli, ["verify", str(clean_db), "--samples", "5", "--dem", str(dem_path)])
    assert res.exit_code == 0 and "9 of 9 present and intact" in res.output and "OK" in res.output

    bad = tmp_path / "bad.zarr"
    shutil.copytree(clean_db, bad)
    chunk = bad / "elevation" / "c" / "0" / "1" / "0"  # block (0, 1): flip bytes mid-file
    data = bytearray(chunk.read_bytes())
    data[len(data) // 2: len(data) // 2 + 8] = b"\xff" * 8
    chunk.write_bytes(bytes(data))
    g = zarr.open_group(str(bad), mode="r+")
    g["ground_z"][16:20, 16:24] = 0.0  # block (2, 2): valid chunk, wrong values
    (bad / MARKER_DIR / marker_name(1, 2)).unlink()  # block (1, 2) missing
    rep = verify_database(bad, samples=0)
    assert rep.missing == [(1, 2)]
    assert [b for b, _ in rep.corrupt] == [(0, 1), (2, 2)]
    assert "ground_z" in dict(rep.corrupt)[(2, 2)]
    res = runner.invoke(cli, ["verify", str(bad), "--samples", "0"])
    assert res.exit_code == 2
    assert "missing block (1, 2)" in res.output and "corrupt block (0, 1)" in res.output


def test_verify_sample_catches_a_store_that_disagrees_with_the_dem(dem_path, clean_db, tmp_path):
    """A consistent store (every block matches its marker's checksums) built from this very DEM
    (same file, same checksum) whose skylines are not the DEM's: only the re-render of sampled
    positions can tell."""
    import hashlib
    import shutil

    import zarr

    rep = verify_database(clean_db, dem=dem_path, samples=8)
    assert rep.ok and rep.samples == 8 and rep.sample_max_error_deg <= SCALE_DEG / 2 + 1e-4

    bad = tmp_path / "shifted.zarr"
    shutil.copytree(clean_db, bad)
    g = zarr.open_group(str(bad), mode="r+")
    el = np.asarray(g["elevation"][:])
    k = 30  # every stored skyline raised by 30 quantisation steps = 0.3 deg
    g["elevation"][:] = np.where(el == MISSING, el, el + k).astype(el.dtype)
    g["coarse"][:] = coarse_of(g["elevation"][:])  # the derived index made to agree as well
    for mp in (bad / MARKER_DIR).glob("r*_c*/zarr.json"):  # re-sign the blocks: the checksums stay consistent
        doc = json.loads(mp.read_text())
        m = doc["attributes"]
        blk = np.asarray(g["elevation"][m["row0"]:m["row0"] + m["rows"], m["col0"]:m["col0"] + m["cols"]])
        m["sha256"]["elevation"] = hashlib.sha256(np.ascontiguousarray(blk).tobytes()).hexdigest()
        mp.write_text(json.dumps(doc))
    rep = verify_database(bad, dem=dem_path, samples=8)
    assert not rep.corrupt and not rep.missing  # past the block checksums and the DEM checksum
    assert not rep.ok and rep.samples == 8 and len(rep.sample_failures) == 8
    assert all("stored skyline differs from a re-render" in f for f in rep.sample_failures)
    # the error is the shift, give or take the original rounding (<= half a step)
    assert abs(rep.sample_max_error_deg - k * SCALE_DEG) <= SCALE_DEG / 2 + 1e-4

    # A DEM file with other heights stops at the checksum gate, before any re-render.
    d = load_dem(dem_path)
    z = d.z.copy()
    z[:, :10] += 50  # a new western ridge changes the skylines
    other = tmp_path / "other.tif"
    write_dem(other, Dem(z, d.x0, d.y0, d.dx, d.dy, d.crs_wkt))
    rep = verify_database(clean_db, dem=other, samples=8)
    assert not rep.ok and rep.samples == 0 and len(rep.sample_failures) == 1
    assert "not the DEM this database was built from" in rep.sample_failures[0]
    # and the command's advice is to pass the right DEM, not to rebuild blocks that are intact
    res = CliRunner().invoke(cli, ["verify", str(clean_db), "--samples", "8", "--dem", str(other)])
    assert res.exit_code == 2 and "pass --dem the DEM the database was built from" in res.output
    assert "marker folder" not in res.output and "rebuild" not in res.output
    # The same heights passed as a Dem claiming the build's checksum get past the gate, and the
    # re-render finds skylines that the ridge changed.
    forged = Dem(z, d.x0, d.y0, d.dx, d.dy, d.crs_wkt, checksum=d.checksum)
    rep = verify_database(clean_db, dem=forged, samples=8)
    assert not rep.ok and rep.samples == 8 and rep.sample_max_error_deg > 1.0
    assert rep.sample_failures and all("differs from a re-render" in f for f in rep.sample_failures)


# --- info and errors -------------------------------------------------------------------------------
def test_info_reports_metadata_completeness_and_size(clean_db):
    res = CliRunner().invoke(cli, ["info", str(clean_db)])
    assert res.exit_code == 0, res.output
    assert "24 x 20 positions at 10 m" in res.output and "9 of 9 blocks (complete)" in res.output
    res = CliRunner().invoke(cli, ["info", str(clean_db), "--json"])
    d = json.loads(res.stdout)
    assert d["complete"] and d["positions"] == 480 and d["size_bytes"] > 480 * 10


def test_coarse_of_is_the_mean_of_four_bins_at_every_second_position():
    """Against a direct loop: row 2i, col 2j, bins 4g..4g+3 averaged, no terrain taken as 0,
    rounded to the step; odd block sides keep their last row and column."""
    rng = np.random.default_rng(3)
    raw = rng.integers(-9000, 9000, (7, 5, 16)).astype(np.int16)
    raw[rng.random(raw.shape) < 0.1] = MISSING
    got = coarse_of(raw)
    assert got.shape == (4, 3, 4) and got.dtype == np.int16
    for i in range(4):
        for j in range(3):
            for g in range(4):
                v = [0 if b == MISSING else int(b) for b in raw[2 * i, 2 * j, 4 * g:4 * g + 4]]
                assert got[i, j, g] == round(sum(v) / 4)  # both round half to even


def test_a_build_writes_the_coarse_index_of_its_skylines(clean_db):
    g = zarr.open_group(str(clean_db), mode="r")
    el, co = np.asarray(g["elevation"][:]), np.asarray(g["coarse"][:])
    assert co.shape == (10, 12, 18)
    np.testing.assert_array_equal(co, coarse_of(el))
    db = open_database(clean_db)
    assert db.has_coarse_index
    np.testing.assert_array_equal(db.read_coarse(2, 1), coarse_of(el[16:20, 8:16]))
    res = CliRunner().invoke(cli, ["info", str(clean_db)])
    assert "coarse index 9 of 9 blocks" in res.output


def test_a_store_without_the_coarse_index_gets_it_from_the_build_command(dem_path, clean_db, tmp_path):
    """A store built before the index (its folder gone, or a run adding it killed part-way) is
    still read and searched the older way; verify and info say so, and the same build-db
    command adds it, from the stored skylines, identical to a fresh build's."""
    import shutil

    args = [str(dem_path), "--out", str(tmp_path / "old.zarr"), "--bounds", *map(str, BOUNDS),
            "--spacing-m", "10", "--azimuth-bins", "72", "--block-positions", "8", "--workers", "0",
            "--no-progress"]
    for lose in ("all", "some"):
        old = tmp_path / "old.zarr"
        shutil.rmtree(old, ignore_errors=True)
        shutil.copytree(clean_db, old)
        if lose == "all":
            shutil.rmtree(old / "coarse")
        else:
            (old / "coarse" / "c" / "1" / "2" / "0").unlink()
        db = open_database(old)
        assert db.is_complete and not db.has_coarse_index
        rep = verify_database(old, samples=0)
        assert rep.ok and any("no coarse index" in n for n in rep.notes)
        assert "rerun the build command to add it" in CliRunner().invoke(cli, ["info", str(old)]).output
        res = CliRunner().invoke(cli, ["build-db", *args])
        assert res.exit_code == 0, res.output
        assert f"coarse index added to {9 if lose == 'all' else 1} block" in res.output
        assert open_database(old).has_coarse_index
        assert _files(old) == _files(clean_db)
    before = _files(old)
    res = CliRunner().invoke(cli, ["build-db", *args])  # now complete: nothing to do, success
    assert res.exit_code == 0 and "already complete, 9 blocks" in res.output, res.output
    assert _files(old) == before


def test_no_coarse_index_where_the_layout_cannot_hold_one(dem_path, tmp_path):
    """Blocks of an odd side (a block's subgrid would start on an odd row) or bins not a multiple
    of 4: no index, and the search reads every block as before."""
    from skyfix.match import MatchConfig, match_database

    for kw in ({"block": 5}, {"azimuth_bins": 70}):
        out = tmp_path / f"db{len(list(tmp_path.iterdir()))}.zarr"
        _build(dem_path, out, **kw)
        db = open_database(out)
        assert "coarse" not in zarr.open_group(str(out), mode="r") and not db.has_coarse_index
        q = db.profiles_at(*db.xy_of(np.array([10]), np.array([12])))[0]
        # 70 bins: the coarse pass averages 2 bins, the largest count below 4 that divides 70
        res = match_database(db, q, MatchConfig(min_observed=10, stride_min_coverage=0.0))
        assert "coarse_index" not in res.timing and (res.candidates[0].row, res.candidates[0].col) == (10, 12)
        assert verify_database(out, samples=0).ok and not verify_database(out, samples=0).notes


def test_clear_errors(dem_path, clean_db, tmp_path):
    with pytest.raises(OutsideDemError, match="outside the DEM"):
        build_database(dem_path, tmp_path / "a.zarr", (700, 700, 900, 900), 10, workers=0,
                       progress=False)
    with pytest.raises(ParameterError, match="spacing must be > 0"):
        build_database(dem_path, tmp_path / "b.zarr", BOUNDS, 0, workers=0, progress=False)
    with pytest.raises(ParameterError, match="spacing must be > 0"):
        build_database(dem_path, tmp_path / "b.zarr", BOUNDS, -5, workers=0, progress=False)
    with pytest.raises(ParameterError, match="XMIN <= XMAX"):
        build_database(dem_path, tmp_path / "b.zarr", (500, 300, 300, 490), 10, workers=0)
    # Existing output: a finished database (nothing to do, untouched), a foreign file, a
    # foreign folder.
    before = _files(clean_db)
    r = _build(dem_path, clean_db)
    assert (r.built, r.resumed_from) == (0, r.n_blocks) and _files(clean_db) == before
    f = tmp_path / "file.zarr"
    f.write_text("not a database")
    with pytest.raises(OutputExistsError, match="--overwrite"):
        _build(dem_path, f)
    d = tmp_path / "folder"
    d.mkdir()
    (d / "precious.txt").write_text("keep me")
    with pytest.raises(OutputExistsError, match="not a skyfix database"):
        _build(dem_path, d, overwrite=True)
    assert (d / "precious.txt").exists()
    # Incompatible resume names the parameter that differs.
    with pytest.raises(DatabaseError, match="camera_height_m: the store has 1.5, this build asks for 2.0"):
        _build(dem_path, clean_db, camera_height_m=2.0)
    # And the CLI turns these into one line, exit status 2.
    res = CliRunner().invoke(cli, ["build-db", str(dem_path), "--out", str(tmp_path / "c.zarr"),
                                   "--bounds", "0", "0", "5000", "5000", "--spacing-m", "10", "--workers", "0"])
    assert res.exit_code == 2 and "outside the DEM" in res.output
    res = CliRunner().invoke(cli, ["build-db", str(dem_path), "--out", str(tmp_path / "c.zarr"),
                                   "--bounds", *map(str, BOUNDS), "--spacing-m", "0", "--workers", "0"])
    assert res.exit_code == 2 and "spacing must be > 0" in res.output
    for bad in (tmp_path / "nothing.zarr", f, d):
        with pytest.raises(DatabaseError):
            open_database(bad)


def test_overwrite_starts_afresh(dem_path, tmp_path):
    out = tmp_path / "o.zarr"
    _build(dem_path, out, azimuth_bins=36)
    r = _build(dem_path, out, azimuth_bins=72, overwrite=True)  # other parameters, replaced
    assert r.built == 9 and open_database(out).azimuth_bins == 72


def test_chunks_decoded_directly_equal_zarrs_reading(clean_db):
    """The search's direct chunk decoding (database/chunks.py) against zarr's own pipeline, on
    every block, edge blocks included; and the direct path is the one a skyfix store takes."""
    db = open_database(clean_db)
    arr = zarr.open_group(str(clean_db), mode="r")["elevation"]
    assert chunk_reader(arr) is not None, "a store skyfix wrote must take the direct path"
    for br, bc in db.grid.blocks():
        rs, cs = db.grid.block_slices(br, bc)
        direct = db.read_raw("elevation", br, bc)
        assert direct.dtype == np.int16
        np.testing.assert_array_equal(direct, np.asarray(arr[rs, cs]))


def test_unshuffle_undelta_inverts_numcodecs_filters():
    """The one-pass decoder against numcodecs' Shuffle and Delta, with values that wrap int16."""
    from numcodecs import Delta, Shuffle

    from skyfix.database.chunks import unshuffle_undelta

    rng = np.random.default_rng(3)
    x = rng.integers(-32768, 32768, 5000).astype(np.int16)
    x[:4] = [-32768, 32767, -32768, 0]  # steps of +-65535: the delta wraps
    enc = Shuffle(elementsize=2).encode(Delta(dtype="i2").encode(x))
    out = np.empty_like(x)
    unshuffle_undelta(np.frombuffer(enc, np.uint8), out)
    np.testing.assert_array_equal(out, x)


def _skyline_like(rng, shape):
    """int16 skylines [0.01 deg] that vary smoothly across positions and azimuths, with the
    store's missing value in places and values near both ends of int16 (the deltas wrap)."""
    ny, nx, nb = shape
    a = np.arange(nb) * (2 * np.pi / nb)
    base = 800 * np.sin(a)[None, None] + 30 * np.arange(ny)[:, None, None] \
        - 20 * np.arange(nx)[None, :, None]
    x = (base + rng.normal(0, 5, shape)).astype(np.int16)
    x[0, 0, :3] = [MISSING, 32767, MISSING]
    return x


@pytest.mark.parametrize("block", [1, 3, 8])
def test_skyline_layouts_round_trip_through_zarr_and_the_direct_reader(tmp_path, block):
    """The layout a build writes now (transposed to (azimuth, y, x) before the delta, for blocks
    of more than one position) and the one earlier stores hold: zarr-python reads back what was
    written, and the direct reader gives the same arrays."""
    from zarr.codecs import Delta, Shuffle, ZstdCodec

    from skyfix.database.build import skyline_codecs

    rng = np.random.default_rng(block)
    shape = (2 * block + 1, 2 * block, 24)  # edge chunks partly outside the array
    x = _skyline_like(rng, shape)
    earlier = {"filters": [Delta(dtype="i2")],
               "compressors": [Shuffle(elementsize=2), ZstdCodec(level=9, checksum=True)]}
    for name, codecs in (("now", skyline_codecs(block)), ("earlier", earlier)):
        a = zarr.create_array(str(tmp_path / f"{name}.zarr"), shape=shape, dtype="int16",
                              chunks=(block, block, shape[2]), fill_value=MISSING, **codecs)
        a[:] = x
        a = zarr.open_array(str(tmp_path / f"{name}.zarr"), mode="r")
        np.testing.assert_array_equal(np.asarray(a[:]), x)
        read = chunk_reader(a)
        assert read is not None, name
        for br in range(-(-shape[0] // block)):
            for bc in range(-(-shape[1] // block)):
                got = read((br, bc, 0))
                want = np.asarray(a[br * block:(br + 1) * block, bc * block:(bc + 1) * block])
                np.testing.assert_array_equal(got[:want.shape[0], :want.shape[1]], want)
                c = read((br, bc, 0), True)  # decoded into C order: the checksums' order
                assert c.flags.c_contiguous
                np.testing.assert_array_equal(c[:want.shape[0], :want.shape[1]], want)
    names = [c["name"] for c in json.loads((tmp_path / "now.zarr" / "zarr.json").read_text())["codecs"]]
    assert (names[0] == "transpose") == (block > 1)


def test_the_transposed_layout_is_smaller_on_real_skylines(clean_db, tmp_path):
    """What the transpose is for: the same skylines, stored both ways, take less room with it."""
    from zarr.codecs import Delta, Shuffle, ZstdCodec

    from skyfix.database.build import skyline_codecs

    x = np.asarray(zarr.open_group(str(clean_db), mode="r")["elevation"][:])
    earlier = {"filters": [Delta(dtype="i2")],
               "compressors": [Shuffle(elementsize=2), ZstdCodec(level=9, checksum=True)]}
    size = {}
    for name, codecs in (("now", skyline_codecs(x.shape[0])), ("earlier", earlier)):
        a = zarr.create_array(str(tmp_path / f"{name}.zarr"), shape=x.shape, dtype="int16",
                              chunks=x.shape, fill_value=MISSING, **codecs)
        a[:] = x
        size[name] = sum(f.stat().st_size for f in (tmp_path / f"{name}.zarr" / "c").rglob("*")
                         if f.is_file())
    assert size["now"] < 0.95 * size["earlier"], size


@pytest.mark.parametrize("edit", [
    lambda c: [c[0], c[1], c[2], c[4], c[3]],  # compressors reordered (zstd before shuffle)
    lambda c: [c[1], c[0], *c[2:]],  # filters reordered (delta before the transpose)
    lambda c: [{**c[0], "configuration": {"order": [0, 1, 2]}}, *c[1:]],
    lambda c: [c[0], *c[2:]],  # the delta gone
    lambda c: [*c[:3], {**c[3], "configuration": {"elementsize": 4}}, c[4]],
    lambda c: [*c[:3], c[3], c[3], c[4]],  # a codec twice
])
def test_an_edited_codec_chain_is_decoded_by_zarr_as_its_metadata_says(clean_db, tmp_path, edit):
    """The direct reader takes only its own chain, name by name and setting by setting: a store
    whose zarr.json lists the codecs otherwise is read through zarr, as its metadata says, and
    the search and verify then read the same values (which the block checksums refuse)."""
    db_path = tmp_path / "db.zarr"
    shutil.copytree(clean_db, db_path)
    f = db_path / "elevation" / "zarr.json"
    meta = json.loads(f.read_text())
    meta["codecs"] = edit(meta["codecs"])
    f.write_text(json.dumps(meta))
    db = open_database(db_path)
    assert chunk_reader(zarr.open_group(str(db_path), mode="r")["elevation"]) is None
    rep = verify_database(db_path, samples=0)
    assert len(rep.corrupt) == db.n_blocks  # every block decodes wrong, or not at all
    with pytest.raises(DatabaseError, match=r"block \(0, 0\) (elevation differs from the checksum"
                                            r"|data unreadable)"):
        db.read_raw("elevation", 0, 0)


def test_other_chunk_layouts_are_read_through_zarr(tmp_path):
    a = zarr.create_array(str(tmp_path / "plain.zarr"), shape=(4, 4, 8), chunks=(2, 2, 8),
                          dtype="int16")
    assert chunk_reader(a) is None  # default codecs: zarr decodes it
