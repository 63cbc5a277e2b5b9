"""The static-shape step (the form torch.compile takes) and its compiled graph follow the eager reference."""

from __future__ import annotations

import os
from dataclasses import fields

import pytest
import torch

from highway_srl.sim import HOLD_LANE, World
from highway_srl.sim.ego_driver import idm_ego
from highway_srl.sim.state import astuple_shallow
from highway_srl.sim.step import step_state

# (scenario, adversary): None nominal, "mild" or "paper" (World's adversary)
VARIANTS = [(sc, adv) for sc in ("two-lane", "multi-lane", "merge", "exit") for adv in (None, "mild")]
VARIANTS += [("two-lane", "paper"), ("merge", "paper")]
# the graph checks trace or run the capture (seconds each): every scenario once, every adversary once
GRAPH_VARIANTS = [("two-lane", None), ("multi-lane", "mild"), ("merge", "paper"), ("exit", "mild")]


def _world(scenario, adversary, traffic="D", seed=11, **kw) -> World:
    return World(scenario, traffic, adversarial=adversary is not None, adversary=adversary or "mild",
                 num_envs=ENVS, seed=seed, **kw)
ENVS = 8


def _commands(world: World, t: int):
    """The IDM ego, with a random lane command every few steps so that refused and accepted changes (and
    lateral holds) occur."""
    lane, speed = idm_ego(world)
    if t % 5 == 0:
        g = torch.Generator().manual_seed(t)
        lane = torch.randint(HOLD_LANE, world.road.num_lanes, (world.num_envs,), generator=g)  # holds too
    return lane, speed


def _copy_state(dst: World, src: World) -> None:
    for f in fields(src.state):
        getattr(dst.state, f.name).copy_(getattr(src.state, f.name))


def _assert_close_state(a: World, b: World, where: str) -> None:
    for f in fields(a.state):
        x, y = getattr(a.state, f.name), getattr(b.state, f.name)
        if x.is_floating_point():
            assert torch.allclose(x, y, rtol=1e-5, atol=1e-4), (where, f.name, float((x - y).abs().max()))
        else:
            assert torch.equal(x, y), (where, f.name)


@pytest.mark.parametrize("scenario,adversarial", VARIANTS)
def test_static_step_is_bit_identical_to_the_compact_step_in_eager(scenario, adversarial):
    ref, static = _world(scenario, adversarial), _world(scenario, adversarial)
    for t in range(160):  # past the first recycles, refused changes and (adversarial) cut-ins
        lane, speed = _commands(ref, t)
        e_ref = ref.step(lane, speed)
        with torch.inference_mode():
            e_static = step_state(static.state, static.road, static._lane_tables, static.layout, static.level, lane,
                                  speed, adversarial, static.max_steps, static=True)
            done = e_ref.terminated | e_ref.truncated
            ref.reset(done)
            static.state = static.spawn_where(static.state, done)
        for f in fields(e_ref):
            assert torch.equal(getattr(e_ref, f.name), getattr(e_static, f.name)), (t, f.name)
        for f in fields(ref.state):
            assert torch.equal(getattr(ref.state, f.name), getattr(static.state, f.name)), (t, f.name)


@pytest.mark.parametrize("scenario,adversarial", GRAPH_VARIANTS)
def test_compiled_step_is_one_graph_and_no_break(scenario, adversarial):
    world = _world(scenario, adversarial, traffic="C", seed=0, compile="eager")
    lane, speed = world._commands(world.ego_lane, torch.full((ENVS,), 8.0))
    explain = torch._dynamo.explain(world._steps.pure_step_reset)
    with torch.inference_mode():
        out = explain(astuple_shallow(world.state), lane, speed)
    assert (out.graph_count, out.graph_break_count) == (1, 0), out.break_reasons


@pytest.mark.parametrize("scenario,adversarial", GRAPH_VARIANTS)
def test_captured_graph_follows_eager(scenario, adversarial):
    """torch.compile's capture (aot_eager: the functional graph, run eagerly; 0.15 s a step, so 30 steps
    here: the static form itself is checked step by step above), from eager's state each step."""
    _follow(scenario, adversarial, "aot_eager", steps=30)


@pytest.mark.slow
@pytest.mark.skipif(os.environ.get("HIGHWAY_SRL_INDUCTOR_TESTS") != "1",
                    reason="about 5 min of C++ compilation on a cold cache, more than the suite's budget; "
                           "run with HIGHWAY_SRL_INDUCTOR_TESTS=1 (docs/benchmarks.md)")
def test_inductor_compiled_step_follows_eager_to_float_rounding():
    """The generated C++ kernels (minutes of compilation on a cold cache, hence slow)."""
    _follow("merge", "mild", True, steps=200)


def _follow(scenario: str, adversarial: str | None, how, steps: int) -> None:
    ref, comp = _world(scenario, adversarial, seed=5), _world(scenario, adversarial, seed=5, compile=how)
    for t in range(steps):
        lane, speed = _commands(ref, t)
        _copy_state(comp, ref)  # from the same state each step: a rounding difference cannot grow into chaos
        e_ref = ref.step_and_reset(lane, speed)
        e_comp = comp.step_and_reset(lane, speed)
        for f in fields(e_ref):
            assert torch.equal(getattr(e_ref, f.name), getattr(e_comp, f.name)), (t, f.name)
        _assert_close_state(ref, comp, f"step {t}")


def test_eager_seeds_reproduce_bit_for_bit_with_compile_off():
    runs = []
    for _ in range(2):
        world = _world("exit", "paper", seed=21)
        for t in range(120):
            world.step_and_reset(*_commands(world, t))
        runs.append(world.state)
    for f in fields(runs[0]):
        assert torch.equal(getattr(runs[0], f.name), getattr(runs[1], f.name)), f.name
