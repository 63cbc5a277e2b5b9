"""Gymnasium interfaces: highway_srl.make, registered ids, make_vec, vector env with same-step autoreset."""

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import highway_srl
from highway_srl.constants import EPISODE_STEPS, OBS_DIM
from highway_srl.env import HighwayVectorEnv


@pytest.mark.parametrize("scenario", ["two-lane", "multi-lane", "merge", "exit"])
def test_single_env_passes_gymnasium_checker(scenario):
    env = highway_srl.make(scenario, traffic="B")
    check_env(env, skip_render_check=True)
    obs, info = env.reset(seed=3)
    assert obs.shape == (OBS_DIM,) and np.isfinite(obs).all()
    assert info["action_mask"].shape == (4,) and info["action_mask"].any()


def test_registered_ids_make_envs():
    env = gymnasium.make("highway-srl/Merge-v0", traffic="A")
    obs, _ = env.reset(seed=0)
    assert obs.shape == (OBS_DIM,)


def test_same_seed_same_episode():
    a, b = highway_srl.make("two-lane"), highway_srl.make("two-lane")
    oa, _ = a.reset(seed=11)
    ob, _ = b.reset(seed=11)
    for _ in range(30):
        oa, ra, *_ = a.step(0)
        ob, rb, *_ = b.step(0)
    assert np.array_equal(oa, ob) and ra == rb


def test_vector_env_steps_batches_and_restarts_finished_envs():
    envs = highway_srl.make("two-lane", traffic="C", num_envs=6)
    obs, info = envs.reset(seed=0)
    assert obs.shape == (6, OBS_DIM)
    finished = 0
    for _ in range(330):
        obs, reward, term, trunc, info = envs.step(np.ones(6, dtype=np.int64))  # Idle
        assert np.isfinite(obs).all() and reward.shape == (6,)
        finished += int((term | trunc).sum())
    assert finished >= 6  # every env ended at least one 320-step episode and restarted


def test_out_of_range_action_is_a_clear_error():
    env = highway_srl.make("two-lane")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="not in"):
        env.step(7)


def test_make_vec_returns_the_batched_env_with_the_episode_limit():
    envs = gymnasium.make_vec("highway-srl/TwoLane-v0", num_envs=3, traffic="B")
    assert isinstance(envs, HighwayVectorEnv) and envs.num_envs == 3
    assert envs.spec.max_episode_steps == EPISODE_STEPS
    # the envs truncate themselves: the registry holds no limit, so gymnasium.make adds no TimeLimit
    assert gymnasium.spec("highway-srl/Merge-v0").max_episode_steps is None
    env = gymnasium.make("highway-srl/Merge-v0")
    assert env.spec.max_episode_steps == EPISODE_STEPS and "TimeLimit" not in str(env)
    obs, _ = envs.reset(seed=0)
    assert obs.shape == (3, OBS_DIM)


def test_vector_true_gives_a_vector_env_at_one_env_and_make_keeps_the_single_env():
    envs = highway_srl.make("merge", vector=True)
    assert isinstance(envs, gymnasium.vector.VectorEnv) and envs.num_envs == 1
    obs, info = envs.reset(seed=0)
    assert obs.shape == (1, OBS_DIM) and info["action_mask"].shape == (1, 4)
    env = highway_srl.make("merge")
    assert isinstance(env, gymnasium.Env) and env.spec.max_episode_steps == EPISODE_STEPS
    with pytest.raises(ValueError, match="vector=True"):
        highway_srl.make("merge", num_envs=4, vector=False)


def test_action_masks_are_the_info_masks_of_single_and_vector_envs():
    env = highway_srl.make("multi-lane")
    _, info = env.reset(seed=5)
    assert env.action_masks().dtype == bool and np.array_equal(env.action_masks(), info["action_mask"])
    envs = highway_srl.make("multi-lane", num_envs=4)
    _, info = envs.reset(seed=5)
    _, _, _, _, info = envs.step(np.zeros(4, dtype=np.int64))
    assert envs.action_masks().shape == (4, 4) and np.array_equal(envs.action_masks(), info["action_mask"])


def test_finished_envs_final_obs_and_final_info_are_the_finished_episodes_and_outlive_the_reset():
    """Env A truncates at step 5 and restarts; env B (limit 50) is the same world continuing, so at step 5
    B's observation and info are A's finished episode. What A returned must still hold after A steps on."""
    a = HighwayVectorEnv("two-lane", "C", num_envs=3, max_episode_steps=5)
    b = HighwayVectorEnv("two-lane", "C", num_envs=3, max_episode_steps=50)
    a.reset(seed=7)
    b.reset(seed=7)
    idle = np.ones(3, dtype=np.int64)
    for _ in range(5):
        obs_a, _, term_a, trunc_a, info_a = a.step(idle)
        obs_b, _, _, _, info_b = b.step(idle)
    assert (trunc_a & ~term_a).all() and info_a["_final_obs"].all() and info_a["_final_info"].all()
    expected = {k: v.copy() for k, v in info_b.items()}
    held = {k: v.copy() for k, v in info_a["final_info"].items()}
    for key in ("action_mask", "rm_state", "ego_speed", "collision", "success"):
        assert np.array_equal(info_a["final_info"][key], expected[key]), key
        assert info_a["final_info"][f"_{key}"].all()
    assert np.array_equal(info_a["final_obs"], obs_b)
    # the top-level info describes the new episodes: their masks, and no step of them has run yet, so (as in
    # SyncVectorEnv) no env's info has a collision or success entry
    assert np.array_equal(info_a["action_mask"], a.action_masks())
    assert "collision" not in info_a and "_success" not in info_a
    assert not np.array_equal(obs_a, obs_b)
    a.step(idle)
    for key, value in held.items():
        assert np.array_equal(info_a["final_info"][key], value), key


def test_info_values_are_copies_that_later_steps_cannot_change():
    envs = highway_srl.make("two-lane", num_envs=2)
    obs, info = envs.reset(seed=1)
    held_obs, held_info = obs.copy(), {k: v.copy() for k, v in info.items()}
    for _ in range(3):
        envs.step(np.zeros(2, dtype=np.int64))  # Faster: the speed changes
    assert np.array_equal(obs, held_obs)
    for key, value in held_info.items():
        assert np.array_equal(info[key], value), key


def test_single_env_renders_its_frame():
    env = highway_srl.make("exit", render_mode="rgb_array", seed=0)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    assert highway_srl.make("exit").render() is None


def test_vector_env_in_worker_processes_gives_the_same_steps():
    one = HighwayVectorEnv("merge", "D", num_envs=5, max_episode_steps=20)
    two = HighwayVectorEnv("merge", "D", num_envs=5, max_episode_steps=20, processes=2)
    try:
        for env in (one, two):
            env.reset(seed=3)
        actions = np.random.default_rng(0).integers(0, 4, size=(45, 5))
        for a in actions:  # past two truncations: the autoreset runs in the workers too
            out_one, out_two = one.step(a), two.step(a)
            for x, y in zip(out_one[:4], out_two[:4]):
                assert np.array_equal(x, y)
            assert out_one[4].keys() == out_two[4].keys()
    finally:
        two.close()
    assert two.spec.kwargs["processes"] == 2
