#!/usr/bin/env bash
# The board install as a rover would carry it, and its footprint.
#
#   bash scripts/board_install.sh DIR [--no-jit]
#
# A fresh virtual environment in DIR with skyfix and only the board's dependencies (pip install
# ., no extras: no Dask, matplotlib, scikit-learn, SciPy), the board's kernels compiled ahead of
# time (scripts/board_kernels.py), then what flight software leaves on the ground: the installer
# (pip, setuptools), the libraries' own test suites and, with --no-jit, numba and LLVM (a kernel
# called with argument types the build did not cover is then an error). Prints the size after
# each step. Check the result by running the board commands with it:
# python benchmarks/bench_board.py ... --board-python DIR/bin/python
set -euo pipefail
DIR="${1:?usage: bash scripts/board_install.sh DIR [--no-jit] (DIR a folder that does not exist yet)}"
NO_JIT="${2:-}"
if [ -n "$NO_JIT" ] && [ "$NO_JIT" != "--no-jit" ]; then
  echo "board_install: unknown option $NO_JIT (the one option is --no-jit)" >&2
  exit 2
fi
if [ -e "$DIR" ]; then
  echo "board_install: $DIR exists; give a new folder (nothing was changed)" >&2
  exit 2
fi
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
size() {  # the files' bytes in MB (10^6), and what they take on this disk in MiB
  echo "$1: $(( $(du -sb --apparent-size "$DIR" | cut -f1) / 1000000 )) MB of files," \
       "$(du -sm "$DIR" | cut -f1) MiB on disk"
}

SRC="$(mktemp -d)"
trap 'rm -rf "$SRC"' EXIT
# from a clean copy of the sources: a build/ folder left in the checkout can carry stale modules
cp -r "$ROOT/pyproject.toml" "$ROOT/README.md" "$ROOT/src" "$SRC/"
find "$SRC" -name __pycache__ -prune -exec rm -rf {} +
python3 -m venv "$DIR"
"$DIR/bin/python" -m pip install -q "$SRC"
size "pip install . (the board install as pip leaves it)"
SITE="$("$DIR/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
if "$DIR/bin/python" -c "import scipy" 2>/dev/null; then
  echo "board_install: SciPy got installed; the board install must not need it" >&2
  exit 1
fi

# The board's numba kernels compiled ahead of time for this machine's processor (skyfix.jit;
# scripts/board_kernels.py --cpu names another): the board commands then run without loading
# numba and LLVM. Done before the installer goes: numba's pycc builds with setuptools and gcc.
"$DIR/bin/python" "$ROOT/scripts/board_kernels.py" build
size "with the kernels compiled ahead of time"

if [ "$NO_JIT" = "--no-jit" ]; then
  # numba and LLVM only compile what the build did not cover (argument types never recorded):
  # without them such a call is an error that says so, and the install is 200 MB lighter
  "$DIR/bin/python" -m pip uninstall -q -y numba llvmlite
  size "without numba and LLVM (--no-jit)"
fi
"$DIR/bin/python" -m pip uninstall -q -y pip setuptools 2>/dev/null || true
size "without the installer"
find "$SITE" -mindepth 2 -type d \( -name tests -o -name test \) -prune -exec rm -rf {} +
size "without the libraries' test suites"
# Not stripped: the wheels' shared libraries are patched by auditwheel, and stripping them breaks
# their loading (numpy's OpenBLAS: "ELF load command address/offset not page-aligned").

# Everything the board commands load must still load, and their kernels come from the build.
"$DIR/bin/python" - <<'PY'
import cv2, rasterio, pyproj, zarr, numcodecs, numpy
import skyfix.cli.main, skyfix.pose, skyfix.detect, skyfix.profile, skyfix.database
print("board install imports: ok")
PY
"$DIR/bin/python" - <<'PY'
import sys
import numpy as np
from skyfix import jit
from skyfix.detect import detect_skyline
detect_skyline(np.full((64, 96), 128, np.uint8))  # the kernels of a detection, from the build
assert jit.ahead_of_time() and "numba" not in sys.modules, "the ahead-of-time kernels did not load"
print("board kernels ahead of time: ok (numba not loaded)")
PY
size "board install"
