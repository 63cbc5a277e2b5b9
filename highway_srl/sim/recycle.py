"""Recycling: the closed loop of traffic around the ego (SVs that leave the window re-enter at its other end)."""

from __future__ import annotations

import math

import torch

from highway_srl.constants import D_MAX_M, VEHICLE_LENGTH_M, TrafficLevel
from highway_srl.sim import rng
from highway_srl.sim.box_geometry import lateral_half_extent
from highway_srl.sim.idm_mobil import occupancy
from highway_srl.sim.road import Road
from highway_srl.sim.spawn import EXIT_INTENT_PROB, Layout
from highway_srl.sim.state import EXIT_INTENT, NO_INTENT, WorldState

S_RECYCLE_LANE, S_RECYCLE_INTENT = 21, 23  # random streams (spawn uses 0-7, the adversary 20)


def _lane_queues(x, v, occ):
    """Each lane's occupants in x order (K, E, N): positions (inf past the last) and speeds (nan there);
    computed once for both ends' _entry_slots (the sort is most of their cost)."""
    xs = torch.where(occ, x.expand_as(occ), float("inf"))
    xs, idx = torch.sort(xs, dim=2)
    vs = torch.gather(v.expand_as(occ), 2, idx)
    return xs, torch.where(torch.isfinite(xs), vs, torch.nan)


def _entry_slots(xs, vs, lo, hi, need, from_edge_lo: bool):
    """Where one car can enter each lane inside [lo, hi] (all (E,) per env), keeping `need` (centre to
    centre) from every occupant (xs, vs: the lanes' queues, see _lane_queues): the free stretch nearest the
    edge lo (from_edge_lo) or hi, entered right at its edge side. Returns per lane (K, E): slot x, ok, and a
    speed that neither the car entering nor the one behind it has to brake for (between the follower's and
    leader's speeds).
    """
    k_lanes = xs.shape[0]
    lo_b, hi_b = (lo - need)[None, :, None], (hi + need)[None, :, None]
    # the stretches between consecutive occupants, and the zone's own ends as virtual occupants
    pts = torch.cat([lo_b.expand(k_lanes, -1, 1), torch.minimum(torch.maximum(xs, lo_b), hi_b), hi_b.expand(k_lanes, -1, 1)], 2)
    pv = torch.cat([torch.full_like(vs[..., :1], torch.nan), vs, torch.full_like(vs[..., :1], torch.nan)], 2)
    a, c = pts[..., :-1], pts[..., 1:]
    feasible = c - a >= 2 * need
    pos = torch.arange(a.shape[2], device=xs.device)
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


def _leavers(s: WorldState, road: Road, reach: float):
    """(B, N) bool each: beyond the window ahead, behind; leaving for the back end (ahead of the window, or
    off the map at the off-ramp's end), for the front end (behind it). The ego never leaves."""
    dx = s.x - s.x[:, :1]
    ahead_out, behind_out = dx > reach, dx < -reach
    to_back = ahead_out.clone()
    if road.spec.svs_may_exit:  # an SV at the off-ramp's end leaves the map
        to_back |= (s.lane == road.mainline_lanes) & (s.x >= road.zones["off_ramp"][1])
    to_back[:, 0] = False
    to_front = behind_out.clone()
    to_front[:, 0] = False
    return ahead_out, behind_out, to_back, to_front


def _choose_lane(entry, pick: torch.Tensor, nearest_edge: str):
    """The entry lane (E, 1) of one end: the randomly picked one (E,) if it has room, else the one whose
    slot is nearest the edge ("low" / "high"); and its slot, neighbour speeds and ok, each (E, 1).
    (Reduced over the lanes in entry's own (lanes, E) layout: an argmin across a transposed view is
    an order of magnitude slower.)"""
    slot, ok, v_behind, v_ahead = entry  # (lanes, E)
    fallback = torch.where(ok, slot, math.inf if nearest_edge == "low" else -math.inf)
    best = fallback.argmin(0) if nearest_edge == "low" else fallback.argmax(0)
    lane_k = torch.where(ok.gather(0, pick[None])[0], pick, best)[None]  # (1, E)
    g = lambda t: t.gather(0, lane_k).T  # noqa: E731
    return lane_k.T, g(slot), g(v_behind), g(v_ahead), g(ok)


def _entry_speed(v, v0, v_behind, v_ahead):
    """Its own speed v, but not slower than the car behind nor faster than the car ahead (nan: none);
    nobody ahead in the window: free road, at least its desired speed v0 (the head of a jam drives off)."""
    out = torch.where(torch.isnan(v_behind), v, torch.maximum(v, v_behind))
    return torch.where(torch.isnan(v_ahead), torch.maximum(out, v0), torch.minimum(out, v_ahead))


def _reentries(x, v, v0, occ, to_back, to_front, keys, road: Road, level: TrafficLevel, reach: float):
    """Where the leavers re-enter, for the envs given (all (E, N) but occ (lanes, E, N), keys (E,)):
    (moving bool, new lane, x, v), x and v unchanged for the others."""
    need = VEHICLE_LENGTH_M + level.headway_m[0]
    hide = D_MAX_M + VEHICLE_LENGTH_M
    ex = x[:, 0]
    edge = reach - need
    xs, vs = _lane_queues(x, v, occ)
    back = _entry_slots(xs, vs, ex - edge, ex - hide, need, from_edge_lo=True)
    front = _entry_slots(xs, vs, ex + hide, ex + edge, need, from_edge_lo=False)
    pick = rng.randint(keys, road.mainline_lanes, 2)  # (E, 2): preferred lane for the back and the front entry
    lb, xb, vb_behind, vb_ahead, okb = _choose_lane(back, pick[:, 0], "low")
    lf, xf, vf_behind, vf_ahead, okf = _choose_lane(front, pick[:, 1], "high")
    any_back, any_front = to_back.any(1, keepdim=True), to_front.any(1, keepdim=True)
    # an end without room sends its leaver to the other end, if that entry is not taken this step
    go_back = (to_back & okb) | (to_front & ~okf & okb & ~any_back)
    go_front = (to_front & okf) | (to_back & ~okb & okf & ~any_front)
    new_lane = torch.where(go_back, lb, lf)
    x = torch.where(go_back, xb, torch.where(go_front, xf, x))
    v = torch.where(go_back, _entry_speed(v, v0, vb_behind, vb_ahead),
                    torch.where(go_front, _entry_speed(v, v0, vf_behind, vf_ahead), v))
    return go_back | go_front, new_lane, x, v


def _fresh_intent(seed, episode, t, road: Road) -> torch.Tensor:
    """(E, 1) long: the intent of a car re-entering in each env (E,): in the exit scenario a drawn share
    exits, elsewhere none; (1, 1) NO_INTENT when nobody exits."""
    if road.spec.svs_may_exit:
        exits = rng.uniform(rng.key(seed, episode, t, S_RECYCLE_INTENT)) < EXIT_INTENT_PROB
        return torch.where(exits, EXIT_INTENT, NO_INTENT)[:, None]
    return torch.full((1, 1), NO_INTENT, device=seed.device)


def recycle(s: WorldState, road: Road, layout: Layout, level: TrafficLevel, static: bool = False) -> None:
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

    Eager, only the envs with a leaver are computed; static (no host read), every env is, and nothing
    moves in those without one (see sim/selection.py).
    """
    reach = layout.window_m + layout.margin_m
    ahead_out, behind_out, to_back, to_front = _leavers(s, road, reach)
    if static:
        envs = None
        sub = lambda t: t  # noqa: E731
    else:
        envs = (to_back | to_front).sum(1).nonzero().squeeze(1)  # sum: any(1) is 3x slower on the CPU
        if envs.numel() == 0:
            return
        sub = lambda t: t.index_select(0, envs)  # noqa: E731
    x, v, y, h, lane, tgt = sub(s.x), sub(s.v), sub(s.y), sub(s.heading), sub(s.lane), sub(s.target_lane)
    to_back, to_front = sub(to_back), sub(to_front)
    # one per end and env: the first flagged index
    to_back &= torch.cumsum(to_back.int(), 1) == 1
    to_front &= torch.cumsum(to_front.int(), 1) == 1
    inside = ~(sub(ahead_out) | sub(behind_out) | to_back)
    occ = occupancy(y, lateral_half_extent(h), lane, tgt, road.mainline_lanes, road.lane_width_m) & inside
    keys = rng.key(sub(s.seed), sub(s.episode), sub(s.t), S_RECYCLE_LANE)
    moving, new_lane, x, v = _reentries(x, v, sub(s.v0), occ, to_back, to_front, keys, road, level, reach)

    def put(name: str, value: torch.Tensor) -> None:
        t = getattr(s, name)
        if envs is None:
            t.copy_(value)
        else:
            t.index_copy_(0, envs, value)

    put("x", x)
    put("v", v)
    put("y", torch.where(moving, new_lane.float() * road.lane_width_m, y))
    put("heading", torch.where(moving, 0.0, h))
    put("lane", torch.where(moving, new_lane, lane))
    put("target_lane", torch.where(moving, new_lane, tgt))
    put("forced", sub(s.forced) & ~moving)
    put("intent", torch.where(moving, _fresh_intent(sub(s.seed), sub(s.episode), sub(s.t), road), sub(s.intent)))
