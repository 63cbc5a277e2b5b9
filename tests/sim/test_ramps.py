"""On-ramp merging and off-ramp exiting: stage events, the lane-end wall and the change windows."""

from __future__ import annotations

import torch

from highway_srl.constants import DT_S, VEHICLE_LENGTH_M
from highway_srl.sim import World
from highway_srl.sim.road import EXIT_X, MERGE_X
from sim_helpers import clear_road, drive


def test_idm_ego_on_the_ramp_merges_into_the_stability_zone():
    world = World("merge", "A", num_envs=16, seed=2)
    assert bool((world.ego_lane == 2).all())
    successes = torch.zeros(16, dtype=torch.long)
    for _, events in drive(world, 320, reset=False):
        assert not bool(events.collision.any())
        assert not bool(events.terminated.any())  # merging is not terminal
        successes += events.success.long()
    merged = world.stage_flags().merged
    assert bool((successes <= 1).all())  # the success event fires once, when the stage is reached
    assert torch.equal(successes == 1, merged)
    assert float(merged.float().mean()) >= 0.75
    s = world.state
    assert bool((s.x[merged, 0] >= MERGE_X["x2"]).all() and (s.lane[merged, 0] < 2).all())


def test_driving_into_the_end_of_the_ramp_is_a_collision():
    world = World("merge", "A", num_envs=1, seed=0, num_vehicles=2)
    clear_road(world, 8.0)
    world.state.v[:, 0] = 8.0
    hit_at = None
    for t in range(200):
        x_before = float(world.state.x[0, 0])
        events = world.step(torch.tensor([2]), torch.tensor([8.0]))
        if bool(events.collision[0]):
            hit_at = float(world.state.x[0, 0])
            assert bool(events.terminated[0])
            break
    assert hit_at is not None
    assert hit_at + 0.5 * VEHICLE_LENGTH_M >= MERGE_X["x2"] > x_before + 0.5 * VEHICLE_LENGTH_M


def test_a_lane_change_off_the_ramp_before_the_merging_zone_is_refused():
    world = World("merge", "A", num_envs=1, seed=0, num_vehicles=2)
    clear_road(world, 8.0)
    world.step(torch.tensor([1]), torch.tensor([8.0]))  # x = 10 m: still behind the barrier
    assert int(world.state.target_lane[0, 0]) == 2


def _exit_run(turn_off: bool):
    world = World("exit", "A", num_envs=1, seed=0, num_vehicles=2)
    clear_road(world, 10.0)
    world.state.v[:, 0] = 10.0
    for t in range(320):
        x = float(world.state.x[0, 0])
        if not turn_off:
            want = 0
        elif x < EXIT_X["x1"]:
            want = 1  # to the lane beside the diverging zone
        elif x < EXIT_X["x2"] - 40.0:
            want = 2  # into the deceleration lane, early enough to be across before the gore
        else:
            want = int(world.ego_lane[0])
        events = world.step(torch.tensor([want]), torch.tensor([10.0]))
        assert not bool(events.collision[0])
        if bool(events.terminated[0]):
            return world, events, t
    raise AssertionError("the episode did not end")


def test_reaching_the_off_ramp_end_is_success():
    world, events, t = _exit_run(turn_off=True)
    assert bool(events.success[0]) and not bool(events.failure[0])
    assert int(world.ego_lane[0]) == 2 and float(world.state.x[0, 0]) >= EXIT_X["x3_suc"]
    flags = world.stage_flags()
    assert bool(flags.exit1[0]) and bool(flags.exit2[0])
    assert t * DT_S < 40.0


def test_staying_on_the_mainline_is_failure_at_its_continuation_end():
    world, events, _ = _exit_run(turn_off=False)
    assert bool(events.failure[0]) and not bool(events.success[0])
    assert int(world.ego_lane[0]) == 0 and float(world.state.x[0, 0]) >= EXIT_X["x3_fail"]
    assert not bool(world.stage_flags().exit2[0])


def test_the_off_ramp_cannot_be_entered_after_the_diverging_zone():
    world = World("exit", "A", num_envs=1, seed=0, num_vehicles=2)
    clear_road(world, 10.0)
    s = world.state
    s.x[:, 0] = EXIT_X["x2"] + 10.0
    s.lane[:, 0] = s.target_lane[:, 0] = 1
    s.y[:, 0] = 3.5
    world.step(torch.tensor([2]), torch.tensor([10.0]))
    assert int(world.state.target_lane[0, 0]) == 1


def test_idm_ego_takes_the_exit_in_light_traffic():
    world = World("exit", "A", num_envs=16, seed=4)
    success = torch.zeros(16, dtype=torch.bool)
    failure = torch.zeros(16, dtype=torch.bool)
    for _, events in drive(world, 320, reset=False):
        assert not bool(events.collision.any())
        success |= events.success
        failure |= events.failure
    assert not bool((success & failure).any())
    assert float(success.float().mean()) >= 0.5
