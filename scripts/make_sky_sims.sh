#!/usr/bin/env bash
# Simulated training frames for the sky classifier (seeds 901-905: never used for evaluation).
# Usage: scripts/make_sky_sims.sh OUT_DIR   (then scripts/train_sky_model.py --sim OUT_DIR/* --sim-max-frames 10)
set -euo pipefail
OUT=${1:?usage: make_sky_sims.sh OUT_DIR}
D=../shared/data/dem
skyfix simulate-set $D/sierra_nevada_30m.tif --set REF --cases 3 --seed 901 --frames 6 --tilt-deg 15 --out "$OUT/sierra_ref" --overwrite
skyfix simulate-set $D/sierra_nevada_30m.tif --set CLUT --cases 2 --seed 902 --frames 6 --tilt-deg 0 --out "$OUT/sierra_clut" --overwrite
skyfix simulate-set $D/alps_srtm3_n46e008.tif --set COND --cases 3 --seed 903 --frames 6 --tilt-deg 0 --out "$OUT/alps_cond" --overwrite
skyfix simulate-set $D/south_glacier_20m.tif --set OCCL --cases 2 --seed 904 --frames 6 --tilt-deg 0 --planet mars --out "$OUT/glacier_mars_occl" --overwrite
skyfix simulate-set $D/alps_srtm3_n46e008.tif --set REF --cases 2 --seed 905 --frames 6 --tilt-deg 15 --planet mars --out "$OUT/alps_mars_ref" --overwrite
