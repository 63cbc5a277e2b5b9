"""Neighbour queries against brute-force Python searches."""

from __future__ import annotations

import math
import random

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from highway_srl.constants import D_MAX_M, SCENARIOS, VEHICLE_LENGTH_M, VEHICLE_WIDTH_M
from highway_srl.sim import LANE_END, NO_VEHICLE, World
from highway_srl.sim.idm_mobil import (
    followers_of,
    inverse_order,
    lane_neighbours,
    neighbour_keys,
    sorted_order,
)
from sim_helpers import drive


def _in_lane(s, b, i, lane_q, road, by_body):
    """Vehicle i's lane is lane_q by its centre, or by_body: its rotated box reaches into the lane's strip."""
    if not by_body:
        return int(s.lane[b, i]) == lane_q
    h, y, w = float(s.heading[b, i]), float(s.y[b, i]), road.lane_width_m
    corners = [y + math.sin(h) * qx + math.cos(h) * qy
               for qx in (VEHICLE_LENGTH_M / 2, -VEHICLE_LENGTH_M / 2) for qy in (VEHICLE_WIDTH_M / 2, -VEHICLE_WIDTH_M / 2)]
    return max(corners) > (lane_q - 0.5) * w + 1e-6 and min(corners) < (lane_q + 0.5) * w - 1e-6


def _brute_slot(s, b, lane_q, front, d_max, road, by_body=False):
    """(kind, distance, candidates) of one neighbour slot: kind 'sv', 'end' or None."""
    ego_x = float(s.x[b, 0])
    best, cands = math.inf, []
    if lane_q >= 0:
        for i in range(1, s.x.shape[1]):
            dx = float(s.x[b, i]) - ego_x
            if not _in_lane(s, b, i, lane_q, road, by_body) or abs(dx) > d_max or (dx > 0) != front:
                continue
            if abs(dx) < best - 1e-9:
                best, cands = abs(dx), [i]
            elif abs(dx) <= best + 1e-9:
                cands.append(i)
    if front and 0 <= lane_q < road.num_lanes and road.lane_drop[lane_q]:
        wall_x = road.lane_end_m[lane_q] + 0.5 * VEHICLE_LENGTH_M
        if ego_x < wall_x <= ego_x + d_max and (not cands or wall_x < ego_x + best):
            return "end", wall_x - ego_x, []
    return ("sv" if cands else None), best, cands


@pytest.mark.parametrize("by_body", [False, True], ids=["by-centre", "by-body"])
@pytest.mark.parametrize("scenario", SCENARIOS)
def test_world_neighbours_match_a_brute_force_search(scenario, by_body):
    rnd = random.Random(scenario)
    world = World(scenario, "D", num_envs=16, seed=5)
    road = world.road
    for t, _ in drive(world, 120):
        if t % 20 != 19:
            continue
        s = world.state
        if scenario == "merge":  # some egos right before the lane end, to see it as an obstacle
            near_end = torch.arange(16) % 4 == 0
            s.x[near_end, 0] = torch.tensor([rnd.uniform(100.0, 165.0) for _ in range(int(near_end.sum()))])
        current = world.ego_lane.clone()
        adjacent = torch.tensor([rnd.choice([-1, int(c) - 1, int(c) + 1]) for c in current])
        adjacent = torch.where((adjacent >= 0) & (adjacent < road.num_lanes), adjacent, -1)
        d_max = rnd.choice([D_MAX_M, 30.0])
        snap = world.neighbours(current, adjacent, d_max, by_body=by_body)
        for b in range(16):
            slots = [(int(current[b]), True), (int(adjacent[b]), True), (int(current[b]), False), (int(adjacent[b]), False)]
            for k, (lane_q, front) in enumerate(slots):
                kind, dist, cands = _brute_slot(s, b, lane_q, front, d_max, road, by_body)
                valid, index = bool(snap.sv_valid[b, k]), int(snap.sv_index[b, k])
                if kind is None:
                    assert not valid and index == NO_VEHICLE
                    assert float(snap.sv_x[b, k]) == 0.0
                elif kind == "end":
                    assert valid and index == LANE_END
                    assert float(snap.sv_x[b, k]) - float(s.x[b, 0]) == pytest.approx(dist, abs=1e-4)
                    assert float(snap.sv_vx[b, k]) == 0.0
                else:
                    assert valid and index in cands
                    assert abs(float(snap.sv_x[b, k]) - float(s.x[b, 0])) == pytest.approx(dist, abs=1e-4)
                    assert float(snap.sv_y[b, k]) == float(s.y[b, index])
                    h, v = float(s.heading[b, index]), float(s.v[b, index])
                    assert float(snap.sv_vx[b, k]) == pytest.approx(v * math.cos(h), abs=1e-5)
                    assert float(snap.sv_vy[b, k]) == pytest.approx(v * math.sin(h), abs=1e-5)
        assert torch.equal(snap.ego_x, s.x[:, 0])
        assert torch.equal(snap.ego_lane, s.lane[:, 0])


@settings(max_examples=150, deadline=None)
@given(data=st.data(), n=st.integers(2, 20), k=st.integers(1, 3), b=st.integers(1, 3))
def test_lane_neighbours_are_the_nearest_occupants_in_stable_order(data, n, k, b):
    # positions from a small grid so that ties happen; ties are ordered by index
    x = torch.tensor(data.draw(st.lists(st.lists(st.integers(0, 6), min_size=n, max_size=n), min_size=b, max_size=b)),
                     dtype=torch.float32)
    occ = torch.tensor(data.draw(st.lists(st.lists(st.lists(st.booleans(), min_size=n, max_size=n), min_size=b,
                                                   max_size=b), min_size=k, max_size=k)))
    leader, follower = lane_neighbours(x, occ)
    for kk in range(k):
        for bb in range(b):
            key = lambda j: (float(x[bb, j]), j)  # noqa: E731
            for i in range(n):
                ahead = [j for j in range(n) if j != i and occ[kk, bb, j] and key(j) > key(i)]
                behind = [j for j in range(n) if j != i and occ[kk, bb, j] and key(j) < key(i)]
                assert int(leader[kk, bb, i]) == (min(ahead, key=key) if ahead else n)
                assert int(follower[kk, bb, i]) == (max(behind, key=key) if behind else n)
    # the step's own path: all leaders at once, followers on demand
    order = sorted_order(x)
    leaders_only, behind = neighbour_keys(occ, order)
    assert torch.equal(leaders_only, leader)
    kq, bq, iq = (t.reshape(-1) for t in torch.meshgrid(torch.arange(k), torch.arange(b), torch.arange(n), indexing="ij"))
    assert torch.equal(followers_of(behind, inverse_order(order), kq, bq, iq), follower.reshape(-1))


@settings(max_examples=100, deadline=None)
@given(data=st.data(), n=st.integers(2, 30))
def test_cached_sort_order_equals_a_fresh_stable_sort(data, n):
    x = torch.tensor(data.draw(st.lists(st.lists(st.integers(0, 10), min_size=n, max_size=n), min_size=4, max_size=4)),
                     dtype=torch.float32)
    stale = torch.stack([torch.randperm(n, generator=torch.Generator().manual_seed(data.draw(st.integers(0, 99))))
                         for _ in range(4)])
    stale[0] = torch.sort(x[0], stable=True).indices  # one env whose cached order still holds
    assert torch.equal(sorted_order(x, stale), torch.sort(x, dim=1, stable=True).indices)


def test_a_car_standing_across_the_line_is_in_both_lanes_by_body():
    """The falsifier's multi-lane D case: a car stopped mid-change at 0.6 rad, its centre in lane 1, its
    tail over the line into lane 0, behind a nearer car of lane 1. By centre the ego's lane 0 has no car
    ahead and lane 1's nearest is the other car; by body lane 0's nearest car ahead is the one across the line."""
    world = World("two-lane", "A", num_envs=1, seed=0, num_vehicles=3)
    s = world.state
    s.x[0, :3], s.y[0, :3], s.heading[0, :3] = torch.tensor([0.0, 20.0, 10.0]), torch.tensor([0.0, 2.27, 3.5]), \
        torch.tensor([0.0, 0.6, 0.0])
    s.lane[0, :3] = torch.tensor([0, 1, 1])
    s.x[0, 3:] = 1e4  # the others out of range
    lanes = (torch.tensor([0]), torch.tensor([1]))
    by_centre, by_body = world.neighbours(*lanes), world.neighbours(*lanes, by_body=True)
    assert by_centre.sv_index[0].tolist() == [NO_VEHICLE, 2, NO_VEHICLE, NO_VEHICLE]
    assert by_body.sv_index[0].tolist() == [1, 2, NO_VEHICLE, NO_VEHICLE]
    s.heading[0, 1], s.y[0, 1] = 0.0, 3.0  # straightened 1.25 m from the line: its body (1 m half-width) stays in lane 1
    assert world.neighbours(*lanes, by_body=True).sv_index[0].tolist() == [NO_VEHICLE, 2, NO_VEHICLE, NO_VEHICLE]
