"""The likely causes of the gaps are counted from the records, and follow them when they change.

The fake jobs (study_fakes) fix every count: a smoke study of three seeds, 4 deployment episodes per seed and
level (two-lane at levels A, C, F; the other scenes at C), 20 training episodes per seed; a baseline's C_r 0.7
makes one collision per seed and level, every one through the creep decision."""

from __future__ import annotations

import json
import shutil

import pytest
import study_fakes as fakes

from highway_srl.experiments.collisions import CREEP, LANE_CHANGE_CYCLE
from highway_srl.experiments.runs import read_json, write_json
from highway_srl.study.causes import TITLE, causes
from highway_srl.study.jobs import OURS
from highway_srl.study.report import write_report
from highway_srl.study.results import load_results
from highway_srl.study.runner import reproduce


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = tmp_path_factory.mktemp("causes") / "study"
    reproduce("smoke", root, jobs=1, work=fakes.fake_work, seeds=(0, 1, 2), log=lambda s: None, report=False)
    return root


@pytest.fixture
def study(built, tmp_path):
    """A fresh copy of the built study for each test, which may rewrite its records."""
    return shutil.copytree(built, tmp_path / "study")


def _bullet(root, start: str) -> str:
    (text,) = [b for b in causes(load_results(root)) if b.startswith(start)]
    return text


def _job(root, method: str, scene: str):
    return next(r for r in load_results(root) if (r.job.method, r.job.scene, r.job.options) == (method, scene, ()))


def test_the_creep_counts_are_the_deployment_collisions_through_it_most_first(study):
    creep = _bullet(study, "**Creeping at standstill.**")
    # one collision per seed at level F, 3 seeds of 4 episodes: the first three baselines in the tables' order
    assert ("two-lane at level F: RL 3 of 3 (3 seeds, 12 episodes), SR-RL 3 of 3 (3 seeds, 12 episodes), "
            "RM-RL 3 of 3 (3 seeds, 12 episodes); merging at level C: RL 3 of 3 (3 seeds, 12 episodes)") in creep
    assert "no finished run in two-lane or merging yet" in creep  # no safe profile in this study
    cycle = _bullet(study, "**The printed mappings' lane-change cycle.**")
    assert "two-lane at levels A, C, F: none; adversarial two-lane at level C: none." in cycle


def test_a_collision_traced_to_the_lane_change_cycle_moves_from_creep_to_the_cycle(study):
    path = _job(study, "rl", "two-lane").folder / "eval.json"
    report = read_json(path)
    for level in report["levels"].values():
        decided = level["collisions"]["by_decision"]
        decided[LANE_CHANGE_CYCLE], decided[CREEP] = decided[CREEP], 0
    write_json(path, report)
    cycle = _bullet(study, "**The printed mappings' lane-change cycle.**")
    assert "two-lane at levels A, C, F: RL 9 of 9 (3 seeds, 36 episodes); adversarial" in cycle
    creep = _bullet(study, "**Creeping at standstill.**")
    assert "two-lane at level F: SR-RL 3 of 3 (3 seeds, 12 episodes), RM-RL 3 of 3" in creep


def test_training_success_is_split_at_the_first_fifth_of_the_steps(study):
    folder = _job(study, OURS, "merge").folder
    rows = [json.loads(line) for line in (folder / "episodes.jsonl").read_text().splitlines()]
    # smoke: 1,344 steps, 20 episodes a seed every 67 steps; the first four end within 268.8 steps
    (folder / "episodes.jsonl").write_text("".join(json.dumps({**r, "success": r["step"] <= 268}) + "\n"
                                                   for r in rows))
    ramps = _bullet(study, "**Merging and exiting success**")
    assert ("merging: MoE-RM-SRL's seeds succeed in 75.0%, 75.0%, 75.0% of their level-C episodes, in training in "
            "100.0%-100.0% of a seed's episodes of the first 268 steps and 0.0%-0.0% after") in ramps
    # the baselines (R_s 0.4 each, 2 of 4 episodes a seed rounded) beside: the first with the highest mean
    assert "the baseline that succeeds most, RL, in 50.0%, 50.0%, 50.0% at C_r 75.0%, 75.0%, 75.0%" in ramps


def test_the_safe_profiles_collisions_in_two_lane_and_merging_are_counted(tmp_path):
    root = tmp_path / "study"
    reproduce("smoke", root, jobs=1, work=fakes.fake_work, seeds=(0, 1, 2), profiles=("paper", "safe"),
              methods=(OURS,), log=lambda s: None, report=False)
    creep = _bullet(root, "**Creeping at standstill.**")
    assert "its MoE-RM-SRL had 0 collisions in two-lane and merging (3 and 3 seeds," in creep
    safe_merge = next(r for r in load_results(root).beyond()[0] if r.job.scene == "merge" and not r.job.options)
    shutil.rmtree(safe_merge.folder)
    fakes.write_fake_job(root, safe_merge.job, {**fakes.GOOD, "T_c": 0.5, "C_r": 0.5})
    # training: 10 of 20 episodes a seed; deployment at C: 2 of 4 a seed; three seeds
    assert "its MoE-RM-SRL had 36 collisions in two-lane and merging" in _bullet(root, "**Creeping at standstill.**")


def test_the_report_and_the_summary_carry_the_causes(study):
    write_report(study)
    summary, report = (study / "summary.md").read_text(), (study / "report.md").read_text()
    assert f"**{TITLE}.**" in summary and f"## {TITLE}" in report
    for bullet in causes(load_results(study)):
        assert f"- {bullet}" in summary and f"- {bullet}" in report
