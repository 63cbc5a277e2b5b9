"""Gymnasium environments: the world plus the paper's rule layer, one action of A* per step.

Observation: the 37 inputs (§3.3, §4.1). Action: Discrete(4) over ACTIONS = (Faster, Idle, Slower,
LaneChange), turned into (target lane, target speed) by the control mapping. Reward: the reward machine's
(§3.2, §4.3; -320 on collision). The safe set of Table 1 is both info["action_mask"] and action_masks()
(the method sb3-contrib's MaskablePPO calls), for shields and MoE gating.

    env = highway_srl.make("merge", traffic="C")                 # gymnasium.Env
    envs = highway_srl.make("two-lane", num_envs=1024)           # gymnasium.vector.VectorEnv, batched
    envs = highway_srl.make("two-lane", vector=True)             # a VectorEnv at any N, 1 included
    gymnasium.make("highway-srl/TwoLane-v0", traffic="B")        # registered ids
    gymnasium.make_vec("highway-srl/TwoLane-v0", num_envs=64)    # the batched VectorEnv, not a SyncVectorEnv

Every info value is a host copy: a later step or reset cannot change what a caller already holds.
"""

from __future__ import annotations

import dataclasses

import gymnasium
import numpy as np
import torch
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv

from highway_srl.constants import EPISODE_STEPS
from highway_srl.rules import ACTIONS, SafetyLayer, observation_ranges, scenario_reward
from highway_srl.rules.episode import advance
from highway_srl.scenarios import ENV_IDS
from highway_srl.sim import World

RENDER_FPS = 8  # one frame per decision at the paper's 8 Hz


def host(t: torch.Tensor) -> np.ndarray:
    """A NumPy copy of t. On the CPU .numpy() alone shares memory with a tensor that the simulator later
    overwrites in place (a reset does), so a value handed out would change under its holder."""
    return t.detach().cpu().numpy().copy()


def env_spec(scenario: str, **kwargs) -> gymnasium.envs.registration.EnvSpec:
    """The registered spec of a scenario with these kwargs (gymnasium.make sets it itself; this is for
    envs built directly with highway_srl.make)."""
    spec = gymnasium.spec(f"highway-srl/{ENV_IDS[scenario]}-v0")
    return dataclasses.replace(spec, kwargs={**spec.kwargs, **kwargs})


class _Batch:
    """World + rule layer for B envs with per-env seeds; shared by the single and the vector env."""

    def __init__(self, scenario, traffic, adversarial, num_envs, device, seed, max_steps=EPISODE_STEPS, processes=1):
        self.world = World(scenario, traffic, adversarial, num_envs, device, seed, max_steps=max_steps,
                           processes=processes)
        self.layer = SafetyLayer(self.world.road)
        self.step_view = self.layer.observe(self.world)

    def reseed(self, seeds: list[int]) -> None:
        s = self.world.state
        s.seed[:] = torch.as_tensor(seeds, dtype=torch.long, device=s.seed.device)
        s.episode[:] = -1  # reset() starts episode 0 of each new seed
        self.world.reset()
        self.layer.reset()
        self.step_view = self.layer.observe(self.world)

    def restart(self, done: torch.Tensor) -> None:
        """Start the next episode of each env where done (B,) is True; the others are not touched."""
        self.world.reset(done)
        self.layer.reset(done)
        self.step_view = self.layer.observe(self.world)

    def act(self, action: torch.Tensor):
        """One step of the rollout (rules.episode.advance) and its training reward (B,)."""
        events, view, flags = advance(self.world, self.layer, action)
        reward = scenario_reward(self.world.scenario, view.primary.r_rm, events.collision, **flags.reward_inputs())
        self.step_view = view
        return reward, events, view

    def info(self, events=None) -> dict[str, np.ndarray]:
        """Host copies, (B, ...) each, of the current state: action_mask (B, 4) bool, rm_state (B,) u*,
        ego_speed (B,) m/s; with events also that step's collision and success (B,) bool."""
        m = self.step_view.primary
        info = {"action_mask": host(m.mask), "rm_state": host(m.rm_state), "ego_speed": host(self.world.ego_speed)}
        if events is not None:
            info["collision"] = host(events.collision)
            info["success"] = host(events.success)
        return info


def _obs_space(batch: int | None = None) -> spaces.Box:
    """Bounds of the 37 inputs (rules.observation_ranges)."""
    ranges = observation_ranges().numpy()
    low, high = ranges[:, 0], ranges[:, 1]
    if batch is not None:
        low, high = np.tile(low, (batch, 1)), np.tile(high, (batch, 1))
    return spaces.Box(low, high, dtype=np.float32)


def _render(batch: _Batch, env: int = 0) -> np.ndarray:
    from highway_srl.sim.render import capture, frame_array

    return frame_array(batch.world.road, capture(batch.world, env))


def _check_render_mode(render_mode: str | None) -> None:
    if render_mode not in (None, "rgb_array"):
        raise ValueError(f"unknown render_mode {render_mode!r}; use rgb_array or None")


class HighwayEnv(gymnasium.Env):
    """One episode at a time (num_envs = 1). For speed use HighwayVectorEnv or the raw World."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": RENDER_FPS}

    def __init__(self, scenario: str = "two-lane", traffic: str = "C", adversarial: bool = False, device: str = "cpu",
                 render_mode: str | None = None):
        _check_render_mode(render_mode)
        self._batch = _Batch(scenario, traffic, adversarial, 1, device, seed=0)
        self.observation_space = _obs_space()
        self.action_space = spaces.Discrete(len(ACTIONS))
        self.render_mode = render_mode
        self.spec = env_spec(scenario, traffic=traffic, adversarial=adversarial, device=device)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is None:
            seed = int(self.np_random.integers(0, 2**31 - 1))
        self._batch.reseed([seed])
        return host(self._batch.step_view.primary.obs[0]), {k: v[0] for k, v in self._batch.info().items()}

    def step(self, action):
        if not self.action_space.contains(action):
            raise ValueError(f"action {action!r} is not in {self.action_space} ({', '.join(ACTIONS)})")
        reward, events, view = self._batch.act(torch.tensor([int(action)], device=self._batch.world.device))
        info = {k: v[0] for k, v in self._batch.info(events).items()}
        return (host(view.primary.obs[0]), float(reward[0]), bool(events.terminated[0]),
                bool(events.truncated[0]), info)

    def action_masks(self) -> np.ndarray:
        """(4,) bool, Table 1's safe set of the current state in ACTIONS order (= info["action_mask"])."""
        return host(self._batch.step_view.primary.mask[0])

    def render(self):
        return _render(self._batch) if self.render_mode == "rgb_array" else None


class HighwayVectorEnv(VectorEnv):
    """B envs stepped as one batch on one device, with Gymnasium's same-step autoreset: a finished env
    restarts inside step(), the returned observation and info start its new episode, and
    info["final_obs"] / info["final_info"] hold the finished episode's last observation and info.

    final_obs is a dense (B, 37) array (SyncVectorEnv's is an object array) so batched code can index it;
    its rows are valid where info["_final_obs"] is True. final_info is a dict of (B, ...) arrays with
    Gymnasium's "_key" masks, valid where info["_final_info"] is True. Since a collision ends the episode,
    count collisions (and the exit's terminal success) in final_info: the top-level info of a restarted
    env describes its new episode, where nothing has happened yet.

    processes: World(processes=...), the simulator's step in that many worker processes (CPU; the rule
    layer stays in this one); close() ends them.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": ["rgb_array"], "render_fps": RENDER_FPS}

    def __init__(self, scenario: str = "two-lane", traffic: str = "C", adversarial: bool = False, num_envs: int = 2,
                 device: str = "cpu", render_mode: str | None = None, max_episode_steps: int = EPISODE_STEPS,
                 processes: int = 1):
        _check_render_mode(render_mode)
        self._batch = _Batch(scenario, traffic, adversarial, num_envs, device, seed=0, max_steps=max_episode_steps,
                             processes=processes)
        self.num_envs = num_envs
        self.single_observation_space = _obs_space()
        self.single_action_space = spaces.Discrete(len(ACTIONS))
        self.observation_space = _obs_space(num_envs)
        self.action_space = spaces.MultiDiscrete([len(ACTIONS)] * num_envs)
        self.render_mode = render_mode
        self.spec = dataclasses.replace(
            env_spec(scenario, traffic=traffic, adversarial=adversarial, device=device, num_envs=num_envs,
                     processes=processes),
            max_episode_steps=max_episode_steps)

    def reset(self, *, seed: int | list[int] | None = None, options: dict | None = None):
        """seed: an int (env b gets seed + b), B ints, or None (a fresh random seed)."""
        if seed is None:
            seed = int(np.random.SeedSequence().generate_state(1)[0] >> 1)
        seeds = list(seed) if isinstance(seed, (list, tuple, np.ndarray)) else [seed + i for i in range(self.num_envs)]
        if len(seeds) != self.num_envs:
            raise ValueError(f"need {self.num_envs} seeds, got {len(seeds)}")
        self._batch.reseed(seeds)
        return host(self._batch.step_view.primary.obs), self._batch.info()

    def step(self, actions):
        a = torch.as_tensor(np.asarray(actions), device=self._batch.world.device).long().reshape(self.num_envs)
        if bool(((a < 0) | (a >= len(ACTIONS))).any()):
            raise ValueError(f"actions must be in 0..{len(ACTIONS) - 1} ({', '.join(ACTIONS)})")
        reward, events, view = self._batch.act(a)
        obs, info = host(view.primary.obs), self._batch.info(events)
        done = events.terminated | events.truncated
        if bool(done.any()):  # the one host sync of a step: only then is there something to restart
            finished = host(done)
            final_info = {**info, **{f"_{k}": finished for k in info}}
            self._batch.restart(done)
            final = {"final_obs": obs, "_final_obs": finished, "final_info": final_info, "_final_info": finished}
            obs = host(self._batch.step_view.primary.obs)
            info = {**self._batch.info(), "collision": info["collision"] & ~finished,
                    "success": info["success"] & ~finished, **final}
        return obs, host(reward), host(events.terminated), host(events.truncated), info

    def action_masks(self) -> np.ndarray:
        """(B, 4) bool, Table 1's safe set of each env's current state (= info["action_mask"])."""
        return host(self._batch.step_view.primary.mask)

    def close_extras(self, **kwargs) -> None:
        self._batch.world.close()

    def render(self):
        """Env 0's frame, (H, W, 3) uint8, if render_mode is "rgb_array" (else None): drawing every env
        would cost far more than stepping them."""
        return _render(self._batch) if self.render_mode == "rgb_array" else None


def make(scenario: str = "two-lane", traffic: str = "C", adversarial: bool = False, num_envs: int = 1,
         device: str = "cpu", seed: int | None = None, vector: bool | None = None, render_mode: str | None = None):
    """A Gymnasium Env (num_envs = 1) or VectorEnv (num_envs > 1, or vector=True at any N) of one scenario;
    reset with `seed` if given."""
    if vector is None:
        vector = num_envs != 1
    if not vector and num_envs != 1:
        raise ValueError(f"a single Env has num_envs = 1, got {num_envs}; use vector=True for a VectorEnv")
    if vector:
        env = HighwayVectorEnv(scenario, traffic, adversarial, num_envs, device, render_mode)
    else:
        env = HighwayEnv(scenario, traffic, adversarial, device, render_mode)
    if seed is not None:
        env.reset(seed=seed)
    return env
