"""The 37 network inputs (§3.1, §3.3, Algorithm 1, §4.1): E_A = ⟨S*, R*_SV, u*⟩.

S* (29) = s_vehicle (ego + SV1..SV4, each x, y, v_x, v_y, φ: 25) + C_ID, m*_L, T*_ID, v*; then R*_SV1..4 (4)
and the RM state u* one-hot over u1..u4 (4). Normalisation (docs/paper-notes.md, "Relative positions"):
  ego x      signed distance to the scenario's next key boundary, (x_key - x_EV) / 100 m, clipped to
             [-3, 3] (merge: x2, the start of the stability zone; exit: x2, the end of the diverging zone;
             two-lane and multi-lane: 0, the road looks the same everywhere)
  SV x       (x_SV - x_EV) / d_max, clipped to [-1, 1] (defaults sit at exactly ±1)
  y          y_local / w_L, clipped to [-2, 3] (local lanes at 0 and 1)
  v_x, v_y   / v_max, clipped to [0, 2] and [-1, 1]
  φ          rad, wrapped to [-π, π]
  v*         / v_max, clipped to [0, 2]; flags and one-hots are 0/1.
"""

from __future__ import annotations

import math

import torch

from highway_srl.constants import D_MAX_M, LANE_WIDTH_M, OBS_DIM, V_MAX_MPS
from highway_srl.rules.reward_machine import NUM_RM_STATES
from highway_srl.sim.road import Road

PROGRESS_SCALE_M = 100.0
PROGRESS_CLIP = 3.0
_VEHICLE_FIELDS = ("x", "y", "vx", "vy", "heading")
OBS_NAMES: tuple[str, ...] = (
    tuple(f"{v}_{f}" for v in ("ego", "sv1", "sv2", "sv3", "sv4") for f in _VEHICLE_FIELDS)
    + ("c_id", "m_l", "t_id", "v_star", "r_sv1", "r_sv2", "r_sv3", "r_sv4", "u1", "u2", "u3", "u4")
)
assert len(OBS_NAMES) == OBS_DIM


def observation_ranges() -> torch.Tensor:
    """(37, 2) [low, high] bounds every observation feature lies in, in OBS_NAMES order."""
    veh_ego = [(-PROGRESS_CLIP, PROGRESS_CLIP), (-2.0, 3.0), (0.0, 2.0), (-1.0, 1.0), (-math.pi, math.pi)]
    veh_sv = [(-1.0, 1.0), (-2.0, 3.0), (0.0, 2.0), (-1.0, 1.0), (-math.pi, math.pi)]
    rows = veh_ego + veh_sv * 4 + [(0.0, 1.0)] * 3 + [(0.0, 2.0)] + [(0.0, 1.0)] * 8
    return torch.tensor(rows, dtype=torch.float32)


def ego_progress_feature(road: Road, ego_x: torch.Tensor) -> torch.Tensor:
    """(x_key - x_EV) / 100 m clipped to [-3, 3]: merge x_key = x2 (stability zone), exit x_key = x2 (end of
    the diverging zone, where the off-ramp leaves); 0 on two-lane and multi-lane. (B,)."""
    zone = road.spec.progress_zone
    if zone is None:
        return torch.zeros_like(ego_x)
    key = road.zones[zone][1]
    return ((key - ego_x) / PROGRESS_SCALE_M).clamp(-PROGRESS_CLIP, PROGRESS_CLIP)


def _wrap(angle: torch.Tensor) -> torch.Tensor:
    return torch.atan2(torch.sin(angle), torch.cos(angle))


def build_observation(
    *,
    ego_progress: torch.Tensor,
    ego_y_local_m: torch.Tensor,
    ego_vx_mps: torch.Tensor,
    ego_vy_mps: torch.Tensor,
    ego_heading: torch.Tensor,
    sv_dx_m: torch.Tensor,
    sv_y_local_m: torch.Tensor,
    sv_vx_mps: torch.Tensor,
    sv_vy_mps: torch.Tensor,
    sv_heading: torch.Tensor,
    c_id: torch.Tensor,
    m_l: torch.Tensor,
    t_id: torch.Tensor,
    v_star_mps: torch.Tensor,
    r_star: torch.Tensor,
    rm_state: torch.Tensor,
    d_max_m: float = D_MAX_M,
    v_max_mps: float = V_MAX_MPS,
    lane_width_m: float = LANE_WIDTH_M,
) -> torch.Tensor:
    """(B, 37) float32 observation; ego_* (B,), sv_* (B, 4) (SV1..SV4), sv_dx_m = x_SV - x_EV,
    y in the model's local frame, c_id / t_id (B,) long local, m_l (B,) bool, r_star (B, 4) bool,
    rm_state (B,) long in 0..3. Every entry is finite and inside observation_ranges()."""
    f32 = lambda t: t.to(torch.float32)  # noqa: E731
    y = lambda t: (f32(t) / lane_width_m).clamp(-2.0, 3.0)  # noqa: E731
    vx = lambda t: (f32(t) / v_max_mps).clamp(0.0, 2.0)  # noqa: E731
    vy = lambda t: (f32(t) / v_max_mps).clamp(-1.0, 1.0)  # noqa: E731
    ego = torch.stack(
        [f32(ego_progress).clamp(-PROGRESS_CLIP, PROGRESS_CLIP), y(ego_y_local_m), vx(ego_vx_mps), vy(ego_vy_mps),
         _wrap(f32(ego_heading))], dim=1)
    sv = torch.stack(
        [(f32(sv_dx_m) / d_max_m).clamp(-1.0, 1.0), y(sv_y_local_m), vx(sv_vx_mps), vy(sv_vy_mps),
         _wrap(f32(sv_heading))], dim=2).reshape(-1, 20)
    extra = torch.stack([f32(c_id), f32(m_l), f32(t_id).clamp(0.0, 1.0), (f32(v_star_mps) / v_max_mps).clamp(0.0, 2.0)],
                        dim=1)
    onehot = torch.nn.functional.one_hot(rm_state.long().clamp(0, NUM_RM_STATES - 1), NUM_RM_STATES).to(torch.float32)
    obs = torch.cat([ego, sv, extra, f32(r_star), onehot], dim=1)
    return torch.nan_to_num(obs, nan=0.0, posinf=0.0, neginf=0.0)
