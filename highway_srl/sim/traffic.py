"""Surrounding traffic: leaders and followers per lane, IDM car following, MOBIL lane changes.

Neighbour search sorts vehicles by x once per step and, per lane, finds the next occupant ahead and
behind in sorted order with cumulative min/max scans: O(N log N) per env and no (B, N, N) tensors,
which is what makes dense levels (N = 45) cheap.
"""

from __future__ import annotations

import torch

from highway_srl.constants import VEHICLE_LENGTH_M

# IDM parameters shared by every style (the style sets the jam distance s0 = DH and the desired speed).
IDM_ACCEL_MPS2 = 1.5  # a: maximum acceleration
IDM_COMFORT_BRAKE_MPS2 = 2.0  # b: comfortable deceleration
IDM_TIME_HEADWAY_S = 1.0  # T
IDM_DELTA = 4.0
SV_BRAKE_LIMIT_MPS2 = 6.0  # physical limit IDM's output is clamped to
# MOBIL parameters
MOBIL_POLITENESS = 0.3
MOBIL_THRESHOLD_MPS2 = 0.2
MOBIL_SAFE_BRAKE_MPS2 = 3.0  # the new follower must not have to brake harder than this
MANDATORY_BONUS_MPS2 = 10.0  # merging / exiting vehicles change whenever it is safe


def lane_neighbours(
    x: torch.Tensor, occupancy: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Nearest vehicle ahead and behind in each lane, for every vehicle.

    x: (B, N) positions; occupancy: (K, B, N) bool, vehicle n occupies lane k.
    Returns leader, follower: (K, B, N) long vehicle indices, -1 where there is none. A vehicle is never
    its own neighbour. Ties in x are broken by index through the stable sort.
    """
    K, B, N = occupancy.shape
    order = torch.sort(x, dim=1, stable=True).indices  # (B, N)
    occ = torch.gather(occupancy, 2, order.expand(K, B, N))  # in sorted order
    pos = torch.arange(N, device=x.device).expand(K, B, N)
    ahead = torch.where(occ, pos, N)
    # min over q > p: reverse cumulative min, shifted by one
    ahead = torch.flip(torch.cummin(torch.flip(ahead, [2]), 2).values, [2])
    ahead = torch.cat([ahead[..., 1:], torch.full_like(ahead[..., :1], N)], 2)
    behind = torch.where(occ, pos, -1)
    behind = torch.cummax(behind, 2).values
    behind = torch.cat([torch.full_like(behind[..., :1], -1), behind[..., :-1]], 2)
    order_k = order.expand(K, B, N)
    lead_sorted = torch.where(ahead < N, torch.gather(order_k, 2, ahead.clamp(max=N - 1)), -1)
    foll_sorted = torch.where(behind >= 0, torch.gather(order_k, 2, behind.clamp(min=0)), -1)
    leader = torch.empty_like(lead_sorted).scatter_(2, order_k, lead_sorted)
    follower = torch.empty_like(foll_sorted).scatter_(2, order_k, foll_sorted)
    return leader, follower


def idm_accel(v, v0, s0, gap, v_lead, has_lead):
    """Intelligent Driver Model acceleration (m/s^2), clamped to the physical braking limit.

    v, v0, s0: follower speed, desired speed, jam distance; gap: bumper-to-bumper distance to the leader;
    v_lead: leader speed; has_lead: False means free road.
    """
    free = 1.0 - (v / v0.clamp(min=0.1)) ** IDM_DELTA
    s_star = s0 + (v * IDM_TIME_HEADWAY_S + v * (v - v_lead) / (2.0 * (IDM_ACCEL_MPS2 * IDM_COMFORT_BRAKE_MPS2) ** 0.5)).clamp(min=0.0)
    inter = torch.where(has_lead, (s_star / gap.clamp(min=0.05)) ** 2, torch.zeros_like(v))
    return (IDM_ACCEL_MPS2 * (free - inter)).clamp(min=-SV_BRAKE_LIMIT_MPS2)


def gather_lead(values: torch.Tensor, idx: torch.Tensor, fill: float) -> torch.Tensor:
    """values (B, N) read at vehicle indices idx (B, M) with -1 -> fill."""
    out = torch.gather(values, 1, idx.clamp(min=0))
    return torch.where(idx >= 0, out, torch.full_like(out, fill))


def accel_behind(x, v, v0, s0, follower_idx, lead_x, lead_v, has_lead, wall_gap=None):
    """IDM acceleration of vehicles (B, M) given leader positions/speeds (B, M); optional lane-end wall."""
    gap = lead_x - x - VEHICLE_LENGTH_M
    v_lead = lead_v
    if wall_gap is not None:
        use_wall = wall_gap < torch.where(has_lead, gap, torch.full_like(gap, float("inf")))
        gap = torch.where(use_wall, wall_gap, gap)
        v_lead = torch.where(use_wall, torch.zeros_like(v_lead), v_lead)
        has_lead = has_lead | use_wall
    return idm_accel(v, v0, s0, gap, v_lead, has_lead)
