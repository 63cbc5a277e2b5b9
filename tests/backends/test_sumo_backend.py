"""The SUMO backend keeps our Backend contract (skipped without the sumo extra)."""

import pytest

pytest.importorskip("libsumo", reason="the sumo extra is not installed: pip install 'highway-srl[sumo]'")

import torch  # noqa: E402

from backend_contract import (  # noqa: E402
    check_merge_episode_succeeds,
    check_ramp_end,
    check_rear_end_collision,
    check_seeded_episode_reproduces,
    check_snapshot_invariants,
    seed_with_sv_ahead_in_ego_lane,
)
from highway_srl.backends import make_backend  # noqa: E402


def make(**kw):
    return make_backend("sumo", **kw)


@pytest.mark.parametrize("scenario", ["multi-lane", "exit"])
def test_snapshot_neighbours_are_nearest_in_their_lanes(scenario):
    check_snapshot_invariants(make, scenario, steps=150)


def test_snapshot_invariants_hold_on_the_merge():
    check_snapshot_invariants(make, "merge", steps=150, traffic="C", seed=0)


def test_driving_into_a_slower_car_is_a_collision_that_sumo_reports():
    check_rear_end_collision(make)
    # SUMO's own collision list names the ego (not only our box check): drive into the car ahead again
    b = make_backend("sumo", "two-lane", "C", seed=seed_with_sv_ahead_in_ego_lane(), style="normal", num_vehicles=1)
    for _ in range(160):
        if bool(b.step(b.ego_lane, torch.tensor([10.0])).collision[0]):
            break
    assert any("ego" in (c.collider, c.victim) for c in b.sumo.simulation.getCollisions())


def test_seeded_episode_reproduces():
    check_seeded_episode_reproduces(make)


def test_idm_driver_completes_a_merge():
    check_merge_episode_succeeds(make)


def test_ramp_end_is_a_standing_obstacle_and_running_into_it_a_collision():
    check_ramp_end(make)


def test_an_older_libsumo_backend_is_closed_when_a_new_one_starts():
    a = make_backend("sumo", "two-lane", "A", seed=0)
    make_backend("sumo", "two-lane", "A", seed=1)
    with pytest.raises(RuntimeError, match="one simulation per process"):
        a.step(torch.tensor([0]), torch.tensor([5.0]))
