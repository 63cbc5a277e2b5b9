"""evaluate's group-3 counters (issue 12): triggers and cut-ins per episode, read from the world as each
episode stood when it ended, and summarised per level in eval.json (the group-3 table's columns)."""

from __future__ import annotations

import pytest
from highway_srl.agents.registry import make_method
from highway_srl.experiments.evaluate import EVAL_SEED_BASE, run_episodes, summarise
from highway_srl.sim import World


def _rule_based(scenario: str, adversarial: bool, envs: int = 24):
    world = World(scenario, "C", adversarial, envs, "cpu", EVAL_SEED_BASE, adversary="paper")
    method = make_method("rule-based", scenario, 1)
    return run_episodes(world, method, None)


@pytest.mark.parametrize("scenario", ["two-lane", "merge"])
def test_adversarial_episodes_count_triggers_and_cut_ins_and_summarise_their_means(scenario):
    results = _rule_based(scenario, True)
    triggers, cut_ins = results["adv_triggers"], results["adv_cut_ins"]
    assert triggers.shape == cut_ins.shape == (24,)
    assert bool((cut_ins <= triggers).all()) and int(cut_ins.sum()) > 0  # a cut-in follows a trigger draw
    out = summarise(results, scenario)["adversary"]
    assert out["triggers_per_episode"] == pytest.approx(float(triggers.float().mean()))
    assert out["cut_ins_per_episode"] == pytest.approx(float(cut_ins.float().mean()))


def test_nominal_episodes_report_zero_adversary_counts():
    results = _rule_based("two-lane", False, envs=8)
    assert int(results["adv_triggers"].sum()) == 0 and int(results["adv_cut_ins"].sum()) == 0
    assert summarise(results, "two-lane")["adversary"] == {"triggers_per_episode": 0.0, "cut_ins_per_episode": 0.0}

