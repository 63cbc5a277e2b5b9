"""Stable-Baselines3 on the batched simulator: a VecEnv over HighwayVectorEnv (install the [sb3] extra).

    from sb3_contrib import MaskablePPO
    from highway_srl.sb3 import make_vec_env
    env = make_vec_env("two-lane", traffic="C", num_envs=16, seed=0)
    model = MaskablePPO("MlpPolicy", env).learn(20_000)     # sees Table 1's safe set via action_masks()

SB3's conventions: step returns (obs, reward, done, infos) with done = terminated or truncated and one info
dict per env; a finished env's dict is the finished episode's last info plus "terminal_observation" and
"TimeLimit.truncated" (DQN bootstraps through a time limit, not through a collision); the observation is
already the new episode's. All B envs share one simulator, so attributes and methods are the batched env's:
get_attr answers the same value for every env, and env_method splits a (B, ...) result into per-env rows.
The rule layer, adversary and configuration are the Gymnasium envs' (make_vec_env takes the same
profile=, adversary=, config=; docs/envs.md). Actions must be B integers in 0..3 (one ValueError otherwise,
raised by step_async), and indices= arguments env indices in 0..B-1.
"""

from __future__ import annotations

from typing import Any

import numpy as np

try:
    from stable_baselines3.common.vec_env import VecEnv
except ModuleNotFoundError:
    raise ModuleNotFoundError("highway_srl.sb3 needs Stable-Baselines3: pip install 'highway-srl[sb3]'") from None

from gymnasium.vector import AutoresetMode

from highway_srl.env import HighwayVectorEnv


class SB3VecEnv(VecEnv):
    """SB3's VecEnv view of a HighwayVectorEnv (B envs; Box(37,) observations, Discrete(4) actions)."""

    def __init__(self, env: HighwayVectorEnv):
        if env.autoreset_mode != AutoresetMode.SAME_STEP:
            raise ValueError("SB3's VecEnv restarts finished envs within the step: use autoreset_mode SAME_STEP")
        self.env = env
        self._actions: np.ndarray | None = None
        super().__init__(env.num_envs, env.single_observation_space, env.single_action_space)

    # ------------------------------------------------------------------ stepping
    def reset(self) -> np.ndarray:
        """Seeds from seed() are used once (env b gets seed + b); without them each env's next episode
        (the first reset: fresh random seeds), as SB3's DummyVecEnv over Gymnasium envs continues their
        seeded streams."""
        seeds = None if any(s is None for s in self._seeds) else list(self._seeds)
        obs, info = self.env.reset(seed=seeds)
        self.reset_infos = _per_env(info, self.num_envs)
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self.env.check_actions(actions)
        self._actions = actions

    def step_wait(self):
        obs, reward, terminated, truncated, info = self.env.step(self._actions)
        done = terminated | truncated
        time_limit = truncated & ~terminated
        running = {k: v for k, v in info.items() if not k.startswith(("final_", "_"))}
        infos = _per_env({**running, "TimeLimit.truncated": time_limit}, self.num_envs)
        for b in np.flatnonzero(done):  # a Python loop over the finished envs only
            infos[b] = {k: v[b] for k, v in info["final_info"].items() if not k.startswith("_")}
            infos[b]["terminal_observation"] = info["final_obs"][b]
            infos[b]["TimeLimit.truncated"] = bool(time_limit[b])
        return obs, reward.astype(np.float32), done, infos

    def action_masks(self) -> np.ndarray:
        """(B, 4) bool, Table 1's safe set of each env's current state."""
        return self.env.action_masks()

    def close(self) -> None:
        self.env.close()

    def get_images(self) -> list[np.ndarray | None]:
        """Env 0's frame only (drawing every env's would cost far more than stepping them); SB3's render()
        and VecVideoRecorder use it."""
        frames = self.env.render()
        return [None if frames is None else frames[0]]

    # ------------------------------------------------------------------ attributes shared by the batch
    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        value = getattr(self.env, attr_name)
        return [value for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        if indices is not None and sorted(self._get_indices(indices)) != list(range(self.num_envs)):
            raise ValueError(f"the {self.num_envs} envs share one simulator: set {attr_name!r} for all of them")
        setattr(self.env, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        """Calls the batched env's method once; a (B, ...) array result is split into per-env rows, any
        other result is repeated for each env asked for."""
        result = getattr(self.env, method_name)(*method_args, **method_kwargs)
        rows = isinstance(result, np.ndarray) and result.ndim >= 1 and result.shape[0] == self.num_envs
        return [result[b] if rows else result for b in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def _get_indices(self, indices) -> list[int]:
        """SB3's indices argument (None: all envs, an int, or a sequence of ints) as a list, or one
        ValueError naming what is allowed."""
        if indices is None:
            return list(range(self.num_envs))
        chosen = [indices] if isinstance(indices, (int, np.integer)) else indices
        try:
            chosen = list(chosen)
        except TypeError:
            chosen = None
        ok = chosen is not None and all(isinstance(i, (int, np.integer)) and not isinstance(i, (bool, np.bool_))
                                        and 0 <= i < self.num_envs for i in chosen)
        if not ok:
            raise ValueError(f"indices must be None, an env index or a list of them in 0..{self.num_envs - 1}, "
                             f"got {indices!r}")
        return [int(i) for i in chosen]


def _per_env(info: dict[str, np.ndarray], num_envs: int) -> list[dict[str, Any]]:
    """Gymnasium's dict of (B, ...) arrays as SB3's list of B dicts."""
    keys = list(info)
    return [dict(zip(keys, row)) for row in zip(*(info[k] for k in keys))] if keys else [{} for _ in range(num_envs)]


def make_vec_env(scenario: str = "two-lane", traffic: str | None = None, adversarial: bool | None = None,
                 num_envs: int = 8, device: str = "cpu", seed: int | None = None, render_mode: str | None = None,
                 max_episode_steps: int | None = None, **options) -> SB3VecEnv:
    """An SB3 VecEnv of num_envs batched envs of one scenario; with seed, its first reset uses seed + b.
    options: profile=, adversary=, config=, processes= (HighwayVectorEnv's)."""
    venv = SB3VecEnv(HighwayVectorEnv(scenario, traffic, adversarial, num_envs, device, render_mode, max_episode_steps,
                                      **options))
    if seed is not None:
        venv.seed(seed)
    return venv
