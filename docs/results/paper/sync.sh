#!/bin/bash
# Copy the campaign's records (no weights, no checkpoints) from OUT into this folder, chunk by chunk.
# Usage, from the repository's root: OUT=../campaign-out bash docs/results/paper/sync.sh
set -u
OUT=$(realpath -m "${OUT:-../campaign-out}")
HERE=$(realpath "$(dirname "$0")")
cd "$OUT" || exit 1
for c in */; do
  c=${c%/}
  [ -f "$c/study.json" ] || continue
  mkdir -p "$HERE/$c"
  cp "$c/study.json" "$HERE/$c/"
  find "$c/runs" -type f \( -name config.json -o -name scalars.csv -o -name episodes.jsonl -o -name metrics.json \
    -o -name eval.json -o -name job.json \) | while read -r f; do
    mkdir -p "$HERE/$(dirname "$f")"; cp "$f" "$HERE/$f"; done
done
