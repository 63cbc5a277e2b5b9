"""One default everywhere and a highway-env style config: the envs, the SB3 adapter and `train` build the same
rule layer from the same arguments; config= round-trips and refuses what it cannot honour in one line."""

import gymnasium
import numpy as np
import pytest
import torch

import highway_srl
from highway_srl.cli import build_parser
from highway_srl.commands import train_config
from highway_srl.constants import DEFAULT_ADVERSARY, DEFAULT_PROFILE, EPISODE_STEPS
from highway_srl.env import HighwayVectorEnv
from highway_srl.env.config import DEFAULTS
from highway_srl.rules.episode import advance

ENVS, STEPS = 4, 60
ACTIONS = np.random.default_rng(4).integers(0, 4, size=(STEPS, ENVS))


def _env_masks(env) -> list[np.ndarray]:
    """The safe sets over the fixed trajectory, same-step autoreset (each env's mask of its current state)."""
    env.reset(seed=0)
    masks = [env.action_masks()]
    for a in ACTIONS:
        env.step(a)
        masks.append(env.action_masks())
    return masks


def _trainer_masks(argv: list[str], tmp_path) -> list[np.ndarray]:
    """The same trajectory through the world and rule layer that `train` with these arguments builds."""
    from highway_srl.agents.trainer import Trainer

    cfg = train_config(build_parser().parse_args(["train", "--out", str(tmp_path / "run"), "--envs", str(ENVS),
                                                  *argv]))
    cfg.dqn.buffer_capacity = 64  # nothing is trained; keep the replay small
    trainer = Trainer(cfg)
    world, layer = trainer.world, trainer.layer
    layer.reset()
    view = layer.observe(world)
    masks = [view.primary.mask.numpy().copy()]
    for a in ACTIONS:
        events, view, _ = advance(world, layer, torch.as_tensor(a))
        done = events.terminated | events.truncated
        if bool(done.any()):  # the envs' same-step autoreset
            world.reset(done)
            layer.reset(done)
            view = layer.observe(world)
        masks.append(view.primary.mask.numpy().copy())
    return masks


def _same(a: list[np.ndarray], b: list[np.ndarray]) -> bool:
    return all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))


def test_env_sb3_adapter_and_train_build_the_same_rule_layer_from_the_same_arguments(tmp_path):
    pytest.importorskip("stable_baselines3")
    from highway_srl.sb3 import make_vec_env

    train = _trainer_masks(["--adversarial"], tmp_path)
    env = _env_masks(HighwayVectorEnv("two-lane", adversarial=True, num_envs=ENVS))
    adapter = make_vec_env("two-lane", adversarial=True, num_envs=ENVS, seed=0)
    adapter.reset()
    sb3 = [adapter.action_masks()]
    for a in ACTIONS:
        adapter.step(a)
        sb3.append(adapter.action_masks())
    assert _same(env, train) and _same(sb3, train)
    # the same arguments spelled out, and the other profile and adversary, both ways
    for profile, adversary in (("safe", "paper"), ("paper", "mild")):
        train_other = _trainer_masks(["--adversarial", "--profile", profile, "--adversary", adversary], tmp_path)
        env_other = _env_masks(HighwayVectorEnv("two-lane", adversarial=True, num_envs=ENVS, profile=profile,
                                                adversary=adversary))
        assert _same(env_other, train_other) and not _same(env_other, train), (profile, adversary)


def test_the_envs_default_is_the_cli_default():
    env = highway_srl.make("merge")
    assert env.config["profile"] == DEFAULT_PROFILE == build_parser().parse_args(["train", "--out", "x"]).profile
    assert env.config["adversary"] == DEFAULT_ADVERSARY == build_parser().parse_args(["train", "--out", "x"]).adversary
    assert gymnasium.make("highway-srl/Merge-v0").unwrapped.config == env.config


def test_config_round_trips_through_make_gymnasium_make_and_make_vec():
    config = {"traffic": "E", "adversarial": True, "profile": "safe", "adversary": "mild", "vehicles_count": 12,
              "style": "cautious", "max_episode_steps": 40, "collision_reward": -5.0,
              "reward_weights": {"rm": 0.6, "merged": 0.4}}
    env = highway_srl.make("merge", config=config)
    assert env.config == config
    assert gymnasium.make("highway-srl/Merge-v0", config=env.config).unwrapped.config == config
    envs = gymnasium.make_vec("highway-srl/Merge-v0", num_envs=2, config=config)
    assert envs.config == config and envs.spec.max_episode_steps == 40
    world = envs.unwrapped._batch.world
    assert (world.traffic, world.adversarial, world.adversary, world.num_vehicles, world.max_steps) == (
        "E", True, "mild", 13, 40)
    # keywords are config keys too; a partial config keeps the defaults of the rest
    partial = highway_srl.make("two-lane", traffic="B", profile="safe").config
    assert partial == {**DEFAULTS, "traffic": "B", "profile": "safe", "reward_weights": {"rm": 1.0}}


def test_max_episode_steps_truncates_and_is_the_specs():
    env = gymnasium.make("highway-srl/TwoLane-v0", config={"max_episode_steps": 7})
    assert env.spec.max_episode_steps == 7
    env.reset(seed=2)
    lengths = [env.step(1)[3] for _ in range(7)]
    assert lengths == [False] * 6 + [True]
    envs = gymnasium.make_vec("highway-srl/TwoLane-v0", num_envs=2, max_episode_steps=50)
    assert envs.spec.max_episode_steps == 50 and envs.config["max_episode_steps"] == 50
    assert highway_srl.make("two-lane", num_envs=2).spec.max_episode_steps == EPISODE_STEPS


def test_reward_weights_and_collision_reward_set_the_training_reward():
    base = HighwayVectorEnv("two-lane", "F", num_envs=8)
    scaled = HighwayVectorEnv("two-lane", "F", num_envs=8, config={"reward_weights": {"rm": 2.0},
                                                                   "collision_reward": -7.0})
    base.reset(seed=1)
    scaled.reset(seed=1)
    collided = 0
    for a in np.random.default_rng(0).integers(0, 4, size=(40, 8)):
        _, r, _, _, info = base.step(a)
        _, r2, _, _, info2 = scaled.step(a)
        hit = info["final_info"]["collision"] if "final_info" in info else np.zeros(8, bool)
        assert np.array_equal(r2[hit], np.full(hit.sum(), -7.0, np.float32))
        assert np.allclose(r2[~hit], 2.0 * r[~hit])
        collided += int(hit.sum())
    assert collided > 0  # level F, random actions: both kinds of step were checked


@pytest.mark.parametrize("kwargs, message", [
    ({"config": {"trafic": "C"}}, "unknown config key 'trafic'; the keys are traffic, adversarial"),
    ({"config": {"traffic": "G"}}, "config 'traffic' must be one of A, B, C, D, E, F, got 'G'"),
    ({"config": {"profile": "strict"}}, "config 'profile' must be one of paper, safe, got 'strict'"),
    ({"config": {"adversary": "wild"}}, "config 'adversary' must be one of mild, paper, got 'wild'"),
    ({"config": {"adversarial": "yes"}}, "config 'adversarial' must be True or False, got 'yes'"),
    ({"config": {"vehicles_count": 64}}, "config 'vehicles_count' must be None or an integer in 1..63, got 64"),
    ({"config": {"vehicles_count": 2.5}}, "config 'vehicles_count' must be None or an integer in 1..63, got 2.5"),
    ({"config": {"style": "reckless"}}, "config 'style' must be one of aggressive, normal, cautious"),
    ({"config": {"max_episode_steps": 0}}, "config 'max_episode_steps' must be a positive integer, got 0"),
    ({"config": {"collision_reward": float("nan")}}, "config 'collision_reward' must be a finite number, got nan"),
    ({"config": {"reward_weights": {"merged": 1.0}}}, "config 'reward_weights' of 'two-lane' takes rm, got 'merged'"),
    ({"config": {"reward_weights": {"rm": float("inf")}}}, "config 'reward_weights' 'rm' must be a finite number"),
    ({"config": ["traffic", "C"]}, "config must be a dict, got list"),
    ({"traffic": "B", "config": {"traffic": "D"}}, "traffic given twice: 'B' as a keyword and 'D' in config"),
])
def test_a_bad_config_is_one_value_error_naming_the_key(kwargs, message):
    for make in (lambda: highway_srl.make("two-lane", **kwargs), lambda: highway_srl.make("two-lane", num_envs=2,
                                                                                          **kwargs)):
        with pytest.raises(ValueError) as info:
            make()
        assert message in str(info.value) and "\n" not in str(info.value)
