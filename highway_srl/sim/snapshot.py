"""The ground-truth world snapshot the rules read.

Every backend (our simulator, SUMO, highway-env) produces this, so every agent runs on every backend.
Shapes: B environments; the four neighbour slots are ordered SV1 (front, current lane), SV2 (front,
adjacent lane), SV3 (rear, current lane), SV4 (rear, adjacent lane), as in §3.1 of the paper.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

NO_VEHICLE = -1  # neighbour slot is empty (nothing within d_max, or the lane does not exist)
LANE_END = -2  # neighbour slot holds the end of a dropped lane, seen as a standing obstacle


@dataclass
class Snapshot:
    """Ego and its four neighbours in the Frenet frame of sim/road.py (x, y in m; v in m/s; heading in rad).

    ego_*: (B,); sv_*: (B, 4); sv_valid: (B, 4) bool; sv_index: (B, 4) long vehicle index in the world,
    NO_VEHICLE or LANE_END. current_lane / adjacent_lane: (B,) long global lane indices the query used
    (adjacent_lane = -1 when there is none). Invalid slots hold zeros; the rules fill in the paper's
    default virtual vehicles SV_i,Def.
    """

    ego_x: torch.Tensor
    ego_y: torch.Tensor
    ego_vx: torch.Tensor
    ego_vy: torch.Tensor
    ego_heading: torch.Tensor
    ego_lane: torch.Tensor
    sv_x: torch.Tensor
    sv_y: torch.Tensor
    sv_vx: torch.Tensor
    sv_vy: torch.Tensor
    sv_heading: torch.Tensor
    sv_valid: torch.Tensor
    sv_index: torch.Tensor
    current_lane: torch.Tensor
    adjacent_lane: torch.Tensor

    @property
    def batch_size(self) -> int:
        return self.ego_x.shape[0]
