"""The world's state: a few tensors shaped (B envs, N vehicles), vehicle 0 being the ego."""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import torch

NO_INTENT, MERGE_INTENT, EXIT_INTENT = 0, 1, 2


@dataclass
class WorldState:
    # kinematics (B, N); v is the speed along the heading, so v_x = v cos(heading), v_y = v sin(heading)
    x: torch.Tensor
    y: torch.Tensor
    v: torch.Tensor
    heading: torch.Tensor
    lane: torch.Tensor  # long, lane whose centre is nearest
    target_lane: torch.Tensor  # long
    # surrounding-vehicle attributes (B, N); the ego's row is unused
    style: torch.Tensor  # long index into constants.STYLES
    v0: torch.Tensor  # desired speed (1 + SVR) v_max
    s0: torch.Tensor  # jam distance = desired headway DH
    lane_change: torch.Tensor  # bool, ALC
    adversarial_prob: torch.Tensor  # ABP
    intent: torch.Tensor  # long: NO_INTENT, MERGE_INTENT, EXIT_INTENT
    trigger_offset: torch.Tensor  # adversarial |d_trig - d_SV| (m)
    trigger_used: torch.Tensor  # bool, the cut-in trigger was evaluated this episode
    forced: torch.Tensor  # bool, a forced (adversarial) lane change is under way
    phase: torch.Tensor  # long, step offset of the vehicle's 1 Hz lane-change decisions
    order: torch.Tensor  # long, the vehicles sorted by x (a cache the neighbour search keeps up to date)
    # per env (B,)
    seed: torch.Tensor  # long
    episode: torch.Tensor  # long, episodes started with this seed
    t: torch.Tensor  # long, steps taken in this episode
    merged: torch.Tensor  # bool, latched stage flags
    exit1: torch.Tensor
    exit2: torch.Tensor
    # adversary counters of this episode (B,) long: triggers evaluated, forced cut-ins started; zero at
    # spawn (filled in by __post_init__, so states saved before they existed still load)
    adv_triggers: torch.Tensor | None = field(default=None)
    adv_cut_ins: torch.Tensor | None = field(default=None)

    def __post_init__(self) -> None:
        if self.adv_triggers is None:
            self.adv_triggers = torch.zeros_like(self.t)
        if self.adv_cut_ins is None:
            self.adv_cut_ins = torch.zeros_like(self.t)

    def index_put(self, idx: torch.Tensor, other: "WorldState") -> None:
        """Overwrite envs idx (K,) with the K envs of other, in place."""
        for f in fields(self):
            getattr(self, f.name).index_copy_(0, idx, getattr(other, f.name))  # index_put_'s general path costs more

    def clone(self) -> "WorldState":
        return WorldState(**{f.name: getattr(self, f.name).clone() for f in fields(self)})

    def to(self, device) -> "WorldState":
        return WorldState(**{f.name: getattr(self, f.name).to(device) for f in fields(self)})


def astuple_shallow(obj) -> tuple:
    """A dataclass's fields as a tuple of the same objects (dataclasses.astuple would deep-copy tensors)."""
    return tuple(getattr(obj, f.name) for f in fields(obj))
