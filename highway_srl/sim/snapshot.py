"""The ground-truth world snapshot the rules read, and ego_neighbours, which takes it from a world state.

Every backend (our simulator, SUMO, highway-env) produces this, so every agent runs on every backend.
Shapes: B environments; the four neighbour slots are ordered SV1 (front, current lane), SV2 (front,
adjacent lane), SV3 (rear, current lane), SV4 (rear, adjacent lane), as in §3.1 of the paper.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from highway_srl.constants import D_MAX_M, VEHICLE_LENGTH_M
from highway_srl.sim.box_geometry import lateral_half_extent
from highway_srl.sim.lane_tables import LaneTables
from highway_srl.sim.road import Road
from highway_srl.sim.state import WorldState

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


def ego_neighbours(s: WorldState, road: Road, tables: LaneTables, current_lane: torch.Tensor,
                   adjacent_lane: torch.Tensor, d_max: float = D_MAX_M, by_body: bool = False) -> Snapshot:
    """SV1..SV4 of the ego: nearest front/rear vehicle in current_lane and adjacent_lane (B,) within d_max.

    Reads s.x, s.y, s.v, s.heading, s.lane (B, N). Lane membership is by the nearest lane centre (the
    paper's SV_i), or with by_body by the body: a vehicle is in every lane its rotated box reaches into, so
    a car standing across a lane line is in both lanes. 'front' means the SV's centre is ahead of the ego's.
    The end of a dropped lane ahead appears as a standing vehicle whose rear bumper is at the lane end.
    """
    x, lane = s.x[:, 1:], s.lane[:, 1:]
    ego_x = s.x[:, 0]
    dx = x - ego_x[:, None]
    near = dx.abs() <= d_max
    inf = torch.full_like(dx, float("inf"))
    half = lateral_half_extent(s.heading[:, 1:]) if by_body else None  # once for both lanes
    slots = []
    for lane_q in (current_lane, adjacent_lane):
        in_lane = (_bodies_in(s.y[:, 1:], half, road, lane_q) if by_body else lane == lane_q[:, None]) & near
        front_d, front_i = torch.where(in_lane & (dx > 0), dx, inf).min(1)
        rear_d, rear_i = torch.where(in_lane & (dx <= 0), -dx, inf).min(1)
        slots.append((front_d, front_i, lane_q))
        slots.append((rear_d, rear_i, lane_q))
    order = (0, 2, 1, 3)  # SV1 front-current, SV2 front-adjacent, SV3 rear-current, SV4 rear-adjacent
    dist = torch.stack([slots[k][0] for k in order], 1)
    idx = torch.stack([slots[k][1] for k in order], 1) + 1
    valid = torch.isfinite(dist)
    gx = lambda t: torch.gather(t, 1, idx)  # noqa: E731
    sv_x, sv_y, sv_v, sv_h = gx(s.x), gx(s.y), gx(s.v), gx(s.heading)
    sv_index = torch.where(valid, idx, NO_VEHICLE)
    # lane ends ahead (merge on-ramp): a standing obstacle if nearer than the front vehicle
    end = tables.drop_end_m
    for k, lane_q in ((0, current_lane), (1, adjacent_lane)):
        lane_end = end[lane_q.clamp(min=0)]
        wall_x = lane_end + 0.5 * VEHICLE_LENGTH_M
        use = (lane_q >= 0) & (wall_x - ego_x <= d_max) & (~valid[:, k] | (wall_x < sv_x[:, k]))
        use &= torch.isfinite(lane_end) & (wall_x > ego_x)
        sv_x[:, k] = torch.where(use, wall_x, sv_x[:, k])
        sv_y[:, k] = torch.where(use, lane_q.float() * road.lane_width_m, sv_y[:, k])
        sv_v[:, k] = torch.where(use, 0.0, sv_v[:, k])
        sv_h[:, k] = torch.where(use, 0.0, sv_h[:, k])
        sv_index[:, k] = torch.where(use, LANE_END, sv_index[:, k])
        valid[:, k] |= use
    zero = torch.zeros_like(sv_x)
    return Snapshot(
        ego_x=ego_x,
        ego_y=s.y[:, 0],
        ego_vx=s.v[:, 0] * torch.cos(s.heading[:, 0]),
        ego_vy=s.v[:, 0] * torch.sin(s.heading[:, 0]),
        ego_heading=s.heading[:, 0],
        ego_lane=s.lane[:, 0],
        sv_x=torch.where(valid, sv_x, zero),
        sv_y=torch.where(valid, sv_y, zero),
        sv_vx=torch.where(valid, sv_v * torch.cos(sv_h), zero),
        sv_vy=torch.where(valid, sv_v * torch.sin(sv_h), zero),
        sv_heading=torch.where(valid, sv_h, zero),
        sv_valid=valid,
        sv_index=sv_index,
        current_lane=current_lane,
        adjacent_lane=adjacent_lane,
    )


def _bodies_in(y: torch.Tensor, half: torch.Tensor, road: Road, lane_q: torch.Tensor) -> torch.Tensor:
    """(B, N - 1) bool: the SVs (centres y, lateral half extents half) whose rotated box reaches into lane_q's
    strip (B,) (none where lane_q < 0)."""
    low = (lane_q.to(y.dtype) - 0.5)[:, None] * road.lane_width_m  # the lane's strip is [low, low + w]
    return (y > low - half) & (y < low + road.lane_width_m + half) & (lane_q >= 0)[:, None]
