"""The report's ego-avoidable collisions: training (metrics.json's collision_verdicts) and deployment per level
(eval.json's census), from constructed records; older records without the verdicts show '–', not 0."""

from __future__ import annotations

from pathlib import Path

from highway_srl.study.jobs import OURS, Job
from highway_srl.study.results import Result, Results
from highway_srl.study.collision_tables import collision_verdicts

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
