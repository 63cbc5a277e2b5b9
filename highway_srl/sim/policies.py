"""A simple built-in ego driver for demos and renderings: IDM in its lane, and on ramps it merges or exits
when the target lane has room (a gap check). The full rule-based driver with the paper's safety check
lives with the baselines.

It reads the world's ground truth directly: an SV counts as being in a lane when its footprint reaches
into that lane or it is changing into it (not only when its centre is there, as in World.neighbours), so a
car nosing in from the ramp is seen before it crosses the boundary.
"""

from __future__ import annotations

import torch

from highway_srl.constants import DT_S, V_MAX_MPS, VEHICLE_LENGTH_M
from highway_srl.scenarios import EXIT, MERGE
from highway_srl.sim.collision import front_x_in_band, lateral_half_extent
from highway_srl.sim.traffic_model import CENTRED_M, COMMITTED_M, WALL_JAM_CHANGING_M
from highway_srl.sim.traffic import LANE_CHANGE_TIME_S, OCCUPANCY_MARGIN_M, idm_accel
from highway_srl.sim.road import Road
from highway_srl.sim.world import World

EGO_JAM_M = 2 * VEHICLE_LENGTH_M
MIN_GAP_M = 2.0  # bumper-to-bumper room a lane change needs ahead and behind, plus:
HEADWAY_S = 0.5  # half a second at the speed of the car behind the gap (the ego ahead, the SV behind)
CLOSING_TIME_S = 2.5  # and this many seconds of closing speed


def _sv_in_lane(world: World, lane: torch.Tensor) -> torch.Tensor:
    """(B, N-1) bool: SV n reaches into lane `lane` (B,) or is changing into it."""
    s, w = world.state, world.road.lane_width_m
    half = lateral_half_extent(s.heading[:, 1:]) + OCCUPANCY_MARGIN_M
    lo = (lane.float() - 0.5)[:, None] * w
    y = s.y[:, 1:]
    return ((y + half > lo) & (y - half < lo + w)) | (s.target_lane[:, 1:] == lane[:, None])


def _nearest(world: World, lane: torch.Tensor, ahead: bool):
    """Bumper-to-bumper gap (B,) (inf if none) and speed (B,) of the nearest SV ahead of / behind the ego
    (by centre x) among those in `lane`; lanes outside the road give none."""
    s = world.state
    x = s.x[:, :1]
    side = s.x[:, 1:] > x if ahead else s.x[:, 1:] <= x
    mask = _sv_in_lane(world, lane) & side & (lane >= 0)[:, None] & (lane < world.road.num_lanes)[:, None]
    d = (s.x[:, 1:] - x) if ahead else (x - s.x[:, 1:])
    gap, i = torch.where(mask, d - VEHICLE_LENGTH_M, float("inf")).min(1)
    return gap, s.v[:, 1:].gather(1, i[:, None])[:, 0]


def task_lane(road: Road, lane: torch.Tensor) -> torch.Tensor:
    """(B,) long: the lane the ego's task sends it to from `lane` (B,) long: merge: off the on-ramp into the
    mainline's right lane; exit: one lane to the right until it is on the off-ramp; cruise: its own lane."""
    task, ramp = road.spec.task, road.mainline_lanes
    if task == MERGE:
        return torch.where(lane == ramp, torch.full_like(lane, ramp - 1), lane)
    if task == EXIT:
        return (lane + 1).clamp(max=ramp)
    return lane.clone()


def idm_ego(world: World) -> tuple[torch.Tensor, torch.Tensor]:
    """(target_lane (B,), target_speed (B,)) for the ego of every env."""
    s, road = world.state, world.road
    tables = world._lane_tables
    w = road.lane_width_m
    x, y, v = s.x[:, 0], s.y[:, 0], s.v[:, 0]
    lane, tgt = s.lane[:, 0], s.target_lane[:, 0]
    want = task_lane(road, lane)
    changing = tgt != lane
    offset = (y - lane.float() * w).abs()

    # lane change: start when centred, when the change fits in the window, and the target lane has room
    gap_f, v_f = _nearest(world, want, ahead=True)
    gap_r, v_r = _nearest(world, want, ahead=False)
    room = (gap_f > MIN_GAP_M + HEADWAY_S * v + (v - v_f).clamp(min=0) * CLOSING_TIME_S) & (
        gap_r > MIN_GAP_M + HEADWAY_S * v_r + (v_r - v).clamp(min=0) * CLOSING_TIME_S
    )
    # (at the speed limit: the ego may speed up while it changes). Leaving a dropped lane is the exception:
    # the lane's end stops the ego, so it may start a change up to the end.
    dropped = torch.tensor(road.lane_drop, device=lane.device)[lane]
    ahead = torch.where(dropped, 0.0, V_MAX_MPS * LANE_CHANGE_TIME_S)
    fits = tables.can_change(x, lane, want, ahead)
    start = (want != lane) & ~changing & (offset < CENTRED_M) & fits & room
    target_lane = torch.where(start, want, tgt)
    # give up a change that is not yet committed if the target lane closes
    gap_tf, _ = _nearest(world, tgt, ahead=True)
    gap_tr, _ = _nearest(world, tgt, ahead=False)
    abort = changing & (offset < COMMITTED_M) & ((gap_tf < 1.0) | (gap_tr < 1.0))
    target_lane = torch.where(abort, lane, target_lane)
    changing = target_lane != lane

    # speed: IDM behind the nearest car in the own lane and, while changing, in the target lane too;
    # the end of a dropped lane is a standing obstacle (crept up to while leaving the lane)
    v0 = torch.full_like(v, V_MAX_MPS)
    jam = torch.full_like(v, EGO_JAM_M)
    g_own, v_own = _nearest(world, lane, ahead=True)
    a = idm_accel(v, v0, jam, g_own, v_own, torch.isfinite(g_own))
    # the end of a dropped lane counts while any part of the ego is still in that lane
    for k in range(road.num_lanes):
        end = tables.drop_end[k]
        if end == float("inf"):
            continue
        front = front_x_in_band(x, y, s.heading[:, 0], (k - 0.5) * w, (k + 0.5) * w)
        wall = end - front
        leaving = changing | (lane != k)
        a_wall = idm_accel(v, v0, torch.where(leaving, WALL_JAM_CHANGING_M, jam), wall, torch.zeros_like(v),
                           torch.ones_like(leaving))
        a = torch.where(torch.isfinite(front) & (wall > -VEHICLE_LENGTH_M), torch.minimum(a, a_wall), a)
    g_tgt, v_tgt = _nearest(world, target_lane, ahead=True)
    a_tgt = idm_accel(v, v0, jam, g_tgt, v_tgt, torch.isfinite(g_tgt))
    a = torch.where(changing, torch.minimum(a, a_tgt), a)
    target_speed = (v + a * DT_S).clamp(0.0, V_MAX_MPS)
    return target_lane, target_speed
