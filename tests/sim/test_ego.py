"""The ego's low-level controller: braking distance and lane-change tracking."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from highway_srl.constants import DT_S, EGO_ACCEL_MAX_MPS2, EGO_BRAKE_MAX_MPS2, LANE_WIDTH_M
from highway_srl.sim import HOLD_LANE, World
from highway_srl.sim.dynamics import MIN_TURN_RADIUS_M, YAW_RATE_MAX
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


@pytest.mark.parametrize("speed", [1.0, 8.0])
def test_a_hold_stops_the_sideways_motion_where_the_ego_is(speed):
    """HOLD_LANE mid-change: the heading turns back to 0 no faster than the yaw-rate limit (v / R, at most
    YAW_RATE_MAX), the centre stays between the lanes (no snap to a lane centre), the target lane is the lane
    the centre is in (the traffic sees no change), and once aligned the ego drives straight on."""
    world = _ego_world(speed)
    s = world.state
    for _ in range(6 if speed > 4 else 12):  # part way into the change to lane 1
        world.step(torch.tensor([1]), torch.tensor([speed]))
    h0, y0 = float(s.heading[0, 0]), float(s.y[0, 0])
    assert h0 > 0.05 and 0.05 < y0 < LANE_WIDTH_M - 0.05
    hs, ys = [h0], [y0]
    for _ in range(40):
        world.step(torch.tensor([HOLD_LANE]), torch.tensor([speed]))
        hs.append(float(s.heading[0, 0]))
        ys.append(float(s.y[0, 0]))
        assert int(s.target_lane[0, 0]) == int(s.lane[0, 0]) == round(ys[-1] / LANE_WIDTH_M)
    yaw = min(speed / MIN_TURN_RADIUS_M, YAW_RATE_MAX)
    assert all(0.0 <= b <= a and a - b <= yaw * DT_S + 1e-6 for a, b in zip(hs, hs[1:]))
    assert hs[-1] == 0.0 and ys[-1] == ys[-2] == ys[-10]
    # it went on sideways only while the heading unwound: at most the arc of turning back at the yaw limit
    assert 0.0 <= ys[-1] - y0 <= speed * DT_S * sum(math.sin(h) for h in hs) + 1e-5
    assert 0.05 < ys[-1] < LANE_WIDTH_M - 0.05
    world.step(torch.tensor([0]), torch.tensor([speed]))  # a lane command again: tracking resumes
    assert float(s.heading[0, 0]) < 0.0


def test_a_hold_on_a_settled_ego_changes_nothing_sideways():
    world = _ego_world(8.0)
    s = world.state
    y0 = float(s.y[0, 0])
    for _ in range(5):
        world.step(torch.tensor([HOLD_LANE]), torch.tensor([8.0]))
    assert float(s.y[0, 0]) == y0 and float(s.heading[0, 0]) == 0.0 and int(s.target_lane[0, 0]) == int(s.lane[0, 0])
