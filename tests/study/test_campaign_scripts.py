"""docs/results/paper/queue.sh and sync.sh, the campaign's plan and its copy back, run on a fake `reproduce`.

The fake (a shell script in place of the worktrees' Python) logs each call and marks its jobs finished the
way a real call leaves them (eval.json, metrics.json and a study.json in the chunk), so the plan's logic is
checked without training: every call once, a pair's halves side by side, the deadline, the fill call and its
study.json.stop snapshots, and what sync.sh copies."""

from __future__ import annotations

import json
import os
import subprocess
import time
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parents[2] / "docs/results/paper"
FAKE = """#!/bin/bash
while [ $# -gt 0 ]; do case $1 in --out) out=$2; shift;; --methods) m=$2; shift;; --scenes) s=$2; shift;;
  --profiles) p=$2; shift;; esac; shift; done
echo "start $(basename $out) $p $m $s" >> "$LOG"
sleep "${FAKE_SLEEP:-0}"
for mm in ${m//,/ }; do for ss in ${s//,/ }; do
  d=$out/runs/$ss/$mm; [ "$p" = safe ] && d=$out/runs/safe/$ss/$mm
  mkdir -p "$d"; echo '{}' > "$d/eval.json"; echo '{}' > "$d/metrics.json"; echo x > "$d/weights.pt"
done; done
echo '{"after": "'"$m $s"'"}' > "$out/study.json"
echo "end $(basename $out) $p $m $s" >> "$LOG"
"""


@pytest.fixture
def campaign(tmp_path):
    tree = tmp_path / "tree"
    (tree / ".venv/bin").mkdir(parents=True)
    (tree / ".venv/bin/python").write_text(FAKE)
    (tree / ".venv/bin/python").chmod(0o755)
    (tmp_path / "out").mkdir()
    return tmp_path


def _queue(root: Path, deadline: float, fill_until: float = 0, sleep: float = 0) -> list[str]:
    env = {**os.environ, "CAMPAIGN": str(root / "tree"), "CAMPAIGN_SAFE": str(root / "tree"), "OUT": str(root / "out"),
           "DEADLINE": str(int(deadline)), "FILL_UNTIL": str(int(fill_until)), "FAKE_SLEEP": str(sleep),
           "LOG": str(root / "calls")}
    (root / "calls").write_text("")
    done = subprocess.run(["bash", str(HERE / "queue.sh")], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    return (root / "calls").read_text().splitlines()


def _planned() -> list[str]:
    """'CHUNK PROFILE METHODS SCENES' of every call the plan names, a pair's two halves each."""
    out = []
    for line in (HERE / "queue.sh").read_text().splitlines():
        words = line.split("#")[0].split()
        if words[:1] == ["call"]:
            out.append(words[1:7])
        elif words[:1] == ["pair"]:
            out += [words[1:7], words[7:13]]
    return [f"{chunk} {profile} {methods} {scenes}" for profile, chunk, _, methods, scenes, _ in out]


def test_a_free_period_runs_every_planned_call_once_and_a_second_none(campaign):
    planned = _planned()
    calls = _queue(campaign, time.time() + 10**6)
    assert sorted(c.removeprefix("start ") for c in calls if c.startswith("start")) == sorted(planned)
    assert _queue(campaign, time.time() + 10**6) == []  # every job finished: passed over


def test_no_call_starts_past_the_deadline_and_the_fill_runs_the_next_one_alone(campaign):
    assert _queue(campaign, time.time() - 1) == []
    calls = _queue(campaign, time.time() - 1, fill_until=time.time() + 600)
    first = _planned()[0]
    assert calls == [f"start {first}", f"end {first}"]  # the fill: the first unfinished call, then the end
    assert not list((campaign / "out").glob("*/study.json.stop"))  # its snapshots go once it ended


def test_a_pair_runs_its_halves_side_by_side_and_a_fill_keeps_the_snapshots_until_both_end(campaign):
    planned = _planned()
    pair = next(line for line in (HERE / "queue.sh").read_text().splitlines() if line.startswith("pair "))
    words = pair.split()
    halves = {f"{words[2]} {words[1]} {words[4]} {words[5]}", f"{words[8]} {words[7]} {words[10]} {words[11]}"}
    _queue(campaign, time.time() + 10**6)  # everything finished ...
    out = campaign / "out"
    for half in halves:  # ... but the pair's two jobs
        chunk, profile, method, scene = half.split()
        (out / chunk / "runs" / scene / method / "eval.json").unlink()
    (out / "seeds-0-2" / "study.json").write_text('{"before": "the fill"}')
    (campaign / "calls").write_text("")
    env_fill = time.time() + 600
    proc = subprocess.Popen(["bash", str(HERE / "queue.sh")], env={
        **os.environ, "CAMPAIGN": str(campaign / "tree"), "CAMPAIGN_SAFE": str(campaign / "tree"), "OUT": str(out),
        "DEADLINE": str(int(time.time() - 1)), "FILL_UNTIL": str(int(env_fill)), "FAKE_SLEEP": "3",
        "LOG": str(campaign / "calls")}, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    assert _snapshot_while_running(proc, out / "seeds-0-2/study.json.stop") == {"before": "the fill"}
    assert proc.wait(timeout=60) == 0
    calls = (campaign / "calls").read_text().splitlines()
    assert [c.split()[0] for c in calls] == ["start", "start", "end", "end"]  # both ran at once
    assert {c.removeprefix("start ") for c in calls[:2]} == halves and halves <= set(planned)
    assert not list(out.glob("*/study.json.stop"))


def _snapshot_while_running(proc: subprocess.Popen, path: Path) -> dict | None:
    """The snapshot's JSON as soon as it is written, read while the fill runs (polled: a loaded machine may
    take a while to reach it); None if the script ended first."""
    while proc.poll() is None:
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError):  # not there yet, or caught mid-copy
            time.sleep(0.02)
    return None


def test_sync_copies_finished_jobs_records_without_weights_and_the_snapshot_in_place_of_study_json(campaign, tmp_path):
    out = campaign / "out"
    run = out / "seeds-2/runs/two-lane/rl"
    run.mkdir(parents=True)
    for name in ("config.json", "eval.json", "metrics.json", "episodes.jsonl", "weights.pt"):
        (run / name).write_text("{}")
    half = out / "seeds-2/runs/merge/rl"  # still training: no eval.json
    half.mkdir(parents=True)
    (half / "metrics.json").write_text("{}")
    (out / "seeds-2/study.json").write_text('{"lists": "the job in training"}')
    (out / "seeds-2/study.json.stop").write_text('{"as": "before the fill"}')
    dest = tmp_path / "repo/docs/results/paper"
    dest.mkdir(parents=True)
    (dest / "sync.sh").write_text((HERE / "sync.sh").read_text())
    done = subprocess.run(["bash", str(dest / "sync.sh")], env={**os.environ, "OUT": str(out)}, capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    copied = sorted(p.name for p in (dest / "seeds-2/runs/two-lane/rl").iterdir())
    assert copied == ["config.json", "episodes.jsonl", "eval.json", "metrics.json"]
    assert not (dest / "seeds-2/runs/merge").exists()
    assert json.loads((dest / "seeds-2/study.json").read_text()) == {"as": "before the fill"}
