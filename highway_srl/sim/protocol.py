"""The interface every simulator backend offers; the rules, agents and experiments use nothing else.

Our World (sim/world.py) implements it batched; the SUMO and highway-env adapters (backends/) implement it
with num_envs = 1 per process.
"""

from __future__ import annotations

from typing import Protocol

import torch

from highway_srl.sim.road import Road
from highway_srl.sim.snapshot import Snapshot
from highway_srl.sim.events import StageFlags, StepEvents


class Backend(Protocol):
    road: Road
    num_envs: int
    device: torch.device
    scenario: str
    traffic: str
    adversarial: bool
    max_steps: int

    def reset(self, mask: torch.Tensor | None = None) -> None: ...

    def step(self, target_lane: torch.Tensor, target_speed: torch.Tensor) -> StepEvents: ...

    def neighbours(self, current_lane: torch.Tensor, adjacent_lane: torch.Tensor, d_max: float = ...,
                   by_body: bool = ...) -> Snapshot: ...

    @property
    def ego_lane(self) -> torch.Tensor: ...

    @property
    def ego_speed(self) -> torch.Tensor: ...

    def stage_flags(self) -> StageFlags: ...
