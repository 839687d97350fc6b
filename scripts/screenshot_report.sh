#!/usr/bin/env bash
# Render an evaluation report (report.html) in a real headless browser and save a screenshot, to
# check it as a reader sees it: tables laid out, figures shown, captions under them.
# Needs Debian's Chromium (apt-get install chromium).
# Usage: scripts/screenshot_report.sh REPORT.html OUT.png [WIDTH HEIGHT]
set -euo pipefail
REPORT=${1:?usage: screenshot_report.sh REPORT.html OUT.png [WIDTH HEIGHT]}
OUT=${2:?usage: screenshot_report.sh REPORT.html OUT.png [WIDTH HEIGHT]}
W=${3:-1200}
H=${4:-4000}
BROWSER=$(command -v chromium || command -v chromium-browser || true)
if [ -z "$BROWSER" ]; then
  echo "no Chromium found: apt-get install chromium" >&2
  exit 2
fi
[ -f "$REPORT" ] || { echo "no report $REPORT" >&2; exit 2; }
ABS=$(cd "$(dirname "$REPORT")" && pwd)/$(basename "$REPORT")
"$BROWSER" --headless --no-sandbox --disable-gpu --hide-scrollbars \
  --window-size="$W,$H" --screenshot="$OUT" "file://$ABS" 2>/dev/null
test -s "$OUT" && echo "screenshot of $REPORT -> $OUT"
