import pytest
import torch


@pytest.fixture(autouse=True)
def _threads():
    # two cores on CI: one intra-op thread per test keeps parallel tests from oversubscribing
    torch.set_num_threads(1)
    yield


@pytest.fixture
def short_config():
    """A few thousand steps of two-lane level A, 8 envs: enough for the DQN to learn, quick on 2 cores."""
    from highway_srl.agents.dqn import DQNConfig
    from highway_srl.agents.trainer import TrainConfig

    def make(steps: int = 2400, **kw) -> TrainConfig:
        dqn = DQNConfig(total_steps=steps, learning_starts=300, target_update_interval=200, exploration_fraction=0.3)
        return TrainConfig(scenario="two-lane", traffic="A", steps=steps, envs=8, updates_per_step=2, dqn=dqn, **kw)

    return make
