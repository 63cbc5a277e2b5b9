"""What the backends share, testable without their simulators: the factory, the networks' layout, the
episode core against World, and the backend-agnostic driver. The contract checks also run on our World."""

import importlib.util

import numpy as np
import pytest
import torch

from backend_contract import check_merge_episode_succeeds, check_rear_end_collision, check_snapshot_invariants
from highway_srl.backends import BACKENDS, make_backend, missing_modules
from highway_srl.backends.bookkeeping import EpisodeCore, Frame
from highway_srl.backends.sumo_networks import edges_of, links_of
from highway_srl.constants import SCENARIOS
from highway_srl.sim.road import make_road
from highway_srl.sim.world import World


def make_ours(**kw):
    return make_backend("ours", **kw)


def test_make_backend_names_the_allowed_backends():
    with pytest.raises(ValueError, match="ours, sumo, highway-env"):
        make_backend("carla", "merge")


@pytest.mark.parametrize("name, extra", [("sumo", "sumo"), ("highway-env", "highway-env")])
def test_make_backend_names_the_missing_pip_extra(monkeypatch, name, extra):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda m, *a: None if m in ("libsumo", "highway_env") else real(m, *a))
    assert missing_modules(name)
    with pytest.raises(ValueError, match=rf"pip install 'highway-srl\[{extra}\]'"):
        make_backend(name, "merge")


def test_make_backend_ours_is_a_one_env_world():
    b = make_backend("ours", "exit", "B", adversarial=True, seed=3)
    assert isinstance(b, World) and b.num_envs == 1 and b.adversarial and set(BACKENDS) >= {"sumo", "highway-env"}


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_sumo_networks_have_our_lanes_where_our_road_has_them(scenario):
    road = make_road(scenario)
    edges = edges_of(scenario)
    for lane in range(road.num_lanes):
        covered = sorted((e.x_from, e.x_to) for e in edges if e.first_lane <= lane < e.first_lane + e.lanes)
        start, end = road.lane_start_m[lane], road.lane_end_m[lane]
        assert covered[0][0] <= max(start, -300.0) and covered[-1][1] >= min(end, 1000.0)
        for (_, a_to), (b_from, _) in zip(covered, covered[1:]):
            assert a_to == b_from  # no gaps
        if road.lane_drop[lane]:
            assert covered[-1][1] == end and not any(fe for fe, fl, _, _ in links_of(scenario)
                                                      if fl == lane and fe == edges[[e.x_to for e in edges].index(end)].id)
    # the change windows are where two lanes share an edge
    for k, (lo, hi) in enumerate(road.change_window_m):
        shared = [e for e in edges if e.first_lane <= k and k + 1 < e.first_lane + e.lanes]
        assert min(e.x_from for e in shared) <= max(lo, -300.0) and max(e.x_to for e in shared) >= min(hi, 1000.0)


def test_episode_core_spawns_what_world_spawns():
    w = World("merge", "C", seed=7)
    core = EpisodeCore("merge", "C", False, 7)
    np.testing.assert_allclose(core.initial["x"], w.state.x[0].numpy(), atol=1e-5)
    np.testing.assert_array_equal(core.initial["lane"], w.state.lane[0].numpy())
    np.testing.assert_allclose(core.initial["v"], w.state.v[0].numpy(), atol=1e-6)


def test_episode_core_snapshot_is_world_neighbours_on_the_same_state():
    w = World("merge", "C", seed=2)
    for _ in range(60):
        w.step(w.ego_lane, torch.tensor([7.0]))
    s = w.state
    core = EpisodeCore("merge", "C", False, 2)
    a = lambda t: t[0].numpy().astype(float)  # noqa: E731
    frame = Frame(a(s.x), a(s.y), a(s.v), a(s.heading), s.lane[0].numpy().copy(), s.target_lane[0].numpy().copy(),
                  np.ones(s.x.shape[1], bool))
    for adj in (1, -1):
        got = core.snapshot(frame, w.ego_lane, torch.tensor([adj]))
        want = w.neighbours(w.ego_lane, torch.tensor([adj]))
        for name, value in vars(want).items():
            torch.testing.assert_close(getattr(got, name), value, msg=name)


def test_episode_core_finds_the_collisions_world_finds():
    w = World("two-lane", "C", seed=0)
    for _ in range(200):
        ev = w.step(w.ego_lane, torch.tensor([10.0]))
        s = w.state
        core = EpisodeCore("two-lane", "C", False, 0)
        a = lambda t: t[0].numpy().astype(float)  # noqa: E731
        frame = Frame(a(s.x), a(s.y), a(s.v), a(s.heading), s.lane[0].numpy().copy(), s.target_lane[0].numpy().copy(),
                      np.ones(s.x.shape[1], bool))
        core.ego_target_lane = int(s.target_lane[0, 0])
        assert core.ego_collision(frame) == bool(ev.collision[0])
        if bool(ev.collision[0]):
            return
    pytest.fail("driving at the limit in level C should hit somebody within 200 steps")


def test_contract_checks_hold_for_our_world():
    check_snapshot_invariants(make_ours, "merge", steps=120, traffic="C", seed=0)
    check_rear_end_collision(make_ours)
    check_merge_episode_succeeds(make_ours)
