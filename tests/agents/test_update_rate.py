"""Algorithm 1's update rate (replay_ratio) and the settings a run records (profile, adversary)."""

import pytest
import torch

from highway_srl.agents.dqn import DQNConfig
from highway_srl.agents.train_config import TrainConfig
from highway_srl.agents.trainer import Trainer


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


@pytest.mark.parametrize("method", ["moe-rm-srl", "lm-rl"])
def test_static_form_gives_each_member_exactly_the_steps_it_is_owed_under_a_mask(method):
    trainer = Trainer(small(method=method, static=True))
    trainer.replay.size[:] = 10
    acted = torch.tensor([0, 0, 0, 5, -1, 3, 0, 5]) if method == "moe-rm-srl" else torch.zeros(8, dtype=torch.long)
    before = trainer.learner.adam_step.clone()
    u = torch.rand(trainer.static_rounds, trainer.trained.shape[0], trainer.config.dqn.batch_size)
    masks = trainer.round_masks(acted, trainer.static_rounds)
    for i in range(trainer.static_rounds):
        trainer.static_round(u[i], masks[i])
    stepped = (trainer.learner.adam_step - before).long().tolist()
    if method == "moe-rm-srl":
        assert stepped == [4, 0, 0, 1, 0, 2, 0, 0, 0, 0, 0]  # as the compact form: 7 steps, 0: 4, 3: 1, 5: 2
        assert trainer.static_rounds == 8  # ceil(1 x 8 envs): all members, 8 masked rounds
    else:
        assert stepped == [8, 8]  # the reward network and its cost network, 8 steps each
    assert int(trainer.update_log.count) == sum(stepped[::2] if method == "lm-rl" else stepped)


def test_static_rounds_cover_the_most_a_member_can_be_owed_with_the_carried_fraction():
    trainer = Trainer(small(method="rl", replay_ratio=0.3125, static=True))
    trainer.replay.size[:] = 10
    assert trainer.static_rounds == 3  # ceil(0.3125 x 8)
    owed = [int(trainer.owed_updates(torch.zeros(8, dtype=torch.long))[0]) for _ in range(5)]
    assert owed == [2, 3, 2, 3, 2] and max(owed) <= trainer.static_rounds  # 2.5 per step, fractions carried


def test_owed_updates_stay_on_the_trainers_device_with_the_credit():
    trainer = Trainer(small(method="rl", replay_ratio=0.25))
    trainer.replay.size[:] = 10
    owed = trainer.owed_updates(torch.zeros(3, dtype=torch.long))
    assert owed.device == trainer.device and trainer.update_credit.device == trainer.device
    assert owed.tolist() == [0] and trainer.update_credit.tolist() == [0.75]


@pytest.mark.parametrize("method", ["rl", "lm-rl"])
def test_static_and_compact_forms_train_one_network_per_seed_alike(method):
    """With one trained network per seed every member is owed steps each vector step: the masked static
    update is the compact one (same draws, same order), to float rounding of the written-out gradient."""
    a, b = Trainer(small(method=method)), Trainer(small(method=method, static=True))
    for _ in range(12):
        a.step()
        b.step()
    torch.testing.assert_close(a.learner.online.flat, b.learner.online.flat, rtol=1e-4, atol=1e-5)
    assert torch.equal(a.world.state.x, b.world.state.x)


def test_config_written_before_profiles_and_replay_ratio_reads_as_what_it_ran_under():
    # updates_per_step: that many steps per vector step for the seed's one network, which acts in all 8 envs
    old = {"method": "sr-rl", "updates_per_step": 2, "envs": 8, "seeds": [0]}
    cfg = TrainConfig.from_dict(old)
    assert (cfg.profile, cfg.adversary, cfg.replay_ratio) == ("safe", "mild", 0.25)
    assert not hasattr(cfg, "updates_per_step") and "updates_per_step" not in cfg.to_dict()
    older = TrainConfig.from_dict({"method": "lm-rl"})  # no rate key at all: the old default, 4 per 16 envs
    assert older.replay_ratio == 0.25
    between = TrainConfig.from_dict({**TrainConfig(method="rl").to_dict(), "replay_ratio": None, "updates_per_step": 3})
    assert between.replay_ratio == 3 / 16
    new = TrainConfig.from_dict({**TrainConfig().to_dict(), "updates_per_step": None})  # null beside replay_ratio
    assert (new.profile, new.adversary, new.replay_ratio) == ("paper", "paper", 1.0)


def test_a_config_written_before_replay_ratio_loads_with_an_equal_schedule():
    """Per vector step, the old rate's steps for the one network per seed (it acts in every env) are the
    converted replay_ratio's steps, with no credit carried over."""
    trainer = Trainer(TrainConfig.from_dict({**small(method="rl", seeds=(0, 1)).to_dict(), "replay_ratio": None,
                                             "updates_per_step": 2}))
    trainer.replay.size[:] = 10
    for _ in range(3):
        members, updates = trainer.update_counts(torch.tensor([0] * 8 + [1] * 8))  # envs 0-7: seed 0
        assert dict(zip(members.tolist(), updates.tolist())) == {0: 2, 1: 2}
    assert float(trainer.update_credit.abs().sum()) == 0.0


@pytest.mark.parametrize("old, needle", [
    ({"method": "moe-rm-srl", "updates_per_step": 4}, "has no replay_ratio equal to it"),  # experts' shares vary
    ({"method": "moe-rm-srl", "options": {"no_rm": True}}, "has no replay_ratio equal to it"),
    ({"method": "rl", "updates_per_step": 1, "envs": 49}, "has no replay_ratio equal to it"),  # 1/49 x 49 != 1
    ({"method": "rl", "replay_ratio": 0.5, "updates_per_step": 2}, "both replay_ratio and updates_per_step"),
    ({"method": "rl", "updates_per_step": 2.5}, "updates_per_step must be a non-negative integer"),
])
def test_an_older_rate_no_replay_ratio_equals_is_refused_in_one_line(old, needle):
    with pytest.raises(ValueError, match=needle) as err:
        TrainConfig.from_dict(old)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("kw, needle", [
    ({"profile": "cautious"}, "unknown profile"), ({"adversary": "evil"}, "unknown adversary"),
    ({"replay_ratio": -1.0}, "replay_ratio"),
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
