"""Gymnasium's vector contract: the batched env answers what SyncVectorEnv over the single env answers (both
autoreset modes, across episode ends and unseeded resets), and Gymnasium's vector wrappers accept it."""

import sys
import types
from collections.abc import Sequence

import gymnasium
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv
from gymnasium.wrappers.vector import DtypeObservation, NormalizeObservation, RecordVideo

from highway_srl.env import HighwayEnv, HighwayVectorEnv

N = 3
CONFIG = {"max_episode_steps": 6, "traffic": "D"}  # short episodes: several ends in a few steps


def _pair(mode: AutoresetMode, scenario: str = "merge"):
    ours = HighwayVectorEnv(scenario, num_envs=N, config=CONFIG, autoreset_mode=mode)
    ref = SyncVectorEnv([lambda: HighwayEnv(scenario, config=CONFIG) for _ in range(N)], autoreset_mode=mode)
    return ours, ref


def _same_info(ours: dict, ref: dict, where: str) -> None:
    """Same keys and "_key" masks; the same values where the mask is set (SyncVectorEnv's final_obs is an
    object array of rows, ours a dense array)."""
    assert set(ours) == set(ref), (where, set(ours) ^ set(ref))
    for key, value in ref.items():
        if key == "final_info":
            _same_info(ours[key], value, where + " final_info")
        elif key == "final_obs":
            rows = ref["_final_obs"]
            assert np.allclose(ours[key][rows], np.stack(value[rows]), atol=1e-5), where
        elif key.startswith("_"):
            assert np.array_equal(ours[key], value), (where, key)
        else:
            rows = ref[f"_{key}"]
            assert _close(ours[key][rows], value[rows]), (where, key)


def _close(a: np.ndarray, b: np.ndarray) -> bool:
    """Floats to float rounding (a batch of B and B batches of one round differently), the rest exactly."""
    if np.issubdtype(np.asarray(b).dtype, np.floating):
        return np.allclose(a, b, atol=1e-5)
    return np.array_equal(a, b)


def _same_step(ours, ref, where: str) -> None:
    (obs, reward, term, trunc, info), (r_obs, r_reward, r_term, r_trunc, r_info) = ours, ref
    assert np.allclose(obs, r_obs, atol=1e-5) and np.allclose(reward, r_reward, atol=1e-5), where
    assert np.array_equal(term, r_term) and np.array_equal(trunc, r_trunc), where
    _same_info(info, r_info, where)


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_batched_env_matches_sync_vector_env_across_episode_ends_and_unseeded_resets(mode):
    ours, ref = _pair(mode)
    o, r = ours.reset(seed=11), ref.reset(seed=11)
    assert np.allclose(o[0], r[0], atol=1e-5)
    _same_info(o[1], r[1], "reset")
    ends = 0
    for t, a in enumerate(np.random.default_rng(1).integers(0, 4, size=(20, N))):
        out, r_out = ours.step(a), ref.step(a)
        _same_step(out, r_out, f"step {t}")
        ends += int((out[2] | out[3]).sum())
    assert ends >= 2 * N  # every env crossed at least two episode ends
    for k in range(2):  # an unseeded reset continues each env's seeded stream (its next episode)
        o, r = ours.reset(), ref.reset()
        assert np.allclose(o[0], r[0], atol=1e-5), f"unseeded reset {k}"
        _same_step(ours.step(np.ones(N, dtype=np.int64)), ref.step(np.ones(N, dtype=np.int64)), f"after reset {k}")


def test_an_unseeded_reset_is_reproducible_and_a_new_episode():
    a, b = HighwayVectorEnv("two-lane", num_envs=2), HighwayVectorEnv("two-lane", num_envs=2)
    first_a, first_b = a.reset(seed=0)[0], b.reset(seed=0)[0]
    second_a, second_b = a.reset()[0], b.reset()[0]
    assert np.array_equal(first_a, first_b) and np.array_equal(second_a, second_b)
    assert not np.array_equal(first_a, second_a)
    assert np.array_equal(a.reset(seed=0)[0], first_a)  # a seed starts its stream over


def test_first_unseeded_reset_draws_fresh_seeds():
    a, b = HighwayVectorEnv("two-lane", num_envs=2), HighwayVectorEnv("two-lane", num_envs=2)
    assert not np.array_equal(a.reset()[0], b.reset()[0])


def test_next_step_autoreset_is_what_the_vector_observation_wrappers_need():
    with pytest.raises(ValueError, match="NEXT_STEP"):
        NormalizeObservation(HighwayVectorEnv("two-lane", num_envs=2))
    env = HighwayVectorEnv("two-lane", num_envs=2, config={"max_episode_steps": 4},
                           autoreset_mode=AutoresetMode.NEXT_STEP)
    norm = NormalizeObservation(env)
    wrapped = DtypeObservation(norm, np.float64)
    obs, _ = wrapped.reset(seed=0)
    for _ in range(6):  # across an episode end
        obs, *_ = wrapped.step(np.ones(2, dtype=np.int64))
    assert obs.dtype == np.float64 and obs.shape == (2, 37) and np.isfinite(obs).all()
    assert norm.obs_rms.count > 7 * 2  # the running statistics saw the reset's and every step's batch


def test_make_vec_takes_the_autoreset_mode_and_refuses_others():
    envs = gymnasium.make_vec("highway-srl/Exit-v0", num_envs=2, autoreset_mode=AutoresetMode.NEXT_STEP)
    assert envs.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert HighwayVectorEnv("exit", num_envs=2, autoreset_mode="NextStep").autoreset_mode == AutoresetMode.NEXT_STEP
    with pytest.raises(ValueError, match="autoreset_mode must be one of SAME_STEP, NEXT_STEP"):
        HighwayVectorEnv("exit", num_envs=2, autoreset_mode=AutoresetMode.DISABLED)


def test_render_gives_one_frame_per_env_taken_when_render_ran():
    envs = HighwayVectorEnv("exit", num_envs=3, render_mode="rgb_array")
    envs.reset(seed=0)
    frames = envs.render()
    assert isinstance(frames, Sequence) and len(frames) == 3  # what RecordVideo asks of a vector render
    first = frames[0]
    assert first.dtype == np.uint8 and first.ndim == 3 and first.shape[2] == 3
    assert len(frames[1:]) == 2 and frames[-1].shape == first.shape
    envs.step(np.zeros(3, dtype=np.int64))
    assert np.array_equal(frames[0], first)  # drawn from the state held at render()
    assert not np.array_equal(envs.render()[0], first)
    with pytest.raises(IndexError):
        frames[3]
    assert HighwayVectorEnv("exit", num_envs=3).render() is None


def test_record_video_records_the_batched_env_without_a_display(monkeypatch, tmp_path):
    """gymnasium.wrappers.vector.RecordVideo writes through moviepy; a stand-in records what it is given."""
    written = []

    class Clip:
        def __init__(self, frames, fps):
            self.frames, self.fps = frames, fps

        def write_videofile(self, path, logger=None):
            written.append((path, self.frames, self.fps))

    module = types.ModuleType("moviepy.video.io.ImageSequenceClip")
    module.ImageSequenceClip = Clip
    for name in ("moviepy", "moviepy.video", "moviepy.video.io"):
        monkeypatch.setitem(sys.modules, name, types.ModuleType(name))
    monkeypatch.setitem(sys.modules, "moviepy.video.io.ImageSequenceClip", module)
    env = HighwayVectorEnv("two-lane", num_envs=2, render_mode="rgb_array", config={"max_episode_steps": 3},
                           autoreset_mode=AutoresetMode.NEXT_STEP)
    recorder = RecordVideo(env, str(tmp_path / "videos"), episode_trigger=lambda episode: episode == 0)
    recorder.reset(seed=0)
    for _ in range(4):
        recorder.step(np.ones(2, dtype=np.int64))
    recorder.close()
    (path, frames, fps), = written
    single = env.render()[0]
    assert fps == 8 and len(frames) == 4  # the reset and three steps of env 0's first episode
    assert frames[0].shape in ((single.shape[0], 2 * single.shape[1], 3), (2 * single.shape[0], single.shape[1], 3))
