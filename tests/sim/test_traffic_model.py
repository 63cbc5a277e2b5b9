"""The traffic model is collision-free: IDM followers, MOBIL lane changes, recycling, with the built-in ego
driver. Every contact check is compared with an all-pairs brute force."""

from __future__ import annotations

import pytest
import torch

from highway_srl.constants import DT_S, SCENARIOS, SV_BRAKE_MAX_MPS2
from highway_srl.sim import World
from highway_srl.sim.sv_drivers import find_neighbours
from sim_helpers import brute_ego_overlap, brute_sv_contacts, drive, keep_lane


def _closest_followed_sv(world: World) -> torch.Tensor:
    """(B,) per env the SV ahead of the ego (so that it stays in the window while it stands) whose
    follower, an SV in its own lane, is nearest behind it."""
    s = world.state
    nb = find_neighbours(s, world.road)
    n = s.x.shape[1]
    b, i = torch.meshgrid(torch.arange(s.x.shape[0]), torch.arange(n), indexing="ij")
    foll = nb.follower(s.lane, b, i)  # own-lane follower (B, N), N = none
    foll_x = torch.gather(nb.x_pad, 1, foll)
    gap = torch.where((foll > 0) & (foll < n) & (s.x > s.x[:, :1]), s.x - foll_x, float("inf"))
    gap[:, 0] = float("inf")
    assert bool(torch.isfinite(gap.min(1).values).all())
    return gap.argmin(1)


def test_idm_follower_never_rear_ends_a_leader_braking_to_a_stop_at_full_force():
    world = World("two-lane", "C", num_envs=64, seed=3)
    for _ in drive(world, 40):
        pass
    s = world.state
    b = torch.arange(world.num_envs)
    leader = _closest_followed_sv(world)
    s.v0[b, leader] = 0.0  # its IDM now brakes as hard as it can, down to (almost) a stop
    s.lane_change[b, leader] = False
    v_before = s.v[b, leader].clone()
    steps = 0
    for t, events in drive(world, 80, reset=False):
        if t == 0:
            dv = v_before - world.state.v[b, leader]
            braking = v_before > SV_BRAKE_MAX_MPS2 * DT_S
            assert torch.allclose(dv[braking], torch.full_like(dv[braking], SV_BRAKE_MAX_MPS2 * DT_S))
        assert int(events.sv_collisions.sum()) == 0
        assert int(brute_sv_contacts(world).sum()) == 0
        steps += 1
    assert steps == 80
    # (with a desired speed of 0 IDM creeps at standstill: its free-road term is +a at v = 0)
    assert bool((world.state.v[b, leader] < 0.25).all())


@pytest.mark.parametrize("traffic", ["A", "C", "F"])
def test_idm_followers_never_rear_end_the_ego_braking_at_full_force(traffic):
    world = World("two-lane", traffic, num_envs=48, seed=11)
    for _ in drive(world, 60, reset=False):
        pass
    # cars close behind the ego at the moment it brakes
    s = world.state
    assert bool(((s.x[:, 1:] < s.x[:, :1]) & (s.x[:, :1] - s.x[:, 1:] < 25.0)).any())
    for _, events in drive(world, 60, driver=keep_lane(0.0), reset=False):
        assert not bool(events.collision.any())
        assert int(events.sv_collisions.sum()) == 0
    assert bool((world.state.v[:, 0] == 0).all())


@pytest.mark.parametrize("traffic", ["A", "C", "F"])
@pytest.mark.parametrize("scenario", SCENARIOS)
def test_nominal_traffic_has_no_sv_contacts_and_the_idm_ego_does_not_crash(scenario, traffic):
    # (a regression guard; offline, 200 envs x 320 steps of every scenario x level, nominal and adversarial,
    # gave no SV-SV contact either, see docs/paper-notes.md)
    world = World(scenario, traffic, num_envs=8, seed=100)
    sv_contacts = brute_contacts = ego_crashes = episodes = 0
    for t, events in drive(world, 320):
        sv_contacts += int(events.sv_collisions.sum())
        brute_contacts += int(brute_sv_contacts(world).sum())
        ego_crashes += int(events.collision.sum())
        assert bool((brute_ego_overlap(world) <= events.collision).all())  # every overlap is reported
        episodes += int((events.terminated | events.truncated).sum())
    assert episodes >= 8
    assert sv_contacts == 0
    assert brute_contacts == 0
    assert ego_crashes == 0
