"""A simple built-in ego driver for demos and renderings: IDM in its lane, and on ramps it merges or exits
when the target lane has room (a MOBIL-style safety check). The full rule-based driver with the paper's
safety check lives with the baselines."""

from __future__ import annotations

import torch

from highway_srl.constants import DT_S, V_MAX_MPS, VEHICLE_LENGTH_M
from highway_srl.sim.traffic import idm_accel
from highway_srl.sim.world import World

EGO_JAM_M = 2 * VEHICLE_LENGTH_M
MIN_GAP_M = 6.0


def idm_ego(world: World) -> tuple[torch.Tensor, torch.Tensor]:
    """(target_lane (B,), target_speed (B,)) for the ego of every env."""
    s, road = world.state, world.road
    lane = world.ego_lane
    v = s.v[:, 0]
    want = lane.clone()
    if road.scenario == "merge":
        want = torch.where(lane == 2, torch.ones_like(lane), lane)
    elif road.scenario == "exit":
        want = (lane + 1).clamp(max=2)
    snap = world.neighbours(lane, torch.where(want != lane, want, -torch.ones_like(lane)))
    gap = lambda k: snap.sv_x[:, k] - snap.ego_x - VEHICLE_LENGTH_M  # noqa: E731
    ahead = idm_accel(v, torch.full_like(v, V_MAX_MPS), torch.full_like(v, EGO_JAM_M), gap(0).where(snap.sv_valid[:, 0], torch.full_like(v, 1e3)),
                      snap.sv_vx[:, 0], snap.sv_valid[:, 0])
    rear_gap = snap.ego_x - snap.sv_x[:, 3] - VEHICLE_LENGTH_M
    room_front = ~snap.sv_valid[:, 1] | (snap.sv_x[:, 1] - snap.ego_x - VEHICLE_LENGTH_M > MIN_GAP_M + v)
    room_rear = ~snap.sv_valid[:, 3] | (rear_gap > MIN_GAP_M + (snap.sv_vx[:, 3] - v).clamp(min=0) * 2.0)
    change = (want != lane) & room_front & room_rear
    changing = s.target_lane[:, 0] != lane  # finish a lane change once begun
    target_lane = torch.where(changing, s.target_lane[:, 0], torch.where(change, want, lane))
    target_speed = (v + ahead * DT_S).clamp(0.0, V_MAX_MPS)
    return target_lane, target_speed
