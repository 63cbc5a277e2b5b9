"""The falsifier's learned adversary (experiments/adversary.py): its reward is +1 exactly on an ego-avoidable
collision, it only ever takes allowed actions, and a short learned search under the paper profile finds an
ego-avoidable collision whose case replays."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from highway_srl.experiments import adversary as adv
from highway_srl.experiments import falsify as fz
from highway_srl.rules import SafetyLayer
from highway_srl.rules.avoidable import SIDE_SWIPE
from highway_srl.rules.safe_actions import FASTER, IDLE, LANE_CHANGE, SLOWER
from highway_srl.sim import World

CASES = Path(__file__).parents[1] / "rules" / "cases"


def _rewards(world: World, profile: str, pick, shaping: float = 0.0) -> tuple[list[float], list[dict]]:
    """Drive one env through AdversaryWorld until its first episode ends: the rewards and the judged records."""
    cell = adv.AdversaryWorld(world, profile, shaping)
    rewards = []
    while not cell.episodes:
        rewards.append(float(cell.step(pick(len(rewards), cell.view))["reward"][0]))
    return rewards, cell.records


def test_the_reward_is_one_exactly_on_the_ego_avoidable_collision_of_a_case():
    case = fz.load_case(CASES / "paper-lane-change-cycle-two-lane-C.json")
    world = World(case.scene, case.level, case.adversarial, 1, "cpu", case.seed + case.env, max_steps=case.steps,
                  adversary=case.adversary)
    rewards, [record] = _rewards(world, case.profile, lambda step, view: torch.tensor([case.actions[step]]))
    assert record["ego_avoidable"] and len(rewards) == len(case.actions)
    assert rewards == [0.0] * (len(case.actions) - 1) + [1.0]


def test_the_reward_is_zero_on_an_unavoidable_collision_and_without_one():
    # an SV at 2 m/s forced into the ego's lane level with its front, the ego at 9 m/s braking when allowed
    world = World("two-lane", "C", num_envs=1, seed=0, max_steps=120)
    s = world.state
    s.x[:, 1:] = 600.0 + 20.0 * torch.arange(1, s.x.shape[1], dtype=torch.float32)
    s.y[:, 1:], s.v[:, 1:], s.heading[:] = 0.0, 1.0, 0.0
    s.lane[:] = s.target_lane[:] = 0
    s.forced[:] = s.lane_change[:] = False
    s.x[0, 0], s.y[0, 0], s.v[0, 0] = 100.0, 0.0, 9.0
    for name, value in dict(x=105.0, y=3.5, v=2.0, v0=2.0, lane=1, target_lane=0, forced=True).items():
        getattr(s, name)[0, 1] = value

    def brake_first(step, view):
        allowed = view.primary.mask[0]
        return torch.tensor([next(a for a in (SLOWER, IDLE, FASTER, LANE_CHANGE) if allowed[a])])
    rewards, [record] = _rewards(world, "safe", brake_first)
    assert (record["ego_avoidable"], record["reason"]) == (False, SIDE_SWIPE)
    assert rewards == [0.0] * len(rewards)
    quiet = World("two-lane", "A", num_envs=1, seed=1, max_steps=40)
    rewards, records = _rewards(quiet, "safe", lambda step, view: torch.tensor([IDLE]))
    assert (records, len(rewards), set(rewards)) == ([], 40, {0.0})


def test_the_shaping_is_a_difference_of_potentials_that_vanish_after_a_collision():
    case = fz.load_case(CASES / "paper-lane-change-cycle-two-lane-C.json")
    world = World(case.scene, case.level, case.adversarial, 1, "cpu", case.seed + case.env, max_steps=case.steps)
    cell = adv.AdversaryWorld(world, case.profile, shaping=0.1)
    phis, rewards = [], []
    for action in case.actions:
        phis.append(float(adv.potential(cell.view.primary, cell.view.snapshot.ego_vx, 0.1)[0]))
        rewards.append(float(cell.step(torch.tensor([action]))["reward"][0]))
    assert all(-0.1 - 1e-6 <= p <= 0.0 for p in phis) and min(phis) < max(phis)
    shaped = [0.99 * after - before for before, after in zip(phis, phis[1:] + [0.0])]
    assert rewards == pytest.approx([r + (i == len(rewards) - 1) for i, r in enumerate(shaped)], abs=1e-6)


def test_the_adversary_takes_only_allowed_actions():
    world = World("two-lane", "F", False, 64, "cpu", 3)
    layer = SafetyLayer(world.road, profile="paper")
    net = adv.DQNLearner(1, torch.ones(1, 4, dtype=torch.bool), adv.default_dqn(), "cpu",
                         generator=torch.Generator().manual_seed(0)).online
    gen = torch.Generator().manual_seed(0)
    policy = adv.LearnedPolicy(net, explore=0.5)
    for _ in range(8):
        view = layer.observe(world)
        mask = view.primary.mask
        assert not bool(mask.all())  # the rule layer forbids something, so the check has teeth
        for explore in (torch.zeros(64, dtype=torch.bool), torch.ones(64, dtype=torch.bool)):
            assert bool(mask.gather(1, adv.act(net, view.primary, explore, gen)[:, None]).all())
        action = policy(view, gen)
        assert bool(mask.gather(1, action[:, None]).all())
        world.step(*layer.act(action))


def test_a_short_learned_search_under_paper_finds_an_ego_avoidable_collision_that_replays(tmp_path):
    """Fixed seed; 1,000 training steps and 16 episodes of 48 steps at two-lane F (a few seconds)."""
    settings = fz.FalsifySettings(levels=("F",), modes=(False,), profile="paper", policy=fz.LEARNED, episodes=16,
                                  envs=16, steps=48, seed=0)
    report = adv.falsify_learned(settings, adv.AdversaryConfig(learn_steps=1000), tmp_path / "found")
    [trained] = report["adversary"]["training"]
    assert trained["scene"] == "two-lane" and trained["learn_steps"] >= 1000
    assert report["ego_avoidable"] >= 1 and report["settings"]["policy"] == fz.LEARNED
    assert json.loads(json.dumps(report)) == json.loads((tmp_path / "found" / "report.json").read_text())
    for case in report["cases"]:
        result = fz.replay_case(fz.load_case(case["path"]))
        assert result["confirmed"] and result["cause"] == case["cause"] and result["all_allowed"]
    assert any(case["ego_avoidable"] for case in report["cases"])


def test_bad_input_is_refused_before_any_training(tmp_path):
    settings = fz.FalsifySettings(levels=("F",), modes=(False,), policy=fz.LEARNED, episodes=4, envs=4, steps=8)
    with pytest.raises(ValueError, match="trained ego for every scene"):
        fz.falsify(settings)
    with pytest.raises(ValueError, match="trained ego for every scene"):
        fz.falsify(settings, policies={"merge": lambda view, gen: view.primary.mask.long().argmax(1)})
    with pytest.raises(ValueError, match="trained ego for every scene"):
        fz.falsify(fz.FalsifySettings(), policies={"two-lane": lambda view, gen: view.primary.mask.long().argmax(1)})
    with pytest.raises(ValueError, match="learn-steps must be a positive integer"):
        adv.falsify_learned(settings, adv.AdversaryConfig(learn_steps=0))
    with pytest.raises(ValueError, match="explore must be"):
        adv.falsify_learned(settings, adv.AdversaryConfig(explore=1.5))
    with pytest.raises(ValueError, match="runs under policy"):
        adv.falsify_learned(fz.FalsifySettings(policy="uniform"))
    (tmp_path / "report.json").write_text("{}")
    with pytest.raises(ValueError, match="already holds"):
        adv.falsify_learned(settings, out=tmp_path)


def test_the_cli_lists_the_learned_adversary_and_refuses_a_bad_learn_steps_in_one_line(capsys):
    from highway_srl.cli import main

    assert main(["falsify", "--help"]) == 0
    text = capsys.readouterr().out
    assert "learned" in text and "--learn-steps" in text
    for bad in (["--policy", "learned", "--learn-steps", "0"], ["--policy", "learned", "--learn-steps", "ten"],
                ["--learn-steps", "100"]):
        assert main(["falsify", *bad]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "learn-steps" in err[0]


def test_worker_processes_give_the_same_report():
    settings = fz.FalsifySettings(levels=("F",), modes=(False,), profile="paper", policy=fz.LEARNED, episodes=8,
                                  envs=4, steps=24, seed=0)
    one, two = (adv.falsify_learned(settings, adv.AdversaryConfig(learn_steps=300, envs=4), processes=n)
                for n in (1, 2))
    for report in (one, two):
        report["adversary"]["training"][0].pop("seconds")
    assert (one.pop("processes"), two.pop("processes")) == (1, 2) and one.pop("wall_s") >= 0 <= two.pop("wall_s")
    assert one == two and one["episodes"] == 8
