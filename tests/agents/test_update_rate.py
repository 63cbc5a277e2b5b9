"""Algorithm 1's update rate (replay_ratio) and the settings a run records (profile, adversary)."""

import pytest
import torch

from highway_srl.agents.dqn import DQNConfig
from highway_srl.agents.trainer import TrainConfig, Trainer


def small(**kw) -> TrainConfig:
    dqn = DQNConfig(total_steps=400, learning_starts=0, batch_size=1, buffer_capacity=512)
    return TrainConfig(scenario="two-lane", traffic="A", steps=400, envs=8, dqn=dqn, **kw)


def test_one_update_per_env_step_goes_to_the_member_that_acted_there():
    trainer = Trainer(small(method="moe-rm-srl"))
    trainer.replay.size[:] = 10  # every buffer holds a batch
    acted = torch.tensor([0, 0, 0, 5, -1, 3, 0, 5])  # member per env (-1: the fallback acted)
    members, updates = trainer.update_counts(acted)
    got = dict(zip(members.tolist(), updates.tolist()))
    assert got == {0: 4, 3: 1, 5: 2}  # B = 8 env steps, 7 with an owner: 7 gradient steps, as Algorithm 1


def test_a_fractional_replay_ratio_carries_the_remainder_over():
    trainer = Trainer(small(method="rl", replay_ratio=0.25))
    trainer.replay.size[:] = 10
    acted = torch.zeros(3, dtype=torch.long)  # one member acted in 3 envs: 0.75 steps owed per vector step
    counts = [int(trainer.update_counts(acted)[1].sum()) for _ in range(4)]
    assert counts == [0, 1, 1, 1]  # 0.75, 1.5, 2.25, 3.0 owed in all: 3 steps over 12 env steps


def test_members_without_a_full_batch_take_no_step_and_owe_nothing():
    trainer = Trainer(small(method="rl"))
    acted = torch.zeros(8, dtype=torch.long)
    members, updates = trainer.update_counts(acted)  # empty buffers
    assert members.numel() == 0 and float(trainer.update_credit.sum()) == 0.0


def test_legacy_updates_per_step_gives_that_many_steps_to_every_member_that_acted():
    trainer = Trainer(small(method="moe-rm-srl", replay_ratio=None, updates_per_step=3))
    trainer.replay.size[:] = 10
    members, updates = trainer.update_counts(torch.tensor([0, 0, 0, 5, -1, 3, 0, 5]))
    assert dict(zip(members.tolist(), updates.tolist())) == {0: 3, 3: 3, 5: 3}


def test_config_written_before_profiles_and_replay_ratio_reads_as_what_it_ran_under():
    old = {"method": "sr-rl", "updates_per_step": 4, "seeds": [0]}
    cfg = TrainConfig.from_dict(old)
    assert (cfg.profile, cfg.adversary, cfg.replay_ratio, cfg.updates_per_step) == ("safe", "mild", None, 4)
    older = TrainConfig.from_dict({"method": "sr-rl"})  # no rate key at all: the old default, 4
    assert (older.replay_ratio, older.updates_per_step) == (None, 4)
    new = TrainConfig.from_dict(TrainConfig().to_dict())
    assert (new.profile, new.adversary, new.replay_ratio, new.updates_per_step) == ("paper", "paper", 1.0, None)


@pytest.mark.parametrize("kw, needle", [
    ({"profile": "cautious"}, "unknown profile"), ({"adversary": "evil"}, "unknown adversary"),
    ({"replay_ratio": -1.0}, "replay_ratio"), ({"updates_per_step": 2}, "exactly one"),
])
def test_bad_settings_are_refused_by_name(kw, needle):
    with pytest.raises(ValueError, match=needle):
        Trainer(small(**kw))


def test_the_trainer_passes_profile_and_adversary_to_rule_layer_and_world():
    trainer = Trainer(small(method="sr-rl", profile="safe", adversary="mild", adversarial=True))
    assert trainer.layer.mapped.profile == "safe" and trainer.world.adversary == "mild"
    trainer = Trainer(small(method="mp-rl"))
    assert trainer.layer.profile == "paper" and trainer.world.adversary == "paper"
    assert not trainer.layer.brake_while_changing and trainer.layer.standstill_gap_m == 0.0
