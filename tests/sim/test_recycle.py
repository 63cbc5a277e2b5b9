"""The closed-loop flow keeps the traffic level's density around the ego for the whole episode."""

from __future__ import annotations

import pytest
import torch

from highway_srl.sim import World
from sim_helpers import drive

LEVELS = ["A", "C", "F"]


def _window_counts(scenario: str, traffic: str, steps: int = 320, envs: int = 8):
    world = World(scenario, traffic, num_envs=envs, seed=21)
    reach = world.layout.window_m + world.layout.margin_m
    inside, near = [], []
    lane_gaps = []
    for t, _ in drive(world, steps, reset=False):
        s = world.state
        dx = (s.x[:, 1:] - s.x[:, :1]).abs()
        inside.append((dx <= reach).sum(1))
        near.append((dx <= reach + 40.0).sum(1))
        if t % 40 == 39:
            for k in range(world.road.mainline_lanes):
                xs = torch.where(s.lane[:, 1:] == k, s.x[:, 1:], float("nan")).sort(1).values
                gaps = xs[:, 1:] - xs[:, :-1] - 5.0
                lane_gaps.append(gaps[torch.isfinite(gaps)])
    return world, torch.stack(inside), torch.stack(near), torch.cat(lane_gaps)


@pytest.mark.parametrize("scenario", ["two-lane", "merge"])
@pytest.mark.parametrize("traffic", LEVELS)
def test_vehicle_count_in_the_window_around_the_ego_stays_constant(scenario, traffic):
    world, inside, near, _ = _window_counts(scenario, traffic)
    m = world.num_vehicles - 1
    assert world.level.num_vehicles == m
    # every SV stays with the ego; one that left the window re-enters within a few steps
    assert bool((near == m).all())
    assert int(inside.min()) >= m - 4
    assert float((inside == m).float().mean()) > 0.9
    assert float(inside.float().mean()) > m - 0.25


def test_per_lane_spacing_follows_the_traffic_level():
    medians = {}
    for traffic in LEVELS:
        world, _, _, gaps = _window_counts("two-lane", traffic, steps=160)
        h_lo, h_hi = world.level.headway_m
        median = float(gaps.median())
        # bumper-to-bumper gaps between consecutive cars of a lane stay of the level's order
        assert 0.5 * h_lo <= median <= 2.0 * h_hi, (traffic, median)
        assert float(gaps.min()) > 0.0
        medians[traffic] = median
    assert medians["A"] > medians["C"] > medians["F"]
