"""Contacts and events of a step: SV-SV contacts, the ego's collisions (boxes, lane ends, change windows,
road edges) and the task's stage events (merge / exit flags, success, failure)."""

from __future__ import annotations

import torch

from highway_srl.scenarios import EXIT, MERGE
from highway_srl.sim.box_geometry import CONTACT_REACH_M, boxes_overlap, front_x_in_band, lateral_half_extent
from highway_srl.sim.lane_tables import LaneTables
from highway_srl.sim.road import Road
from highway_srl.sim.selection import take_flat
from highway_srl.sim.state import WorldState
from highway_srl.sim.sv_drivers import Neighbours

EDGE_TOLERANCE_M = 0.5  # how far the ego's side may reach past the road's outer edge before it is a collision


def sv_contacts(s: WorldState, near: torch.Tensor, leader: torch.Tensor, static: bool = False) -> torch.Tensor:
    """Distinct overlapping SV-SV pairs per env (B,) long.

    Two boxes that overlap share a point, which lies in some lane band that both footprints reach, so each
    is the other's nearest occupant of that band or has a vehicle between them in x there (which would
    then overlap one of them too). Checking every vehicle against its leader in each lane it occupies (at
    the start of the step, with a margin wider than a step's lateral travel) finds every contact. Only the
    pairs that were within CONTACT_GAP_M (bumper to bumper) at the start of the step can touch by its end;
    they go through the exact box test. static: test every (lane, vehicle) pair under the mask instead of
    listing the near ones (see sim/selection.py); the same count.
    """
    b, n = s.x.shape
    near[:, :, 0] = False
    if static:
        return _sv_contacts_static(s, near, leader)
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


def _sv_contacts_static(s: WorldState, near: torch.Tensor, leader: torch.Tensor) -> torch.Tensor:
    """sv_contacts over every (lane k, vehicle i) with its leader j: a pair (i, j) found in several lanes
    counts once, in the first lane it is found in (the compact form's torch.unique)."""
    n = s.x.shape[1]
    keep = near & (leader > 0) & (leader < n)
    j = leader.clamp(max=n - 1)
    g = lambda t: torch.gather(t.expand_as(j), 2, j)  # noqa: E731
    hit = keep & boxes_overlap(s.x, s.y, s.heading, g(s.x), g(s.y), g(s.heading))
    first = hit.clone()
    for k in range(1, hit.shape[0]):
        for q in range(k):
            first[k] &= ~(hit[q] & (leader[q] == leader[k]))
    return first.sum((0, 2))


def ego_collision(s: WorldState, road: Road, tables: LaneTables, nb: Neighbours, static: bool = False) -> torch.Tensor:
    """The ego overlaps an SV, runs into a lane end, or crosses a boundary it may not cross (B,) bool.

    Any SV the ego overlaps is its leader or follower (at the start of the step) in a lane both occupy,
    by the argument of sv_contacts, so only those 2K are tested."""
    b, n = s.x.shape
    envs, zero = torch.arange(b, device=s.x.device), torch.zeros(b, dtype=torch.long, device=s.x.device)
    lanes = torch.arange(road.num_lanes, device=s.x.device)[:, None].expand(road.num_lanes, b)
    j = torch.cat([nb.leader[:, :, 0], nb.follower(lanes, envs, zero)])  # (2K, B): lanes' leaders, followers
    # a missing neighbour (j = N) reads vehicle N - 1 and is masked out by j < n: no padded copies
    flat = envs * n + j.clamp(max=n - 1)
    xj, yj = take_flat(s.x, flat), take_flat(s.y, flat)
    near = ((xj - s.x[:, 0]).abs() < CONTACT_REACH_M) & ((yj - s.y[:, 0]).abs() < CONTACT_REACH_M) & (j < n)
    if static or s.x.device.type != "cpu":  # no host read: the dense test under the mask
        hit = (boxes_overlap(s.x[:, 0], s.y[:, 0], s.heading[:, 0], xj, yj, take_flat(s.heading, flat)) & near).any(0)
    elif not bool(near.any()):  # on the CPU a branch is free, and at small batches usually taken
        hit = torch.zeros_like(near[0])
    else:
        # the box test only for the pairs within reach (a few in a batch: contacts are rare); the same
        # formulas on the same values as the static form's dense test
        kk, bb = near.nonzero(as_tuple=True)
        ego, other = bb * n, take_flat(flat, kk * b + bb)
        pair = boxes_overlap(take_flat(s.x, ego), take_flat(s.y, ego), take_flat(s.heading, ego),
                             take_flat(s.x, other), take_flat(s.y, other), take_flat(s.heading, other))
        hit = torch.zeros_like(near[0]).index_fill_(0, bb[pair], True)
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
