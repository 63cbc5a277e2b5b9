"""One step of the world: decisions, accelerations, lateral control, integration, events, recycling."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from highway_srl.constants import (
    D_MAX_M,
    DT_S,
    EGO_ACCEL_MAX_MPS2,
    EGO_BRAKE_MAX_MPS2,
    SV_BRAKE_MAX_MPS2,
    V_MAX_MPS,
    VEHICLE_LENGTH_M,
    TrafficLevel,
)
from highway_srl.scenarios import EXIT, MERGE
from highway_srl.sim import rng
from highway_srl.sim.collision import CONTACT_REACH_M, boxes_overlap, front_x_in_band, lateral_half_extent
from highway_srl.sim.road import Road
from highway_srl.sim.spawn import EXIT_INTENT_PROB, Layout
from highway_srl.sim.state import EXIT_INTENT, MERGE_INTENT, NO_INTENT, WorldState
from highway_srl.sim.traffic import (
    ABORT_BRAKE_MPS2,
    ABORT_EGO_BRAKE_MPS2,
    ABORT_GAP_M,
    LANE_CHANGE_TIME_S,
    MANDATORY_BONUS_MPS2,
    MOBIL_EGO_SAFE_BRAKE_MPS2,
    MOBIL_MIN_GAP_M,
    MOBIL_POLITENESS,
    MOBIL_SAFE_BRAKE_MPS2,
    MOBIL_THRESHOLD_MPS2,
    FAR_M,
    approx_half_width,
    gather_lead,
    idm_accel_fast,
    idm_free_term,
    follower_keys,
    followers_of,
    inverse_order,
    lane_leaders,
    occupancy,
    pad,
    sorted_order,
)

# Lateral tracking controller on a kinematic model (shared by the ego and the SVs): a desired lateral
# speed proportional to the lateral error, turned into a desired heading that a rate-limited heading
# loop follows. At 8 m/s a lane change settles (|e_y| < 0.2 m, |heading| < 0.02) in about 2.6 s without
# overshoot. Below LOW_SPEED_VY_MPS / HEADING_MAX_RAD = 4 m/s the heading limit opens up to
# HEADING_MAX_LOW_RAD, so that a car that has slowed down (at a lane end, in a jam) can still move
# sideways at about LOW_SPEED_VY_MPS. The yaw rate is at most v / MIN_TURN_RADIUS_M (a standing car
# neither turns nor moves sideways), and the heading is never more than can be unwound within the
# remaining lateral error (UNWIND_MARGIN x the turning radius), so that slow cars do not overshoot.
K_Y = 2.0  # 1/s
VY_MAX_MPS = 2.0
HEADING_MAX_RAD = 0.25
HEADING_MAX_LOW_RAD = 0.6
LOW_SPEED_VY_MPS = 1.0
K_HEADING = 8.0  # 1/s
YAW_RATE_MAX = 0.8  # rad/s
MIN_TURN_RADIUS_M = 4.0  # yaw rate <= v / R: the heading of a standing car does not change
UNWIND_MARGIN = 1.5
DECISION_PERIOD = 8  # SVs reconsider lane changes once a second
CENTRED_M = 0.3
YIELD_BRAKE_MPS2 = 3.0  # mainline SVs let a merging car in if that needs at most this deceleration
COMMITTED_M = 0.75  # a change is committed (no abort) once the car's side is over the lane boundary
MIN_CHANGE_SPEED_MPS = 2.0  # discretionary changes only above this speed; mandatory ones at any speed
WALL_JAM_CHANGING_M = 1.0  # a car leaving a dropped lane may creep this close to its end
EDGE_TOLERANCE_M = 0.5
SETTLED_M, SETTLED_RAD = 1e-3, 1e-3  # a car this close to its lane's centre line, and aligned, is put on it
NOT_BINDING_MPS2 = 100.0
# the bumper gap below which a pair may touch within a step (two L x B boxes touch only with centres
# closer than CONTACT_REACH_M; a car gains at most v dt < 2 m on its leader per step at SV speeds <= 13 m/s)
CONTACT_GAP_M = CONTACT_REACH_M - VEHICLE_LENGTH_M + 2.5
# Group 3 reading: cut-ins only by SVs wholly ahead of the ego (False) or also alongside it (True)
ADVERSARIAL_ALONGSIDE = False
S_ADV, S_RECYCLE_LANE, S_RECYCLE_INTENT = 20, 21, 23  # random streams (spawn uses 0-7)


@dataclass(frozen=True)
class LaneTables:
    start_m: torch.Tensor  # (K,)
    end_m: torch.Tensor  # (K,)
    drop_end_m: torch.Tensor  # (K,) x where a dropped lane ends, inf otherwise
    window_lo: torch.Tensor  # (K-1,) lane-change window per boundary
    window_hi: torch.Tensor
    drop_end: tuple[float, ...]  # drop_end_m on the host, so the step never reads it back from a GPU
    lane_width_m: float

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
            tuple(drop),
            road.lane_width_m,
        )

    def can_change(self, x: torch.Tensor, lane: torch.Tensor, to: torch.Tensor, ahead_m=0.0) -> torch.Tensor:
        """Moving from lane to the adjacent lane `to` is allowed at x and still at x + ahead_m (all (B, N)
        or (B,); ahead_m: a float or a tensor like x, the distance the change will take)."""
        k = self.start_m.shape[0]
        ok = ((to - lane).abs() == 1) & (to >= 0) & (to < k)
        toc = to.clamp(0, k - 1)
        x_end = x + ahead_m
        ok &= (self.start_m[toc] <= x) & (x_end + 0.5 * VEHICLE_LENGTH_M < self.end_m[toc])
        b = torch.minimum(lane, toc).clamp(0, k - 2)
        return ok & (self.window_lo[b] <= x) & (x_end < self.window_hi[b])


def decision_slots(s: WorldState) -> torch.Tensor:
    """(B, J) vehicle indices that reconsider their lane this step, J = ceil(N / DECISION_PERIOD).

    Vehicle n of env b decides when (t + phase[b, n]) % DECISION_PERIOD == 0, phase[b, n] =
    (n + phase[b, 0]) % DECISION_PERIOD, so the deciders form a strided slice; indices >= N are padding.
    """
    n = s.x.shape[1]
    j = -(-n // DECISION_PERIOD)
    first = torch.remainder(-s.t - s.phase[:, 0], DECISION_PERIOD)
    return first[:, None] + DECISION_PERIOD * torch.arange(j, device=s.x.device)


@dataclass
class Neighbours:
    """Who is next to whom at the start of a step: every vehicle's leader in every lane ((K, B, N) long,
    N = none), and followers on demand; x, v padded with a sentinel column (B, N + 1)."""

    occ: torch.Tensor  # (K, B, N) bool lane occupancy
    leader: torch.Tensor
    x_pad: torch.Tensor
    v_pad: torch.Tensor
    behind_keys: torch.Tensor  # (K, B, N) in x order, see traffic.follower_keys
    rank: torch.Tensor  # (B, N) position of each vehicle in x order

    def follower(self, k: torch.Tensor, b: torch.Tensor, i: torch.Tensor) -> torch.Tensor:
        """The follower of vehicle i of env b in lane k (all (M,)), N where there is none."""
        return followers_of(self.behind_keys, self.rank, k, b, i)


def find_neighbours(s: WorldState, road: Road) -> Neighbours:
    occ = occupancy(s.y, approx_half_width(s.heading), s.lane, s.target_lane, road.num_lanes, road.lane_width_m)
    s.order.copy_(sorted_order(s.x, s.order))
    leader, occ_sorted = lane_leaders(occ, s.order)
    behind = follower_keys(occ_sorted, s.order)
    return Neighbours(occ, leader, pad(s.x, FAR_M), pad(s.v, 0.0), behind, inverse_order(s.order))


def _car_following(s: WorldState, road: Road, tables: LaneTables, nb: Neighbours):
    """IDM acceleration (B, N) of every vehicle: the most restrictive over the leaders in all lanes it
    occupies (own, target, or reached by its footprint) and the ends of dropped lanes it is in; and the
    (K, B, N) mask of vehicles that are close enough to their leader there to touch it within the step."""
    free = idm_free_term(s.v, s.v0)
    accel, near = None, []
    for k in range(road.num_lanes):
        lead = nb.leader[k]
        gap = nb.x_pad.gather(1, lead) - s.x - VEHICLE_LENGTH_M
        a_k = idm_accel_fast(free, s.v, s.s0, gap, nb.v_pad.gather(1, lead))
        a_k = a_k + NOT_BINDING_MPS2 * (~nb.occ[k]).float()  # lanes a vehicle is not in do not bind it
        accel = a_k if accel is None else torch.minimum(accel, a_k)
        near.append(nb.occ[k] & (gap < CONTACT_GAP_M))
    for k in range(road.num_lanes):
        if math.isfinite(tables.drop_end[k]):
            _lane_end(s, tables, k, nb, free, accel)
    return accel, torch.stack(near)


def _lane_end(s: WorldState, tables: LaneTables, k: int, nb: Neighbours, free, accel) -> None:
    """The end of dropped lane k is a standing obstacle for every vehicle that occupies the lane (its
    footprint included), measured from the foremost point of the part of the car still in the lane; one
    that is leaving the lane (changing lanes, or already centred on another) may creep up to
    WALL_JAM_CHANGING_M of it instead of its jam distance. Updates accel in place."""
    end, w = tables.drop_end[k], tables.lane_width_m
    bb, ii = (nb.occ[k] & (s.x < end + VEHICLE_LENGTH_M)).nonzero(as_tuple=True)
    if bb.numel() == 0:
        return
    x, y, h, v, s0 = s.x[bb, ii], s.y[bb, ii], s.heading[bb, ii], s.v[bb, ii], s.s0[bb, ii]
    front = front_x_in_band(x, y, h, (k - 0.5) * w, (k + 0.5) * w)
    wall = end - front
    use = torch.isfinite(front) & (wall > -VEHICLE_LENGTH_M)
    leaving = (s.target_lane[bb, ii] != s.lane[bb, ii]) | (s.lane[bb, ii] != k)
    s0 = torch.where(leaving, s0.clamp(max=WALL_JAM_CHANGING_M), s0)
    a_w = idm_accel_fast(free[bb, ii], v, s0, torch.where(use, wall, FAR_M), torch.zeros_like(v))
    accel[bb, ii] = torch.minimum(accel[bb, ii], a_w)


def _yield_to_mergers(s: WorldState, road: Road, nb: Neighbours, accel: torch.Tensor) -> torch.Tensor:
    """Cooperative merging: an SV in the mainline lane beside a dropped lane also follows the nearest car
    ahead of it in the dropped lane while that car is in the merging zone and has to merge (an SV with
    merge intent, or the ego), if it can do so braking at most YIELD_BRAKE_MPS2; otherwise it goes on and
    leaves the gap to the next car. Without this a queue at the lane end can wait forever in dense flow."""
    for k in range(1, road.num_lanes):
        if not road.lane_drop[k] or "merging" not in road.zones:
            continue
        z0, z1 = road.zones["merging"]
        j = nb.leader[k]
        jx = nb.x_pad.gather(1, j)
        must_merge = (gather_lead(s.intent, j, NO_INTENT) == MERGE_INTENT) | (j == 0)
        cand = (s.lane == k - 1) & (s.target_lane == k - 1) & must_merge
        cand &= (gather_lead(s.lane, j, -1) == k) & (jx >= z0) & (jx < z1)
        cand[:, 0] = False
        bb, ii = cand.nonzero(as_tuple=True)
        if bb.numel() == 0:
            continue
        jj = j[bb, ii]
        free = idm_free_term(s.v[bb, ii], s.v0[bb, ii])
        a_y = idm_accel_fast(free, s.v[bb, ii], s.s0[bb, ii], jx[bb, ii] - s.x[bb, ii] - VEHICLE_LENGTH_M, s.v[bb, jj])
        accel[bb, ii] = torch.where(a_y >= -YIELD_BRAKE_MPS2, torch.minimum(accel[bb, ii], a_y), accel[bb, ii])
    return accel


def _abort_unsafe_changes(s: WorldState, road: Road, nb: Neighbours, accel: torch.Tensor) -> None:
    """An SV whose change is not yet committed (its side not yet over the boundary) returns to its lane
    when the change turned unsafe: too little room, or it or its new follower would have to brake hard
    (accel: the IDM accelerations of this step, in which the new follower already reacts to the changer).
    A committed change goes on: the new follower sees the changer in its lane and yields."""
    bb, ii = (s.target_lane != s.lane).nonzero(as_tuple=True)
    keep = (ii > 0) & ~s.forced[bb, ii]
    keep &= (s.y[bb, ii] - s.lane[bb, ii].float() * road.lane_width_m).abs() < COMMITTED_M
    bb, ii = bb[keep], ii[keep]
    if bb.numel() == 0:
        return
    tk = s.target_lane[bb, ii]
    nl, nf = nb.leader[tk, bb, ii], nb.follower(tk, bb, ii)
    x, v = s.x[bb, ii], s.v[bb, ii]
    g_front = nb.x_pad[bb, nl] - x - VEHICLE_LENGTH_M
    nf_x = torch.where(nf < s.x.shape[1], nb.x_pad[bb, nf], -FAR_M)
    g_back = x - nf_x - VEHICLE_LENGTH_M
    a_target = idm_accel_fast(idm_free_term(v, s.v0[bb, ii]), v, s.s0[bb, ii], g_front, nb.v_pad[bb, nl])
    accel_pad = pad(accel, 0.0)
    nf_limit = torch.where(nf == 0, -ABORT_EGO_BRAKE_MPS2, -ABORT_BRAKE_MPS2)
    unsafe = (g_front < ABORT_GAP_M) | (g_back < ABORT_GAP_M) | (a_target < -ABORT_BRAKE_MPS2)
    unsafe |= accel_pad[bb, nf] < nf_limit
    s.target_lane[bb[unsafe], ii[unsafe]] = s.lane[bb[unsafe], ii[unsafe]]


def _take(t: torch.Tensor, flat: torch.Tensor) -> torch.Tensor:
    """Elements of a contiguous tensor at flat indices (faster than advanced indexing with index pairs)."""
    return t.reshape(-1).index_select(0, flat)


def _lane_changes(s: WorldState, road: Road, tables: LaneTables, nb: Neighbours, accel: torch.Tensor) -> None:
    """MOBIL decisions (incentive + safety) of the SVs due to decide this step; mandatory merge/exit first.

    Only one vehicle in DECISION_PERIOD is due each step (a strided slice), and only those that may change
    at all (centred, lane-changing style or a ramp intent, fast enough) are evaluated, both directions at
    once.
    """
    b_envs, n = s.x.shape
    k_lanes, w = road.num_lanes, road.lane_width_m
    slots = decision_slots(s)  # (B, J)
    idx = slots.clamp(max=n - 1)
    g = lambda t: torch.gather(t, 1, idx)  # noqa: E731
    lane, intent = g(s.lane), g(s.intent)
    on_ramp_merge = (intent == MERGE_INTENT) & (lane >= road.mainline_lanes)
    decide = (slots < n) & (slots > 0) & (g(s.target_lane) == lane) & ~g(s.forced)
    # a car that gave up a merge near the lane end may not be able to re-centre: let it try again anyway
    decide &= ((g(s.y) - lane.float() * w).abs() < CENTRED_M) | on_ramp_merge
    decide &= g(s.lane_change) | (intent != NO_INTENT)
    decide &= (g(s.v) >= MIN_CHANGE_SPEED_MPS) | on_ramp_merge  # a crawling car would hang across the boundary
    bb, jj = decide.nonzero(as_tuple=True)
    m = bb.numel()
    if m == 0:
        return
    ii = idx[bb, jj]
    flat1 = bb * n + ii
    lane1, intent1, merge1 = lane[bb, jj], intent[bb, jj], on_ramp_merge[bb, jj]
    # both directions side by side: candidate c < m goes left (-1), c >= m right (+1)
    d = torch.cat([torch.full_like(lane1, -1), torch.full_like(lane1, 1)])
    two = lambda t: torch.cat([t, t])  # noqa: E731
    bb2, flat, lane, intent, on_ramp_merge = two(bb), two(flat1), two(lane1), two(intent1), two(merge1)
    x, v, v0, s0, alc = (two(_take(t, flat1)) for t in (s.x, s.v, s.v0, s.s0, s.lane_change))
    a_cur = two(_take(accel, flat1))
    to = lane + d
    ok = tables.can_change(x, lane, to, v * LANE_CHANGE_TIME_S)
    ok &= (to < road.mainline_lanes) | (intent == EXIT_INTENT)  # only cars bound for the off-ramp enter it
    toc = to.clamp(0, k_lanes - 1)
    flat_k = toc * (b_envs * n) + flat
    nl, nf = _take(nb.leader, flat_k), nb.follower(toc, bb2, two(ii))
    row = bb2 * (n + 1)
    nl_x, nl_v = _take(nb.x_pad, row + nl), _take(nb.v_pad, row + nl)
    g_front = nl_x - x - VEHICLE_LENGTH_M
    wall = tables.drop_end_m[toc] - x - 0.5 * VEHICLE_LENGTH_M
    use_wall = wall < g_front
    a_new = idm_accel_fast(idm_free_term(v, v0), v, s0, torch.minimum(wall, g_front), torch.where(use_wall, 0.0, nl_v))
    has_nf = nf < n
    nf_flat = bb2 * n + nf.clamp(max=n - 1)
    nf_x = torch.where(has_nf, _take(s.x, nf_flat), -FAR_M)
    nf_v, nf_v0, nf_s0 = _take(s.v, nf_flat), _take(s.v0, nf_flat), _take(s.s0, nf_flat)
    nf_free = idm_free_term(nf_v, nf_v0)
    g_back = x - nf_x - VEHICLE_LENGTH_M
    a_nf_new = idm_accel_fast(nf_free, nf_v, nf_s0, g_back, v)
    a_nf_old = idm_accel_fast(nf_free, nf_v, nf_s0, nl_x - nf_x - VEHICLE_LENGTH_M, nl_v)
    nf_limit = torch.where(nf == 0, -MOBIL_EGO_SAFE_BRAKE_MPS2, -MOBIL_SAFE_BRAKE_MPS2)
    safe = (g_front > MOBIL_MIN_GAP_M) & (g_back > MOBIL_MIN_GAP_M) & (a_new >= -MOBIL_SAFE_BRAKE_MPS2)
    safe &= ~has_nf | (a_nf_new >= nf_limit)
    gain = a_new - a_cur + MOBIL_POLITENESS * has_nf.float() * (a_nf_new - a_nf_old) - MOBIL_THRESHOLD_MPS2
    mandatory = (on_ramp_merge & (d < 0)) | ((intent == EXIT_INTENT) & (d > 0))
    against = (intent == EXIT_INTENT) & (d < 0)
    gain = gain + MANDATORY_BONUS_MPS2 * (mandatory.float() - against.float())
    gain = torch.where(ok & safe & (alc | mandatory) & (gain > 0), gain, -math.inf)
    left, right = gain[:m], gain[m:]
    best = torch.where(right > left, toc[m:], toc[:m])  # ties go left, as MOBIL prefers overtaking lanes
    change = torch.maximum(left, right) > -math.inf
    s.target_lane.view(-1).index_copy_(0, flat1, torch.where(change, best, lane1))


def _adversarial_cut_ins(s: WorldState, tables: LaneTables, nb: Neighbours) -> None:
    """Group 3: an adjacent-lane SV ahead of the ego (its rear bumper ahead of the ego's front bumper)
    cuts into the ego's lane once its gap falls below d_trig = (the ego's kinematic safe distance to it)
    + offset, offset in {0, 5, 10} m, with probability ABP; each SV evaluates its trigger once per episode.

    The attack is on the ego: only an SV with the ego as its immediate follower in the ego's lane and room
    to its leader there (MOBIL_MIN_GAP_M plus the difference of their braking distances) is a candidate,
    so a cut-in never lands on another SV. With
    ADVERSARIAL_ALONGSIDE an SV alongside the ego (its centre at most L behind the ego's) may also cut
    in, which is a side swipe no driving policy can avoid (see docs/paper-notes.md).
    """
    ego_lane, ego_x, ego_v = s.lane[:, :1], s.x[:, :1], s.v[:, :1]
    lowest = ego_x - VEHICLE_LENGTH_M if ADVERSARIAL_ALONGSIDE else ego_x + VEHICLE_LENGTH_M
    cand = ((s.lane - ego_lane).abs() == 1) & (s.x >= lowest) & ~s.trigger_used
    cand &= (s.adversarial_prob > 0) & (s.target_lane == s.lane)
    cand[:, 0] = False
    bb, ii = cand.nonzero(as_tuple=True)
    if bb.numel() == 0:
        return
    el = ego_lane[bb, 0]
    x, v = s.x[bb, ii], s.v[bb, ii]
    keep = tables.can_change(x, s.lane[bb, ii], el)
    nl, nf = nb.leader[el, bb, ii], nb.follower(el, bb, ii)
    # room to stop behind the car it cuts in front of, whatever that car does (it attacks the ego only)
    v_l = nb.v_pad[bb, nl]
    stop = ((v * v - v_l * v_l) / (2 * SV_BRAKE_MAX_MPS2)).clamp(min=0.0)
    room_ahead = nb.x_pad[bb, nl] - x - VEHICLE_LENGTH_M > MOBIL_MIN_GAP_M + stop
    room_behind = x - torch.where(nf < s.x.shape[1], nb.x_pad[bb, nf], -FAR_M) - VEHICLE_LENGTH_M > MOBIL_MIN_GAP_M
    keep &= ((nf == 0) & room_ahead) | ((nl == 0) & room_behind)
    gap = x - ego_x[bb, 0] - VEHICLE_LENGTH_M
    ev = ego_v[bb, 0]
    d_safe = (ev * DT_S + ev * ev / (2 * EGO_BRAKE_MAX_MPS2) - v * v / (2 * SV_BRAKE_MAX_MPS2)).clamp(min=0)
    trig = keep & (gap < d_safe + s.trigger_offset[bb, ii])
    bb, ii, el = bb[trig], ii[trig], el[trig]
    if bb.numel() == 0:
        return
    u = rng.uniform_at(rng.key(s.seed[bb], s.episode[bb], s.t[bb], S_ADV), ii)
    fire = u < s.adversarial_prob[bb, ii]
    s.trigger_used[bb, ii] = True
    s.forced[bb[fire], ii[fire]] = True
    s.target_lane[bb[fire], ii[fire]] = el[fire]


def advance(s: WorldState, road: Road, tables: LaneTables, layout: Layout, target_lane, target_speed, adversarial):
    """Move every vehicle by one step in place.

    Returns the number of SV-SV contacts per env (B,) long and the neighbours found at the start of the
    step (which ego_collision uses)."""
    nb = find_neighbours(s, road)
    accel, near = _car_following(s, road, tables, nb)
    accel = _yield_to_mergers(s, road, nb, accel)
    _abort_unsafe_changes(s, road, nb, accel)
    _lane_changes(s, road, tables, nb, accel)
    if adversarial:
        _adversarial_cut_ins(s, tables, nb)

    # ego: the low-level controller tracks the commanded lane and speed within its limits
    ego_lane = s.lane[:, 0]
    ok = (target_lane == ego_lane) | tables.can_change(s.x[:, 0], ego_lane, target_lane)
    s.target_lane[:, 0] = torch.where(ok, target_lane, s.target_lane[:, 0])
    v_bar = target_speed.clamp(0.0, V_MAX_MPS)
    accel[:, 0] = ((v_bar - s.v[:, 0]) / DT_S).clamp(-EGO_BRAKE_MAX_MPS2, EGO_ACCEL_MAX_MPS2)

    v_new = (s.v + accel * DT_S).clamp(min=0.0)
    v_new[:, 0] = v_new[:, 0].clamp(max=V_MAX_MPS)
    v_mid = 0.5 * (s.v + v_new)
    x_old = s.x.clone()
    s.x.add_(v_mid * DT_S)  # along the lane; corrected below for the few cars that are turned
    _lateral(s, road, v_mid, x_old)
    s.v.copy_(v_new)
    return sv_contacts(s, near, nb.leader), nb


def _lateral(s: WorldState, road: Road, v_mid: torch.Tensor, x_old: torch.Tensor) -> None:
    """Lateral tracking and the lateral part of the integration, for the cars that are not settled in
    their lane (a changing car, one off its lane's centre, or one not aligned with the road); a car that
    comes within SETTLED_M / SETTLED_RAD of its lane's centre line is snapped onto it."""
    w = road.lane_width_m
    active = (s.target_lane != s.lane) | (s.heading != 0) | (s.y != s.lane.float() * w)
    bb, ii = active.nonzero(as_tuple=True)
    if bb.numel() == 0:
        return
    y, h, v, tgt = s.y[bb, ii], s.heading[bb, ii], s.v[bb, ii], s.target_lane[bb, ii]
    y_t = tgt.float() * w
    e_y = y_t - y
    vy_d = (K_Y * e_y).clamp(-VY_MAX_MPS, VY_MAX_MPS)
    v_safe = v.clamp(min=0.5)
    sin_max = torch.sin((LOW_SPEED_VY_MPS / v_safe).clamp(HEADING_MAX_RAD, HEADING_MAX_LOW_RAD))
    # never steer further than can be unwound within the remaining lateral error: turning back from
    # heading h on a circle of radius R moves the car R (1 - cos h) sideways
    radius = UNWIND_MARGIN * torch.clamp(v / YAW_RATE_MAX, min=MIN_TURN_RADIUS_M)
    cos_u = (1.0 - e_y.abs() / radius).clamp(min=0.0)
    sin_max = torch.minimum(sin_max, torch.sqrt(1.0 - cos_u * cos_u))
    heading_d = torch.asin(torch.maximum(torch.minimum(vy_d / v_safe, sin_max), -sin_max))
    yaw_max = (v / MIN_TURN_RADIUS_M).clamp(max=YAW_RATE_MAX)
    turn = torch.maximum(torch.minimum(K_HEADING * (heading_d - h), yaw_max), -yaw_max) * DT_S
    h = h + turn
    vm = v_mid[bb, ii]
    x = x_old[bb, ii] + vm * torch.cos(h) * DT_S
    y = y + vm * torch.sin(h) * DT_S
    settled = ((y - y_t).abs() < SETTLED_M) & (h.abs() < SETTLED_RAD)
    y = torch.where(settled, y_t, y)
    h = torch.where(settled, 0.0, h)
    lane = torch.round(y / w).long().clamp(0, road.num_lanes - 1)
    s.x[bb, ii], s.y[bb, ii], s.heading[bb, ii], s.lane[bb, ii] = x, y, h, lane
    centred = (lane == tgt) & ((y - y_t).abs() < CENTRED_M)
    s.forced[bb, ii] = s.forced[bb, ii] & ~centred


def sv_contacts(s: WorldState, near: torch.Tensor, leader: torch.Tensor) -> torch.Tensor:
    """Distinct overlapping SV-SV pairs per env (B,) long.

    Two boxes that overlap share a point, which lies in some lane band that both footprints reach, so each
    is the other's nearest occupant of that band or has a vehicle between them in x there (which would
    then overlap one of them too). Checking every vehicle against its leader in each lane it occupies (at
    the start of the step, with a margin wider than a step's lateral travel) finds every contact. Only the
    pairs that were within CONTACT_GAP_M (bumper to bumper) at the start of the step can touch by its end;
    they go through the exact box test.
    """
    b, n = s.x.shape
    near[:, :, 0] = False
    kk, bb, ii = near.nonzero(as_tuple=True)
    count = torch.zeros(b, dtype=torch.long, device=s.x.device)
    jj = leader[kk, bb, ii]
    keep = (jj > 0) & (jj < n)
    bb, ii, jj = bb[keep], ii[keep], jj[keep]
    if bb.numel() == 0:
        return count
    hit = boxes_overlap(s.x[bb, ii], s.y[bb, ii], s.heading[bb, ii], s.x[bb, jj], s.y[bb, jj], s.heading[bb, jj])
    key = ((bb * n + ii) * n + jj)[hit]
    if key.numel() == 0:
        return count
    key = torch.unique(key)
    return count.index_add_(0, key // (n * n), torch.ones_like(key))


def ego_collision(s: WorldState, road: Road, tables: LaneTables, nb: Neighbours) -> torch.Tensor:
    """The ego overlaps an SV, runs into a lane end, or crosses a boundary it may not cross (B,) bool.

    Any SV the ego overlaps is its leader or follower (at the start of the step) in a lane both occupy,
    by the argument of sv_contacts, so only those 2K are tested."""
    n = s.x.shape[1]
    b = s.x.shape[0]
    envs, zero = torch.arange(b, device=s.x.device), torch.zeros(b, dtype=torch.long, device=s.x.device)
    followers = [nb.follower(torch.full_like(zero, k), envs, zero) for k in range(road.num_lanes)]
    j = torch.cat([nb.leader[:, :, 0].T, torch.stack(followers, 1)], 1)  # (B, 2K)
    x_pad, y_pad, h_pad = pad(s.x, FAR_M), pad(s.y, 0.0), pad(s.heading, 0.0)
    g = lambda t: torch.gather(t, 1, j)  # noqa: E731
    xj, yj = g(x_pad), g(y_pad)
    near = ((xj - s.x[:, :1]).abs() < CONTACT_REACH_M) & ((yj - s.y[:, :1]).abs() < CONTACT_REACH_M) & (j < n)
    if s.x.device.type != "cpu" or bool(near.any()):  # on CPU a branch is free and contacts are rare
        hit = (boxes_overlap(s.x[:, :1], s.y[:, :1], s.heading[:, :1], xj, yj, g(h_pad)) & near).any(1)
    else:
        hit = torch.zeros_like(near[:, 0])
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
            # the part of the ego still in the dropped lane reaches the lane's end
            front = front_x_in_band(x, y, s.heading[:, 0], (k - 0.5) * w, (k + 0.5) * w)
            hit |= front >= road.lane_end_m[k]
    return hit


def stage_events(s: WorldState, road: Road) -> tuple[torch.Tensor, torch.Tensor]:
    """Latch the merge / exit stage flags; return (success, failure) events of this step (B,)."""
    lane, x = s.lane[:, 0], s.x[:, 0]
    none = torch.zeros_like(lane, dtype=torch.bool)
    task = road.spec.task
    if task == MERGE:
        now = (lane < road.mainline_lanes) & (x >= road.zones["stability"][0])
        success = now & ~s.merged
        s.merged |= now
        return success, none
    if task == EXIT:
        s.exit1 |= lane == 1
        s.exit2 |= lane == 2
        end = road.zones["off_ramp"][1]
        return (lane == 2) & (x >= end), (lane < 2) & (x >= road.zones["mainline_continuation"][1])
    return none, none


def _entry_slots(x, v, occ, lo, hi, need, from_edge_lo: bool):
    """Where one car can enter each lane inside [lo, hi] (all (E,) per env), keeping `need` (centre to
    centre) from every occupant (occ: (K, E, N) bool): the free stretch nearest the edge lo (from_edge_lo)
    or hi, entered right at its edge side. Returns per lane (K, E): slot x, ok, and a speed that neither
    the car entering nor the one behind it has to brake for (between the follower's and leader's speeds).
    """
    inf = float("inf")
    k_lanes = occ.shape[0]
    xs = torch.where(occ, x.expand_as(occ), inf)
    xs, idx = torch.sort(xs, dim=2)
    vs = torch.gather(v.expand_as(occ), 2, idx)
    vs = torch.where(torch.isfinite(xs), vs, torch.nan)
    lo_b, hi_b = (lo - need)[None, :, None], (hi + need)[None, :, None]
    # the stretches between consecutive occupants, and the zone's own ends as virtual occupants
    pts = torch.cat([lo_b.expand(k_lanes, -1, 1), torch.minimum(torch.maximum(xs, lo_b), hi_b), hi_b.expand(k_lanes, -1, 1)], 2)
    pv = torch.cat([torch.full_like(vs[..., :1], torch.nan), vs, torch.full_like(vs[..., :1], torch.nan)], 2)
    a, c = pts[..., :-1], pts[..., 1:]
    feasible = c - a >= 2 * need
    pos = torch.arange(a.shape[2], device=x.device)
    if from_edge_lo:
        rank = torch.where(feasible, pos, a.shape[2]).min(2).values
    else:
        rank = torch.where(feasible, pos, -1).max(2).values
    ok = (rank >= 0) & (rank < a.shape[2])
    r = rank.clamp(0, a.shape[2] - 1)[..., None]
    a_r, c_r = a.gather(2, r)[..., 0], c.gather(2, r)[..., 0]
    slot = torch.maximum(a_r + need, lo[None]) if from_edge_lo else torch.minimum(c_r - need, hi[None])
    v_behind, v_ahead = pv[..., :-1].gather(2, r)[..., 0], pv[..., 1:].gather(2, r)[..., 0]
    return slot, ok, v_behind, v_ahead


def recycle(s: WorldState, road: Road, layout: Layout, level: TrafficLevel) -> None:
    """Keep the flow centred on the ego (a closed loop): an SV that leaves the window [ego - reach,
    ego + reach] (reach = window + margin), or the map at the off-ramp's end, re-enters at the other end.

    Per env and step at most one SV re-enters at each end. The entry zone of the back end is
    [ego - reach + need, ego - d_max - L] (the front's is its mirror image), out of the ego's sight, with
    need = L + the level's smallest headway: the SV enters as near the far edge as it can while keeping
    `need` (centre to centre) from every car in the lane, i.e. at the edge, or just beyond the lane's last
    car, or in the first free stretch after it. Speed: its own, but not slower than the car behind it nor faster than the car ahead
    (the latter wins), so nobody has to brake for it. Lane: a random mainline lane if it has room, else
    the one whose entry is nearest the edge. If its own end is full (the ego stuck in a jam: the cars ahead
    drive off while the queue behind is full) it enters at the other end if that entry is free this step,
    else it waits a step. Lanes are occupied by own lane, target lane and footprint, as in the traffic
    model; cars that are themselves leaving do not count.
    """
    ego_x = s.x[:, :1]
    reach = layout.window_m + layout.margin_m
    dx = s.x - ego_x
    ahead_out, behind_out = dx > reach, dx < -reach
    to_back = ahead_out.clone()
    if road.spec.svs_may_exit:  # an SV at the off-ramp's end leaves the map
        to_back |= (s.lane == 2) & (s.x >= road.zones["off_ramp"][1])
    to_back[:, 0] = False
    to_front = behind_out.clone()
    to_front[:, 0] = False
    envs = (to_back | to_front).any(1).nonzero().squeeze(1)
    if envs.numel() == 0:
        return
    w = road.lane_width_m
    need = VEHICLE_LENGTH_M + level.headway_m[0]
    hide = D_MAX_M + VEHICLE_LENGTH_M
    sub = lambda t: t.index_select(0, envs)  # noqa: E731
    x, v, y, h, lane, tgt = sub(s.x), sub(s.v), sub(s.y), sub(s.heading), sub(s.lane), sub(s.target_lane)
    v0 = sub(s.v0)
    ex = x[:, 0]
    to_back, to_front = sub(to_back), sub(to_front)
    # one per end and env: the first flagged index
    to_back &= torch.cumsum(to_back.int(), 1) == 1
    to_front &= torch.cumsum(to_front.int(), 1) == 1
    inside = ~(sub(ahead_out) | sub(behind_out) | to_back)
    occ = occupancy(y, lateral_half_extent(h), lane, tgt, road.mainline_lanes, w) & inside
    edge = reach - need
    back = _entry_slots(x, v, occ, ex - edge, ex - hide, need, from_edge_lo=True)
    front = _entry_slots(x, v, occ, ex + hide, ex + edge, need, from_edge_lo=False)
    keys = rng.key(sub(s.seed), sub(s.episode), sub(s.t), S_RECYCLE_LANE)
    pick = rng.randint(keys, road.mainline_lanes, 2)  # (E, 2): preferred lane for the back and the front entry

    def choose(entry, pick_col, nearest_edge):
        slot, ok, v_behind, v_ahead = (t.T for t in entry)  # (E, lanes)
        fallback = torch.where(ok, slot, math.inf if nearest_edge == "low" else -math.inf)
        best = fallback.argmin(1) if nearest_edge == "low" else fallback.argmax(1)
        lane_k = torch.where(ok.gather(1, pick_col[:, None])[:, 0], pick_col, best)[:, None]
        g = lambda t: t.gather(1, lane_k)  # noqa: E731
        return lane_k, g(slot), g(v_behind), g(v_ahead), g(ok)

    lb, xb, vb_behind, vb_ahead, okb = choose(back, pick[:, 0], "low")
    lf, xf, vf_behind, vf_ahead, okf = choose(front, pick[:, 1], "high")
    any_back, any_front = to_back.any(1, keepdim=True), to_front.any(1, keepdim=True)
    # an end without room sends its leaver to the other end, if that entry is not taken this step
    go_back = (to_back & okb) | (to_front & ~okf & okb & ~any_back)
    go_front = (to_front & okf) | (to_back & ~okb & okf & ~any_front)
    moving = go_back | go_front
    new_lane = torch.where(go_back, lb, lf)

    def entry_speed(v_behind, v_ahead):
        # nobody ahead in the window: free road, at its desired speed (the head of a jam drives off)
        out = torch.where(torch.isnan(v_behind), v, torch.maximum(v, v_behind))
        return torch.where(torch.isnan(v_ahead), torch.maximum(out, v0), torch.minimum(out, v_ahead))

    x = torch.where(go_back, xb, torch.where(go_front, xf, x))
    v = torch.where(go_back, entry_speed(vb_behind, vb_ahead), torch.where(go_front, entry_speed(vf_behind, vf_ahead), v))
    put = lambda name, value: getattr(s, name).index_copy_(0, envs, value)  # noqa: E731
    put("x", x)
    put("v", v)
    put("y", torch.where(moving, new_lane.float() * w, y))
    put("heading", torch.where(moving, 0.0, h))
    put("lane", torch.where(moving, new_lane, lane))
    put("target_lane", torch.where(moving, new_lane, tgt))
    put("forced", sub(s.forced) & ~moving)
    if road.spec.svs_may_exit:
        exits = rng.uniform(rng.key(sub(s.seed), sub(s.episode), sub(s.t), S_RECYCLE_INTENT)) < EXIT_INTENT_PROB
        fresh = torch.where(exits, EXIT_INTENT, NO_INTENT)[:, None]
    else:
        fresh = torch.full((1, 1), NO_INTENT, device=x.device)
    put("intent", torch.where(moving, fresh, sub(s.intent)))
