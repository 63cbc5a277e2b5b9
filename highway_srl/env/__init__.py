"""Gymnasium environments: the world plus the paper's rule layer, one action of A* per step.

Observation: the 37 inputs (§3.3, §4.1). Action: Discrete(4) over ACTIONS = (Faster, Idle, Slower,
LaneChange), turned into (target lane, target speed) by the control mapping. Reward: the reward machine's
(§3.2, §4.3; -320 on collision). The safe set of Table 1 is both info["action_mask"] and action_masks()
(the method sb3-contrib's MaskablePPO calls), for shields and MoE gating.

    env = highway_srl.make("merge", traffic="C")                 # gymnasium.Env
    envs = highway_srl.make("two-lane", num_envs=1024)           # gymnasium.vector.VectorEnv, batched
    envs = highway_srl.make("two-lane", vector=True)             # a VectorEnv at any N, 1 included
    gymnasium.make("highway-srl/TwoLane-v0", config={"traffic": "B", "adversarial": True})
    gymnasium.make_vec("highway-srl/TwoLane-v0", num_envs=64)    # the batched VectorEnv, not a SyncVectorEnv

The rule layer and the adversary are the reproduction's (constants.DEFAULT_PROFILE, DEFAULT_ADVERSARY),
the same as `train`'s; profile=, adversary= and config={...} change them (env.config, docs/envs.md).
An env's episodes are episodes 0, 1, 2, ... of its seed: reset(seed=s) starts episode 0 of seed s,
reset() the next episode, so an unseeded reset continues the seeded stream as Gymnasium's envs do.
Every info value is a host copy: a later step or reset cannot change what a caller already holds.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from types import SimpleNamespace

import gymnasium
import numpy as np
import torch
from gymnasium import spaces
from gymnasium.error import ResetNeeded
from gymnasium.vector import AutoresetMode, VectorEnv

from highway_srl.env.config import TrainingReward, env_config
from highway_srl.rules import ACTIONS, SafetyLayer, observation_ranges
from highway_srl.rules.episode import advance
from highway_srl.scenarios import ENV_IDS
from highway_srl.sim import World
from highway_srl.sim.state import WorldState

RENDER_FPS = 8  # one frame per decision at the paper's 8 Hz
AUTORESET_MODES = (AutoresetMode.SAME_STEP, AutoresetMode.NEXT_STEP)


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

    def __init__(self, scenario: str, config: dict, num_envs: int, device, processes: int = 1):
        c = config
        self.config = c
        self.world = World(scenario, c["traffic"], c["adversarial"], num_envs, device, seed=0, style=c["style"],
                           num_vehicles=c["vehicles_count"], max_steps=c["max_episode_steps"],
                           adversary=c["adversary"], processes=processes)
        self.layer = SafetyLayer(self.world.road, profile=c["profile"])
        self.reward = TrainingReward(scenario, c)
        self.step_view = self.layer.observe(self.world)
        self.started = False  # reset() has run: step() may follow, reset() without a seed continues

    def reseed(self, seeds: list[int]) -> None:
        for seed in seeds:  # the world's seeds are int64 counters (sim/rng.py)
            if not 0 <= seed < 2**63:
                raise ValueError(f"a seed must be an integer from 0 to 2**63 - 1, got {seed}")
        s = self.world.state
        s.seed[:] = torch.as_tensor(seeds, dtype=torch.long, device=s.seed.device)
        s.episode[:] = -1  # reset() starts episode 0 of each new seed
        self.world.reset()
        self.layer.reset()
        self.step_view = self.layer.observe(self.world)
        self.started = True

    def restart(self, done: torch.Tensor) -> None:
        """Start the next episode of each env where done (B,) is True; the others are not touched."""
        self.world.reset(done)
        self.layer.reset(done)
        self.step_view = self.layer.observe(self.world)

    def act(self, action: torch.Tensor):
        """One step of the rollout (rules.episode.advance) and its training reward (B,)."""
        events, view, flags = advance(self.world, self.layer, action)
        reward = self.reward(view.primary.r_rm, events.collision, flags)
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

    def frames(self) -> "Frames":
        """Every env's frame, drawn when read, from a host copy of the state taken now."""
        s = self.world.state
        held = WorldState(**{f.name: getattr(s, f.name).detach().cpu().clone() for f in dataclasses.fields(s)})
        return Frames(self.world.road, held)


class Frames(Sequence):
    """A vector env's render(): one (H, W, 3) uint8 frame per env, as Gymnasium's vector envs give, each
    drawn when it is read (a frame takes tens of milliseconds to draw, so drawing all B at every step would
    cost far more than stepping them). The state was copied when render() ran: a later step does not change
    the frames. gymnasium.wrappers.vector.RecordVideo(record_first_only=True) draws env 0's only."""

    def __init__(self, road, state: WorldState):
        self.road, self.state = road, state

    def __len__(self) -> int:
        return self.state.x.shape[0]

    def __getitem__(self, index):
        from highway_srl.sim.render import capture, frame_array

        envs = range(len(self))[index]  # IndexError out of range, as a tuple's
        if isinstance(envs, range):
            return tuple(self[b] for b in envs)
        return frame_array(self.road, capture(SimpleNamespace(state=self.state), envs))


def _obs_space(batch: int | None = None) -> spaces.Box:
    """Bounds of the 37 inputs (rules.observation_ranges)."""
    ranges = observation_ranges().numpy()
    low, high = ranges[:, 0], ranges[:, 1]
    if batch is not None:
        low, high = np.tile(low, (batch, 1)), np.tile(high, (batch, 1))
    return spaces.Box(low, high, dtype=np.float32)


def _check_render_mode(render_mode: str | None) -> None:
    if render_mode not in (None, "rgb_array"):
        raise ValueError(f"unknown render_mode {render_mode!r}; use rgb_array or None")


def _check_options(options: dict | None) -> None:
    if options:
        raise ValueError(f"reset takes no options, got {sorted(options, key=str)}")


class _Configured:
    """config and spec of both envs: the spec's max_episode_steps is the env's own episode limit, also when
    gymnasium.make or make_vec sets the spec (they would write the registered one, which has none)."""

    _batch: _Batch
    _spec = None

    @property
    def config(self) -> dict:
        """The env's full configuration (a copy): make(..., config=env.config) builds the same env."""
        c = self._batch.config
        return {**c, "reward_weights": dict(c["reward_weights"])}

    @property
    def spec(self):
        return self._spec

    @spec.setter
    def spec(self, value) -> None:
        limit = self._batch.config["max_episode_steps"]
        self._spec = None if value is None else dataclasses.replace(value, max_episode_steps=limit)


class HighwayEnv(_Configured, gymnasium.Env):
    """One episode at a time (num_envs = 1). For speed use HighwayVectorEnv or the raw World.

    traffic, adversarial, profile, adversary, max_episode_steps: config keys as keywords (None: from config,
    else the default); config: see highway_srl.env.config."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": RENDER_FPS}

    def __init__(self, scenario: str = "two-lane", traffic: str | None = None, adversarial: bool | None = None,
                 device: str = "cpu", render_mode: str | None = None, *, profile: str | None = None,
                 adversary: str | None = None, max_episode_steps: int | None = None, config: dict | None = None):
        _check_render_mode(render_mode)
        cfg = env_config(scenario, config, traffic=traffic, adversarial=adversarial, profile=profile,
                         adversary=adversary, max_episode_steps=max_episode_steps)
        self._batch = _Batch(scenario, cfg, 1, device)
        self.observation_space = _obs_space()
        self.action_space = spaces.Discrete(len(ACTIONS))
        self.render_mode = render_mode
        self.spec = env_spec(scenario, config=self.config, device=device)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """seed: episode 0 of that seed; None: the next episode (the first reset: a fresh random seed)."""
        _check_options(options)
        super().reset(seed=seed)
        if seed is not None or not self._batch.started:
            self._batch.reseed([int(self.np_random.integers(0, 2**31 - 1)) if seed is None else seed])
        else:
            self._batch.restart(torch.ones(1, dtype=torch.bool, device=self._batch.world.device))
        return host(self._batch.step_view.primary.obs[0]), {k: v[0] for k, v in self._batch.info().items()}

    def step(self, action):
        if not self._batch.started:
            raise ResetNeeded("call reset() before step()")
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
        return self._batch.frames()[0] if self.render_mode == "rgb_array" else None


def with_masks(info: dict[str, np.ndarray], present: np.ndarray) -> dict[str, np.ndarray]:
    """info with Gymnasium's "_key" mask beside each key: the envs whose info has that key (none of the keys
    if no env has them, as SyncVectorEnv leaves them out)."""
    if not present.any():
        return {}
    return {**info, **{f"_{k}": present for k in info}}


class HighwayVectorEnv(_Configured, VectorEnv):
    """B envs stepped as one batch on one device.

    autoreset_mode: Gymnasium's SAME_STEP (the default) or NEXT_STEP. Same-step: a finished env restarts
    inside step(), the returned observation and info start its new episode, and info["final_obs"] /
    info["final_info"] hold the finished episode's last observation and info. Next-step (what Gymnasium's
    vector observation wrappers need): step() returns the last observation of a finished env, and the next
    step() restarts it, ignoring its action, with reward 0 and neither terminated nor truncated.

    final_obs is a dense (B, 37) array (SyncVectorEnv's is an object array) so batched code can index it;
    its rows are valid where info["_final_obs"] is True. Every info key has Gymnasium's "_key" mask: the envs
    whose info holds it; final_info is a dict of (B, ...) arrays with its own masks, valid where
    info["_final_info"] is True. Since a collision ends the episode, count collisions (and the exit's
    terminal success) in final_info under same-step autoreset: the info of a restarted env describes its
    new episode, where no step has run yet (its "_collision" and "_success" masks are False).

    processes: World(processes=...), the simulator's step in that many worker processes (CPU; the rule
    layer stays in this one); close() ends them. The other arguments: as HighwayEnv's.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": ["rgb_array"], "render_fps": RENDER_FPS}

    def __init__(self, scenario: str = "two-lane", traffic: str | None = None, adversarial: bool | None = None,
                 num_envs: int = 2, device: str = "cpu", render_mode: str | None = None,
                 max_episode_steps: int | None = None, processes: int = 1, *, profile: str | None = None,
                 adversary: str | None = None, config: dict | None = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.SAME_STEP):
        _check_render_mode(render_mode)
        mode = _autoreset_mode(autoreset_mode)
        cfg = env_config(scenario, config, traffic=traffic, adversarial=adversarial, profile=profile,
                         adversary=adversary, max_episode_steps=max_episode_steps)
        self._batch = _Batch(scenario, cfg, num_envs, device, processes=processes)
        self.num_envs = num_envs
        self.autoreset_mode = mode
        self.metadata = {**type(self).metadata, "autoreset_mode": mode}
        self.single_observation_space = _obs_space()
        self.single_action_space = spaces.Discrete(len(ACTIONS))
        self.observation_space = _obs_space(num_envs)
        self.action_space = spaces.MultiDiscrete([len(ACTIONS)] * num_envs)
        self.render_mode = render_mode
        self._pending = np.zeros(num_envs, dtype=bool)  # next-step autoreset: envs that restart at the next step
        self._all = np.ones(num_envs, dtype=bool)
        self.spec = env_spec(scenario, config=self.config, device=device, num_envs=num_envs, processes=processes,
                             autoreset_mode=mode)

    def reset(self, *, seed: int | list[int] | None = None, options: dict | None = None):
        """seed: an int (env b gets seed + b) or B ints: episode 0 of each; None: the next episode of every
        env (the first reset: fresh random seeds)."""
        _check_options(options)
        if seed is None and self._batch.started:
            self._batch.restart(torch.ones(self.num_envs, dtype=torch.bool, device=self._batch.world.device))
        else:
            self._batch.reseed(self._seeds(seed))
        self._pending[:] = False
        return host(self._batch.step_view.primary.obs), with_masks(self._batch.info(), self._all)

    def _seeds(self, seed) -> list[int]:
        if seed is None:
            seed = int(np.random.SeedSequence().generate_state(1)[0] >> 1)
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            return [int(seed) + i for i in range(self.num_envs)]
        seeds = list(seed) if isinstance(seed, (list, tuple, np.ndarray)) else None
        if seeds is None or not all(isinstance(s, (int, np.integer)) and not isinstance(s, bool) for s in seeds):
            raise ValueError(f"seed must be None, an integer or {self.num_envs} integers, got {seed!r}")
        if len(seeds) != self.num_envs:
            raise ValueError(f"need {self.num_envs} seeds, got {len(seeds)}")
        return [int(s) for s in seeds]

    def check_actions(self, actions) -> torch.Tensor:
        """actions as a (B,) long tensor on the env's device, or one ValueError: B integers in 0..3 are
        needed (a float such as 0.9 or 2.5 is refused, not truncated)."""
        a = actions.detach().cpu().numpy() if isinstance(actions, torch.Tensor) else np.asarray(actions)
        last = len(ACTIONS) - 1
        if a.dtype.kind not in "iu":
            raise ValueError(f"actions must be integers in 0..{last} ({', '.join(ACTIONS)}), got dtype {a.dtype}")
        if a.shape != (self.num_envs,):
            raise ValueError(f"actions must have shape ({self.num_envs},), one per env, got {a.shape}")
        if a.size and (a.min() < 0 or a.max() > last):
            raise ValueError(f"actions must be in 0..{last} ({', '.join(ACTIONS)}), got {a.min()}..{a.max()}")
        return torch.as_tensor(a, device=self._batch.world.device).long()

    def step(self, actions):
        if not self._batch.started:
            raise ResetNeeded("call reset() before step()")
        reward, events, view = self._batch.act(self.check_actions(actions))
        terminated, truncated = host(events.terminated), host(events.truncated)
        if self.autoreset_mode == AutoresetMode.NEXT_STEP:
            obs, reward, info = self._restart_pending(host(reward), terminated, truncated, events)
            self._pending = terminated | truncated
            return obs, reward, terminated, truncated, info
        obs, info = self._restart_finished(host(view.primary.obs), self._batch.info(events), terminated | truncated)
        return obs, host(reward), terminated, truncated, info

    def _restart_finished(self, obs: np.ndarray, info: dict, finished: np.ndarray):
        """Same-step autoreset: the finished envs start their next episode now."""
        if not finished.any():
            return obs, with_masks(info, self._all)
        final = {"final_obs": obs, "final_info": with_masks(info, finished)}
        self._batch.restart(torch.as_tensor(finished, device=self._batch.world.device))
        info = {**with_masks(self._batch.info(), self._all),
                **with_masks({"collision": info["collision"] & ~finished, "success": info["success"] & ~finished},
                             ~finished)}
        return host(self._batch.step_view.primary.obs), {**info, **with_masks(final, finished)}

    def _restart_pending(self, reward: np.ndarray, terminated: np.ndarray, truncated: np.ndarray, events):
        """Next-step autoreset: the envs that finished at the last step start their next episode now, with
        the reset's observation and info, reward 0, neither terminated nor truncated (terminated and
        truncated are changed in place)."""
        pending = self._pending
        if pending.any():
            self._batch.restart(torch.as_tensor(pending, device=self._batch.world.device))
        info = self._batch.info(events)
        events_info = {k: info.pop(k) & ~pending for k in ("collision", "success")}
        reward[pending] = 0.0
        terminated[pending] = False
        truncated[pending] = False
        info = {**with_masks(info, self._all), **with_masks(events_info, ~pending)}
        return host(self._batch.step_view.primary.obs), reward, info

    def action_masks(self) -> np.ndarray:
        """(B, 4) bool, Table 1's safe set of each env's current state (= info["action_mask"])."""
        return host(self._batch.step_view.primary.mask)

    def close_extras(self, **kwargs) -> None:
        self._batch.world.close()

    def render(self) -> Frames | None:
        """Every env's frame (Frames: drawn when read) if render_mode is "rgb_array", else None."""
        return self._batch.frames() if self.render_mode == "rgb_array" else None


def _autoreset_mode(mode) -> AutoresetMode:
    try:
        mode = AutoresetMode(mode)
    except (ValueError, TypeError):
        mode = None
    if mode not in AUTORESET_MODES:
        raise ValueError(f"autoreset_mode must be one of {', '.join(m.name for m in AUTORESET_MODES)}")
    return mode


def make(scenario: str = "two-lane", traffic: str | None = None, adversarial: bool | None = None, num_envs: int = 1,
         device: str = "cpu", seed: int | None = None, vector: bool | None = None, render_mode: str | None = None,
         **options):
    """A Gymnasium Env (num_envs = 1) or VectorEnv (num_envs > 1, or vector=True at any N) of one scenario;
    reset with `seed` if given. options: profile=, adversary=, max_episode_steps=, config= (both envs);
    autoreset_mode=, processes= (the VectorEnv)."""
    if vector is None:
        vector = num_envs != 1
    if not vector and num_envs != 1:
        raise ValueError(f"a single Env has num_envs = 1, got {num_envs!r}; use vector=True for a VectorEnv")
    if vector:
        env = HighwayVectorEnv(scenario, traffic, adversarial, num_envs, device, render_mode, **options)
    else:
        env = HighwayEnv(scenario, traffic, adversarial, device, render_mode, **options)
    if seed is not None:
        env.reset(seed=seed)
    return env
