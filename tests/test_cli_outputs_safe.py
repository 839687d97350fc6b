"""simulate, simulate-set, evaluate and demo: bad options are refused before any output is touched,
an earlier output survives a refusal or a failure, and an unwritable --out is a one-line error.

The heavy stages (database build, set rendering) are replaced by a stub that raises
:class:`Reached` where a test only needs to know whether a run got past its checks.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from conftest import cli_run as run
from skyfix.dem import Dem, write_dem


class Reached(Exception):
    """The run got past its checks to the stage a test stubbed out."""


def hill_dem() -> Dem:
    """2 km square at 20 m, one broad hill: a real skyline, quick to render."""
    n = 101
    yy, xx = np.mgrid[0:n, 0:n] * 20.0
    z = 100.0 + 300.0 * np.exp(-((xx - 1500.0) ** 2 + (yy - 600.0) ** 2) / (2 * 300.0**2))
    return Dem.from_array(z, 20.0)


@pytest.fixture(scope="module")
def dem(tmp_path_factory):
    return write_dem(tmp_path_factory.mktemp("dem") / "hill.tif", hill_dem())


def snapshot(folder: Path) -> dict:
    """Every file under ``folder`` (relative name -> bytes)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def leftovers(folder: Path) -> list[str]:
    """Hidden staging folders left beside ``folder``."""
    return sorted(p.name for p in folder.parent.iterdir() if p.name.startswith(f".{folder.name}."))


def simulate(dem, out, *extra):
    return run("simulate", dem, "--x", 1000, "--y", 1000, "--yaw-deg", 30, "--frames", 1,
               "--camera", "wide", "--out", out, *extra)


@pytest.fixture(scope="module")
def acquisition(dem, tmp_path_factory):
    """A finished two-frame acquisition to copy as 'the user's earlier output'."""
    out = tmp_path_factory.mktemp("acq") / "acq"
    r = run("simulate", dem, "--x", 1000, "--y", 1000, "--yaw-deg", 10, "--frames", 2, "--camera", "wide",
            "--out", out)
    assert r.exit_code == 0, r.output
    return out


@pytest.fixture
def old_acq(acquisition, tmp_path):
    import shutil

    dst = tmp_path / "acq"
    shutil.copytree(acquisition, dst)
    return dst


# --- simulate ------------------------------------------------------------------------------------

def test_simulate_overwrite_with_a_bad_seed_keeps_the_old_acquisition(dem, old_acq):
    before = snapshot(old_acq)
    r = simulate(dem, old_acq, "--overwrite", "--seed", -1)
    assert r.exit_code == 2, r.output
    assert "seed must be a whole number >= 0" in r.output and "Traceback" not in r.output
    assert snapshot(old_acq) == before


def test_simulate_failing_midway_keeps_the_old_acquisition(dem, old_acq, monkeypatch):
    """A crash (or a kill) while rendering leaves the earlier acquisition whole, and no debris."""
    import skyfix.simulate.acquisition as sim

    real = sim._render_one
    calls = []

    def crash_after_one(*a, **k):
        calls.append(1)
        if len(calls) > 1:
            raise KeyboardInterrupt  # what Ctrl-C does midway
        return real(*a, **k)

    monkeypatch.setattr(sim, "_render_one", crash_after_one)
    before = snapshot(old_acq)
    run("simulate", dem, "--x", 1000, "--y", 1000, "--yaw-deg", 30, "--frames", 3, "--camera", "wide",
        "--out", old_acq, "--overwrite")
    assert len(calls) == 2
    assert snapshot(old_acq) == before
    assert leftovers(old_acq) == []


@pytest.mark.parametrize("exchange", [True, False], ids=["renameat2", "two-renames"])
def test_simulate_overwrite_replaces_the_folder_whole(dem, old_acq, monkeypatch, exchange):
    import skyfix.simulate.folders as sim

    if not exchange:  # a filesystem without an atomic exchange
        monkeypatch.setattr(sim, "_exchange", lambda a, b: False)
    assert (old_acq / "frame_001.png").exists()
    r = simulate(dem, old_acq, "--overwrite")
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in old_acq.glob("*.png")) == ["frame_000.png"]  # no stale frame_001
    assert leftovers(old_acq) == []
    umask = os.umask(0)
    os.umask(umask)
    assert old_acq.stat().st_mode & 0o777 == 0o777 & ~umask  # a plain folder's mode, not mkdtemp's 0700


@pytest.mark.parametrize("args, msg", [
    (["--frames", 0], "at least one frame"),
    (["--pan-step-deg", 0], "pan step must be > 0"),
    (["--seed", -1], "seed must be"),
    (["--prior-pitch-deg", "nan"], "attitude prior must be finite"),
    (["--prior-roll-deg", "inf"], "attitude prior must be finite"),
    (["--prior-pitch-deg", 80], "attitude prior must be within +-60"),
    (["--camera-height-m", -1], "camera height must be >= 0"),
])
def test_simulate_refusals_leave_no_output(dem, tmp_path, args, msg):
    out = tmp_path / "o"
    r = run("simulate", dem, "--x", 1000, "--y", 1000, "--yaw-deg", 30, *args, "--out", out)
    assert r.exit_code == 2, r.output
    assert msg in r.output and "Traceback" not in r.output
    assert not out.exists() and leftovers(out) == []


def test_simulate_writes_yaw_in_0_360(dem, tmp_path):
    from skyfix.formats import load_truth

    for yaw, want in ((400, 40.0), (-30, 330.0), (360, 0.0)):
        out = tmp_path / f"y{yaw}"
        r = run("simulate", dem, "--x", 1000, "--y", 1000, "--yaw-deg", yaw, "--frames", 1,
                "--camera", "wide", "--out", out)
        assert r.exit_code == 0, r.output
        assert load_truth(out).yaw_deg == pytest.approx(want)


def test_simulate_refuses_to_overwrite_the_folder_holding_its_dem(tmp_path):
    """--overwrite replaces --out whole: the DEM inside it would go with it."""
    write_dem(tmp_path / "hill.tif", hill_dem())
    r = simulate(tmp_path / "hill.tif", tmp_path, "--overwrite")
    assert r.exit_code == 2 and "lies inside --out" in r.output, r.output
    assert (tmp_path / "hill.tif").exists()


# --- simulate-set --------------------------------------------------------------------------------

@pytest.mark.parametrize("args, msg", [
    (["--seed", -1], "seed must be"),
    (["--frames", 0], "at least one frame"),
    (["--camera-height-m", -1], "camera height must be >= 0"),
    (["--cases", 0], "cases must be"),
])
def test_simulate_set_refuses_before_any_output_or_progress(dem, tmp_path, args, msg):
    out = tmp_path / "set"
    r = run("simulate-set", dem, "--set", "REF", "--cases", 1, *args, "--out", out)
    assert r.exit_code == 2, r.output
    assert msg in r.output and "Traceback" not in r.output
    assert "set REF" not in r.output  # no progress bar before the refusal
    assert not out.exists() and leftovers(out) == []


def test_simulate_set_overwrite_with_a_bad_option_keeps_the_old_set(dem, old_acq, tmp_path):
    before = snapshot(old_acq)
    for args in (["--seed", -1], ["--frames", 0]):
        r = run("simulate-set", dem, "--set", "REF", "--cases", 1, *args, "--out", old_acq, "--overwrite")
        assert r.exit_code == 2, r.output
        assert snapshot(old_acq) == before


def test_simulate_set_failing_midway_keeps_the_old_set(dem, old_acq, monkeypatch):
    import skyfix.simulate.acquisition as sim

    called = []

    def crash(*a, **k):
        called.append(1)
        raise KeyboardInterrupt

    monkeypatch.setattr(sim, "_render_one", crash)
    before = snapshot(old_acq)
    r = run("simulate-set", dem, "--set", "REF", "--cases", 2, "--frames", 1, "--camera", "wide",
            "--out", old_acq, "--overwrite")
    assert called and r.exit_code == 130, r.output  # it did fail midway, while rendering
    assert snapshot(old_acq) == before
    assert leftovers(old_acq) == []


# --- unwritable --out ----------------------------------------------------------------------------

def test_unwritable_out_is_a_one_line_error(dem, tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    out = blocker / "sub"
    for r in (simulate(dem, out),
              run("simulate-set", dem, "--set", "REF", "--cases", 1, "--frames", 1, "--camera", "wide",
                  "--out", out),
              run("evaluate", "--dem", dem, "--scenario", 2, "--cases", 1, "--out", out),
              run("demo", "--out", out)):
        assert r.exit_code == 2, (r.output, r.exception)
        assert f"cannot write {out}" in r.output and "Traceback" not in r.output
    assert blocker.read_text() == "not a folder"


# --- evaluate ------------------------------------------------------------------------------------

@pytest.fixture
def stub_set(monkeypatch):
    """Replace the set simulator: records its keyword arguments and stops the run there."""
    import skyfix.simulate as sim

    seen = {}

    def stub(*a, **k):
        seen.update(k)
        raise Reached

    monkeypatch.setattr(sim, "simulate_set", stub)
    return seen


@pytest.mark.parametrize("args, msg", [
    (["--seed", -1], "seed must be"),
    (["--camera-height-m", -1], "camera height must be >= 0"),
    (["--camera-height-m", "nan"], "camera height must be >= 0"),
    (["--sets", ","], "no robustness set given: choose from REF, HREL"),
    (["--sets", "REF,NOPE"], "unknown set"),
    (["--tilt-deg", 200], "mast tilt"),
    (["--area", -500, -500, 10, 10], "outside the DEM"),
    (["--scenario", 1], "give --db"),
    (["--cases", 10**9], "at most 10000 cases a set"),  # 1e9 started simulating, with no end
])
def test_evaluate_refusals_leave_no_output(dem, tmp_path, stub_set, args, msg):
    out = tmp_path / "e"
    base = {"--scenario": 2}
    if "--scenario" in args:
        base = {}
    r = run("evaluate", "--dem", dem, *[x for kv in base.items() for x in kv], "--cases", 1, *args,
            "--out", out)
    assert r.exit_code == 2, (r.output, r.exception)
    assert msg in r.output and "Traceback" not in r.output
    assert not out.exists()


def test_evaluate_simulates_with_its_camera_height(dem, tmp_path, stub_set):
    r = run("evaluate", "--dem", dem, "--scenario", 2, "--cases", 1, "--camera-height-m", 2.5,
            "--out", tmp_path / "e")
    assert isinstance(r.exception, Reached), r.output
    assert stub_set.get("camera_height_m") == 2.5


def test_evaluate_writes_its_tables_atomically(tmp_path, monkeypatch):
    import skyfix._io as io
    from skyfix.evaluate import EvalConfig, write_outputs
    from skyfix.report import CaseResult

    real = io.atomic_path
    staged = []

    def recording(path, **kw):
        staged.append(Path(path).name)
        return real(path, **kw)

    monkeypatch.setattr(io, "atomic_path", recording)
    res = [CaseResult(case="case_000", set="REF", scenario=2, truth_x=1000.0, truth_y=1000.0,
                      truth_yaw_deg=10.0, fix_x=1000.2, fix_y=1000.1, fix_grid_heading_deg=10.1,
                      confidence=0.9, score=0.01)]
    write_outputs(tmp_path, res, [], EvalConfig(scenario=2), hill_dem(), command="")
    assert {"tables.txt", "tables.md"} <= set(staged)
    assert (tmp_path / "tables.txt").read_text().startswith("Results per set")


# --- demo ----------------------------------------------------------------------------------------

@pytest.fixture
def stub_build(monkeypatch):
    """Stop the demo where it starts its 15 s database build."""
    import skyfix.database as database

    def stub(*a, **k):
        raise Reached

    monkeypatch.setattr(database, "build_database", stub)


def test_demo_refuses_a_users_folder_without_overwrite(tmp_path, stub_build):
    out = tmp_path / "demo_user"
    (out / "acquisition").mkdir(parents=True)
    (out / "acquisition" / "acquisition.json").write_text('{"mine": true}')
    (out / "notes.txt").write_text("keep me")
    before = snapshot(out)
    r = run("demo", "--out", out)
    assert r.exit_code == 2, (r.output, r.exception)
    assert "not an earlier skyfix demo" in r.output and "--overwrite" in r.output
    assert snapshot(out) == before
    # A folder holding only an acquisition/ (no demo marker) is the user's too.
    (out / "notes.txt").unlink()
    assert run("demo", "--out", out).exit_code == 2
    assert json.loads((out / "acquisition" / "acquisition.json").read_text()) == {"mine": True}
    # With --overwrite it proceeds.
    assert isinstance(run("demo", "--out", out, "--overwrite").exception, Reached)


def test_demo_reruns_over_its_own_output(tmp_path, stub_build):
    """The README quick start run twice: the second run rebuilds the default folder."""
    out = tmp_path / "skyfix-demo"
    r = run("demo", "--out", out)
    assert isinstance(r.exception, Reached), r.output
    assert (out / ".skyfix-demo").exists()
    for name in ("fix.json", "summary.json"):
        (out / name).write_text("{}")
    (out / "acquisition").mkdir()
    r = run("demo", "--out", out)
    assert isinstance(r.exception, Reached), r.output
    # an output from before the marker: the demo's own summary.json beside its skylines.zarr
    (out / ".skyfix-demo").unlink()
    (out / "summary.json").write_text(json.dumps({"fix": {}, "truth": {}, "timings_s": {},
                                                  "files": []}))
    (out / "skylines.zarr").mkdir()
    assert isinstance(run("demo", "--out", out).exception, Reached)


def test_demo_refuses_a_users_summary_and_fix(tmp_path, stub_build):
    """A user's folder holding a summary.json and a fix.json of their own passed as an earlier
    demo's (the names alone were checked) and was overwritten, then marked as the demo's."""
    out = tmp_path / "myrun"
    out.mkdir()
    (out / "summary.json").write_text('{"my": "results"}')
    (out / "fix.json").write_text('{"x": 1}')
    before = snapshot(out)
    r = run("demo", "--out", out)
    assert r.exit_code == 2, (r.output, r.exception)
    assert "not an earlier skyfix demo" in r.output
    assert snapshot(out) == before


def test_demo_refuses_a_bad_seed_before_building(tmp_path, stub_build):
    out = tmp_path / "demo_neg"
    r = run("demo", "--out", out, "--seed", -1)
    assert r.exit_code == 2, (r.output, r.exception)
    assert "seed must be a whole number >= 0" in r.output
    assert not out.exists()


def test_seed_check_takes_numpy_integers():
    from skyfix.errors import ParameterError
    from skyfix.simulate import check_seed

    assert check_seed(np.int64(3)) == 3
    for bad in (-1, 1.5, True, math.nan):
        with pytest.raises(ParameterError):
            check_seed(bad)


def test_a_rerun_clears_what_a_killed_run_of_the_same_output_left(tmp_path):
    """A simulate killed mid-render left .NAME.xxx.partial (6 MB) that no rerun removed; an .old
    folder (an earlier output moved aside mid-swap) and another output's partial are kept."""
    from skyfix.simulate.folders import staged_folder

    out = tmp_path / "acq"
    stale = tmp_path / ".acq.k1ll3d.partial"
    stale.mkdir()
    (stale / "frame_000.png").write_bytes(b"half")
    kept = [tmp_path / ".acq.s4v3d.old", tmp_path / ".other.abc.partial"]
    for k in kept:
        k.mkdir()
    with staged_folder(out, overwrite=False) as tmp:
        (tmp / "acquisition.json").write_text("{}")
    assert (out / "acquisition.json").is_file() and not stale.exists()
    assert all(k.is_dir() for k in kept)


@pytest.mark.parametrize("args, says", [
    (("--mode", "panorama", "--frames", 3, "--pan-step-deg", 10),
     "--frames, --pan-step-deg: not read in --mode panorama"),
    (("--mode", "panorama", "--camera", "wide"), "--camera: not read in --mode panorama"),
    (("--pano-size", 400, 100), "--pano-size: not read in --mode frames"),
])
def test_simulate_refuses_options_its_mode_does_not_read(dem, tmp_path, args, says):
    """They were ignored without a word."""
    r = run("simulate", dem, "--x", 1000, "--y", 1000, "--yaw-deg", 0, *args, "-o", tmp_path / "s")
    assert r.exit_code == 2 and says in r.output and "Traceback" not in r.output, r.output
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize("args, says", [
    (("--set", "SCOM", "--tilt-deg", 40), "--tilt-deg: not read by --set SCOM"),
    (("--set", "scom", "--tilt-deg", 15), "--tilt-deg: not read by --set SCOM"),
    (("--set", "REF", "--mode", "panorama", "--tilt-deg", 30),
     "--tilt-deg: not read in --mode panorama"),
    (("--set", "REF", "--pano-size", 400, 100), "--pano-size: not read in --mode frames"),
])
def test_simulate_set_refuses_options_it_does_not_read(dem, tmp_path, monkeypatch, args, says):
    """SCOM rendered at its own tilt, exit 0, whatever --tilt-deg said; so did a panorama."""
    import skyfix.simulate

    def reached(*a, **k):
        raise Reached

    monkeypatch.setattr(skyfix.simulate, "simulate_set", reached)
    r = run("simulate-set", dem, *args, "--cases", 1, "-o", tmp_path / "s")
    assert r.exit_code == 2 and says in r.output and "Traceback" not in r.output, r.output
    assert not (tmp_path / "s").exists()
    # without the option the set is rendered
    r = run("simulate-set", dem, "--set", args[1], "--cases", 1, "-o", tmp_path / "s")
    assert isinstance(r.exception, Reached), r.output


def test_evaluate_refuses_a_tilt_only_scom_would_ignore(dem, tmp_path, monkeypatch):
    """evaluate --sets SCOM --tilt-deg 40 simulated SCOM at its own tilt, exit 0, not a word;
    with another set beside SCOM the tilt is that set's, and the run goes on."""
    import skyfix.evaluate

    def reached(*a, **k):
        raise Reached

    monkeypatch.setattr(skyfix.evaluate, "evaluate", reached)
    out = tmp_path / "e"
    r = run("evaluate", "--dem", dem, "--scenario", 2, "--sets", "scom", "--tilt-deg", 40,
            "--cases", 1, "--out", out)
    assert r.exit_code == 2 and "--tilt-deg: not read by the set SCOM" in r.output, r.output
    assert "Traceback" not in r.output and not out.exists()
    for sets in ("SCOM,REF", "SCOM"):  # with a set that reads it; without the option
        extra = ("--tilt-deg", 40) if "REF" in sets else ()
        r = run("evaluate", "--dem", dem, "--scenario", 2, "--sets", sets, *extra, "--cases", 1,
                "--out", out)
        assert isinstance(r.exception, Reached), r.output


def test_quiet_demo_says_no_stage_lines_and_draws_no_bar(tmp_path, monkeypatch):
    """``skyfix -q demo`` drew the database build's progress bar and printed every stage line."""
    import skyfix.database as database

    seen = {}

    def stub(*a, **k):
        seen["progress"] = k.get("progress")
        raise Reached

    monkeypatch.setattr(database, "build_database", stub)
    r = run("-q", "demo", "--out", tmp_path / "q")
    assert isinstance(r.exception, Reached), r.output
    assert seen["progress"] is False and "1/4" not in r.output and "DEM:" not in r.output
    r = run("demo", "--out", tmp_path / "loud")
    assert isinstance(r.exception, Reached), r.output
    assert seen["progress"] is True and "1/4 building" in r.output
