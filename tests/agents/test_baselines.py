"""What each baseline and ablation does at one decision, and the pieces that make each different."""

from types import SimpleNamespace

import pytest
import torch

from highway_srl.agents.ablations import MoEAblation, NoMoE
from highway_srl.agents.baselines import COST_LIMIT, LMRL, SRRL, dual_update, speed_reward
from highway_srl.agents.methods import MoERMSRL
from highway_srl.agents.registry import METHODS, make_method
from highway_srl.agents.trainer import Trainer
from highway_srl.experiments.evaluate import run_episodes
from highway_srl.rules import SafetyLayer
from highway_srl.rules.raw import FIVE_ACTIONS, LANE_LEFT, LANE_RIGHT, RawSafetyLayer
from highway_srl.sim import StageFlags, World


class _FixedQ:
    """A learner stand-in whose every member returns the given Q-values (B, out)."""

    def __init__(self, q):
        self.q = q
        self.action_mask = torch.ones(1, q.shape[1], dtype=torch.bool)

    def online(self, x):
        return self.q.unsqueeze(0).expand(x.shape[0], -1, -1)


def _step(mask5):
    model = SimpleNamespace(obs=torch.zeros(mask5.shape[0], 37), mask5=mask5)
    return SimpleNamespace(two_models=torch.zeros(mask5.shape[0], dtype=torch.bool), primary=model,
                           select=lambda use_second: model)


def test_sr_rl_executes_the_highest_q_action_that_passes_the_safety_check():
    gen = torch.Generator().manual_seed(0)
    masks = torch.tensor([[(m >> i) & 1 for i in range(5)] for m in range(1, 32)], dtype=torch.bool)  # every non-empty set
    masks = masks.repeat(4, 1)
    q = torch.randn(masks.shape[0], 5, generator=gen)
    method = SRRL("two-lane", 1, {})
    u = torch.rand(masks.shape, generator=gen)
    d = method.decide(_FixedQ(q), _step(masks), torch.zeros(masks.shape[0], dtype=torch.bool), u)
    for b in range(masks.shape[0]):  # Mirchevska et al.: try actions in descending Q order, run the first safe one
        first_safe = next(a for a in q[b].argsort(descending=True).tolist() if masks[b, a])
        assert int(d.action[b]) == first_safe
    # exploring, the random action is drawn from the safe set only
    d = method.decide(_FixedQ(q), _step(masks), torch.ones(masks.shape[0], dtype=torch.bool), u)
    assert masks.gather(1, d.action[:, None]).all()


def test_lagrange_multiplier_rises_above_the_cost_limit_and_falls_back_below_it():
    lam = torch.tensor([0.5])
    up = dual_update(lam, torch.tensor([COST_LIMIT + 20.0]))
    assert up > lam
    down = dual_update(up, torch.tensor([COST_LIMIT - 20.0]))
    assert down < up and torch.allclose(down, lam)
    assert dual_update(torch.tensor([0.05]), torch.tensor([0.0])) == 0.0  # projected onto λ >= 0


def test_lm_rl_dual_ascent_runs_on_finished_episodes_per_seed():
    method = LMRL("two-lane", 2, {"lambda_init": 1.0})
    b = 4  # envs 0, 1 belong to seed 0; envs 2, 3 to seed 1
    not_done = torch.zeros(b, dtype=torch.bool)
    for _ in range(30):  # seed 0 violates the rules every step, seed 1 never
        method.after_step(None, torch.tensor([1.0, 1.0, 0.0, 0.0]), not_done)
    assert torch.equal(method.lam, torch.tensor([1.0, 1.0])), "λ only moves when episodes end"
    method.after_step(None, torch.tensor([1.0, 1.0, 0.0, 0.0]), torch.tensor([True, False, True, False]))
    assert method.lam[0] > 1.0 and method.lam[1] < 1.0  # 31 > COST_LIMIT; 0 < COST_LIMIT
    assert method.episode_cost.tolist() == [0.0, 31.0, 0.0, 0.0]


def test_lm_rl_cost_counts_rule_violations_and_collisions_and_lambda_survives_a_checkpoint(short_config):
    trainer = Trainer(short_config("lm-rl", options={"lambda_init": 0.7}))
    for _ in range(3):
        trainer.step()
    state = trainer.state_dict()
    assert torch.allclose(state["method.lambda"], torch.tensor([0.7]))
    other = Trainer(short_config("lm-rl"))
    other.load_state_dict(state)
    assert torch.allclose(other.method.lam, torch.tensor([0.7]))
    nxt = trainer.current.primary
    events = SimpleNamespace(collision=torch.tensor([True] + [False] * (trainer.batch - 1)))
    flags = StageFlags(*(torch.zeros(trainer.batch, dtype=torch.bool) for _ in range(3)))
    reward, cost = trainer.method.reward("two-lane", nxt, events, flags)
    assert cost[0] == 320.0 and reward[0] == -320.0
    violated = (nxt.rm_state[1:] == 1) | (nxt.rm_state[1:] == 3)
    assert torch.equal(cost[1:], violated.float())


def test_rule_based_driver_drives_100_episodes_of_two_lane_level_c_without_collision():
    method = make_method("rule-based", "two-lane", 1)
    results = run_episodes(World("two-lane", "C", num_envs=100, seed=10**9), method, None)
    assert not results["collided"].any()
    assert results["avg_speed"].mean() > 4.0  # it drives, not just waits


def test_rule_based_driver_learns_nothing_and_stores_nothing(short_config):
    trainer = Trainer(short_config("rule-based", steps=10**6))
    before = trainer.learner.online.flat.clone()
    trainer.config.dqn.learning_starts = 0
    for _ in range(5):
        trainer.step()
    assert int(trainer.replay.size.sum()) == 0
    assert torch.equal(trainer.learner.online.flat, before)


def test_speed_reward_is_v_over_v_max_and_minus_320_on_collision():
    obs = torch.zeros(3, 37)
    obs[:, 2] = torch.tensor([0.5, 1.0, 0.8])  # ego v_x / v_max
    events = SimpleNamespace(collision=torch.tensor([False, False, True]))
    flags = StageFlags(*(torch.zeros(3, dtype=torch.bool) for _ in range(3)))
    assert speed_reward("two-lane", obs, events, flags).tolist() == [0.5, 1.0, -320.0]


# ---------------------------------------------------------------- ablations
def test_ablations_remove_exactly_their_part():
    full = make_method("moe-rm-srl", "two-lane", 1)
    assert type(full) is MoERMSRL
    road = World("two-lane", "A").road
    no_map = make_method("moe-rm-srl", "two-lane", 1, {"no_mapping": True})
    assert isinstance(no_map, MoEAblation) and no_map.num_members == 11
    assert isinstance(no_map.make_layer(road), RawSafetyLayer) and not no_map.make_layer(road).five_actions
    no_moe = make_method("moe-rm-srl", "two-lane", 1, {"no_moe": True})
    assert isinstance(no_moe, NoMoE) and no_moe.num_members == 1 and not no_moe.shielded
    assert no_moe.reward_kind == "rm" and isinstance(no_moe.make_layer(road), SafetyLayer)
    no_rm = make_method("moe-rm-srl", "two-lane", 1, {"no_rm": True})
    assert no_rm.num_members == 11 and isinstance(no_rm.make_layer(road), SafetyLayer)
    all_three = make_method("moe-rm-srl", "two-lane", 1, {"no_mapping": True, "no_moe": True, "no_rm": True})
    assert isinstance(all_three.make_layer(road), RawSafetyLayer) and all_three.reward_kind == "speed"


def test_no_rm_trains_on_the_speed_reward_and_no_moe_on_the_rm_reward(short_config):
    for options, expect_rm in (({"no_rm": True}, False), ({"no_moe": True}, True)):
        trainer = Trainer(short_config("moe-rm-srl", options=options))
        nxt = trainer.current.primary
        events = SimpleNamespace(collision=torch.zeros(trainer.batch, dtype=torch.bool))
        flags = StageFlags(*(torch.zeros(trainer.batch, dtype=torch.bool) for _ in range(3)))
        reward, _ = trainer.method.reward("two-lane", nxt, events, flags)
        expected = nxt.r_rm if expect_rm else nxt.obs[:, 2].clamp(0, 1)
        assert torch.allclose(reward, expected)


@pytest.mark.parametrize("name, options", [("sr-rl", {"no_moe": True}), ("moe-rm-srl", {"no_shield": True}),
                                           ("rl", {"cost_limit": 3})])
def test_options_a_method_does_not_take_are_rejected_by_name(name, options):
    with pytest.raises(ValueError, match=next(iter(options))):
        make_method(name, "two-lane", 1, options)


def test_manual_is_registered_but_points_to_play():
    assert "manual" in METHODS
    with pytest.raises(ValueError, match="highway-srl play"):
        make_method("manual", "two-lane", 1)


# ---------------------------------------------------------------- the raw view (no mappings)
def test_raw_view_keeps_global_lane_indices_and_checks_each_lane_change_direction():
    world = World("multi-lane", "A", num_envs=16, seed=3)
    layer = RawSafetyLayer(world.road, five_actions=True)
    model = layer.observe(world).primary
    lane = world.ego_lane
    assert torch.equal(model.obs[:, 25], lane.float())  # C_ID: 0, 1 or 2, no ID mapping
    assert not model.mask5[lane == 2, LANE_RIGHT].any() and not model.mask5[lane == 0, LANE_LEFT].any()
    assert model.mask5.any(1).all()  # every state has a safe action
    action = torch.where(lane == 2, LANE_LEFT, LANE_RIGHT)
    target, _ = layer.act(action)
    assert torch.equal(target, torch.where(lane == 2, lane - 1, lane + 1))
    assert FIVE_ACTIONS[LANE_LEFT] == "LaneLeft"


def test_raw_view_scores_deployment_with_the_mapped_rules_so_r_r_is_the_same_for_every_method():
    world = World("two-lane", "C", num_envs=8, seed=5)
    raw = RawSafetyLayer(world.road).observe(world).primary
    mapped = SafetyLayer(world.road).observe(world).primary
    assert torch.equal(raw.r_star, mapped.r_star) and torch.equal(raw.speed_ratio, mapped.speed_ratio)


def test_raw_view_respects_the_roads_barriers():
    world = World("merge", "A", num_envs=4, seed=0)  # the ego starts on the on-ramp, before the merging zone
    layer = RawSafetyLayer(world.road, five_actions=True)
    model = layer.observe(world).primary
    assert not model.mask5[:, LANE_LEFT].any()
    target, _ = layer.act(torch.full((4,), LANE_LEFT))
    assert torch.equal(target, world.ego_lane)


def test_every_method_drives_every_scenario_through_the_trainer_and_resumes():
    from highway_srl.agents.dqn import DQNConfig
    from highway_srl.agents.train_config import TrainConfig

    for scenario in ("multi-lane", "merge", "exit"):
        for name, options in (("rl", {}), ("sr-rl", {}), ("lm-rl", {}), ("et-rl", {}), ("rule-based", {}),
                              ("moe-rm-srl", {"no_mapping": True})):
            dqn = DQNConfig(learning_starts=0, batch_size=4, total_steps=100, buffer_capacity=16)
            cfg = TrainConfig(method=name, scenario=scenario, traffic="C", steps=10**6, envs=2, seeds=(0, 1),
                              options=options, dqn=dqn)
            trainer = Trainer(cfg)
            for _ in range(3):
                trainer.step()
            again = Trainer(cfg)
            # state_dict() returns the live tensors: a copy, as a checkpoint on disk is
            again.load_state_dict({k: v.clone() for k, v in trainer.state_dict().items()})
            trainer.step()
            again.step()
            a, b = trainer.state_dict(), again.state_dict()
            assert a.keys() == b.keys()
            differ = [k for k in a if not torch.equal(a[k], b[k])]
            assert not differ, f"{scenario} {name} {options}: resumed state differs in {differ}"
