"""Strict API inputs: actions are integers in range with the right shape, step needs a reset first, and the
SB3 adapter's indices are env indices; anything else is one clear error, nothing is truncated or stepped."""

import numpy as np
import pytest
import torch
from gymnasium.error import ResetNeeded

import highway_srl
from highway_srl.env import HighwayVectorEnv


@pytest.mark.parametrize("actions, message", [
    ([0.9, 1.1, 2.5, 3.99], "actions must be integers in 0..3 (Faster, Idle, Slower, LaneChange), got dtype float64"),
    (np.ones(4, dtype=np.float32), "got dtype float32"),
    (torch.ones(4), "got dtype float32"),
    ([True, False, True, False], "got dtype bool"),
    (["1", "2", "3", "0"], "got dtype <U1"),
    ([0, 1, 2], "actions must have shape (4,), one per env, got (3,)"),
    (np.ones((4, 1), dtype=np.int64), "got (4, 1)"),
    (1, "got ()"),
    ([0, 1, 2, 4], "actions must be in 0..3 (Faster, Idle, Slower, LaneChange), got 0..4"),
    ([-1, 1, 2, 3], "got -1..3"),
])
def test_bad_vector_actions_are_one_value_error_and_nothing_is_stepped(actions, message):
    envs = highway_srl.make("two-lane", num_envs=4, seed=0)
    held = envs.step(np.ones(4, dtype=np.int64))[0]
    envs.reset(seed=0)
    with pytest.raises(ValueError) as info:
        envs.step(actions)
    assert message in str(info.value) and "\n" not in str(info.value)
    assert np.array_equal(envs.step(np.ones(4, dtype=np.int64))[0], held)  # the refused step changed nothing


def test_integer_actions_of_any_integer_type_are_taken():
    envs = highway_srl.make("two-lane", num_envs=4, seed=0)
    ref = envs.step(np.array([0, 1, 2, 3]))[0]
    for actions in ([0, 1, 2, 3], np.array([0, 1, 2, 3], dtype=np.uint8), torch.tensor([0, 1, 2, 3])):
        envs.reset(seed=0)
        assert np.array_equal(envs.step(actions)[0], ref)


def test_step_before_reset_raises_reset_needed():
    with pytest.raises(ResetNeeded):
        highway_srl.make("two-lane").step(0)
    with pytest.raises(ResetNeeded):
        highway_srl.make("two-lane", num_envs=2).step(np.ones(2, dtype=np.int64))
    env = highway_srl.make("two-lane")
    env.reset(seed=0)
    env.step(0)  # after a reset it steps


def test_single_env_refuses_float_actions():
    env = highway_srl.make("two-lane", seed=0)
    with pytest.raises(ValueError, match="is not in Discrete"):
        env.step(1.7)


@pytest.mark.parametrize("seed, message", [
    ([1, 2, 3], "need 2 seeds, got 3"),
    (1.5, "seed must be None, an integer or 2 integers, got 1.5"),
    ([1, None], "seed must be None, an integer or 2 integers"),
    (-5, "a seed must be an integer from 0 to 2\\*\\*63 - 1, got -5"),
    (2**63 - 1, "a seed must be an integer from 0 to 2\\*\\*63 - 1, got 9223372036854775808"),  # env 1's: seed + 1
    (2**70, "from 0 to 2\\*\\*63 - 1, got 1180591620717411303424"),
])
def test_bad_vector_seeds_are_one_value_error(seed, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(")):
        HighwayVectorEnv("two-lane", num_envs=2).reset(seed=seed)


def test_a_single_env_seed_beyond_int64_is_one_value_error():
    with pytest.raises(ValueError, match="a seed must be an integer from 0 to"):
        highway_srl.make("two-lane").reset(seed=2**70)


def test_reset_options_are_refused_rather_than_ignored():
    with pytest.raises(ValueError, match="reset takes no options, got \\['reset_mask'\\]"):
        HighwayVectorEnv("two-lane", num_envs=2).reset(seed=0, options={"reset_mask": np.ones(2, bool)})


def test_sb3_adapter_refuses_float_actions_and_bad_indices():
    pytest.importorskip("stable_baselines3")
    from highway_srl.sb3 import SB3VecEnv, make_vec_env

    env = make_vec_env("two-lane", num_envs=4, seed=0)
    with pytest.raises(ResetNeeded):
        env.step(np.ones(4, dtype=np.int64))
    env.reset()
    with pytest.raises(ValueError, match="got dtype float64"):
        env.step_async(np.array([0.9, 1.1, 2.5, 3.99]))
    for indices in (4, -1, [0, 7], [1.0], "0", True):
        with pytest.raises(ValueError, match=r"indices must be None, an env index or a list of them in 0\.\.3"):
            env.get_attr("render_mode", indices=indices)
    assert env.get_attr("render_mode", indices=np.int64(3)) == [None]
    assert len(env.env_method("action_masks", indices=range(2))) == 2
    with pytest.raises(ValueError, match="SAME_STEP"):
        SB3VecEnv(HighwayVectorEnv("two-lane", num_envs=2, autoreset_mode="NextStep"))
