"""Kernels compiled ahead of time (skyfix.jit, scripts/board_kernels.py): the same answers as
numba's JIT, without numba in the process, and never an export called with types it cannot take
(pycc's exports check nothing: an int64 array passed for a float64 one is read as float64)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numba
import numpy as np
import pytest

from skyfix import jit

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))
from board_kernels import decode, encode  # noqa: E402

RECORD = ROOT / "src" / "skyfix" / "board_kernels.json"


def _values():
    a = np.arange(24, dtype=np.float64).reshape(4, 6)
    ro = a.copy()
    ro.flags.writeable = False
    vals = [a, a[:, ::2], np.asfortranarray(a), ro, a.astype(np.float32), a.astype(np.int16),
            a.astype(np.uint8), a > 3, a[0], a[0, ::2], a.astype(np.int64)[1],
            np.zeros((2, 3, 4), np.float32), 3, 2.5, True, np.float32(1.5), np.int16(4)]
    return vals


def test_an_export_is_called_only_with_types_numba_would_take():
    """For every pair of a recorded type and a value: the check accepts a value of exactly that
    type, and whenever it accepts, numba's own dispatcher compiled for that one signature takes
    the value too (the independent reference: numba's typing of the call)."""
    vals = _values()
    for v in vals:
        spec = encode(numba.typeof(v))
        assert spec is not None
        assert jit.accepts(spec, v), (spec, v)
        ref = numba.njit(numba.types.int64(decode(spec)))(lambda x: 0)
        for w in vals:
            if jit.accepts(spec, w):
                assert ref(w) == 0, (spec, numba.typeof(w))  # raises TypeError if numba refuses
            elif encode(numba.typeof(w)) == spec:
                pytest.fail(f"{spec} refused a value of its own type")


def test_checks_refuse_what_pycc_would_misread():
    a = np.zeros((3, 4))
    c = ["array", "float64", 2, "C", False]
    assert not jit.accepts(c, a.astype(np.int64))         # another dtype
    assert not jit.accepts(c, a[:, ::2])                  # strided, for a C-contiguous export
    assert not jit.accepts(c, a[None])                    # another rank
    ro = a.copy()
    ro.flags.writeable = False
    assert not jit.accepts(c, ro)                         # a kernel may write into its argument
    assert not jit.accepts(c, a.astype(a.dtype.newbyteorder()))
    assert not jit.accepts(c, a.tolist())
    assert not jit.accepts(["scalar", "float64"], 3)      # an int is int64 to numba
    assert not jit.accepts(["scalar", "int64"], True)


def test_the_shipped_record_names_kernels_that_exist():
    import importlib

    kernels = json.loads(RECORD.read_text())["kernels"]
    assert kernels
    for k in kernels:
        disp = getattr(importlib.import_module(k["module"]), k["name"])
        assert isinstance(disp, numba.core.registry.CPUDispatcher), k["name"]
        for sig in k["signatures"]:
            args = [decode(a) for a in sig["args"]]
            assert len(args) == disp.py_func.__code__.co_argcount, k["name"]
            decode(sig["return"])


RUNNER = """
import atexit, json, sys
def report():
    sys.stderr.write('LOADED:' + json.dumps(sorted({'numba', 'llvmlite'} & set(sys.modules))) + '\\n')
atexit.register(report)
from skyfix.cli.main import cli
cli(sys.argv[1:], prog_name='skyfix')
"""


def _run(env_extra, *args):
    env = {k: v for k, v in os.environ.items() if k not in ("SKYFIX_JIT", "SKYFIX_BOARD_KERNELS")}
    env.update(env_extra)
    r = subprocess.run([sys.executable, "-c", RUNNER, *args], capture_output=True, text=True,
                       timeout=600, env=env)
    assert r.returncode == 0, r.stderr
    loaded = [json.loads(ln[7:]) for ln in r.stderr.splitlines() if ln.startswith("LOADED:")]
    return loaded[0]


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    if shutil.which("gcc") is None and shutil.which("cc") is None:
        pytest.skip("no C compiler: numba's pycc cannot build the kernels here")
    out = tmp_path_factory.mktemp("kernels")
    r = subprocess.run([sys.executable, str(ROOT / "scripts" / "board_kernels.py"), "build",
                        "--types", str(RECORD), "--out", str(out)],
                       capture_output=True, text=True, timeout=900,
                       env={**os.environ, "PYTHONPATH": str(ROOT / "src")})
    assert r.returncode == 0, r.stderr
    assert (out / "_board_kernels.json").exists()
    return out


def test_board_commands_from_the_build_match_the_jit_without_numba(built, tmp_path):
    from skyfix.dem import fractal_dem, write_dem
    from skyfix.formats import Truth
    from skyfix.simulate import simulate_acquisition

    dem = fractal_dem(160, 30.0, relief_m=900.0, seed=6)
    dem_path = write_dem(tmp_path / "dem.tif", dem)
    xmin, ymin, xmax, ymax = dem.bounds
    x, y = (xmin + xmax) / 2, (ymin + ymax) / 2
    acq = simulate_acquisition(dem, Truth(x, y, 40.0, 0.0, 0.0), tmp_path / "acq",
                               camera="navcam", frames=6, tilt_deg=10.0, seed=3)
    aot = {"SKYFIX_BOARD_KERNELS": str(built)}
    ref = {"SKYFIX_JIT": "1"}
    for name, env in (("aot", aot), ("jit", ref)):
        loaded = _run(env, "detect", str(acq / "frame_001.png"), "-o", str(tmp_path / f"{name}.sky.json"),
                      "--overwrite")
        assert loaded == ([] if name == "aot" else ["llvmlite", "numba"])
        loaded = _run(env, "locate", str(acq), "--dem", str(dem_path), "--prior-x", str(x + 3),
                      "--prior-y", str(y - 2), "--prior-radius-m", "10", "-o",
                      str(tmp_path / f"{name}.fix.json"), "--overwrite")
        assert loaded == ([] if name == "aot" else ["llvmlite", "numba"])
        loaded = _run(env, "heading", str(acq), "--dem", str(dem_path), "--x", str(x + 6),
                      "--y", str(y - 4), "--heading-prior-deg", "44", "--prior-north", "grid",
                      "-o", str(tmp_path / f"{name}.heading.json"), "--overwrite")
        assert loaded == ([] if name == "aot" else ["llvmlite", "numba"])
    heads = [json.loads((tmp_path / f"{n}.heading.json").read_text()) for n in ("aot", "jit")]
    assert heads[0]["heading_deg"] == heads[1]["heading_deg"]
    assert heads[0]["confidence"] == heads[1]["confidence"]
    sky = [json.loads((tmp_path / f"{n}.sky.json").read_text())["rows"] for n in ("aot", "jit")]
    assert sky[0] == sky[1]
    fix = [json.loads((tmp_path / f"{n}.fix.json").read_text()) for n in ("aot", "jit")]
    for k in ("x", "y", "heading_deg", "confidence", "position_sigma_m"):
        assert fix[0].get(k) == fix[1].get(k), k
    assert fix[0]["x"] is not None


def _python_with_kernels(code, folder):
    """Run ``code`` (which prints ok) in a fresh Python whose kernels build is ``folder``; its
    stderr, for what it told the user."""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600,
                       env={**os.environ, "SKYFIX_BOARD_KERNELS": str(folder)})
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr
    return r.stderr


def test_types_the_build_did_not_cover_fall_back_to_the_jit(built):
    code = """
import sys
import numpy as np
from skyfix import jit
from skyfix.detect.path import column_prefix
assert jit.ahead_of_time()
d = np.arange(12, dtype=np.float64).reshape(4, 3)
v = np.ones((4, 3), bool)
v[1, 2] = False
want = np.vstack([np.zeros(3), np.cumsum(np.where(v, d, 0), axis=0)])
assert np.array_equal(column_prefix(d, v), want) and 'numba' not in sys.modules
# float32 and a strided array were never recorded: numba compiles them, the same sums
assert np.array_equal(column_prefix(d.astype(np.float32), v), want)
assert 'numba' in sys.modules
assert np.array_equal(column_prefix(np.asfortranarray(d), v), want)
print('ok')
"""
    stderr = _python_with_kernels(code, built)
    # the user hears of it, once per kernel, with the types that were not covered
    said = [ln for ln in stderr.splitlines() if "ahead-of-time build does not cover" in ln]
    assert len(said) == 1 and "column_prefix" in said[0] and "float32[2d, C]" in said[0], stderr


def test_a_build_that_cannot_load_falls_back_to_the_jit(tmp_path):
    """A kernels module built for another Python or machine (here: not a shared object at all)
    is said once and left aside: the kernels run on numba's JIT, the same answers."""
    (tmp_path / (jit.MODULE + ".json")).write_text('{"exports": {}}')
    (tmp_path / (jit.MODULE + ".cpython-311-x86_64-linux-gnu.so")).write_bytes(b"not an ELF file")
    code = """
import numpy as np
from skyfix import jit
from skyfix.detect.path import column_prefix
assert not jit.ahead_of_time()
d = np.arange(6, dtype=np.float64).reshape(3, 2)
v = np.ones((3, 2), bool)
assert np.array_equal(column_prefix(d, v), np.vstack([np.zeros(2), np.cumsum(d, axis=0)]))
print('ok')
"""
    stderr = _python_with_kernels(code, tmp_path)
    said = [ln for ln in stderr.splitlines() if "cannot be used" in ln]
    assert len(said) == 1 and "ImportError" in said[0] and "board_kernels.py build" in said[0], stderr
