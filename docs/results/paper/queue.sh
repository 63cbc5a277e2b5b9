#!/bin/bash
# The campaign's plan: resumable `reproduce` calls, one thread per job, two jobs at once, in the order of
# README.md here. A call whose jobs have finished (eval.json in OUT) is passed over; any other starts only if
# its estimate (minutes on two free cores) ends before DEADLINE, so that a work period ends with no job half
# trained (a wiped machine would lose it); a later, shorter call may still fit.
# Usage, from a checkout of this repository (the worktrees' commits: README.md here):
#   git worktree add --detach ../campaign 92e3795 && (cd ../campaign && make setup)
#   git worktree add --detach ../campaign-safe 7344cc8 && (cd ../campaign-safe && make setup)
#   mkdir -p ../campaign-out && cp -r docs/results/paper/*seeds-* ../campaign-out/   # the finished jobs
#   DEADLINE=$(date -d '+150 min' +%s) OUT=../campaign-out setsid nohup bash docs/results/paper/queue.sh \
#     > ../campaign-out/queue.log 2>&1 < /dev/null &
#   echo 19 > /proc/PID/autogroup   # keep it behind interactive work (README.md here)
# then copy the records back with docs/results/paper/sync.sh and rebuild the report (README.md here).
# With FILL_UNTIL (a time, e.g. "$(date -d '+170 min' +%s)") the plan's pass is followed, if it ends before
# FILL_UNTIL, by the first unfinished call whatever its estimate: the period's end is killed with it, and it
# resumes from its last checkpoint in the next period if the machine keeps its files. Before it starts, each
# chunk's study.json is kept as study.json.stop, which sync.sh copies in its place (no half-run job listed).
set -u
PAPER=$(realpath -m "${CAMPAIGN:-../campaign}")      # paper profile: 92e3795 (pins equal to 1d3a74e's)
SAFE=$(realpath -m "${CAMPAIGN_SAFE:-../campaign-safe}")  # safe profile: 7344cc8 (b696c91's rules, kept_its_line's verdicts; README.md here)
OUT=$(realpath -m "${OUT:-../campaign-out}")
DEADLINE=${DEADLINE:-$(date -d '+150 min' +%s)}
FILL_UNTIL=${FILL_UNTIL:-0} FILL=
rm -f "$OUT"/*/study.json.stop  # a new period: the last one's fill call resumes and writes its study.json
finished() {  # folder methods scenes: every named job has eval.json there
  local m s
  for m in ${2//,/ }; do for s in ${3//,/ }; do [ -f "$1/$s/$m/eval.json" ] || return 1; done; done
}
call() {  # profile chunk seeds methods scenes minutes; returns 1 if it passed the call over
  local tree=$PAPER runs="$OUT/$2/runs"
  [ "$1" = safe ] && tree=$SAFE runs="$OUT/$2/runs/safe"
  if finished "$runs" "$4" "$5"; then return 1; fi
  if [ -z "$FILL" ] && (( $(date +%s) + $6 * 60 > DEADLINE )); then echo "$(date -Is) no time left for: $*"; return 1; fi
  [ -n "$FILL" ] && echo "$(date -Is) fill: $* (to be resumed if stopped)"
  (cd "$tree" && OMP_NUM_THREADS=1 nice -n 19 .venv/bin/python -m highway_srl.cli reproduce --budget paper \
    --profiles "$1" --seeds "$3" --jobs 2 --out "$OUT/$2" --methods "$4" --scenes "$5")
  echo "$(date -Is) done: $*"
  if [ -n "$FILL" ] && [ -z "${PAIRED:-}" ]; then rm -f "$OUT"/*/study.json.stop; exit; fi
}
pair() {  # two one-job calls side by side, each its 6 arguments: their chunks differ, which one reproduce
  # call cannot span, and one job alone would leave a core idle; a fill pair ends the script when both end
  local a b ran=
  PAIRED=1 call "${@:1:6}" & a=$!
  PAIRED=1 call "${@:7:6}" & b=$!
  wait $a && ran=1
  wait $b && ran=1
  if [ -n "$FILL" ] && [ -n "$ran" ]; then rm -f "$OUT"/*/study.json.stop; exit; fi
}
plan() {
# safe profile (beyond the paper), MoE-RM-SRL one seed a chunk in the nominal scenes first: three seeds there
# are the safe promise's last open target (docs/results.md); the adversarial scenes follow the paper baselines
call safe safe-seeds-0 0 moe-rm-srl two-lane,multi-lane 35
call safe safe-seeds-0 0 moe-rm-srl merge,exit 60
call safe safe-seeds-1 1 moe-rm-srl two-lane,multi-lane 35
call safe safe-seeds-1 1 moe-rm-srl merge,exit 60
call safe safe-seeds-2 2 moe-rm-srl two-lane,multi-lane 35
call safe safe-seeds-2 2 moe-rm-srl merge,exit 60
# paper profile: MoE-RM-SRL (and the ablations) in every scene, the two-lane baselines and the merge RL, SR-RL and
# MP-RL have seeds 0-1 or 0-2 (tables/progress.md). The jobs not started take seeds 0-2 batched in one process
# (chunk seeds-0-2: about 1/7 less CPU than seeds 0-1 and seed 2 apart, by docs/benchmarks.md's 1- and
# 10-seed training rows), two jobs a call; LM-RL, 1.8x slower a step, takes seeds 0-1 so that a call fits a work period
call paper seeds-0-1 0,1 lm-rl merge,exit 110
call paper seeds-0-2 0,1,2 rl,sr-rl exit 110
call paper seeds-0-2 0,1,2 mp-rl,et-rl exit 110
call paper seeds-0-2 0,1,2 et-rl merge,adv-merge 110
call paper seeds-0-2 0,1,2 rl,sr-rl adv-two-lane 110
call paper seeds-0-2 0,1,2 mp-rl,et-rl adv-two-lane 110
call paper seeds-0-2 0,1,2 rl,sr-rl adv-merge 110
call paper seeds-0-2 0,1,2 mp-rl adv-merge,adv-exit 110
call paper seeds-0-2 0,1,2 rl,sr-rl adv-exit 110
call paper seeds-0-1 0,1 lm-rl adv-two-lane,adv-merge 110
pair paper seeds-0-2 0,1,2 et-rl adv-exit 90 paper seeds-0-1 0,1 lm-rl adv-exit 110
# LM-RL's third seed where it has two: the last paper-profile jobs under three seeds, before the safe
# adversarial calls (one LM-RL seed on one core: about 60 min, as the seeds-2 runs took)
call paper seeds-2 2 lm-rl merge,exit 65
call paper seeds-2 2 lm-rl adv-two-lane,adv-merge 65
call safe safe-seeds-0 0 moe-rm-srl adv-exit,adv-multi-lane 35
call safe safe-seeds-1 1 moe-rm-srl adv-exit,adv-multi-lane 35
call safe safe-seeds-2 2 moe-rm-srl adv-exit,adv-multi-lane 35
# adv-two-lane brings the three ablations: five one-seed jobs, about 90 min (as seed 0's took)
call safe safe-seeds-0 0 moe-rm-srl adv-two-lane,adv-merge 90
call safe safe-seeds-1 1 moe-rm-srl adv-two-lane,adv-merge 90
call safe safe-seeds-2 2 moe-rm-srl adv-two-lane,adv-merge 90
# the third seed of the baselines that have seeds 0-1, one seed a call, two jobs a call (the short calls fill
# the time a 110-min call leaves in a work period)
call paper seeds-2 2 rl two-lane 35  # one job: best run by hand beside a call whose last job leaves a core idle
call paper seeds-2 2 rl,sr-rl merge 35
call paper seeds-2 2 mp-rl,et-rl two-lane 35
pair paper seeds-2 2 mp-rl merge 35 paper seeds-3 3 moe-rm-srl two-lane 35  # MoE-RM-SRL's fourth seed beside
call paper seeds-2 2 sr-rl,lm-rl two-lane 55
pair paper seeds-2 2 lm-rl adv-exit 55 paper seeds-3 3 moe-rm-srl merge 35
# then SR-RL and MP-RL under the safe profile, and seeds 3 and on (seeds-3, ...), in the same order
}
plan
if (( $(date +%s) < FILL_UNTIL )); then
  for f in "$OUT"/*/study.json; do cp "$f" "$f.stop"; done
  FILL=1 plan
fi
