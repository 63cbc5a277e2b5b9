"""Integration: MoE-RM-SRL learns on two-lane level A in a few thousand steps (Algorithm 1 end to end)."""

import torch

from highway_srl.agents.gating import explore_gate
from highway_srl.agents.methods import Decision
from highway_srl.agents.trainer import Trainer
from highway_srl.experiments.evaluate import run_episodes
from highway_srl.sim import World


class RandomSafe:
    """ExG's distribution: uniformly random proposals through the same safety gate."""

    layer_options: dict = {}

    def decide(self, learner, step, explore, u):
        action, expert = explore_gate(step.primary.mask, torch.Generator().manual_seed(0))
        return Decision(action, expert, None)


def test_moe_rm_srl_greedy_policy_beats_random_safe_policy_and_never_collides(trainer_config):
    trainer = Trainer(trainer_config())
    episodes = []
    while trainer.env_steps < trainer.config.steps:
        episodes += trainer.step()
    assert not any(e.collision for e in episodes), "the shield must keep training collision-free"
    learned = run_episodes(World("two-lane", "A", num_envs=24, seed=10**9), trainer.method, trainer.learner)
    random = run_episodes(World("two-lane", "A", num_envs=24, seed=10**9), RandomSafe(), None)
    assert not learned["collided"].any()
    # R_r (Table 5's formula) rewards speed: a learned policy drives clearly faster than random safe actions
    assert learned["deploy_reward"].mean() > random["deploy_reward"].mean() + 40
    assert learned["avg_speed"].mean() > random["avg_speed"].mean() + 2.0
