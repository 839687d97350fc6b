"""Ctrl-C during a build with Dask workers: one line and exit 130, not the workers' tracebacks;
the same command then resumes, and the store is byte for byte the one an uninterrupted build
writes."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from skyfix.dem import fractal_dem, write_dem

ARGS = ["--bounds", "501000", "4193500", "506500", "4199000", "--spacing-m", "40",
        "--azimuth-bins", "360"]


def _tree(root: Path) -> dict:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.mark.slow
def test_ctrl_c_is_one_line_and_the_rerun_resumes_byte_for_byte(tmp_path):
    dem = write_dem(tmp_path / "dem.tif", fractal_dem(260, 30.0, seed=4))
    out = tmp_path / "db.zarr"
    cmd = [sys.executable, "-m", "skyfix.cli.main", "build-db", str(dem), "-o", str(out), *ARGS,
           "--workers", "2", "--block-positions", "16"]
    # Ctrl-C's default action in the child, whatever this process inherited: a test runner
    # started in the background by a non-interactive shell has SIGINT ignored, a child inherits
    # that, and Python then installs no KeyboardInterrupt handler (the build ran to its end)
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    markers = out / "_skyfix" / "blocks"
    t0 = time.time()
    while time.time() - t0 < 120 and p.poll() is None:
        if markers.is_dir() and len(list(markers.glob("*/zarr.json"))) >= 2:
            break
        time.sleep(0.2)
    assert p.poll() is None, "the build ended before it could be interrupted: make it bigger"
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130, err
    lines = [ln for ln in err.replace("\r", "\n").splitlines()
             if ln.strip() and not ln.startswith("skylines:")]
    assert lines == ["interrupted; run the same command again to resume where it stopped"], err
    assert "Traceback" not in err
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    import re

    kept = re.search(r"(\d+) already there", r.stdout + r.stderr)
    assert kept and int(kept.group(1)) >= 1, r.stdout + r.stderr  # resumed, not redone
    clean = tmp_path / "clean.zarr"
    r = subprocess.run([sys.executable, "-m", "skyfix.cli.main", "build-db", str(dem), "-o",
                        str(clean), *ARGS, "--workers", "0", "--block-positions", "16"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert _tree(out) == _tree(clean)


@pytest.mark.slow
def test_a_relative_out_through_an_external_scheduler(tmp_path):
    """`build-db ... -o rel.zarr --scheduler tcp://...` from a folder other than the workers':
    paths are sent absolute, and the store equals an in-process build byte for byte."""
    import json

    dem = write_dem(tmp_path / "dem.tif", fractal_dem(120, 30.0, seed=2))
    args = ["--bounds", "500600", "4196600", "503000", "4199000", "--spacing-m", "60",
            "--azimuth-bins", "180", "--block-positions", "16"]
    sched_file = tmp_path / "scheduler.json"
    elsewhere = tmp_path / "workers_cwd"
    elsewhere.mkdir()
    bindir = Path(sys.executable).parent
    sched = subprocess.Popen([str(bindir / "dask"), "scheduler", "--scheduler-file", str(sched_file),
                              "--port", "0", "--no-dashboard"], cwd=elsewhere,
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    worker = None
    try:
        t0 = time.time()
        while not sched_file.exists() and time.time() - t0 < 60:
            time.sleep(0.2)
        worker = subprocess.Popen([str(bindir / "dask"), "worker", "--scheduler-file", str(sched_file),
                                   "--nworkers", "1", "--nthreads", "1", "--no-dashboard"],
                                  cwd=elsewhere, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        address = json.loads(sched_file.read_text())["address"]
        here = tmp_path / "user_cwd"
        here.mkdir()
        r = subprocess.run([sys.executable, "-m", "skyfix.cli.main", "build-db", str(dem), "-o",
                            "rel.zarr", *args, "--scheduler", address],
                           cwd=here, capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
    finally:
        for p in (worker, sched):
            if p is not None:
                p.terminate()
                p.wait(timeout=30)
    clean = tmp_path / "clean.zarr"
    r = subprocess.run([sys.executable, "-m", "skyfix.cli.main", "build-db", str(dem), "-o",
                        str(clean), *args, "--workers", "0"], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    assert _tree(here / "rel.zarr") == _tree(clean)


def test_workers_that_cannot_see_the_files_are_refused_by_name():
    from concurrent.futures import Future

    from skyfix.database.build import _check_workers_see
    from skyfix.errors import ParameterError

    class Blind:
        def submit(self, fn, *a):
            f = Future()
            f.set_result((False, True))
            return f

    with pytest.raises(ParameterError, match="workers cannot see the DEM /data/dem.tif"):
        _check_workers_see(Blind(), "/data/dem.tif", Path("/data/out.zarr"))
