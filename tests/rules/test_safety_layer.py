"""SafetyLayer (Algorithm 1 lines 6-9 with §3.3) on hand-built worlds."""

import pytest
import torch

from highway_srl.rules import ACTIONS, SafetyLayer, choose_second, observation_ranges
from highway_srl.rules.reward_machine import U2, U3, U4
from highway_srl.rules.safe_actions import FASTER, IDLE, LANE_CHANGE, SLOWER
from highway_srl.sim.road import make_road
from highway_srl.sim.world import World

W = 3.5


def in_ranges(obs):
    lo, hi = observation_ranges().unbind(1)
    return bool(torch.isfinite(obs).all() and ((obs >= lo - 1e-5) & (obs <= hi + 1e-5)).all())


def test_close_slow_leader_allows_only_slower_and_lane_change_table1_row9(hand_world):
    # ego lane 0 at 10 m/s, SV1 8 m ahead (gap 3 m) at 5 m/s, nothing else: R* = (0, 1, 1, 1)
    world = hand_world(make_road("two-lane"), [{"ego": (0.0, 0.0, 10.0, 0.0), "svs": [(8.0, 0.0, 5.0, 0.0)]}])
    layer = SafetyLayer(world.road)
    step = layer.observe(world)
    p = step.primary
    assert p.r_star[0].tolist() == [False, True, True, True]
    assert dict(zip(ACTIONS, p.mask[0].tolist())) == {"Faster": False, "Idle": False, "Slower": True,
                                                     "LaneChange": True}
    assert p.vehicles.virtual[0].tolist() == [False, True, True, True]
    assert int(p.rm_state[0]) == U2 and float(p.r_rm[0]) == 0.0
    assert float(p.v_star[0]) == 5.0  # SV1 within d_ACC and a rule fails
    assert p.obs.shape == (1, 37) and in_ranges(p.obs)


def test_lane_change_sets_target_and_rm_enters_lane_change_mode(hand_world):
    world = hand_world(make_road("two-lane"), [{"ego": (0.0, 0.0, 10.0, 0.0), "svs": [(8.0, 0.0, 5.0, 0.0)]}])
    layer = SafetyLayer(world.road, profile="safe", hold_lane_change=False)  # safe: brake_while_changing
    layer.observe(world)
    lane, speed = layer.act(torch.tensor([LANE_CHANGE]))
    # R*_SV1 = 0: the ego changes lanes braking as Slower would (brake_while_changing, docs/paper-notes.md)
    assert lane.tolist() == [1] and speed.tolist() == [9.25]
    p = layer.observe(world).primary  # the ego has not moved: d_VL = 3.5 >= w_L/2, R1 false -> u4
    assert int(p.t_id[0]) == 1 and int(p.rm_state[0]) == U4
    # literal Eq. 34: Idle resets the target to the current lane (the change is aborted)
    lane, _ = layer.act(torch.tensor([IDLE]))
    assert lane.tolist() == [0]


def test_literal_lane_change_keeps_the_speed_when_brake_while_changing_is_off(hand_world):
    world = hand_world(make_road("two-lane"), [{"ego": (0.0, 0.0, 10.0, 0.0), "svs": [(8.0, 0.0, 5.0, 0.0)]}])
    layer = SafetyLayer(world.road, brake_while_changing=False)
    layer.observe(world)
    lane, speed = layer.act(torch.tensor([LANE_CHANGE]))
    assert lane.tolist() == [1] and speed.tolist() == [10.0]


def test_hold_lane_change_keeps_the_target_on_keep_actions(hand_world):
    world = hand_world(make_road("two-lane"), [{"ego": (0.0, 0.0, 8.0, 0.0), "svs": []}])
    layer = SafetyLayer(world.road, hold_lane_change=True)
    layer.observe(world)
    layer.act(torch.tensor([LANE_CHANGE]))
    p = layer.observe(world).primary
    assert int(p.rm_state[0]) == U3  # all rules hold (default vehicles), not aligned with the target
    lane, speed = layer.act(torch.tensor([FASTER]))
    assert lane.tolist() == [1] and abs(float(speed[0]) - 8.4375) < 1e-5


def test_multi_lane_middle_lane_gives_two_models_and_a_selector(hand_world):
    scenes = [{"ego": (0.0, W, 8.0, 0.0), "svs": [(30.0, 0.0, 6.0, 0.0), (-30.0, 2 * W, 6.0, 0.0)]},
              {"ego": (0.0, 0.0, 8.0, 0.0), "svs": []}]
    world = hand_world(make_road("multi-lane"), scenes)
    layer = SafetyLayer(world.road)
    step = layer.observe(world)
    assert step.two_models.tolist() == [True, False]
    a, b = step.primary, step.second
    assert a.lanes.c_id.tolist()[0] == 1 and b.lanes.c_id.tolist()[0] == 0
    assert b.lanes.adjacent_lane.tolist()[0] == 2
    assert float(a.vehicles.x[0, 1]) == 30.0 and float(b.vehicles.x[0, 3]) == -30.0  # SV2 in A, SV4 in B
    use_b = choose_second(torch.tensor([1.0, 1.0]), torch.tensor([2.0, 2.0]), step.two_models)
    assert use_b.tolist() == [True, False]
    lane, _ = layer.act(torch.tensor([LANE_CHANGE, LANE_CHANGE]), use_b)
    assert lane.tolist() == [2, 1]  # model B sends the middle-lane ego right; env 1 goes 0 -> 1
    # while the change is under way there is one model, the pair holding the target
    step = layer.observe(world)
    assert step.two_models.tolist() == [False, False] and step.primary.lanes.base_lane.tolist() == [1, 0]


def test_merge_on_ramp_uses_default_adjacent_vehicles_and_cannot_change_lanes(hand_world):
    road = make_road("merge")
    scenes = [{"ego": (30.0, 2 * W, 8.0, 0.0), "svs": [(35.0, W, 8.0, 0.0)]},  # on-ramp, SV beyond the barrier
              {"ego": (100.0, 2 * W, 8.0, 0.0), "svs": [(105.0, W, 8.0, 0.0)]}]  # merging zone
    world = hand_world(road, scenes)
    layer = SafetyLayer(road)
    p = layer.observe(world).primary
    assert ([2, 2], [-1, 1]) in world.queries  # the pair's query (the third lane is asked too)
    assert p.vehicles.virtual[0].tolist() == [True, True, True, True]
    assert p.vehicles.virtual[1].tolist() == [True, False, True, True]
    assert p.r_star[1, 1].item() is False  # SV2 overlaps the ego longitudinally
    assert p.lanes.c_id.tolist() == [1, 1] and p.lanes.base_lane.tolist() == [1, 1]
    lane, _ = layer.act(torch.tensor([LANE_CHANGE, SLOWER]))
    assert lane.tolist() == [2, 2]  # the barrier keeps the on-ramp ego in its lane


def test_exit_diverging_zone_and_off_ramp_queries(hand_world):
    road = make_road("exit")
    diverging, off_ramp = sum(road.zones["diverging"]) / 2, sum(road.zones["off_ramp"]) / 2
    scenes = [{"ego": (diverging, W, 8.0, 0.0), "svs": []}, {"ego": (off_ramp, 2 * W, 8.0, 0.0), "svs": []}]
    world = hand_world(road, scenes)
    layer = SafetyLayer(road)
    p = layer.observe(world).primary
    assert ([1, 2], [2, -1]) in world.queries  # the pair's query (the third lane is asked too)
    assert p.lanes.c_id.tolist() == [0, 1] and p.lanes.default_adjacent.tolist() == [False, True]
    lane, _ = layer.act(torch.tensor([LANE_CHANGE, LANE_CHANGE]))
    assert lane.tolist() == [2, 2]  # diverging zone: to the off-ramp; off-ramp: no way back


def test_batched_step_equals_one_env_at_a_time(hand_world):
    road = make_road("two-lane")
    scenes = [
        {"ego": (0.0, 0.0, 10.0, 0.0), "svs": [(8.0, 0.0, 5.0, 0.0), (20.0, W, 9.0, 0.0)]},
        {"ego": (50.0, 1.2, 6.0, 0.1), "svs": [(47.0, W, 9.0, 0.0), (80.0, 0.0, 3.0, 0.0)]},
        {"ego": (10.0, W, 3.0, 0.0), "svs": [(0.0, W, 9.0, 0.0), (12.0, 1.6, 4.0, -0.1)]},
    ]
    batch = SafetyLayer(road).observe(hand_world(road, scenes))
    actions = torch.tensor([LANE_CHANGE, IDLE, FASTER])
    layer = SafetyLayer(road)
    layer.observe(hand_world(road, scenes))
    lanes, speeds = layer.act(actions)
    for b, scene in enumerate(scenes):
        one_layer = SafetyLayer(road)
        one = one_layer.observe(hand_world(road, [scene])).primary
        assert torch.allclose(one.obs[0], batch.primary.obs[b], atol=1e-6)
        assert torch.equal(one.mask[0], batch.primary.mask[b])
        assert int(one.rm_state[0]) == int(batch.primary.rm_state[b])
        lane, speed = one_layer.act(actions[b:b + 1])
        assert int(lane[0]) == int(lanes[b]) and float(speed[0]) == pytest.approx(float(speeds[b]))


def test_reset_forgets_the_target_of_reset_envs_only(hand_world):
    road = make_road("two-lane")
    world = hand_world(road, [{"ego": (0.0, 0.0, 8.0, 0.0), "svs": []}] * 2)
    layer = SafetyLayer(road, hold_lane_change=True)
    layer.observe(world)
    layer.act(torch.tensor([LANE_CHANGE, LANE_CHANGE]))
    layer.reset(torch.tensor([True, False]))
    step = layer.observe(world)
    assert step.primary.t_id.tolist() == [0, 1]


def test_act_before_observe_is_an_error():
    with pytest.raises(RuntimeError, match="observe"):
        SafetyLayer(make_road("two-lane")).act(torch.tensor([0]))


def test_a_lane_change_is_started_only_if_it_ends_before_the_window_closes(hand_world):
    """Control mapping (Eq. 34) with the road's change window: near the exit's gore (x2) a LaneChange
    keeps the lane unless the change can end in time (the remaining-distance scaling: the next test)."""
    road = make_road("exit")
    x1, x2 = road.zones["diverging"]
    # the change may run 3 s with Faster at every step: from 8 m/s, 0.57 s to the 10 m/s limit then 2.43 s at
    # it, 29.4 m (+1); from 2 m/s 20.9 m (+1); from a standstill 15.7 m (+1), where speed x 3 s says 0
    scenes = [{"ego": (x1 + 10.0, W, 8.0, 0.0), "svs": []},  # plenty of room
              {"ego": (x2 - 15.0, W, 8.0, 0.0), "svs": []},  # 15 m left: no
              {"ego": (x2 - 25.0, W, 2.0, 0.0), "svs": []},  # slowly, 25 m left: yes
              {"ego": (x2 - 15.0, W, 0.0, 0.0), "svs": []}]  # standing 15 m before the gore: no
    world = hand_world(road, scenes)
    layer = SafetyLayer(road, profile="safe")  # the safe profile's finish_in_window
    layer.observe(world)
    lane, _ = layer.act(torch.tensor([LANE_CHANGE] * 4))
    assert lane.tolist() == [2, 1, 2, 1]
    literal = SafetyLayer(road, finish_in_window=False)
    literal.observe(world)
    assert literal.act(torch.tensor([LANE_CHANGE] * 4))[0].tolist() == [2, 2, 2, 2]


def test_change_fits_window_scales_with_the_lateral_distance_left():
    from highway_srl.rules.mappings import change_fits_window

    road = make_road("merge")
    _, end = road.zones["merging"]
    x = torch.full((4,), end - 13.0)
    y = torch.tensor([2 * W, 1.5 * W, 1.5 * W, 1.5 * W])  # on the ramp; half-way across
    speed = torch.tensor([0.0, 0.0, 5.0, 7.0])  # 3 s or 1.5 s of Faster: needs 15.7+1, 3.9+1, 11.4+1, 13.7+1 m
    fits = change_fits_window(road, torch.full((4,), 2), torch.full((4,), 1), x, y, speed)
    assert fits.tolist() == [False, True, True, False]


def test_change_run_golden_values():
    """change_run_m: accelerating at 3.5 m/s² to the 10 m/s limit, then at it (by hand)."""
    from highway_srl.rules.mappings import change_run_m

    run = change_run_m(torch.tensor([0.0, 8.0, 10.0, 2.0]), torch.tensor([3.0, 3.0, 3.0, 1.0]))
    t0 = 10 / 3.5  # from a standstill the limit comes after 2.857 s
    assert run.tolist() == pytest.approx([0.5 * 3.5 * t0 ** 2 + 10 * (3 - t0), 8 * (2 / 3.5) + 0.5 * 3.5 * (2 / 3.5) ** 2
                                          + 10 * (3 - 2 / 3.5), 30.0, 2 + 0.5 * 3.5], abs=1e-5)



@pytest.mark.parametrize("scenario", ["multi-lane", "merge"])
def test_static_form_gives_the_same_steps_and_controls_as_the_compact_one(scenario):
    """SafetyLayer.static (no host reads: the second model always computed, the neighbours always
    re-queried, no action check) changes nothing in what the layer computes."""
    gen = torch.Generator().manual_seed(3)
    worlds = [World(scenario, "C", num_envs=6, seed=11) for _ in range(2)]
    compact, static = SafetyLayer(worlds[0].road), SafetyLayer(worlds[1].road)
    static.static = True
    a, b = compact.observe(worlds[0]), static.observe(worlds[1])
    two_models_seen = False
    for _ in range(40):
        two_models_seen |= bool(a.two_models.any())
        use_second = torch.rand(6, generator=gen) < 0.5
        for name in ("obs", "mask", "r_rm", "r_star"):
            assert torch.equal(getattr(a.select(use_second), name), getattr(b.select(use_second), name)), name
        action = torch.randint(0, len(ACTIONS), (6,), generator=gen)
        (lane, speed), (lane_s, speed_s) = compact.act(action, use_second), static.act(action, use_second)
        assert torch.equal(lane, lane_s) and torch.equal(speed, speed_s)
        worlds[0].step(lane, speed)
        worlds[1].step(lane_s, speed_s)
        a, b = compact.observe(worlds[0]), static.observe(worlds[1])
    assert b.static and not a.static
    assert two_models_seen or scenario == "merge"  # multi-lane: the second model was in use
