"""The ego's low-level controller: braking distance and lane-change tracking."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from highway_srl.constants import DT_S, EGO_ACCEL_MAX_MPS2, EGO_BRAKE_MAX_MPS2, LANE_WIDTH_M
from highway_srl.sim import World
from highway_srl.sim.dynamics import YAW_RATE_MAX
from sim_helpers import clear_road


def _ego_world(speed: float, scenario: str = "two-lane", seed: int = 0) -> World:
    world = World(scenario, "A", num_envs=1, seed=seed, num_vehicles=2)
    clear_road(world, speed)
    world.state.v[:, 0] = speed
    return world


@settings(max_examples=25, deadline=None)
@given(v0=st.floats(0.5, 10.0))
def test_hard_brake_stops_within_kinematic_distance_plus_one_step(v0):
    world = _ego_world(v0)
    x0 = float(world.state.x[0, 0])
    lane = world.ego_lane
    for _ in range(40):
        world.step(lane, torch.zeros(1))
    s = world.state
    assert float(s.v[0, 0]) == 0.0
    travelled = float(s.x[0, 0]) - x0
    assert travelled <= v0**2 / (2 * EGO_BRAKE_MAX_MPS2) + v0 * DT_S + 1e-4


def test_speed_command_is_tracked_within_the_acceleration_limits():
    world = _ego_world(5.0)
    lane = world.ego_lane
    world.step(lane, torch.tensor([9.0]))  # Faster by more than one step allows
    assert float(world.state.v[0, 0]) == pytest.approx(5.0 + EGO_ACCEL_MAX_MPS2 * DT_S, abs=1e-5)
    world.step(lane, torch.tensor([0.0]))  # Slower by more than one step allows
    assert float(world.state.v[0, 0]) == pytest.approx(5.0 + (EGO_ACCEL_MAX_MPS2 - EGO_BRAKE_MAX_MPS2) * DT_S, abs=1e-5)
    world.step(lane, torch.tensor([4.5]))  # within reach: exact
    assert float(world.state.v[0, 0]) == pytest.approx(4.5, abs=1e-5)
    world.step(lane, torch.tensor([25.0]))  # never above v_max
    for _ in range(20):
        world.step(lane, torch.tensor([25.0]))
    assert float(world.state.v[0, 0]) == pytest.approx(10.0, abs=1e-5)


@pytest.mark.parametrize("speed", [8.0, 10.0])
@pytest.mark.parametrize("start_lane", [0, 1])
def test_lane_change_ends_centred_within_3_s_with_continuous_motion_and_no_overshoot(speed, start_lane):
    world = _ego_world(speed)
    s = world.state
    s.lane[:, 0] = start_lane
    s.target_lane[:, 0] = start_lane
    s.y[:, 0] = start_lane * LANE_WIDTH_M
    clear_road(world, speed)
    target = 1 - start_lane
    y_t = target * LANE_WIDTH_M
    sign = 1.0 if target > start_lane else -1.0
    ys, hs = [float(s.y[0, 0])], [float(s.heading[0, 0])]
    for _ in range(int(4.0 / DT_S)):
        events = world.step(torch.tensor([target]), torch.tensor([speed]))
        assert not bool(events.collision[0])
        ys.append(float(world.state.y[0, 0]))
        hs.append(float(world.state.heading[0, 0]))
    steps_3s = int(round(3.0 / DT_S))
    # within 3 s: centred and aligned, and it stays so
    assert all(abs(y - y_t) < 0.2 for y in ys[steps_3s:])
    assert all(abs(h) < 0.02 for h in hs[steps_3s:])
    # continuous: lateral motion bounded by the speed, heading by the yaw-rate limit; no overshoot
    for a, b in zip(ys, ys[1:]):
        assert abs(b - a) <= speed * DT_S * math.sin(0.3) + 1e-6
    for a, b in zip(hs, hs[1:]):
        assert abs(b - a) <= YAW_RATE_MAX * DT_S + 1e-6
    assert max(sign * (y - y_t) for y in ys) < 0.2
    # monotone approach: y never moves away from the target
    assert all(sign * (b - a) >= -1e-6 for a, b in zip(ys, ys[1:]))
    assert int(world.ego_lane[0]) == target


def test_standing_car_does_not_turn_or_move_sideways():
    world = _ego_world(0.0)
    lane = int(world.ego_lane[0])
    y0 = float(world.state.y[0, 0])
    for _ in range(10):
        world.step(torch.tensor([1 - lane]), torch.tensor([0.0]))
    assert float(world.state.y[0, 0]) == y0
    assert float(world.state.heading[0, 0]) == 0.0
