"""Gymnasium environments: the world plus the paper's rule layer, one action of A* per step.

Observation: the 37 inputs (§3.3, §4.1). Action: Discrete(4) over ACTIONS = (Faster, Idle, Slower,
LaneChange), turned into (target lane, target speed) by the control mapping. Reward: the reward machine's
(§3.2, §4.3; -320 on collision). info["action_mask"] is Table 1's safe set, for shields and MoE gating.

    env = highway_srl.make("merge", traffic="C")                 # gymnasium.Env
    envs = highway_srl.make("two-lane", num_envs=1024)           # gymnasium.vector.VectorEnv, batched
    gymnasium.make("highway-srl/TwoLane-v0", traffic="B")        # registered ids
"""

from __future__ import annotations

import gymnasium
import numpy as np
import torch
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv

from highway_srl.rules import ACTIONS, SafetyLayer, observation_ranges, scenario_reward
from highway_srl.sim import World

ENV_IDS = {"two-lane": "TwoLane", "multi-lane": "MultiLane", "merge": "Merge", "exit": "Exit"}


class _Batch:
    """World + rule layer for B envs with per-env seeds; shared by the single and the vector env."""

    def __init__(self, scenario, traffic, adversarial, num_envs, device, seed):
        self.world = World(scenario, traffic, adversarial, num_envs, device, seed)
        self.layer = SafetyLayer(self.world.road)
        self.step_view = self.layer.observe(self.world)

    def reseed(self, seeds: list[int]) -> None:
        s = self.world.state
        s.seed[:] = torch.as_tensor(seeds, dtype=torch.long, device=s.seed.device)
        s.episode[:] = -1  # reset() starts episode 0 of each new seed
        self.world.reset()
        self.layer.reset()
        self.step_view = self.layer.observe(self.world)

    def act(self, action: torch.Tensor):
        lane, speed = self.layer.act(action)
        events = self.world.step(lane, speed)
        view = self.layer.observe(self.world)
        flags = self.world.stage_flags()
        reward = scenario_reward(self.world.scenario, view.primary.r_rm, events.collision, r_merge=flags["merged"],
                                 r_exit1=flags["exit1"], r_exit2=flags["exit2"])
        self.step_view = view
        return reward, events, view

    def info(self, view, events=None) -> dict:
        m = view.primary
        info = {"action_mask": m.mask.cpu().numpy(), "rm_state": m.rm_state.cpu().numpy(),
                "ego_speed": self.world.ego_speed.cpu().numpy()}
        if events is not None:
            info["collision"] = events.collision.cpu().numpy()
            info["success"] = events.success.cpu().numpy()
        return info


def _obs_space(batch: int | None = None) -> spaces.Box:
    """Bounds of the 37 inputs (rules.observation_ranges)."""
    ranges = observation_ranges().numpy()
    low, high = ranges[:, 0], ranges[:, 1]
    if batch is not None:
        low, high = np.tile(low, (batch, 1)), np.tile(high, (batch, 1))
    return spaces.Box(low, high, dtype=np.float32)


class HighwayEnv(gymnasium.Env):
    """One episode at a time (num_envs = 1). For speed use HighwayVectorEnv or the raw World."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 8}

    def __init__(self, scenario: str = "two-lane", traffic: str = "C", adversarial: bool = False, device: str = "cpu",
                 render_mode: str | None = None):
        self._args = (scenario, traffic, adversarial, 1, device)
        self._batch = _Batch(*self._args, seed=0)
        self.observation_space = _obs_space()
        self.action_space = spaces.Discrete(len(ACTIONS))
        self.render_mode = render_mode

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is None:
            seed = int(self.np_random.integers(0, 2**31 - 1))
        self._batch.reseed([seed])
        view = self._batch.step_view
        return view.primary.obs[0].cpu().numpy(), {k: v[0] for k, v in self._batch.info(view).items()}

    def step(self, action):
        if not self.action_space.contains(action):
            raise ValueError(f"action {action!r} is not in {self.action_space} ({', '.join(ACTIONS)})")
        reward, events, view = self._batch.act(torch.tensor([int(action)], device=self._batch.world.device))
        info = {k: v[0] for k, v in self._batch.info(view, events).items()}
        return (view.primary.obs[0].cpu().numpy(), float(reward[0]), bool(events.terminated[0]),
                bool(events.truncated[0]), info)

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        from highway_srl.sim.render import capture, frame_array

        return frame_array(self._batch.world.road, capture(self._batch.world))


class HighwayVectorEnv(VectorEnv):
    """B envs stepped as one batch on one device; finished envs restart in the same step (SAME_STEP
    autoreset: the returned observation starts the new episode, info["final_obs"] holds the last one)."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, scenario: str = "two-lane", traffic: str = "C", adversarial: bool = False, num_envs: int = 2,
                 device: str = "cpu"):
        self._batch = _Batch(scenario, traffic, adversarial, num_envs, device, seed=0)
        self.num_envs = num_envs
        self.single_observation_space = _obs_space()
        self.single_action_space = spaces.Discrete(len(ACTIONS))
        self.observation_space = _obs_space(num_envs)
        self.action_space = spaces.MultiDiscrete([len(ACTIONS)] * num_envs)

    def reset(self, *, seed: int | list[int] | None = None, options: dict | None = None):
        if seed is None:
            seed = int(np.random.SeedSequence().generate_state(1)[0] >> 1)
        seeds = list(seed) if isinstance(seed, (list, tuple)) else [seed + i for i in range(self.num_envs)]
        self._batch.reseed(seeds)
        view = self._batch.step_view
        return view.primary.obs.cpu().numpy(), self._batch.info(view)

    def step(self, actions):
        a = torch.as_tensor(np.asarray(actions), device=self._batch.world.device).long().reshape(self.num_envs)
        if bool(((a < 0) | (a >= len(ACTIONS))).any()):
            raise ValueError(f"actions must be in 0..{len(ACTIONS) - 1} ({', '.join(ACTIONS)})")
        reward, events, view = self._batch.act(a)
        info = self._batch.info(view, events)
        done = events.terminated | events.truncated
        if bool(done.any()):
            info["final_obs"] = view.primary.obs.cpu().numpy()
            info["_final_obs"] = done.cpu().numpy()
            self._batch.world.reset(done)
            self._batch.layer.reset(done)
            view = self._batch.step_view = self._batch.layer.observe(self._batch.world)
            info["action_mask"] = view.primary.mask.cpu().numpy()
        return (view.primary.obs.cpu().numpy(), reward.cpu().numpy(), events.terminated.cpu().numpy(),
                events.truncated.cpu().numpy(), info)


def make(scenario: str = "two-lane", traffic: str = "C", adversarial: bool = False, num_envs: int = 1,
         device: str = "cpu", seed: int | None = None):
    """A Gymnasium Env (num_envs = 1) or VectorEnv (num_envs > 1) of one scenario; reset with `seed`."""
    env = HighwayEnv(scenario, traffic, adversarial, device) if num_envs == 1 else \
        HighwayVectorEnv(scenario, traffic, adversarial, num_envs, device)
    if seed is not None:
        env.reset(seed=seed)
    return env

