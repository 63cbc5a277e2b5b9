"""Group 3's adversarial cut-ins: some SVs force their way into the ego's lane, each at most once."""

from __future__ import annotations

import pytest
import torch

from highway_srl.constants import DEFAULT_ADVERSARY, VEHICLE_LENGTH_M
from highway_srl.sim import World
from highway_srl.sim.adversary import ADVERSARIES, cut_ins_ahead_with_room, cut_ins_whatever_the_gaps
from sim_helpers import drive


def _watch(world: World, steps: int):
    """Per step: the forced flags and trigger flags after the step, and the state before it."""
    for _ in drive(world, 0):
        pass
    prev_forced = world.state.forced.clone()
    prev_state = world.state.clone()
    for t, events in drive(world, steps):
        yield prev_state, prev_forced, world.state.forced.clone(), world.state.trigger_used.clone(), events
        prev_state = world.state.clone()
        prev_forced = world.state.forced.clone()


def _check_cut_ins(world: World, steps: int) -> int:
    starts = torch.zeros(world.num_envs, world.num_vehicles, dtype=torch.long)
    total = 0
    for before, was_forced, forced, used, events in _watch(world, steps):
        new = forced & ~was_forced
        # (drive resets finished envs after yielding, so the flags seen here are this episode's)
        starts += new.long()
        total += int(new.sum())
        assert not bool(new[:, 0].any())
        assert bool((used | ~forced).all())  # a forced change was triggered
        b, i = new.nonzero(as_tuple=True)
        if b.numel():
            s = world.state
            # the cutter was in a lane next to the ego's, wholly ahead of the ego, and heads for its lane
            assert bool(((before.lane[b, i] - before.lane[b, 0]).abs() == 1).all())
            assert bool((before.x[b, i] - before.x[b, 0] >= VEHICLE_LENGTH_M).all())
            assert torch.equal(s.target_lane[b, i], before.lane[b, 0])
            # only SVs with an adversarial style
            assert bool((before.adversarial_prob[b, i] > 0).all())
        done = events.terminated | events.truncated
        starts[done] = 0
        assert bool((starts <= 1).all())
        assert int(events.sv_collisions.sum()) == 0  # a cut-in never lands on another SV
    return total


def test_adversarial_svs_cut_into_the_ego_lane_with_the_styles_probabilities():
    # (about 1.2 triggers per episode at level C, each firing with the SV's ABP of 1/9 or 1/27)
    world = World("two-lane", "C", adversarial=True, num_envs=96, seed=9, adversary="mild")  # ahead, with room
    assert _check_cut_ins(world, 320) >= 1


def test_every_triggered_sv_cuts_in_at_most_once_per_episode_when_abp_is_one():
    world = World("multi-lane", "C", adversarial=True, num_envs=32, seed=4, adversary="mild")
    s = world.state
    s.adversarial_prob[:, 1:] = 1.0  # every style attacks, every trigger fires (this episode)
    total = _check_cut_ins(world, 300)
    assert total >= 20
    assert bool((world.state.forced <= world.state.trigger_used).all())


def test_nominal_traffic_never_forces_a_lane_change():
    world = World("two-lane", "C", adversarial=False, num_envs=32, seed=9)
    for _, _, forced, used, _ in _watch(world, 320):
        assert not bool(forced.any())
        assert not bool(used.any())


def test_kinematic_safe_distance_golden_values():
    from highway_srl.sim.adversary import kinematic_safe_distance

    v_ego = torch.tensor([8.0, 0.0, 10.0])
    v_sv = torch.tensor([6.0, 5.0, 10.0])
    # 8 * 0.125 + 64 / 12 - 36 / 12 = 3.3333; a standing ego needs none; equal speeds: one step of reaction
    expected = torch.tensor([1.0 + 64 / 12 - 3.0, 0.0, 1.25])
    assert torch.allclose(kinematic_safe_distance(v_ego, v_sv), expected, atol=1e-5)


def test_the_adversaries_are_chosen_by_their_user_facing_names():
    # the names World, the CLI and the configs take; a world refuses any other in one line naming them
    assert ADVERSARIES == {"mild": cut_ins_ahead_with_room, "paper": cut_ins_whatever_the_gaps}
    with pytest.raises(ValueError, match="unknown adversary 'evil'; choose one of mild, paper"):
        World(adversary="evil")
    # one default in one place: a World made without one runs every entry point's (constants.DEFAULT_ADVERSARY)
    assert World("two-lane", adversarial=True).adversary == DEFAULT_ADVERSARY
