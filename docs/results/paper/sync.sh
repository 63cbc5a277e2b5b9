#!/bin/bash
# Copy the campaign's records (no weights, no checkpoints) from OUT into this folder, chunk by chunk: the
# finished jobs only (metrics.json and eval.json written), and a chunk only once one of its jobs has finished,
# so that a job still training leaves nothing here to clean up. A chunk's study.json.stop (queue.sh's fill call
# runs there) is copied as its study.json: the study as it stood before that call.
# Usage, from the repository's root: OUT=../campaign-out bash docs/results/paper/sync.sh
set -u
OUT=$(realpath -m "${OUT:-../campaign-out}")
HERE=$(realpath "$(dirname "$0")")
cd "$OUT" || exit 1
for c in */; do
  c=${c%/}
  [ -f "$c/study.json" ] || continue
  find "$c/runs" -name eval.json -printf '%h\n' 2>/dev/null | sort | while read -r run; do
    [ -f "$run/metrics.json" ] || continue
    mkdir -p "$HERE/$run"
    for f in config.json scalars.csv episodes.jsonl metrics.json eval.json job.json; do
      [ -f "$run/$f" ] && cp "$run/$f" "$HERE/$run/"
    done
    study=$c/study.json
    [ -f "$study.stop" ] && study=$study.stop
    cp "$study" "$HERE/$c/study.json"
  done
done
