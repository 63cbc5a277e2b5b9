"""One step of the world: decisions, accelerations, lateral control, integration, events, recycling."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from highway_srl.constants import (
    DT_S,
    EGO_ACCEL_MAX_MPS2,
    EGO_BRAKE_MAX_MPS2,
    SV_BRAKE_MAX_MPS2,
    V_MAX_MPS,
    VEHICLE_LENGTH_M,
    TrafficLevel,
)
from highway_srl.sim import rng
from highway_srl.sim.collision import boxes_overlap, lateral_half_extent
from highway_srl.sim.road import Road
from highway_srl.sim.spawn import EXIT_INTENT_PROB, Layout
from highway_srl.sim.state import EXIT_INTENT, MERGE_INTENT, NO_INTENT, WorldState
from highway_srl.sim.traffic import (
    MANDATORY_BONUS_MPS2,
    MOBIL_POLITENESS,
    MOBIL_SAFE_BRAKE_MPS2,
    MOBIL_THRESHOLD_MPS2,
    gather_lead,
    idm_accel,
    lane_neighbours,
)

# Lateral tracking controller on a kinematic model (shared by the ego and the SVs): a desired lateral
# speed proportional to the lateral error, turned into a desired heading that a rate-limited heading
# loop follows. At 8 m/s a lane change takes about 2.5 s; a standing car cannot move sideways.
K_Y = 1.6  # 1/s
VY_MAX_MPS = 2.0
HEADING_MAX_RAD = 0.25
K_HEADING = 8.0  # 1/s
YAW_RATE_MAX = 0.6  # rad/s
DECISION_PERIOD = 8  # SVs reconsider lane changes once a second
CENTRED_M = 0.3
MIN_CHANGE_SPEED_MPS = 2.0
ABORT_GAP_M = 1.0  # an SV returns to its lane if the gap it is moving into closes below this
EDGE_TOLERANCE_M = 0.5
S_ADV, S_RECYCLE_LANE, S_RECYCLE_GAP, S_RECYCLE_INTENT = 20, 21, 22, 23


@dataclass(frozen=True)
class LaneTables:
    start_m: torch.Tensor  # (K,)
    end_m: torch.Tensor  # (K,)
    drop_end_m: torch.Tensor  # (K,) x where a dropped lane ends, inf otherwise
    window_lo: torch.Tensor  # (K-1,) lane-change window per boundary
    window_hi: torch.Tensor

    @staticmethod
    def of(road: Road, device) -> "LaneTables":
        t = lambda v: torch.tensor(v, dtype=torch.float32, device=device)  # noqa: E731
        drop = [e if d else math.inf for e, d in zip(road.lane_end_m, road.lane_drop)]
        return LaneTables(
            t(road.lane_start_m),
            t(road.lane_end_m),
            t(drop),
            t([w[0] for w in road.change_window_m]),
            t([w[1] for w in road.change_window_m]),
        )

    def can_change(self, x: torch.Tensor, lane: torch.Tensor, to: torch.Tensor) -> torch.Tensor:
        """Moving from lane to the adjacent lane `to` is allowed at x (all (B, N) or (B,))."""
        k = self.start_m.shape[0]
        ok = ((to - lane).abs() == 1) & (to >= 0) & (to < k)
        toc = to.clamp(0, k - 1)
        ok &= (self.start_m[toc] <= x) & (x + 0.5 * VEHICLE_LENGTH_M < self.end_m[toc])
        b = torch.minimum(lane, toc).clamp(0, k - 2)
        return ok & (self.window_lo[b] <= x) & (x < self.window_hi[b])


def _idm_behind(s: WorldState, tables: LaneTables, lead: torch.Tensor, lane: torch.Tensor) -> torch.Tensor:
    """IDM acceleration of every vehicle behind leader indices lead (B, N), with lane's end as a wall."""
    inf = float("inf")
    gap = gather_lead(s.x, lead, inf) - s.x - VEHICLE_LENGTH_M
    v_lead = gather_lead(s.v, lead, 0.0)
    wall = tables.drop_end_m[lane] - s.x - 0.5 * VEHICLE_LENGTH_M
    use_wall = (wall > -VEHICLE_LENGTH_M) & (wall < gap)
    gap = torch.where(use_wall, wall, gap)
    v_lead = torch.where(use_wall, torch.zeros_like(v_lead), v_lead)
    return idm_accel(s.v, s.v0, s.s0, gap, v_lead, (lead >= 0) | use_wall)


def _lane_changes(s, road, tables, leader, follower, a_own, wall_lane_ok=True):
    """MOBIL decisions (incentive + safety) for SVs due to decide this step; mandatory merge/exit first."""
    k_lanes = road.num_lanes
    decide = ((s.t[:, None] + s.phase) % DECISION_PERIOD == 0) & (s.target_lane == s.lane) & ~s.forced
    decide &= (s.y - s.lane.float() * road.lane_width_m).abs() < CENTRED_M
    decide &= s.lane_change | (s.intent != NO_INTENT)
    decide &= s.v >= MIN_CHANGE_SPEED_MPS  # a crawling car would hang across the boundary for seconds
    decide[:, 0] = False
    if not bool(decide.any()):
        return
    best_gain = torch.full_like(s.x, -float("inf"))
    best_lane = s.lane.clone()
    inf = float("inf")
    for d in (-1, 1):
        to = s.lane + d
        ok = tables.can_change(s.x, s.lane, to)
        toc = to.clamp(0, k_lanes - 1)
        nl = leader.gather(0, toc[None]).squeeze(0)
        nf = follower.gather(0, toc[None]).squeeze(0)
        g_front = gather_lead(s.x, nl, inf) - s.x - VEHICLE_LENGTH_M
        nf_x = gather_lead(s.x, nf, -inf)
        g_back = s.x - nf_x - VEHICLE_LENGTH_M
        a_new = _idm_behind(s, tables, nl, toc)
        has_nf = nf >= 0
        nf_v, nf_v0, nf_s0 = gather_lead(s.v, nf, 0.0), gather_lead(s.v0, nf, 1.0), gather_lead(s.s0, nf, 0.0)
        a_nf_new = idm_accel(nf_v, nf_v0, nf_s0, g_back, s.v, has_nf)
        a_nf_old = idm_accel(nf_v, nf_v0, nf_s0, gather_lead(s.x, nl, inf) - nf_x - VEHICLE_LENGTH_M,
                             gather_lead(s.v, nl, 0.0), nl >= 0)
        safe = (g_front > 2.0) & (g_back > 2.0) & (~has_nf | (a_nf_new >= -MOBIL_SAFE_BRAKE_MPS2))
        gain = a_new - a_own + MOBIL_POLITENESS * torch.where(has_nf, a_nf_new - a_nf_old, 0.0) - MOBIL_THRESHOLD_MPS2
        mandatory = ((s.intent == MERGE_INTENT) & (s.lane >= road.mainline_lanes) & (d < 0)) | (
            (s.intent == EXIT_INTENT) & (d > 0)
        )
        against = (s.intent == EXIT_INTENT) & (d < 0)
        gain = gain + MANDATORY_BONUS_MPS2 * mandatory.float() - MANDATORY_BONUS_MPS2 * against.float()
        gain = torch.where(s.lane_change | mandatory, gain, torch.full_like(gain, -inf))
        better = decide & ok & safe & (gain > 0) & (gain > best_gain)
        best_gain = torch.where(better, gain, best_gain)
        best_lane = torch.where(better, toc, best_lane)
    s.target_lane = torch.where(decide, best_lane, s.target_lane)


def _abort_closing_changes(s: WorldState, leader, follower) -> None:
    """An SV that has not yet crossed into its target lane returns if the gap there is closing."""
    changing = (s.target_lane != s.lane) & ~s.forced
    changing[:, 0] = False
    if not bool(changing.any()):
        return
    nl = leader.gather(0, s.target_lane[None]).squeeze(0)
    nf = follower.gather(0, s.target_lane[None]).squeeze(0)
    g_front = gather_lead(s.x, nl, float("inf")) - s.x - VEHICLE_LENGTH_M
    g_back = s.x - gather_lead(s.x, nf, -float("inf")) - VEHICLE_LENGTH_M
    abort = changing & ((g_front < ABORT_GAP_M) | (g_back < ABORT_GAP_M))
    s.target_lane = torch.where(abort, s.lane, s.target_lane)


def _adversarial_cut_ins(s: WorldState, tables: LaneTables) -> None:
    """Group 3: an adjacent-lane SV ahead of the ego cuts into the ego's lane once its gap falls below
    d_trig = (the ego's kinematic safe distance to it) + offset, offset in {0, 5, 10} m, with probability ABP."""
    ego_lane, ego_x, ego_v = s.lane[:, :1], s.x[:, :1], s.v[:, :1]
    cand = ((s.lane - ego_lane).abs() == 1) & (s.x >= ego_x) & ~s.trigger_used & (s.adversarial_prob > 0)
    cand &= (s.target_lane == s.lane) & tables.can_change(s.x, s.lane, ego_lane.expand_as(s.lane))
    cand[:, 0] = False
    gap = s.x - ego_x - VEHICLE_LENGTH_M
    d_safe = (ego_v * DT_S + ego_v**2 / (2 * EGO_BRAKE_MAX_MPS2) - s.v**2 / (2 * SV_BRAKE_MAX_MPS2)).clamp(min=0)
    trig = cand & (gap < d_safe + s.trigger_offset)
    u = rng.uniform(rng.key(s.seed, s.episode, s.t, S_ADV), s.x.shape[1])
    fire = trig & (u < s.adversarial_prob)
    s.trigger_used |= trig
    s.forced |= fire
    s.target_lane = torch.where(fire, ego_lane.expand_as(s.lane), s.target_lane)


def advance(s: WorldState, road: Road, tables: LaneTables, layout: Layout, target_lane, target_speed, adversarial):
    """Move every vehicle by one step in place; returns the number of SV-SV contacts per env (B,)."""
    k_lanes = road.num_lanes
    occ = torch.stack([(s.lane == k) | (s.target_lane == k) for k in range(k_lanes)])
    leader, follower = lane_neighbours(s.x, occ)
    lead_own = leader.gather(0, s.lane[None]).squeeze(0)
    lead_tgt = leader.gather(0, s.target_lane[None]).squeeze(0)
    a_own = _idm_behind(s, tables, lead_own, s.lane)
    accel = torch.minimum(a_own, _idm_behind(s, tables, lead_tgt, s.target_lane))

    _abort_closing_changes(s, leader, follower)
    _lane_changes(s, road, tables, leader, follower, a_own)
    if adversarial:
        _adversarial_cut_ins(s, tables)

    # ego: the low-level controller tracks the commanded lane and speed within its limits
    ego_lane = s.lane[:, 0]
    ok = (target_lane == ego_lane) | tables.can_change(s.x[:, 0], ego_lane, target_lane)
    s.target_lane[:, 0] = torch.where(ok, target_lane, s.target_lane[:, 0])
    v_bar = target_speed.clamp(0.0, V_MAX_MPS)
    accel[:, 0] = ((v_bar - s.v[:, 0]) / DT_S).clamp(-EGO_BRAKE_MAX_MPS2, EGO_ACCEL_MAX_MPS2)

    # lateral tracking and integration
    y_t = s.target_lane.float() * road.lane_width_m
    vy_d = (K_Y * (y_t - s.y)).clamp(-VY_MAX_MPS, VY_MAX_MPS)
    sin_max = math.sin(HEADING_MAX_RAD)
    heading_d = torch.asin((vy_d / s.v.clamp(min=0.5)).clamp(-sin_max, sin_max))
    turn = (K_HEADING * (heading_d - s.heading)).clamp(-YAW_RATE_MAX, YAW_RATE_MAX) * DT_S
    heading = s.heading + turn
    v_new = (s.v + accel * DT_S).clamp(min=0.0)
    v_new[:, 0] = v_new[:, 0].clamp(max=V_MAX_MPS)
    v_mid = 0.5 * (s.v + v_new)
    s.x = s.x + v_mid * torch.cos(heading) * DT_S
    s.y = s.y + v_mid * torch.sin(heading) * DT_S
    s.v, s.heading = v_new, heading
    s.lane = torch.round(s.y / road.lane_width_m).long().clamp(0, k_lanes - 1)
    centred = (s.y - y_t).abs() < CENTRED_M
    s.forced &= ~((s.lane == s.target_lane) & centred)

    lx, ly, lh = gather_lead(s.x, lead_own, 1e9), gather_lead(s.y, lead_own, 0.0), gather_lead(s.heading, lead_own, 0.0)
    contact = boxes_overlap(s.x, s.y, s.heading, lx, ly, lh) & (lead_own >= 1)
    contact[:, 0] = False
    return contact.sum(1)


def ego_collision(s: WorldState, road: Road, tables: LaneTables) -> torch.Tensor:
    """The ego overlaps an SV, runs into a lane end, or crosses a boundary it may not cross (B,) bool."""
    hit = boxes_overlap(s.x[:, :1], s.y[:, :1], s.heading[:, :1], s.x[:, 1:], s.y[:, 1:], s.heading[:, 1:]).any(1)
    x, y, w = s.x[:, 0], s.y[:, 0], road.lane_width_m
    e = lateral_half_extent(s.heading[:, 0])
    lo, hi = y - e, y + e
    for k in range(road.num_lanes - 1):
        yb = (k + 0.5) * w
        straddle = (lo < yb) & (hi > yb)
        hit |= straddle & ~((tables.window_lo[k] <= x) & (x < tables.window_hi[k]))
    hit |= (lo < -0.5 * w - EDGE_TOLERANCE_M) | (hi > (road.num_lanes - 0.5) * w + EDGE_TOLERANCE_M)
    for k in range(road.num_lanes):
        if road.lane_drop[k]:
            in_band = (hi > (k - 0.5) * w) & (lo < (k + 0.5) * w)
            hit |= in_band & (x + 0.5 * VEHICLE_LENGTH_M >= road.lane_end_m[k])
    return hit


def stage_events(s: WorldState, road: Road) -> tuple[torch.Tensor, torch.Tensor]:
    """Latch the merge / exit stage flags; return (success, failure) events of this step (B,)."""
    lane, x = s.lane[:, 0], s.x[:, 0]
    none = torch.zeros_like(lane, dtype=torch.bool)
    if road.scenario == "merge":
        now = (lane < road.mainline_lanes) & (x >= road.zones["stability"][0])
        success = now & ~s.merged
        s.merged |= now
        return success, none
    if road.scenario == "exit":
        s.exit1 |= lane == 1
        s.exit2 |= lane == 2
        end = road.zones["off_ramp"][1]
        return (lane == 2) & (x >= end), (lane < 2) & (x >= road.zones["mainline_continuation"][1])
    return none, none


def recycle(s: WorldState, road: Road, layout: Layout, level: TrafficLevel) -> None:
    """Keep the flow centred on the ego: SVs that fall out of the window re-enter at the other end."""
    ego_x = s.x[:, :1]
    reach = layout.window_m + layout.margin_m
    dx = s.x - ego_x
    to_back = dx > reach
    if road.scenario == "exit":
        to_back |= (s.lane == 2) & (s.x >= road.zones["off_ramp"][1])
    to_front = dx < -reach
    to_back[:, 0] = False
    to_front[:, 0] = False
    moving = to_back | to_front
    if not bool(moving.any()):
        return
    n = s.x.shape[1]
    h_lo = level.headway_m[0]
    step = VEHICLE_LENGTH_M + h_lo
    new_lane = rng.randint(rng.key(s.seed, s.episode, s.t, S_RECYCLE_LANE), road.mainline_lanes, n)
    new_x, new_v = s.x.clone(), s.v.clone()
    staying = ~moving
    for lane in range(road.mainline_lanes):
        in_lane = staying & (s.lane == lane)
        xs = torch.where(in_lane, s.x, torch.full_like(s.x, -float("inf")))
        front_x, front_i = xs.max(1, keepdim=True)
        front_v = torch.gather(s.v, 1, front_i)
        xr = torch.where(in_lane, s.x, torch.full_like(s.x, float("inf")))
        rear_x, rear_i = xr.min(1, keepdim=True)
        rear_v = torch.gather(s.v, 1, rear_i)
        for mask, sign in ((to_front, 1.0), (to_back, -1.0)):
            sel = mask & (new_lane == lane)
            rank = (torch.cumsum(sel.long(), 1) - 1).float()
            if sign > 0:
                base = torch.maximum(ego_x + layout.window_m, front_x + step)
                new_x = torch.where(sel, base + rank * step, new_x)
                # never re-enter ahead of a vehicle slower than it, so nobody has to brake for the newcomer
                new_v = torch.where(sel & torch.isfinite(front_x), torch.maximum(s.v, front_v), new_v)
            else:
                base = torch.minimum(ego_x - layout.window_m, rear_x - step)
                new_x = torch.where(sel, base - rank * step, new_x)
                new_v = torch.where(sel & torch.isfinite(rear_x), torch.minimum(s.v, rear_v), new_v)
    s.x, s.v = new_x, new_v
    s.y = torch.where(moving, new_lane.float() * road.lane_width_m, s.y)
    s.heading = torch.where(moving, 0.0, s.heading)
    s.lane = torch.where(moving, new_lane, s.lane)
    s.target_lane = torch.where(moving, new_lane, s.target_lane)
    s.forced &= ~moving
    if road.scenario == "exit":
        exits = rng.uniform(rng.key(s.seed, s.episode, s.t, S_RECYCLE_INTENT), n) < EXIT_INTENT_PROB
        fresh = torch.where(exits, EXIT_INTENT, NO_INTENT)
    else:
        fresh = torch.full_like(s.intent, NO_INTENT)
    s.intent = torch.where(moving, fresh, s.intent)
