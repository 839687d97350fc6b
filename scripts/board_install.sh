#!/usr/bin/env bash
# The board install as a rover would carry it, and its footprint.
#
#   bash scripts/board_install.sh DIR
#
# A fresh virtual environment in DIR with skyfix and only the board's dependencies (pip install
# ., no extras: no Dask, matplotlib, scikit-learn, SciPy), then what flight software leaves on
# the ground: the installer (pip, setuptools) and the libraries' own test suites. Prints the size
# after each step. Check the result by running the board commands with it:
# python benchmarks/bench_board.py ... --board-python DIR/bin/python
set -euo pipefail
DIR="${1:?usage: bash scripts/board_install.sh DIR (a folder that does not exist yet)}"
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

"$DIR/bin/python" -m pip uninstall -q -y pip setuptools 2>/dev/null || true
size "without the installer"
find "$SITE" -mindepth 2 -type d \( -name tests -o -name test \) -prune -exec rm -rf {} +
size "without the libraries' test suites"
# Not stripped: the wheels' shared libraries are patched by auditwheel, and stripping them breaks
# their loading (numpy's OpenBLAS: "ELF load command address/offset not page-aligned").

# Everything the board commands load must still load (and numba compiles nothing here: its
# kernels are cached on the first run, next to the sources or under NUMBA_CACHE_DIR).
"$DIR/bin/python" - <<'PY'
import numba, cv2, rasterio, pyproj, zarr, numcodecs, numpy
import skyfix.cli.main, skyfix.pose, skyfix.detect, skyfix.profile, skyfix.database
print("board install imports: ok")
PY
size "board install"
