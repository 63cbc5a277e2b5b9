"""The built-in IDM ego driver for demos, renderings, the foreign backends and the rule-based method: IDM in
its lane, and on ramps it merges or exits when the target lane has room.

One gap rule, `room_to_change`: a lane change needs, ahead and behind in the target lane, a bumper-to-bumper
gap of MIN_GAP_M (2 m) + HEADWAY_S (0.5 s) x the speed of the car behind the gap (the ego ahead, the SV
behind) + CLOSING_TIME_S (2.5 s) x the speed at which that car closes in. It replaced a second rule, 6 m
(+ 1 s at the ego's speed ahead, + 2 s of closing speed behind), that the backends' driver kept, because it
merges and exits more often at about the same collisions (docs/backends.md; scripts/gap_rule_table.py):
on our World, level C, idm_ego merges in 83.5 % vs 62.5 % of 200 episodes and exits in 53.5 % vs 22 %
(no collision with either rule), idm_ego_backend 47.5 % vs 38.5 % and 64.5 % vs 36.5 %; in SUMO and
highway-env it succeeds more often in 7 of their 8 merge / exit x A / C cells. A 6 m standstill gap is also
what left the old World driver standing at the ramp's end: the yielding car behind never opened it.

The drivers differ only in how they read the neighbours, for what each simulator lets them see:
- idm_ego (World): the world's ground truth: an SV counts as being in a lane when its footprint reaches
  into that lane or it is changing into it (not only when its centre is there, as in World.neighbours),
  so a car nosing in from the ramp is seen before it crosses the boundary; its remembered target lane,
  the change windows and the lane-drop walls.
- idm_ego_backend (any Backend): only the protocol (ego_speed, ego_lane, road, neighbours()), which places
  SVs by their centres. Instead of the remembered target lane it infers a lane change under way from the
  snapshot: off the lane centre and moving sideways, it keeps heading for the lane it moves to.
- the rule-based method (agents/rule_based.py) applies the same rule to its model's SV2 / SV4 before it
  asks for a LaneChange, and shares the IDM parameters (EGO_V0 = v_max, EGO_JAM_M) and task lanes.
"""

from __future__ import annotations

import torch

from highway_srl.constants import DT_S, V_MAX_MPS, VEHICLE_LENGTH_M
from highway_srl.scenarios import EXIT, MERGE
from highway_srl.sim.box_geometry import front_x_in_band, lateral_half_extent
from highway_srl.sim.idm_mobil import LANE_CHANGE_TIME_S, OCCUPANCY_MARGIN_M, idm_accel
from highway_srl.sim.protocol import Backend
from highway_srl.sim.road import Road
from highway_srl.sim.sv_drivers import CENTRED_M, COMMITTED_M, WALL_JAM_CHANGING_M
from highway_srl.sim.world import World

EGO_JAM_M = 2 * VEHICLE_LENGTH_M  # IDM s0 of the ego: a cautious style's desired headway
MIN_GAP_M = 2.0  # bumper-to-bumper room a lane change needs ahead and behind, plus:
HEADWAY_S = 0.5  # half a second at the speed of the car behind the gap (the ego ahead, the SV behind)
CLOSING_TIME_S = 2.5  # and this many seconds of closing speed
CENTRED_SNAPSHOT_M = 0.3  # idm_ego_backend: closer than this to a lane centre counts as in the lane
MOVING_SIDEWAYS_MPS = 0.1


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


def room_to_change(gap_ahead_m: torch.Tensor, v_ahead_mps: torch.Tensor, gap_behind_m: torch.Tensor,
                   v_behind_mps: torch.Tensor, v_mps: torch.Tensor) -> torch.Tensor:
    """(B,) bool: the target lane has room for the ego's lane change, given the bumper-to-bumper gaps (B,) to
    the nearest car ahead of and behind the ego in that lane (inf: none), their speeds (B,) and the ego's
    speed v_mps (B,). On each side the gap must exceed MIN_GAP_M + HEADWAY_S x the speed of the car behind
    the gap (the ego ahead, the SV behind) + CLOSING_TIME_S x the speed at which that car closes in."""
    need_ahead = MIN_GAP_M + HEADWAY_S * v_mps + (v_mps - v_ahead_mps).clamp(min=0) * CLOSING_TIME_S
    need_behind = MIN_GAP_M + HEADWAY_S * v_behind_mps + (v_behind_mps - v_mps).clamp(min=0) * CLOSING_TIME_S
    return (gap_ahead_m > need_ahead) & (gap_behind_m > need_behind)


def idm_ego(world: World) -> tuple[torch.Tensor, torch.Tensor]:
    """(target_lane (B,), target_speed (B,)) for the ego of every env."""
    s, road = world.state, world.road
    tables = world.lane_tables
    w = road.lane_width_m
    x, y, v = s.x[:, 0], s.y[:, 0], s.v[:, 0]
    lane, tgt = s.lane[:, 0], s.target_lane[:, 0]
    want = task_lane(road, lane)
    changing = tgt != lane
    offset = (y - lane.float() * w).abs()

    # lane change: start when centred, when the change fits in the window, and the target lane has room
    gap_f, v_f = _nearest(world, want, ahead=True)
    gap_r, v_r = _nearest(world, want, ahead=False)
    room = room_to_change(gap_f, v_f, gap_r, v_r, v)
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
    inf = torch.full_like(v, float("inf"))
    gap_f = torch.where(snap.sv_valid[:, 1], snap.sv_x[:, 1] - snap.ego_x - VEHICLE_LENGTH_M, inf)
    gap_r = torch.where(snap.sv_valid[:, 3], snap.ego_x - snap.sv_x[:, 3] - VEHICLE_LENGTH_M, inf)
    change = (want != lane) & room_to_change(gap_f, snap.sv_vx[:, 1], gap_r, snap.sv_vx[:, 3], v)
    # a lane change under way: off-centre and moving sideways -> keep going to the lane it moves towards
    offset = snap.ego_y - lane.float() * w
    toward = torch.where(snap.ego_vy > 0, torch.ceil(snap.ego_y / w), torch.floor(snap.ego_y / w)).long()
    changing = (offset.abs() > CENTRED_SNAPSHOT_M) & (snap.ego_vy.abs() > MOVING_SIDEWAYS_MPS)
    target_lane = torch.where(changing, toward.clamp(0, road.num_lanes - 1), torch.where(change, want, lane))
    target_speed = (v + ahead * DT_S).clamp(0.0, V_MAX_MPS)
    return target_lane, target_speed
