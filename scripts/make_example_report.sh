#!/usr/bin/env bash
# Regenerate docs/example-report/ (the committed example evaluation) from the repo root:
#   scripts/make_example_report.sh [DB]
# DB: the 7 x 7 km / 5 m Sierra store for scenario 1 (built here if missing: ~10-25 min on 2 cores).
set -euo pipefail
DEM=../shared/data/dem/sierra_nevada_30m.tif
DB=${1:-../skyfix-data/sierra_7km_5m.zarr}
OUT=docs/example-report
CASES=${CASES:-10}
if [ ! -f "$DB/zarr.json" ] || ! skyfix info "$DB" | grep -q "(complete)"; then
  skyfix build-db "$DEM" --out "$DB" --bounds 297800 4143100 304800 4150100 --spacing-m 5
fi
skyfix evaluate --dem "$DEM" --scenario 1 --db "$DB" --sets REF,LREL --cases "$CASES" --seed 1 --out "$OUT/scenario1" --overwrite
skyfix evaluate --dem "$DEM" --scenario 2 --sets REF,LREL,OCCL --cases "$CASES" --seed 2 --out "$OUT/scenario2" --overwrite
skyfix evaluate --dem "$DEM" --scenario 3 --sets REF,LREL,CLUT --cases "$CASES" --seed 3 --out "$OUT/scenario3" --overwrite
# The simulated images are reproducible from the seeds; keep the repository small.
rm -rf "$OUT"/scenario*/cases
# Diagnosis: the same cases with detection bypassed by the simulator's exact skylines, to separate
# the localisation layer's accuracy from the detector's (labelled as such in each report).
skyfix evaluate --dem "$DEM" --scenario 1 --db "$DB" --sets REF,LREL --cases "$CASES" --seed 1 --skylines truth --out "$OUT/scenario1-truth-skylines" --overwrite
skyfix evaluate --dem "$DEM" --scenario 2 --sets REF,LREL,OCCL --cases "$CASES" --seed 2 --skylines truth --out "$OUT/scenario2-truth-skylines" --overwrite
skyfix evaluate --dem "$DEM" --scenario 3 --sets REF,LREL,CLUT --cases "$CASES" --seed 3 --skylines truth --out "$OUT/scenario3-truth-skylines" --overwrite
rm -rf "$OUT"/scenario*/cases
