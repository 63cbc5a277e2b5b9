"""hold_lateral's body-swing guard (rules.body_swing): box separations by hand, the predicted pose against the
simulator's own step, and the guard holding an ego whose corner would swing into a car beside it."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from highway_srl.constants import LANE_WIDTH_M, VEHICLE_LENGTH_M, VEHICLE_WIDTH_M
from highway_srl.rules.avoidable import LAT_MARGIN_M
from highway_srl.rules.body_swing import NearCars, next_pose, swing_guard
from highway_srl.sim import HOLD_LANE, World
from highway_srl.sim.box_geometry import boxes_overlap, boxes_separation

L, B = VEHICLE_LENGTH_M, VEHICLE_WIDTH_M


def _t(*v):
    return torch.tensor(v, dtype=torch.float32)


@pytest.mark.parametrize("b, expected", [
    ((0.0, B + 0.3, 0.0), 0.3),  # side by side, flanks 0.3 m apart
    ((L + 0.5, 0.0, 0.0), 0.5),  # nose to tail
    ((L + 0.3, B + 0.4, 0.0), 0.4),  # corner to corner: the larger axis gap, 0.4 (the distance is 0.5)
    ((0.0, 1.0 + 0.5 * L + 0.2, math.pi / 2), 0.2),  # crosswise: its short side 0.2 m from the flank
    ((0.0, 0.5 * B + 0.5 * L * math.sin(0.5) + 0.5 * B * math.cos(0.5) + 0.2, 0.5), 0.2),
])
def test_boxes_separation_golden(b, expected):
    """L x B = 5 x 2 m boxes; the ego's at the origin, heading 0. The last: a car turned 0.5 rad above the
    ego's flank, its lowest corner L/2 sin h + B/2 cos h below its centre and 0.2 m above the flank (at x =
    -L/2 cos h + B/2 sin h, over the ego's side: the distance is 0.2 too)."""
    d = boxes_separation(_t(0.0), _t(0.0), _t(0.0), _t(b[0]), _t(b[1]), _t(b[2]))
    assert float(d) == pytest.approx(expected, abs=1e-5)
    assert float(boxes_separation(_t(b[0]), _t(b[1]), _t(b[2]), _t(0.0), _t(0.0), _t(0.0))) == pytest.approx(
        expected, abs=1e-5)  # symmetric


@settings(max_examples=200, deadline=None)
@given(x=st.floats(-8, 8), y=st.floats(-5, 5), h=st.floats(-1.6, 1.6))
def test_boxes_separation_is_positive_exactly_where_the_boxes_are_apart_and_never_above_their_distance(x, y, h):
    """> 0 iff boxes_overlap says apart; and no larger than the distance between any corner of one box and
    any point of the other's boundary (sampled)."""
    zero = _t(0.0)
    d = float(boxes_separation(zero, zero, zero, _t(x), _t(y), _t(h)))
    assert (d > 1e-6) <= (not bool(boxes_overlap(zero, zero, zero, _t(x), _t(y), _t(h))))
    assert (d < -1e-6) <= bool(boxes_overlap(zero, zero, zero, _t(x), _t(y), _t(h)))
    if d > 0:
        u = torch.linspace(-0.5, 0.5, 41)
        edge = torch.cat([torch.stack([u * L, torch.full_like(u, s * 0.5 * B)], 1) for s in (-1, 1)]
                         + [torch.stack([torch.full_like(u, s * 0.5 * L), u * B], 1) for s in (-1, 1)])
        c, s_ = math.cos(h), math.sin(h)
        other = torch.stack([x + edge[:, 0] * c - edge[:, 1] * s_, y + edge[:, 0] * s_ + edge[:, 1] * c], 1)
        assert d <= float(torch.cdist(edge, other).min()) + 1e-4


def _ego_pose(s) -> SimpleNamespace:
    v, h = s.v[:, 0], s.heading[:, 0]
    return SimpleNamespace(ego_x=s.x[:, 0].clone(), ego_y=s.y[:, 0].clone(), ego_heading=h.clone(),
                           ego_vx=v * torch.cos(h), ego_vy=v * torch.sin(h))


@pytest.mark.parametrize("speed", [1.0, 8.0])
@pytest.mark.parametrize("command", [0, 1, HOLD_LANE])
def test_the_predicted_pose_is_the_simulators_next_pose(speed, command):
    """Mid-change from lane 0 to lane 1, the pose next_pose predicts for a command is where the world's step
    puts the ego (the guard judges the move the simulator will make)."""
    world = World("two-lane", "A", num_envs=1, seed=0, num_vehicles=2)
    s = world.state
    s.x[:, 1:] = s.x[:, :1] - 80.0  # the SV out of the way
    s.v[:, 0] = speed
    for _ in range(6 if speed > 4 else 12):
        world.step(torch.tensor([1]), torch.tensor([speed]))
    snap = _ego_pose(s)
    target = torch.tensor([speed * 0.5])
    x, y, h = next_pose(snap, torch.tensor([command]), target, LANE_WIDTH_M)
    world.step(torch.tensor([command]), target)
    for got, want in ((x, s.x), (y, s.y), (h, s.heading)):
        assert float(got[0]) == pytest.approx(float(want[0, 0]), abs=1e-5)


def _beside_behind(gap: float) -> NearCars:
    """A car standing in lane 0 behind-beside an ego centred in lane 1: its nose 1.5 m past the ego's tail,
    its left flank `gap` m below the ego's right flank."""
    return NearCars(_t(-0.5 * L - 0.5 * L + 1.5)[None], _t(LANE_WIDTH_M - B - gap)[None], _t(0.0)[None],
                    torch.tensor([[True]]))


def _slow_ego() -> SimpleNamespace:
    return SimpleNamespace(ego_x=_t(0.0), ego_y=_t(LANE_WIDTH_M), ego_heading=_t(0.0), ego_vx=_t(1.0),
                           ego_vy=_t(0.0))


def test_a_move_that_swings_the_tail_into_a_car_within_the_margin_holds():
    """Turning left toward lane 2 at 1 m/s turns the body about its centre: the right rear corner swings down
    toward the car 6 cm from its flank. Holding the lateral position keeps the 6 cm; the move is refused."""
    cars = _beside_behind(0.06)
    lane = swing_guard(_slow_ego(), cars, torch.tensor([2]), _t(1.0), LANE_WIDTH_M)
    assert int(lane) == HOLD_LANE
    held = next_pose(_slow_ego(), torch.tensor([HOLD_LANE]), _t(1.0), LANE_WIDTH_M)
    moved = next_pose(_slow_ego(), torch.tensor([2]), _t(1.0), LANE_WIDTH_M)
    assert float(moved[2]) > 0.0 and float(held[2]) == 0.0


def test_a_car_beyond_the_margin_or_a_move_away_from_it_leaves_the_command():
    ego = _slow_ego()
    assert int(swing_guard(ego, _beside_behind(LAT_MARGIN_M + 0.5), torch.tensor([2]), _t(1.0), LANE_WIDTH_M)) == 2
    # keeping the lane (no turn) is no swing: the command stays, however near the car
    assert int(swing_guard(ego, _beside_behind(0.06), torch.tensor([1]), _t(1.0), LANE_WIDTH_M)) == 1
    # an invalid slot (a default virtual vehicle) is no car
    cars = _beside_behind(0.06)
    cars.valid[:] = False
    assert int(swing_guard(ego, cars, torch.tensor([2]), _t(1.0), LANE_WIDTH_M)) == 2
