"""The built-in ego drivers' one gap rule (sim/ego_driver.room_to_change): golden values, and the World driver,
the backends' driver and the rule-based method all change lanes exactly when it gives room."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch

from highway_srl.agents.rule_based import NO_WISH, lane_change_wish
from highway_srl.constants import VEHICLE_LENGTH_M
from highway_srl.sim import World
from highway_srl.sim.ego_driver import CLOSING_TIME_S, HEADWAY_S, MIN_GAP_M, idm_ego, idm_ego_backend, room_to_change
from highway_srl.sim.road import MERGE_X
from sim_helpers import clear_road

INF = float("inf")


def test_gap_rule_golden_values():
    t = lambda *v: torch.tensor(v)  # noqa: E731
    assert (MIN_GAP_M, HEADWAY_S, CLOSING_TIME_S) == (2.0, 0.5, 2.5)
    # ego 10 m/s behind a car at 8 m/s: 2 + 0.5 x 10 + 2.5 x 2 = 12 m ahead; nobody behind
    assert room_to_change(t(12.01, 11.99), t(8.0, 8.0), t(INF, INF), t(0.0, 0.0), t(10.0, 10.0)).tolist() == [True, False]
    # a faster car ahead adds no closing term: 2 + 0.5 x 10 = 7 m
    assert room_to_change(t(7.01, 6.99), t(15.0, 15.0), t(INF, INF), t(0.0, 0.0), t(10.0, 10.0)).tolist() == [True, False]
    # the car behind at 12 m/s closes on an ego at 10 m/s: 2 + 0.5 x 12 + 2.5 x 2 = 13 m behind
    assert room_to_change(t(INF, INF), t(0.0, 0.0), t(13.01, 12.99), t(12.0, 12.0), t(10.0, 10.0)).tolist() == [True, False]
    # a standing ego, nobody anywhere: room; both sides must have it
    assert room_to_change(t(INF, 2.5, INF), t(0.0, 0.0, 0.0), t(INF, INF, 1.0), t(0.0, 0.0, 0.0), t(0.0, 0.0, 0.0)).tolist() == [True, True, False]


EGO_V, SV_V = 6.0, 10.0
NEED_BEHIND_M = MIN_GAP_M + HEADWAY_S * SV_V + CLOSING_TIME_S * (SV_V - EGO_V)  # 17 m


def _ego_on_the_ramp_with_a_car_behind_in_lane_1(gap_m: float) -> World:
    """The merge's ego centred on the on-ramp inside the merging zone at 6 m/s; SV 1 in the mainline's
    right lane, gap_m behind it at 10 m/s; SV 2 far behind on the ramp."""
    world = World("merge", "A", num_envs=1, seed=0, num_vehicles=2)
    clear_road(world, EGO_V)
    s, w = world.state, world.road.lane_width_m
    s.x[:, 0] = 0.5 * (MERGE_X["x1"] + MERGE_X["x2"])
    s.v[:, 0] = EGO_V
    s.x[:, 1] = s.x[:, 0] - VEHICLE_LENGTH_M - gap_m
    s.y[:, 1], s.lane[:, 1], s.target_lane[:, 1], s.v[:, 1] = w, 1, 1, SV_V
    s.order = torch.sort(s.x, dim=1, stable=True).indices
    return world


@pytest.mark.parametrize("gap_m, room", [(NEED_BEHIND_M + 0.2, True), (NEED_BEHIND_M - 0.2, False)])
def test_world_and_backend_drivers_merge_exactly_when_the_gap_rule_gives_room(gap_m, room):
    world = _ego_on_the_ramp_with_a_car_behind_in_lane_1(gap_m)
    assert int(world.ego_lane[0]) == 2
    for driver in (idm_ego, idm_ego_backend):
        lane, _ = driver(world)
        assert int(lane[0]) == (1 if room else 2), driver.__name__


@pytest.mark.parametrize("gap_m, room", [(NEED_BEHIND_M + 0.2, True), (NEED_BEHIND_M - 0.2, False)])
def test_rule_based_driver_wants_the_merge_exactly_when_the_gap_rule_gives_room(gap_m, room):
    # a two-lane model of the merge's ramp (C_ID 1) and mainline lane 1: SV4 (behind in lane 1) at gap_m,
    # SV1 / SV2 / SV3 the paper's virtual vehicles
    veh = SimpleNamespace(vx=torch.tensor([[15.0, 15.0, 0.0, SV_V]]), virtual=torch.tensor([[True, True, True, False]]))
    lanes = SimpleNamespace(adjacent_lane=torch.tensor([1]), current_lane=torch.tensor([2]), c_id=torch.tensor([1]))
    model = SimpleNamespace(lanes=lanes, vehicles=veh, gaps_m=torch.tensor([[55.0, 55.0, 55.0, gap_m]]),
                            m_l_ego=torch.tensor([False]), t_id=torch.tensor([1]))
    wish = lane_change_wish(model, torch.tensor([EGO_V]), "merge")
    assert float(wish[0]) == (INF if room else NO_WISH)
