"""Reproducibility: counter-based random numbers make an env's episodes a function of its seed alone."""

from __future__ import annotations

from dataclasses import fields

import pytest
import torch

from highway_srl.sim import World
from highway_srl.sim.ego_driver import idm_ego
from highway_srl.sim.state import WorldState


def _same(a: WorldState, b: WorldState, rows_a=slice(None), rows_b=slice(None)) -> bool:
    return all(torch.equal(getattr(a, f.name)[rows_a], getattr(b, f.name)[rows_b]) for f in fields(a))


def _step_all(worlds):
    out = []
    for w in worlds:
        lane, speed = idm_ego(w)
        out.append(w.step(lane, speed))
    return out


@pytest.mark.parametrize("scenario", ["two-lane", "merge"])
def test_the_same_seed_reproduces_a_trajectory_bit_for_bit(scenario):
    a = World(scenario, "C", adversarial=True, num_envs=6, seed=123)
    b = World(scenario, "C", adversarial=True, num_envs=6, seed=123)
    assert _same(a.state, b.state)
    for _ in range(200):
        ea, eb = _step_all([a, b])
        assert _same(a.state, b.state)
        for f in fields(ea):
            assert torch.equal(getattr(ea, f.name), getattr(eb, f.name))
        done = ea.terminated | ea.truncated
        a.reset(done)
        b.reset(done)
    other = World(scenario, "C", adversarial=True, num_envs=6, seed=124)
    assert not torch.equal(other.state.x, World(scenario, "C", num_envs=6, seed=123).state.x)


@pytest.mark.parametrize("scenario", ["exit", "multi-lane"])
def test_env_b_of_a_batch_equals_a_single_env_world_with_seed_b(scenario):
    seeds = [907, 3, 55, 1_000_003, 42, 8, 77, 500, 12, 31]
    batch = World(scenario, "C", adversarial=True, num_envs=len(seeds), seed=seeds, max_steps=90)
    picked = [1, 4, 9]
    singles = [World(scenario, "C", adversarial=True, num_envs=1, seed=[seeds[i]], max_steps=90) for i in picked]
    for _ in range(200):  # crosses two automatic episode ends (max_steps = 90)
        eb = _step_all([batch])[0]
        es = _step_all(singles)
        for i, w, e in zip(picked, singles, es):
            assert _same(batch.state, w.state, slice(i, i + 1), slice(None))
            assert bool(e.collision[0]) == bool(eb.collision[i])
            assert int(e.sv_collisions[0]) == int(eb.sv_collisions[i])
        done = eb.terminated | eb.truncated
        batch.reset(done)
        for i, w in zip(picked, singles):
            w.reset(done[i : i + 1])
    assert int(batch.state.episode[picked[0]]) >= 2


def test_resetting_some_envs_leaves_the_others_untouched():
    world = World("two-lane", "C", num_envs=8, seed=0)
    twin = World("two-lane", "C", num_envs=8, seed=0)
    for _ in range(30):
        _step_all([world, twin])
    before = world.state.clone()
    mask = torch.tensor([True, False, False, True, False, False, False, True])
    world.reset(mask)
    keep = ~mask
    assert _same(world.state, before, keep, keep)
    assert torch.equal(world.state.episode[mask], before.episode[mask] + 1)
    assert bool((world.state.t[mask] == 0).all())
    assert not torch.equal(world.state.x[mask], before.x[mask])
    # and they go on exactly as if nothing had happened
    for _ in range(50):
        _step_all([world, twin])
        assert _same(world.state, twin.state, keep, keep)
    # a reset env starts the episode that its seed and episode number define, whatever the other envs do
    everywhere = World("two-lane", "C", num_envs=8, seed=0)
    everywhere.reset()
    somewhere = World("two-lane", "C", num_envs=8, seed=0)
    somewhere.reset(mask)
    assert _same(everywhere.state, somewhere.state, mask, mask)
