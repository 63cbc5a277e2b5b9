"""A simple ego driver that uses only the Backend protocol, so it runs on every backend.

sim/policies.idm_ego reads World.state (the ego's speed and its commanded target lane), which the other
backends do not have. This variant keeps the same decisions (IDM in the lane; on ramps merge or exit when
the target lane has room) and reads only ego_speed, ego_lane, road and neighbours(). Instead of the
remembered target lane it infers a lane change under way from the snapshot: off the lane centre and
moving sideways, the ego keeps heading for the lane it is moving towards.
"""

from __future__ import annotations

import torch

from highway_srl.constants import DT_S, V_MAX_MPS, VEHICLE_LENGTH_M
from highway_srl.sim.policies import task_lane
from highway_srl.sim.protocol import Backend
from highway_srl.sim.traffic import idm_accel

EGO_JAM_M = 2 * VEHICLE_LENGTH_M
MIN_GAP_M = 6.0
CENTRED_M = 0.3  # closer than this to a lane centre counts as in the lane
MOVING_SIDEWAYS_MPS = 0.1


def idm_ego_backend(backend: Backend) -> tuple[torch.Tensor, torch.Tensor]:
    """(target_lane (B,), target_speed (B,)) for the ego of every env of any backend."""
    road = backend.road
    lane = backend.ego_lane
    v = backend.ego_speed.float()
    want = task_lane(road, lane)
    snap = backend.neighbours(lane, torch.where(want != lane, want, -torch.ones_like(lane)))
    w = road.lane_width_m
    gap_front = torch.where(snap.sv_valid[:, 0], snap.sv_x[:, 0] - snap.ego_x - VEHICLE_LENGTH_M, torch.full_like(v, 1e3))
    ahead = idm_accel(v, torch.full_like(v, V_MAX_MPS), torch.full_like(v, EGO_JAM_M), gap_front,
                      snap.sv_vx[:, 0], snap.sv_valid[:, 0])
    rear_gap = snap.ego_x - snap.sv_x[:, 3] - VEHICLE_LENGTH_M
    room_front = ~snap.sv_valid[:, 1] | (snap.sv_x[:, 1] - snap.ego_x - VEHICLE_LENGTH_M > MIN_GAP_M + v)
    room_rear = ~snap.sv_valid[:, 3] | (rear_gap > MIN_GAP_M + (snap.sv_vx[:, 3] - v).clamp(min=0) * 2.0)
    change = (want != lane) & room_front & room_rear
    # a lane change under way: off-centre and moving sideways -> keep going to the lane it moves towards
    offset = snap.ego_y - lane.float() * w
    toward = torch.where(snap.ego_vy > 0, torch.ceil(snap.ego_y / w), torch.floor(snap.ego_y / w)).long()
    changing = (offset.abs() > CENTRED_M) & (snap.ego_vy.abs() > MOVING_SIDEWAYS_MPS)
    target_lane = torch.where(changing, toward.clamp(0, road.num_lanes - 1), torch.where(change, want, lane))
    target_speed = (v + ahead * DT_S).clamp(0.0, V_MAX_MPS)
    return target_lane, target_speed
