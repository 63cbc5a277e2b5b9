"""Finished episodes wait on the device and are read every few vector steps, in the order they ended."""

import pytest
import torch

from highway_srl.agents.dqn import DQNConfig
from highway_srl.agents.train_config import TrainConfig
from highway_srl.agents.trainer import Trainer
from highway_srl.rules.episode import FinishedEpisodes


def _trainer(drain_every: int, static: bool = False) -> Trainer:
    dqn = DQNConfig(total_steps=400, learning_starts=10**9, buffer_capacity=64)  # no learning: episodes only
    trainer = Trainer(TrainConfig(method="rl", scenario="two-lane", traffic="A", steps=400, envs=4, seeds=(0, 1),
                                  static=static, dqn=dqn), drain_every=drain_every)
    trainer.world.max_steps = 7  # episodes end every 7 steps, or earlier on a collision
    return trainer


def _run(trainer: Trainer, steps: int) -> list:
    episodes = []
    for _ in range(steps):
        episodes += trainer.step()
    return episodes + trainer.drain()


def test_episodes_read_every_few_steps_are_those_read_every_step_in_the_same_order():
    every_step, every_five = _run(_trainer(1), 23), _run(_trainer(5), 23)
    assert len(every_step) >= 3 * 8 and every_step == every_five
    assert [e.step for e in every_step] == sorted(e.step for e in every_step)
    assert {e.seed for e in every_step} == {0, 1} and all(e.step % 4 == 0 for e in every_step)


def test_static_resets_give_the_same_episodes_as_compact_ones():
    assert _run(_trainer(3, static=True), 23) == _run(_trainer(1), 23)


def test_step_returns_episodes_only_when_it_drains_and_state_dict_wants_them_drained():
    trainer = _trainer(5)
    returned = [len(trainer.step()) for _ in range(10)]
    assert all(n == 0 for i, n in enumerate(returned) if (i + 1) % 5) and returned[9] > 0
    while int(trainer.finished.count) == 0:  # until some episodes wait on the device
        trainer.step()
    with pytest.raises(RuntimeError, match="drain"):
        trainer.state_dict()
    trainer.drain()
    assert "counters.vector_steps" in trainer.state_dict()


def test_finished_episodes_keep_rows_in_order_and_refuse_an_overflow():
    buf = FinishedEpisodes(capacity=4, width=2, device="cpu")
    buf.record(torch.tensor([False, True, True]), torch.tensor([[0.0, 10.0], [1.0, 11.0], [2.0, 12.0]]),
               torch.tensor(1))
    buf.record(torch.tensor([True, False, False]), torch.tensor([[0.0, 20.0], [1.0, 21.0], [2.0, 22.0]]),
               torch.tensor(2))
    assert buf.drain() == ([[1.0, 11.0], [2.0, 12.0], [0.0, 20.0]], [1, 1, 2])
    assert buf.drain() == ([], [])
    for tag in range(2):
        buf.record(torch.tensor([True, True, True]), torch.zeros(3, 2), torch.tensor(tag))
    with pytest.raises(RuntimeError, match="overflowed"):
        buf.drain()
