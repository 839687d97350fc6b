"""The board segment imports only what it uses: each board command, run in a fresh process, must
not import scikit-learn, matplotlib, Dask, PyTorch or SciPy (hundreds of MB of a 256 MB budget;
SciPy is not even in the board install)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

HEAVY = ("sklearn", "matplotlib", "dask", "distributed", "torch")
# SciPy is made unimportable, as in the board install (which leaves it out): numba, which
# imports it where it can, then runs without it, and any import of it by skyfix fails the command.

RUNNER = """
import atexit, sys
sys.modules['scipy'] = None
def report():
    got = sorted({m.split('.')[0] for m in sys.modules} & set(%r))
    sys.stderr.write('HEAVY:' + ','.join(got) + '\\n')
atexit.register(report)
from skyfix.cli.main import cli
cli(sys.argv[1:], prog_name='skyfix')
""" % (HEAVY,)


@pytest.fixture(scope="module")
def board_inputs(tmp_path_factory):
    from skyfix.dem import fractal_dem, write_dem
    from skyfix.formats import Truth
    from skyfix.simulate import simulate_acquisition

    d = tmp_path_factory.mktemp("board")
    dem = fractal_dem(160, 30.0, relief_m=900.0, seed=6)
    dem_path = write_dem(d / "dem.tif", dem)
    xmin, ymin, xmax, ymax = dem.bounds
    x, y = (xmin + xmax) / 2, (ymin + ymax) / 2
    acq = simulate_acquisition(dem, Truth(x, y, 40.0, 0.0, 0.0), d / "acq", camera="wide",
                               frames=4, tilt_deg=10.0, seed=1)
    return d, dem_path, acq, x, y


@pytest.mark.parametrize("command", ["detect", "profile", "locate", "heading"])
def test_board_commands_stay_lean(board_inputs, command):
    d, dem_path, acq, x, y = board_inputs
    args = {
        "detect": ["detect", str(acq / "frame_000.png"), "-o", str(d / "sky.json"), "--overwrite"],
        "profile": ["profile", str(acq), "-o", str(d / "prof.json"), "--overwrite"],
        "locate": ["locate", str(acq), "--dem", str(dem_path), "--prior-x", str(x + 3),
                   "--prior-y", str(y - 2), "--prior-radius-m", "10", "-o", str(d / "fix.json"),
                   "--overwrite"],
        "heading": ["heading", str(acq), "--dem", str(dem_path), "--x", str(x), "--y", str(y),
                    "--heading-prior-deg", "40", "--prior-north", "grid", "-o",
                    str(d / "heading.json"), "--overwrite"],
    }[command]
    r = subprocess.run([sys.executable, "-c", RUNNER, *args], capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr
    heavy = [ln for ln in r.stderr.splitlines() if ln.startswith("HEAVY:")]
    assert heavy == ["HEAVY:"], f"{command} imported {heavy}"


# The board install (``pip install skyfix``, no ``[ground]``): the ground libraries absent. An
# entry of None in sys.modules makes ``import`` fail as if the package were not installed.
WITHOUT_GROUND = """
import sys
for name in ('sklearn', 'matplotlib', 'dask', 'distributed'):
    sys.modules[name] = None
from skyfix.cli.main import cli
cli(sys.argv[1:], prog_name='skyfix')
"""


def _without_ground(*args):
    return subprocess.run([sys.executable, "-c", WITHOUT_GROUND, *args], capture_output=True,
                          text=True, timeout=600)


def test_board_install_runs_the_board_and_names_the_ground_extra(board_inputs):
    d, dem_path, acq, x, y = board_inputs
    frame = str(acq / "frame_000.png")
    r = _without_ground("detect", frame, "-o", str(d / "lean.json"), "--overwrite")
    assert r.returncode == 0, r.stderr
    assert (d / "lean.json").exists()

    # a figure asked of a board install: refused before any work, with the install that adds it
    r = _without_ground("detect", frame, "-o", str(d / "lean2.json"), "--plot", str(d / "p.png"))
    assert r.returncode == 2, r.stderr
    assert "matplotlib" in r.stderr and 'skyfix[ground]' in r.stderr
    assert "Traceback" not in r.stderr
    assert not (d / "lean2.json").exists() and not (d / "p.png").exists()

    # the ground commands that draw: refused before their long work, nothing written
    r = _without_ground("demo", "-o", str(d / "demo"))
    assert r.returncode == 2 and "matplotlib" in r.stderr and not (d / "demo").exists(), r.stderr

    r = _without_ground("detect", frame, "-o", str(d / "lean3.json"), "--method", "bayes")
    assert r.returncode == 2 and "scikit-learn" in r.stderr and "Traceback" not in r.stderr, r.stderr

    # a build: worker processes need Dask (the message offers --workers 0), and --workers 0 builds
    db = d / "lean.zarr"
    common = ["build-db", str(dem_path), "-o", str(db), "--bounds", str(x - 30), str(y - 30),
              str(x + 30), str(y + 30), "--spacing-m", "30"]
    r = _without_ground(*common)
    assert r.returncode == 2 and "Dask" in r.stderr and "--workers 0" in r.stderr, r.stderr
    assert not db.exists()
    r = _without_ground(*common, "--workers", "0")
    assert r.returncode == 0, r.stderr
    assert db.exists()


def test_board_commands_get_one_malloc_arena():
    """The board's heap setting reaches glibc (where there is one): a wrong symbol or argument
    type would silently leave the 40 MB of per-thread arenas in place."""
    import platform

    libc, _ = platform.libc_ver()
    if libc != "glibc":
        pytest.skip(f"not glibc ({libc or 'unknown C library'}): one_malloc_arena is a no-op")
    r = subprocess.run([sys.executable, "-c", "from skyfix.cli.heap import one_malloc_arena; "
                        "print(one_malloc_arena())"], capture_output=True, text=True, timeout=60)
    assert r.stdout.strip() == "True", r.stderr


def test_board_heap_gives_large_blocks_back():
    """With the board's heap settings a freed 16 MB array leaves no anonymous memory behind; with
    glibc's dynamic mmap threshold (one arena alone) the second such array came from the heap
    and stayed resident after it was freed."""
    import platform

    libc, _ = platform.libc_ver()
    if libc != "glibc" or not Path("/proc/self/status").exists():
        pytest.skip("glibc and /proc needed")
    prog = (
        "import sys, numpy as np\n"
        "from skyfix.cli import heap\n"
        "print(getattr(heap, sys.argv[1])())\n"
        "def anon():\n"
        "    return next(int(l.split()[1]) // 1024 for l in open('/proc/self/status')\n"
        "                if l.startswith('RssAnon'))\n"
        "a = np.ones(1 << 21); del a\n"  # mapped; freeing it raises the dynamic threshold
        "base = anon()\n"
        "b = np.ones(1 << 21)\n"
        "pin = [bytearray(64) for _ in range(1000)]\n"  # small blocks above it hold the top
        "del b\n"
        "print(anon() - base)\n")
    left = {}
    # glibc's own defaults: a MALLOC_* variable in the environment (a shell's, Dask's) changes them
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    for setting in ("board_heap", "one_malloc_arena"):
        r = subprocess.run([sys.executable, "-c", prog, setting], capture_output=True, text=True,
                           timeout=60, env=env)
        took, mb = r.stdout.split()
        assert took == "True", r.stderr
        left[setting] = int(mb)
    assert left["board_heap"] <= 1 and left["one_malloc_arena"] >= 15, left
