#!/bin/sh
# `tessera view` in windowed mode (GLFW on an X server, the HUD drawn) end to end: Xvfb stands in
# for a display. Fails when xvfb-run is missing: tools/setup.sh --tests installs it, so a machine without it
# is broken, and a skip would read as a pass. Usage: view_window_smoke.sh TESSERA
set -eu
tessera="$1"
command -v xvfb-run >/dev/null 2>&1 || { echo "xvfb-run not found (tools/setup.sh --tests installs xvfb and xauth)"; exit 1; }
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
"$tessera" build procedural:terrain:2048 -o "$dir/t.tsr" -q
xvfb-run -a -s "-screen 0 640x480x24" "$tessera" view --store "$dir/t.tsr" --frames 90 --size 320x180 \
    --stats "$dir/stats.csv" >"$dir/out.txt" 2>&1 || { cat "$dir/out.txt"; exit 1; }
grep -q "^frames *90 in" "$dir/out.txt" || { echo "no summary of 90 frames"; cat "$dir/out.txt"; exit 1; }
# 90 frame rows; the last one textured with no fallback left (the view loaded).
rows=$(($(wc -l <"$dir/stats.csv") - 1))
[ "$rows" -eq 90 ] || { echo "expected 90 rows, got $rows"; exit 1; }
tail -n 1 "$dir/stats.csv" | awk -F, '{ if ($10 + 0 <= 0 || $11 + 0 != 0) { print "last frame: textured " $10 ", fallback " $11; exit 1 } }'
echo "windowed view: 90 frames, last frame fully resident"
