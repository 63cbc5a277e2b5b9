"""The surrounding vehicles' driver model: IDM car following (with lane ends and cooperative merging) and
MOBIL lane changes (with aborts), as functions over (state, road, lane tables, neighbours).

The formulas and the neighbour scans they use (IDM terms, lane occupancy, leaders, followers) are in
sim/idm_mobil.py; this module decides, per step, which vehicle follows whom and who changes lanes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from highway_srl.constants import VEHICLE_LENGTH_M
from highway_srl.sim.box_geometry import CONTACT_GAP_M, front_x_in_band
from highway_srl.sim.idm_mobil import (
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
    followers_of,
    inverse_order,
    neighbour_keys,
    occupancy,
    pad,
    sorted_order,
    take_flat,
)
from highway_srl.sim.lane_tables import LaneTables
from highway_srl.sim.road import Road
from highway_srl.sim.selection import entries, flat_index, narrow, none_left, put, put_flat
from highway_srl.sim.state import EXIT_INTENT, MERGE_INTENT, NO_INTENT, WorldState

DECISION_PERIOD = 8  # SVs reconsider lane changes once a second
CENTRED_M = 0.3  # closer than this to its lane's centre a car counts as centred (may decide, is released)
YIELD_BRAKE_MPS2 = 3.0  # mainline SVs let a merging car in if that needs at most this deceleration
COMMITTED_M = 0.75  # a change is committed (no abort) once the car's side is over the lane boundary
MIN_CHANGE_SPEED_MPS = 2.0  # discretionary changes only above this speed; mandatory ones at any speed
WALL_JAM_CHANGING_M = 1.0  # a car leaving a dropped lane may creep this close to its end
NOT_BINDING_MPS2 = 100.0


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
    behind_keys: torch.Tensor  # (K, B, N + 1) in x order, see idm_mobil.neighbour_keys
    rank: torch.Tensor  # (B, N) position of each vehicle in x order

    def follower(self, k: torch.Tensor, b: torch.Tensor, i: torch.Tensor) -> torch.Tensor:
        """The follower of vehicle i of env b in lane k (b, i (M,); k (M,) or (L, M) for several lanes at
        once), N where there is none."""
        return followers_of(self.behind_keys, self.rank, k, b, i)


def find_neighbours(s: WorldState, road: Road, static: bool = False) -> Neighbours:
    occ = occupancy(s.y, approx_half_width(s.heading), s.lane, s.target_lane, road.num_lanes, road.lane_width_m)
    s.order.copy_(sorted_order(s.x, s.order, static))
    leader, behind = neighbour_keys(occ, s.order)
    return Neighbours(occ, leader, pad(s.x, FAR_M), pad(s.v, 0.0), behind, inverse_order(s.order))


def car_following(s: WorldState, road: Road, tables: LaneTables, nb: Neighbours, static: bool = False):
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
            _lane_end(s, tables, k, nb, free, accel, static)
    return accel, torch.stack(near)


def _lane_end(s: WorldState, tables: LaneTables, k: int, nb: Neighbours, free, accel, static: bool) -> None:
    """The end of dropped lane k is a standing obstacle for every vehicle that occupies the lane (its
    footprint included), measured from the foremost point of the part of the car still in the lane; one
    that is leaving the lane (changing lanes, or already centred on another) may creep up to
    WALL_JAM_CHANGING_M of it instead of its jam distance. Updates accel in place."""
    end, w = tables.drop_end[k], tables.lane_width_m
    bb, ii, sel = entries(nb.occ[k] & (s.x < end + VEHICLE_LENGTH_M), static)
    if none_left(bb, sel):
        return
    x, y, h, v, s0 = s.x[bb, ii], s.y[bb, ii], s.heading[bb, ii], s.v[bb, ii], s.s0[bb, ii]
    front = front_x_in_band(x, y, h, (k - 0.5) * w, (k + 0.5) * w)
    wall = end - front
    use = torch.isfinite(front) & (wall > -VEHICLE_LENGTH_M)
    leaving = (s.target_lane[bb, ii] != s.lane[bb, ii]) | (s.lane[bb, ii] != k)
    s0 = torch.where(leaving, s0.clamp(max=WALL_JAM_CHANGING_M), s0)
    a_w = idm_accel_fast(free[bb, ii], v, s0, torch.where(use, wall, FAR_M), torch.zeros_like(v))
    put(accel, bb, ii, torch.minimum(accel[bb, ii], a_w), sel)


def yield_to_mergers(s: WorldState, road: Road, nb: Neighbours, accel: torch.Tensor,
                     static: bool = False) -> torch.Tensor:
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
        bb, ii, sel = entries(cand, static)
        if none_left(bb, sel):
            continue
        jj = j[bb, ii].clamp(max=s.x.shape[1] - 1)  # a candidate's leader is a vehicle (its lane is k)
        free = idm_free_term(s.v[bb, ii], s.v0[bb, ii])
        a_y = idm_accel_fast(free, s.v[bb, ii], s.s0[bb, ii], jx[bb, ii] - s.x[bb, ii] - VEHICLE_LENGTH_M, s.v[bb, jj])
        put(accel, bb, ii, torch.where(a_y >= -YIELD_BRAKE_MPS2, torch.minimum(accel[bb, ii], a_y), accel[bb, ii]), sel)
    return accel


def abort_unsafe_changes(s: WorldState, road: Road, nb: Neighbours, accel: torch.Tensor, static: bool = False) -> None:
    """An SV whose change is not yet committed (its side not yet over the boundary) returns to its lane
    when the change turned unsafe: too little room, or it or its new follower would have to brake hard
    (accel: the IDM accelerations of this step, in which the new follower already reacts to the changer).
    A committed change goes on: the new follower sees the changer in its lane and yields."""
    b_envs, n = s.x.shape
    bb, ii, sel = entries(s.target_lane != s.lane, static)
    flat = flat_index(bb, ii, n)
    y, lane, forced = take_flat(s.y, flat), take_flat(s.lane, flat), take_flat(s.forced, flat)
    keep = (ii > 0) & ~forced & ((y - lane.float() * road.lane_width_m).abs() < COMMITTED_M)
    sel, bb, ii, flat, lane = narrow(sel, keep, bb, ii, flat, lane)
    if none_left(bb, sel):
        return
    tk = take_flat(s.target_lane, flat)
    nl, nf = take_flat(nb.leader, tk * (b_envs * n) + flat), nb.follower(tk, bb, ii)
    x, v = take_flat(s.x, flat), take_flat(s.v, flat)
    row = bb * (n + 1)
    nl_x, nf_x = take_flat(nb.x_pad, row + nl), take_flat(nb.x_pad, row + nf)
    g_front = nl_x - x - VEHICLE_LENGTH_M
    nf_x = torch.where(nf < n, nf_x, -FAR_M)
    g_back = x - nf_x - VEHICLE_LENGTH_M
    free = idm_free_term(v, take_flat(s.v0, flat))
    a_target = idm_accel_fast(free, v, take_flat(s.s0, flat), g_front, take_flat(nb.v_pad, row + nl))
    nf_limit = torch.where(nf == 0, -ABORT_EGO_BRAKE_MPS2, -ABORT_BRAKE_MPS2)
    unsafe = (g_front < ABORT_GAP_M) | (g_back < ABORT_GAP_M) | (a_target < -ABORT_BRAKE_MPS2)
    # the new follower's acceleration (none: 0, never below the limits)
    unsafe |= torch.where(nf < n, take_flat(accel, bb * n + nf.clamp(max=n - 1)), 0.0) < nf_limit
    sel, flat, lane = narrow(sel, unsafe, flat, lane)
    put_flat(s.target_lane, flat, lane, sel)


def _deciders(s: WorldState, road: Road):
    """The SVs due to decide this step: their indices idx (B, J), whether each may change at all (B, J)
    bool (centred, lane-changing style or a ramp intent, fast enough), and their lane, intent and
    on-ramp-merge flag (B, J)."""
    n, w = s.x.shape[1], road.lane_width_m
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
    return idx, decide, lane, intent, on_ramp_merge


def _write_targets(s: WorldState, flat: torch.Tensor, sel: torch.Tensor | None, target: torch.Tensor) -> None:
    """s.target_lane at the flat (env * N + vehicle) indices `flat` (E,) becomes `target` (E,); static form
    (sel (E,) bool): only where sel (padding slots repeat index N - 1 and write to a scratch element past
    the end instead)."""
    if sel is None:
        s.target_lane.view(-1).index_copy_(0, flat, target)
        return
    dest = torch.where(sel, flat, s.target_lane.numel())
    out = torch.cat([s.target_lane.view(-1), s.target_lane.new_zeros(1)])
    out.index_copy_(0, dest, target)  # the padding slots' values land in the scratch element
    s.target_lane.view(-1).copy_(out[:-1])


def mobil_lane_changes(s: WorldState, road: Road, tables: LaneTables, nb: Neighbours, accel: torch.Tensor,
                       static: bool = False) -> None:
    """MOBIL decisions (incentive + safety) of the SVs due to decide this step; mandatory merge/exit first.

    Only one vehicle in DECISION_PERIOD is due each step (a strided slice), and only those that may change
    at all (centred, lane-changing style or a ramp intent, fast enough) are evaluated, both directions at
    once. static: every decision slot is evaluated under the mask (see sim/selection.py).
    """
    b_envs, n = s.x.shape
    k_lanes = road.num_lanes
    idx, decide, lane, intent, on_ramp_merge = _deciders(s, road)
    bb, jj, sel = entries(decide, static)
    if none_left(bb, sel):
        return
    flat_j = flat_index(bb, jj, idx.shape[1])
    ii, lane1, intent1, merge1 = (take_flat(t, flat_j) for t in (idx, lane, intent, on_ramp_merge))
    flat1 = flat_index(bb, ii, n)
    # both directions at once: row 0 of the (2, M) candidates goes left (-1), row 1 right (+1); what does not
    # depend on the direction stays (M,) and broadcasts
    d = torch.tensor([[-1], [1]], device=lane1.device)
    x, v, v0, s0, alc, a_cur = (take_flat(t, flat1) for t in (s.x, s.v, s.v0, s.s0, s.lane_change, accel))
    to = lane1 + d
    ok = tables.can_change(x, lane1, to, v * LANE_CHANGE_TIME_S)
    ok &= (to < road.mainline_lanes) | (intent1 == EXIT_INTENT)  # only cars bound for the off-ramp enter it
    toc = to.clamp(0, k_lanes - 1)
    nl, nf = take_flat(nb.leader, toc * (b_envs * n) + flat1), nb.follower(toc, bb, ii)
    row = bb * (n + 1)
    nl_x, nl_v = take_flat(nb.x_pad, row + nl), take_flat(nb.v_pad, row + nl)
    g_front = nl_x - x - VEHICLE_LENGTH_M
    wall = tables.drop_end_m.take(toc) - x - 0.5 * VEHICLE_LENGTH_M
    use_wall = wall < g_front
    a_new = idm_accel_fast(idm_free_term(v, v0), v, s0, torch.minimum(wall, g_front), torch.where(use_wall, 0.0, nl_v))
    has_nf = nf < n
    nf_flat = bb * n + nf.clamp(max=n - 1)
    nf_x = torch.where(has_nf, take_flat(s.x, nf_flat), -FAR_M)
    nf_v, nf_v0, nf_s0 = take_flat(s.v, nf_flat), take_flat(s.v0, nf_flat), take_flat(s.s0, nf_flat)
    nf_free = idm_free_term(nf_v, nf_v0)
    g_back = x - nf_x - VEHICLE_LENGTH_M
    a_nf_new = idm_accel_fast(nf_free, nf_v, nf_s0, g_back, v)
    a_nf_old = idm_accel_fast(nf_free, nf_v, nf_s0, nl_x - nf_x - VEHICLE_LENGTH_M, nl_v)
    nf_limit = torch.where(nf == 0, -MOBIL_EGO_SAFE_BRAKE_MPS2, -MOBIL_SAFE_BRAKE_MPS2)
    safe = (g_front > MOBIL_MIN_GAP_M) & (g_back > MOBIL_MIN_GAP_M) & (a_new >= -MOBIL_SAFE_BRAKE_MPS2)
    safe &= ~has_nf | (a_nf_new >= nf_limit)
    gain = a_new - a_cur + MOBIL_POLITENESS * has_nf.float() * (a_nf_new - a_nf_old) - MOBIL_THRESHOLD_MPS2
    mandatory = (merge1 & (d < 0)) | ((intent1 == EXIT_INTENT) & (d > 0))
    against = (intent1 == EXIT_INTENT) & (d < 0)
    gain = gain + MANDATORY_BONUS_MPS2 * (mandatory.float() - against.float())
    gain = torch.where(ok & safe & (alc | mandatory) & (gain > 0), gain, -math.inf)
    left, right = gain[0], gain[1]
    best = torch.where(right > left, toc[1], toc[0])  # ties go left, as MOBIL prefers overtaking lanes
    change = torch.maximum(left, right) > -math.inf
    _write_targets(s, flat1, sel, torch.where(change, best, lane1))


