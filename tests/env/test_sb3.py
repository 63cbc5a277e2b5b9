"""highway_srl.sb3: Stable-Baselines3's VecEnv conventions over the batched simulator, and SB3 learning through it."""

import importlib
import sys

import gymnasium
import numpy as np
import pytest

import highway_srl
from highway_srl.env import HighwayVectorEnv

pytest.importorskip("stable_baselines3")
pytest.importorskip("sb3_contrib")

from stable_baselines3.common.env_checker import check_env  # noqa: E402
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv  # noqa: E402

from highway_srl.sb3 import make_vec_env  # noqa: E402


@pytest.mark.parametrize("scenario", ["two-lane", "multi-lane", "merge", "exit"])
def test_single_env_passes_sb3_checker(scenario):
    check_env(highway_srl.make(scenario), warn=True)


def test_adapter_steps_like_sb3s_dummy_vec_env_over_single_envs():
    """Up to and including each env's first episode end, the adapter answers what DummyVecEnv over seeded
    single envs answers: observations, rewards, dones, per-env infos with terminal_observation and
    TimeLimit.truncated (SB3's conventions). Episodes are cut at 12 steps to keep this short."""
    n, limit = 3, 12
    ours = make_vec_env("merge", num_envs=n, seed=20, max_episode_steps=limit)
    ref = DummyVecEnv([lambda: gymnasium.make("highway-srl/Merge-v0", max_episode_steps=limit) for _ in range(n)])
    ref.seed(20)
    assert np.allclose(ours.reset(), ref.reset(), atol=1e-5)
    rng = np.random.default_rng(0)
    for step in range(limit):
        actions = rng.integers(0, 4, n)
        obs, reward, done, infos = ours.step(actions)
        ref_obs, ref_reward, ref_done, ref_infos = ref.step(actions)
        assert np.array_equal(reward, ref_reward) and np.array_equal(done, ref_done)
        for b in range(n):
            assert set(infos[b]) == set(ref_infos[b]) - {"episode"}, b
            for key, value in ref_infos[b].items():
                if key == "terminal_observation":
                    assert np.allclose(infos[b][key], value, atol=1e-5)
                elif key != "episode":
                    assert np.array_equal(infos[b][key], value), key
            if not done[b]:
                assert np.allclose(obs[b], ref_obs[b], atol=1e-5)
    assert done.all() and all(info["TimeLimit.truncated"] for info in infos)


def test_adapter_is_an_sb3_vec_env_with_masks_attributes_and_methods():
    env = make_vec_env("two-lane", num_envs=4, seed=0)
    assert isinstance(env, VecEnv)
    env.reset()
    masks = env.action_masks()
    assert masks.shape == (4, 4) and masks.dtype == bool
    assert np.array_equal(np.stack(env.env_method("action_masks")), masks)  # what MaskablePPO calls
    assert [m.tolist() for m in env.env_method("action_masks", indices=[2])] == [masks[2].tolist()]
    assert env.has_attr("action_masks") and not env.has_attr("no_such_attribute")
    assert env.get_attr("render_mode") == [None] * 4
    env.set_attr("note", "shared")
    assert env.get_attr("note", indices=[1, 3]) == ["shared", "shared"]
    with pytest.raises(ValueError, match="share one simulator"):
        env.set_attr("note", "env 0 only", indices=[0])
    assert env.env_is_wrapped(gymnasium.Wrapper) == [False] * 4


def test_adapter_renders_env_zero_for_sb3s_video_recorder():
    env = make_vec_env("merge", num_envs=2, seed=0, render_mode="rgb_array")
    env.reset()
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3


def test_adapter_seed_reproduces_the_first_reset():
    a, b = make_vec_env("exit", num_envs=2), make_vec_env("exit", num_envs=2)
    a.seed(3)
    b.seed(3)
    first = a.reset()
    assert np.array_equal(first, b.reset())
    assert not np.array_equal(a.reset(), first)  # SB3: a seed is used for one reset only


def test_missing_sb3_is_one_line_naming_the_extra(monkeypatch):
    for name in ("stable_baselines3", "stable_baselines3.common", "stable_baselines3.common.vec_env"):
        monkeypatch.setitem(sys.modules, name, None)  # as if it were not installed
    monkeypatch.delitem(sys.modules, "highway_srl.sb3")
    with pytest.raises(ModuleNotFoundError, match=r"pip install 'highway-srl\[sb3\]'"):
        importlib.import_module("highway_srl.sb3")


def _mean_return(policy, seed: int = 1000, envs: int = 8, steps: int = 100, profile: str | None = None) -> float:
    """Mean return of the first `steps`-step episode of each env."""
    vec = HighwayVectorEnv("two-lane", "C", num_envs=envs, max_episode_steps=steps, profile=profile)
    obs, _ = vec.reset(seed=seed)
    total = np.zeros(envs)
    for _ in range(steps):
        obs, reward, *_ = vec.step(policy(obs, vec.action_masks()))
        total += reward
    return float(total.mean())


def _random_return(profile: str | None = None) -> float:
    rng = np.random.default_rng(0)
    return _mean_return(lambda obs, masks: rng.integers(0, 4, len(obs)), profile=profile)


@pytest.mark.slow
def test_sb3_dqn_through_the_adapter_beats_a_random_policy():
    from stable_baselines3 import DQN

    # 6,000 steps: at 3,000 the outcome hung on the seed (safe profile: seeds 0-3 gave 57.7, 68.9, 30.3, 10.1
    # against a random 19.5, and seed 0 fell to -15.4 when one SV's trajectory changed); at 6,000 they gave 45.1,
    # 51.4, 64.4, 48.5; under the default paper profile seed 0 gives 49.8 against a random 17.9
    env = make_vec_env("two-lane", num_envs=8, seed=0, max_episode_steps=100)
    model = DQN("MlpPolicy", env, learning_starts=500, buffer_size=20_000, batch_size=64, target_update_interval=250,
                exploration_fraction=0.5, learning_rate=1e-3, train_freq=1, seed=0, device="cpu").learn(6_000)
    learned = _mean_return(lambda obs, masks: model.predict(obs, deterministic=True)[0])
    assert learned > _random_return() + 20


@pytest.mark.slow
def test_maskable_ppo_through_the_adapter_beats_a_random_policy():
    from sb3_contrib import MaskablePPO

    # the safe profile: under the default paper profile (Eqs. 31-35 as printed) the safe set does not keep a
    # briefly trained policy out of collisions (3,000 and 6,000 steps: -232 against a random 18), so there
    # this would test the profile rather than the adapter; safe: 47 against a random 20
    env = make_vec_env("two-lane", num_envs=8, seed=0, max_episode_steps=100, profile="safe")
    model = MaskablePPO("MlpPolicy", env, n_steps=64, batch_size=128, n_epochs=4, seed=0, device="cpu").learn(3_000)
    learned = _mean_return(lambda obs, masks: model.predict(obs, action_masks=masks, deterministic=True)[0],
                           profile="safe")
    assert learned > _random_return("safe") + 20
