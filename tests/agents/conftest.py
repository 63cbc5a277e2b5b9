import sys
from pathlib import Path

import pytest
import torch

# the golden Table 1 (tests/rules/table_1.py) importable by name
sys.path.insert(0, str(Path(__file__).parents[1] / "rules"))


@pytest.fixture(autouse=True)
def _one_thread(one_thread):
    """Tiny networks: every test here runs with one thread (tests/conftest.py)."""


@pytest.fixture
def short_config():
    """A method's config: 1600 steps of two-lane level A, 8 envs (trainer_config: 2400 for MoE-RM-SRL)."""
    from highway_srl.agents.dqn import DQNConfig
    from highway_srl.agents.train_config import TrainConfig

    def make(method: str, steps: int = 1600, **kw) -> TrainConfig:
        dqn = DQNConfig(total_steps=steps, learning_starts=300, target_update_interval=200, exploration_fraction=0.3,
                        buffer_capacity=max(steps, 2048))  # never full here; the default would allocate GBs for 11 experts
        return TrainConfig(method=method, scenario="two-lane", traffic="A", steps=steps, envs=8, replay_ratio=0.25,
                           dqn=dqn, **kw)

    return make


@pytest.fixture
def trainer_config():
    """MoE-RM-SRL by default: 2400 steps of two-lane level A, 8 envs: enough for the DQN to learn."""
    from highway_srl.agents.dqn import DQNConfig
    from highway_srl.agents.train_config import TrainConfig

    def make(steps: int = 2400, **kw) -> TrainConfig:
        dqn = DQNConfig(total_steps=steps, learning_starts=300, target_update_interval=200, exploration_fraction=0.3)
        return TrainConfig(scenario="two-lane", traffic="A", steps=steps, envs=8, replay_ratio=0.25, dqn=dqn, **kw)

    return make


class _HalfRandom:
    """The method with ε = 1 in the first half of the envs and ε = 0 in the second (same traffic in both)."""

    def __init__(self, method, generator):
        self.method, self.gen = method, generator

    def make_layer(self, road):
        return self.method.make_layer(road)

    def decide(self, learner, step, explore, u):
        b, width = explore.shape[0], self.method.draw_width
        u = torch.rand(b, width, generator=self.gen) if width else None
        return self.method.decide(learner, step, torch.arange(b) < b // 2, u)


@pytest.fixture
def greedy_vs_random():
    """deploy(method, learner, episodes) -> (greedy results, random results) of run_episodes on two-lane
    level A: 'random' is the same method exploring with ε = 1 (through its own shield, if it has one)."""
    from highway_srl.experiments.evaluate import run_episodes
    from highway_srl.sim import World

    def deploy(method, learner, episodes: int = 16, traffic: str = "A"):
        seeds = [10**9 + i for i in range(episodes)] * 2
        world = World("two-lane", traffic, num_envs=2 * episodes, seed=seeds)
        out = run_episodes(world, _HalfRandom(method, torch.Generator().manual_seed(0)), learner)
        return {k: v[episodes:] for k, v in out.items()}, {k: v[:episodes] for k, v in out.items()}

    return deploy
