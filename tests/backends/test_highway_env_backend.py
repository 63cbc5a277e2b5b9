"""The highway-env backend keeps our Backend contract (skipped without the highway-env extra)."""

import pytest

pytest.importorskip("highway_env", reason="the highway-env extra is not installed: pip install 'highway-srl[highway-env]'")

import torch  # noqa: E402

from backend_contract import (  # noqa: E402
    check_merge_episode_succeeds,
    check_ramp_end,
    check_rear_end_collision,
    check_seeded_episode_reproduces,
    check_snapshot_invariants,
)
from highway_srl.backends import make_backend  # noqa: E402


def make(**kw):
    return make_backend("highway-env", **kw)


@pytest.mark.parametrize("scenario", ["multi-lane", "exit"])
def test_snapshot_neighbours_are_nearest_in_their_lanes(scenario):
    check_snapshot_invariants(make, scenario, steps=150)


def test_snapshot_invariants_hold_on_the_merge():
    check_snapshot_invariants(make, "merge", steps=150, traffic="C", seed=0)



def test_driving_into_a_slower_car_is_a_collision_that_highway_env_reports():
    check_rear_end_collision(make)


def test_seeded_episode_reproduces():
    check_seeded_episode_reproduces(make)


def test_idm_driver_completes_a_merge():
    check_merge_episode_succeeds(make)


def test_ramp_end_is_a_standing_obstacle_and_running_into_it_a_collision():
    check_ramp_end(make, tolerance_m=0.5)  # highway-env's frames may stop it a little before the lane end


def test_ego_follows_the_paper_speed_command_within_one_step():
    b = make(scenario="two-lane", traffic="A", seed=0)
    v = float(b.ego_speed[0])
    b.step(b.ego_lane, torch.tensor([v + 0.3]))
    assert abs(float(b.ego_speed[0]) - (v + 0.3)) < 0.05
