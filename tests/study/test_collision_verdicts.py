"""The report's ego-avoidable collisions: training (metrics.json's collision_verdicts) and deployment per level
(eval.json's census), from constructed records; older records without the verdicts show '–', not 0."""

from __future__ import annotations

from pathlib import Path

from highway_srl.study.jobs import OURS, Job
from highway_srl.study.results import Result, Results
from highway_srl.study.collision_tables import collision_verdicts
from highway_srl.study.verdicts import promise_claim

RATE = {"value": 0.9, "low": 0.8, "high": 0.95}
ESTIMATE = {"value": 7.0, "low": 6.5, "high": 7.5}


def _level(episodes: int, census: dict | None) -> dict:
    lv = {"episodes": episodes, "C_r": RATE, "avg_speed": ESTIMATE, "R_r": ESTIMATE}
    return lv if census is None else {**lv, "collisions": census}


def _result(method: str, scene: str, verdicts: dict | None, levels: dict) -> Result:
    metrics = {"mean": {"T_c": 0.9}, "per_seed": {"0": {"episodes": 30, "collisions": 7},
                                                  "1": {"episodes": 20, "collisions": 5}}}
    if verdicts is not None:
        metrics["collision_verdicts"] = {"per_seed": {}, "all": verdicts}
    return Result(Job(method, scene, steps=100, seeds=(0, 1)), "done", None, Path("x"), metrics=metrics,
                  evaluation={"episodes_per_level": 20, "levels": levels})


def _table(*results: Result):
    return collision_verdicts(Results(Path("x"), {}, list(results)))


def test_training_and_each_deployment_level_split_into_ego_avoidable_unavoidable_and_not_judged():
    res = _result(OURS, "two-lane", {"collisions": 12, "ego_avoidable": 3, "unavoidable": 8, "not_judged": 1},
                  {"C": _level(40, {"collisions": 4, "ego_avoidable": 1, "unavoidable": 2}),
                   "A": _level(40, {"collisions": 0, "ego_avoidable": 0, "unavoidable": 0})})
    table = _table(res)
    rows = [(r["phase"], r["level"], r["episodes"], r["collisions"], r["ego_avoidable"], r["unavoidable"],
             r["not_judged"]) for r in table.rows]
    assert rows == [("training", "C", 50, 12, 3, 8, 1), ("deployment", "C", 40, 4, 1, 2, 1),
                    ("deployment", "A", 40, 0, 0, 0, 0)]
    assert "training,C,50,12,3,8,1" in table.csv_text()
    md = table.markdown()
    assert ("| training (collisions: ego-avoidable / unavoidable / not judged) | deployment at A | deployment "
            "at C |") in md
    assert "| Two-lane | MoE-RM-SRL | 12: 3 / 8 / 1 | 0: 0 / 0 / 0 | 4: 1 / 2 / 1 |" in md


def test_records_written_before_the_verdicts_show_their_count_and_a_dash_not_zero():
    before_census = _level(20, None)  # C_r 0.9 of 20 episodes: 2 collisions
    res = _result("rl", "merge", None, {"C": before_census})
    census_only = _result("rl", "exit", None, {"C": _level(20, {"collisions": 2, "by_kind": {"front": 2}})})
    table = _table(res, census_only)
    assert all(r["ego_avoidable"] is None and r["unavoidable"] is None and r["not_judged"] is None
               for r in table.rows)
    assert [r["collisions"] for r in table.rows] == [12, 2, 12, 2]
    assert "training,C,50,12,,,\n" in table.csv_text()
    md = table.markdown()
    assert "| Merging | RL | 12: – / – / – | 2: – / – / – |" in md


def test_a_job_not_deployed_at_a_level_leaves_that_cell_empty_and_unfinished_jobs_are_left_out():
    levels = {"C": _level(20, {"collisions": 1, "ego_avoidable": 1, "unavoidable": 0})}
    every = _result(OURS, "two-lane", {"collisions": 0, "ego_avoidable": 0, "unavoidable": 0, "not_judged": 0},
                    {**levels, "E": _level(20, {"collisions": 3, "ego_avoidable": 0, "unavoidable": 3})})
    one = _result("rl", "two-lane", {"collisions": 2, "ego_avoidable": 2, "unavoidable": 0, "not_judged": 0},
                  levels)
    pending = Result(Job("sr-rl", "two-lane", steps=100, seeds=(0,)), "pending", None, Path("x"))
    md = _table(every, one, pending).markdown()
    assert "| Two-lane | MoE-RM-SRL | 0: 0 / 0 / 0 | 1: 1 / 0 / 0 | 3: 0 / 3 / 0 |" in md
    assert "| Two-lane | RL | 2: 2 / 0 / 0 | 1: 1 / 0 / 0 |  |" in md
    assert "SR-RL" not in md


def _safe(scene: str, training: dict | None, levels: dict) -> Result:
    res = _result(OURS, scene, training, levels)
    return Result(Job(OURS, scene, steps=100, seeds=(0, 1), profile="safe"), "done", None, Path("x"),
                  metrics=res.metrics, evaluation=res.evaluation)


def _promise(*results: Result):
    return promise_claim(Results(Path("x"), {"budget": "paper"}, list(results), profile="safe"))


NONE_AVOIDABLE = {"collisions": 4, "ego_avoidable": 0, "unavoidable": 4, "not_judged": 0}


def test_the_promise_holds_in_a_scene_with_only_unavoidable_collisions_and_states_the_rule_of_three_bound():
    c = _promise(_safe("two-lane", NONE_AVOIDABLE, {"C": _level(100, {"collisions": 1, "ego_avoidable": 0,
                                                                      "unavoidable": 1})}))
    check = c.checks[0]
    assert check.ok is True and check.what == "Two-lane"
    # 50 training + 100 deployment episodes: none ego-avoidable, the bound 3/150
    assert check.detail.startswith("0 ego-avoidable, 0 not judged, 5 unavoidable in 150 episodes")
    assert "at most 2.0e-02 an episode" in check.detail and "safe profile" in check.detail
    assert [ch.ok for ch in c.checks[1:]] == [None] * (len(c.checks) - 1)  # the other scenes: no finished seeds
    assert c.verdict == f"confirmed where checked (1 of {len(c.checks)})"


def test_an_ego_avoidable_or_unjudged_collision_breaks_the_promise_and_old_records_cannot_judge_it():
    unjudged = {**NONE_AVOIDABLE, "collisions": 5, "not_judged": 1}
    avoidable = {"collisions": 2, "ego_avoidable": 1, "unavoidable": 1}
    c = _promise(_safe("two-lane", unjudged, {"C": _level(100, None)}),
                 _safe("merge", NONE_AVOIDABLE, {"C": _level(100, avoidable)}),
                 _safe("exit", None, {"C": _level(100, avoidable)}))
    by = {ch.what: ch for ch in c.checks}
    assert by["Two-lane"].ok is None  # the deployment census was written before the verdicts
    assert by["Merging"].ok is False and by["Merging"].detail.startswith("1 ego-avoidable, 0 not judged")
    assert by["Exiting"].ok is None and "before the collision verdicts" in by["Exiting"].detail
    c = _promise(_safe("two-lane", unjudged, {"C": _level(100, {"collisions": 0, "ego_avoidable": 0,
                                                               "unavoidable": 0})}))
    assert c.checks[0].ok is False and c.verdict == "not confirmed"
