#!/bin/bash
# The campaign's queue as this folder's chunks were made: resumable `reproduce` calls, one thread per job,
# from a worktree pinned at the chunks' commit (1d3a74e). Usage, from a checkout of this repository:
#   git worktree add --detach ../campaign 1d3a74e && (cd ../campaign && make setup)
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
# done: seeds-0-1 two-lane,merge; seeds-0-1 exit,adv-merge (tables/progress.md says what is finished)
run seeds-2 2 moe-rm-srl two-lane,merge
run seeds-2 2 moe-rm-srl exit,adv-merge
run seeds-0-1 0,1 moe-rm-srl adv-exit,multi-lane
run seeds-0-1 0,1 moe-rm-srl adv-two-lane,adv-multi-lane  # restarted from scratch on a new machine
run seeds-2 2 moe-rm-srl adv-exit,multi-lane
run seeds-2 2 moe-rm-srl adv-two-lane,adv-multi-lane
# done: seeds-0-1 rl,sr-rl two-lane; seeds-0-1 rm-rl,mp-rl two-lane; seeds-0-1 lm-rl two-lane;
#       seeds-0-1 et-rl,rule-based two-lane; seeds-0-1 rl merge
# next (in training at the last stop): seeds-0-1 sr-rl merge; then mp-rl,et-rl merge; lm-rl merge;
# then exit and the adversarial scenes, then seed 2 of every baseline;
# LM-RL's jobs from a worktree at 92e3795 or later (its a' from the target networks; every other method's
# behaviour pin is 1d3a74e's there)
# next, under the safe profile (PROFILES=safe CAMPAIGN=../campaign-safe, a worktree at be654c2 or later):
#   run safe-seeds-0-1 0,1 moe-rm-srl two-lane,merge   and on through every scene, then sr-rl,mp-rl
