#!/usr/bin/env bash
# Simulated sets for the detection benchmark (seeds 41-44: never used for training or calibration).
# Usage: scripts/make_detect_sims.sh OUT_DIR   (then python benchmarks/bench_detect.py --methods dp --no-all --sim OUT_DIR)
set -euo pipefail
OUT=${1:?usage: make_detect_sims.sh OUT_DIR}
D=../shared/data/dem
skyfix simulate-set $D/sierra_nevada_30m.tif --set REF --cases 2 --seed 41 --frames 6 --tilt-deg 15 --out "$OUT/REF" --overwrite
skyfix simulate-set $D/sierra_nevada_30m.tif --set CLUT --cases 2 --seed 42 --frames 6 --tilt-deg 15 --out "$OUT/CLUT" --overwrite
skyfix simulate-set $D/south_glacier_20m.tif --set OCCL --cases 2 --seed 43 --frames 6 --tilt-deg 15 --planet mars --out "$OUT/OCCL" --overwrite
skyfix simulate-set $D/alps_srtm3_n46e008.tif --set COND --cases 3 --seed 44 --frames 6 --tilt-deg 15 --planet mars --out "$OUT/COND" --overwrite
