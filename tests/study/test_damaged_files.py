"""A damaged file of a study (study.json, a job's metrics.json, eval.json or episodes.jsonl) stops the
report with one line naming the file and the field, exit status 2, and leaves the report it would have
replaced as it was: never a traceback, a table quietly missing rows, or a report of None values."""

from __future__ import annotations

import json
import shutil

import pytest
import study_fakes as fakes

from highway_srl.cli import main
from highway_srl.study.jobs import OURS
from highway_srl.study.runner import reproduce
from highway_srl.study.results import load_results


@pytest.fixture(scope="module")
def good_study(tmp_path_factory):
    root = tmp_path_factory.mktemp("good") / "study"
    reproduce("smoke", root, jobs=1, work=fakes.fake_work, log=lambda s: None, report=False)
    assert main(["reproduce", "--out", str(root), "--report-only"]) == 0
    return root


def _edit_json(path, change) -> None:
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


def _edit_first_line(path, change) -> None:
    lines = path.read_text().splitlines(keepends=True)
    row = json.loads(lines[0])
    change(row)
    path.write_text(json.dumps(row) + "\n" + "".join(lines[1:]))


DAMAGE = {  # name: (file under the job folder or the study, how it is damaged, what the line must say)
    "metrics-mean-text": ("metrics.json", lambda p: _edit_json(p, lambda d: d["mean"].update(T_c="high")),
                          "metrics.json: mean: T_c must be a number from 0 to 1"),
    "metrics-no-per-seed": ("metrics.json", lambda p: _edit_json(p, lambda d: d.pop("per_seed")),
                            "metrics.json: per_seed must be a JSON object"),
    "eval-rate-above-1": ("eval.json", lambda p: _edit_json(p, lambda d: d["levels"]["C"]["C_r"].update(value=1.5)),
                          "eval.json: levels.C.C_r: value must be a number from 0 to 1"),
    "eval-not-json": ("eval.json", lambda p: p.write_text('{"method": '), "eval.json is not valid JSON"),
    "episode-other-seed": ("episodes.jsonl", lambda p: _edit_first_line(p, lambda r: r.update(seed=7)),
                           "episodes.jsonl line 1 is damaged: seed 7 is not one of the run's seeds"),
    "episode-text-return": ("episodes.jsonl", lambda p: _edit_first_line(p, lambda r: r.update({"return": "x"})),
                            "episodes.jsonl line 1 is damaged: the row: return must be a finite number"),
    "metrics-verdict-text": ("metrics.json", lambda p: _edit_json(p, lambda d: d.update(collision_verdicts={
        "all": {"collisions": 1, "ego_avoidable": "one", "unavoidable": 0, "not_judged": 0}})),
        "metrics.json: collision_verdicts.all: ego_avoidable must be a non-negative integer"),
    "eval-verdict-negative": ("eval.json", lambda p: _edit_json(
        p, lambda d: d["levels"]["C"]["collisions"].update(ego_avoidable=0, unavoidable=-1)),
        "eval.json: levels.C.collisions: unavoidable must be a non-negative integer"),
    "study-empty": ("../study.json", lambda p: p.write_text("{}"), "study.json: budget is missing"),
    "study-jobs-list": ("../study.json", lambda p: _edit_json(p, lambda d: d.update(jobs=[])),
                        "study.json: jobs must be a JSON object, got []"),
    "study-budget-config-null": ("../study.json", lambda p: _edit_json(p, lambda d: d.update(budget_config=None)),
                                 "study.json: budget_config must be a JSON object, got null"),
    "study-invocations-null": ("../study.json", lambda p: _edit_json(p, lambda d: d.update(invocations=None)),
                               "study.json: invocations must be a JSON list, got null"),
    "study-steps-text": ("../study.json", lambda p: _edit_json(p, lambda d: d["budget_config"].update(steps="1e3")),
                         "study.json: budget_config: steps must be a non-negative integer"),
    "study-job-seeds-text": ("../study.json", lambda p: _edit_job(p, lambda j: j.update(seeds="x")),
                             "study.json: jobs.two-lane/moe-rm-srl.job: seeds must be a JSON list, each item a "
                             "non-negative integer"),
    "study-job-method-number": ("../study.json", lambda p: _edit_job(p, lambda j: j.update(method=5)),
                                "study.json: jobs.two-lane/moe-rm-srl.job: method must be a string, got 5"),
    "study-job-unknown-scene": ("../study.json", lambda p: _edit_job(p, lambda j: j.update(scene="nope")),
                                "study.json: jobs.two-lane/moe-rm-srl.job: unknown scene 'nope'"),
    "study-job-episodes-negative": ("../study.json", lambda p: _edit_job(p, lambda j: j.update(eval_episodes=-5)),
                                    "study.json: jobs.two-lane/moe-rm-srl.job: eval_episodes must be a non-negative"),
    "study-seeds-negative": ("../study.json", lambda p: _edit_json(p, lambda d: d["budget_config"].update(seeds=[-1])),
                             "study.json: budget_config: seeds must be a JSON list, each item a non-negative integer"),
    "metrics-seed-key": ("metrics.json", lambda p: _edit_json(p, lambda d: d.update(per_seed={"x": {"episodes": 1}})),
                         'metrics.json: per_seed: "x" is not a seed'),
    "eval-trained-seeds-text": ("eval.json", lambda p: _edit_json(p, lambda d: d.update(trained_seeds="0")),
                                "eval.json: trained_seeds must be a JSON list, each item a non-negative integer"),
    # the kinds of damage tests/cli/test_records.py gives each run file, where the cases above leave them out
    "study-nan": ("../study.json", lambda p: _edit_json(p, lambda d: d["budget_config"].update(replay_ratio=NAN)),
                  "study.json: budget_config: replay_ratio must be a finite number or null, got nan"),
    "study-garbage-line": ("../study.json", lambda p: _garbage(p), "study.json is not valid JSON"),
    "study-truncated": ("../study.json", lambda p: _truncated(p), "study.json is not valid JSON"),
    "eval-missing-field": ("eval.json", lambda p: _edit_json(p, lambda d: d["levels"]["C"].pop("R_r")),
                           "eval.json: levels.C.R_r must be a JSON object"),
    "eval-nan": ("eval.json", lambda p: _edit_json(p, lambda d: d["levels"]["C"]["avg_speed"].update(low=NAN)),
                 "eval.json: levels.C.avg_speed: low must be a finite number, got nan"),
    "eval-garbage-line": ("eval.json", lambda p: _garbage(p), "eval.json is not valid JSON"),
    "eval-truncated": ("eval.json", lambda p: _truncated(p), "eval.json is not valid JSON"),
    "metrics-nan": ("metrics.json", lambda p: _edit_json(p, lambda d: d.update(wall_s=float("inf"))),
                    "metrics.json: wall_s must be a finite number, got inf"),
    "metrics-garbage-line": ("metrics.json", lambda p: _garbage(p), "metrics.json is not valid JSON"),
    "metrics-truncated": ("metrics.json", lambda p: _truncated(p), "metrics.json is not valid JSON"),
    "episode-missing-field": ("episodes.jsonl", lambda p: _edit_first_line(p, lambda r: r.pop("step")),
                              "episodes.jsonl line 1 is damaged: the row: step is missing"),
    "episode-nan": ("episodes.jsonl", lambda p: _edit_first_line(p, lambda r: r.update(avg_speed=NAN)),
                    "episodes.jsonl line 1 is damaged: the row: avg_speed must be a finite number, got nan"),
    "episode-garbage-line": ("episodes.jsonl", lambda p: _garbage(p), "episodes.jsonl line 2 is damaged: not JSON"),
    "episode-cut-off-last-line": ("episodes.jsonl", lambda p: p.write_bytes(p.read_bytes()[:-5]),
                                  "episodes.jsonl ends in a cut-off line although its job finished"),
}
NAN = float("nan")


def _edit_job(path, change) -> None:  # the two-lane MoE-RM-SRL job's entry
    _edit_json(path, lambda d: change(d["jobs"]["two-lane/moe-rm-srl"]["job"]))


def _garbage(path) -> None:  # a line of garbage after the first
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(lines[:1] + ["\x00garbage}{\n"] + lines[1:]))


def _truncated(path) -> None:  # cut at half its bytes
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


@pytest.mark.parametrize("case", DAMAGE)
def test_a_damaged_file_stops_the_report_with_one_line_naming_it(case, good_study, tmp_path, capsys):
    root = tmp_path / "study"
    shutil.copytree(good_study, root)
    name, damage, says = DAMAGE[case]
    ours = next(r for r in load_results(root) if r.job.method == OURS and not r.job.options and r.done)
    path = (root / "study.json") if name.startswith("../") else ours.folder / name
    damage(path)
    report = (root / "report.md").read_text()
    rc = main(["reproduce", "--out", str(root), "--report-only"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and says in err[0] and str(path) in err[0], err
    assert (root / "report.md").read_text() == report
