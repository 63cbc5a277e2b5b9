"""One step of a method driving B envs: act -> world step -> observe -> reward -> account.

The trainer (with exploration and the training reward) and `evaluate` (greedy, no reward) both step
through `policy_step`; episode scoring is rules.episode.EpisodeStats.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from highway_srl.agents.methods import Decision
from highway_srl.rules.episode import EpisodeStats, advance
from highway_srl.sim import StageFlags


@dataclass
class Transition:
    decision: Decision
    events: object  # StepEvents of the world step
    view: object  # the rule layer's SafetyStep after the step (before any reset)
    flags: StageFlags  # the world's latched stage flags after the step
    reward: torch.Tensor | None  # (B,) the method's training reward (train=True)
    cost: torch.Tensor | None  # (B,) its cost signal, for methods that use one


def policy_step(method, learner, world, layer, view, explore: torch.Tensor, u: torch.Tensor | None,
                stats: EpisodeStats, alive: torch.Tensor | None = None, train: bool = False) -> Transition:
    """Decide from `view` (the layer's SafetyStep of the current state), step the world through the layer,
    compute the training reward if `train`, and account the step in `stats` (only the `alive` envs, if given).
    explore: (B,) bool, the ε-greedy draw the method reads; u: its uniforms (B, method.draw_width), None
    where explore is all False (Method.decide)."""
    decision = method.decide(learner, view, explore, u)
    events, nxt, flags = advance(world, layer, decision.action, decision.use_second)
    reward = cost = None
    if train:
        reward, cost = method.reward(world.scenario, nxt.primary, events, flags)
    stats.add(events, flags, nxt.primary, world.ego_speed, reward, alive)
    return Transition(decision, events, nxt, flags, reward, cost)
