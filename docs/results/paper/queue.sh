#!/bin/bash
# The campaign's queue as this folder's chunks were made: resumable `reproduce` calls, one thread per job,
# from a worktree pinned at a commit whose paper-profile pins are the first chunks' (1d3a74e): the calls below
# run from 92e3795 (LM-RL's a' from the target networks; every other method's pin is 1d3a74e's there).
# Usage, from a checkout of this repository:
#   git worktree add --detach ../campaign 92e3795 && (cd ../campaign && make setup)
#   CAMPAIGN=../campaign OUT=../campaign-out setsid nohup bash docs/results/paper/queue.sh > queue.log 2>&1 &
#   echo 19 > /proc/PID/autogroup   # keep it behind interactive work (README.md here)
# then copy the records back with docs/results/paper/sync.sh and rebuild the report (README.md here).
# Each call finishes within a work period of about three hours on two free cores; the order is README.md's.
set -u
CAMPAIGN=${CAMPAIGN:-../campaign}
PROFILES=${PROFILES:-paper}  # safe: the chunks beyond the paper, from a worktree with today's safe profile
OUT=$(realpath -m "${OUT:-../campaign-out}")
cd "$CAMPAIGN" || exit 1
run() {  # chunk seeds methods scenes
  OMP_NUM_THREADS=1 nice -n 19 .venv/bin/python -m highway_srl.cli reproduce --budget paper --profiles "$PROFILES" \
    --seeds "$2" --jobs 2 --out "$OUT/$1" --methods "$3" --scenes "$4"
  echo "$(date -Is) done: $*"
}
# done: every MoE-RM-SRL job (and the ablations) at seeds 0-2; seeds-0-1 every two-lane baseline and rl merge
#   (tables/progress.md says what is finished)
run seeds-0-1 0,1 sr-rl,mp-rl merge
run seeds-0-1 0,1 et-rl,lm-rl merge
run seeds-0-1 0,1 rl,sr-rl exit
run seeds-0-1 0,1 mp-rl,et-rl exit
run seeds-0-1 0,1 lm-rl exit,adv-two-lane
run seeds-0-1 0,1 rl,sr-rl adv-two-lane
run seeds-0-1 0,1 mp-rl,et-rl adv-two-lane
# next: the adversarial merge and exit baselines, then seed 2 of every baseline (seeds-2), then seeds 3 and on;
# under the safe profile (PROFILES=safe CAMPAIGN=../campaign-safe, a worktree at b696c91, whose safe profile the
# falsifier's sweeps found no ego-avoidable collision in: docs/results/falsify-safe):
#   safe-seeds-0-1 moe-rm-srl in every scene first, then sr-rl,mp-rl
