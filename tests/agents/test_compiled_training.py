"""The static training step compiled: the vector step (and the update round in it) is one graph with no break
for every method and scene, and the compiled step, split (the step, one round per call, the method's tail)
or unrolled (one graph), follows the eager static step to float rounding."""

from __future__ import annotations

import os

import pytest
import torch

from highway_srl.agents.dqn import DQNConfig
from highway_srl.agents.train_config import TrainConfig
from highway_srl.agents.trainer import Trainer
from highway_srl.sim import compiled as compiled_module


def _config(method: str = "moe-rm-srl", learning_starts: int = 0, **kw) -> TrainConfig:
    dqn = DQNConfig(total_steps=400, learning_starts=learning_starts, batch_size=8, buffer_capacity=512)
    kw = {"static": True, "scenario": "two-lane", "traffic": "A", "envs": 4, **kw}
    return TrainConfig(method=method, steps=400, dqn=dqn, **kw)


@pytest.mark.parametrize("method", ["moe-rm-srl", "lm-rl"])
def test_update_round_is_one_graph_without_a_break(method):
    trainer = Trainer(_config(method))
    for _ in range(3):  # some rows in the buffers
        trainer.step()
    members = trainer.trained
    u = torch.rand(members.shape[0], trainer.config.dqn.batch_size)
    mask = torch.arange(members.shape[0]) % 2 == 0
    explained = torch._dynamo.explain(trainer.update_round)(members, u, mask)
    assert (explained.graph_count, explained.graph_break_count) == (1, 0), explained.break_reasons


# torch._dynamo.explain of the static step on two-lane (4 envs, torch 2.11, CPU), graphs / breaks: before the
# layer's and the methods' static forms (5c38dfd) Trainer.step gave MoE-RM-SRL 24 / 23, LM-RL 26 / 25 (host reads);
# with them 11 / 10 and 13 / 12, every break a random draw with a generator object, which dynamo does not take;
# with the draws made before the step (Trainer.draw) Trainer.vector_step is 1 / 0 for every method
# each trace takes 15-80 s on the loaded 2-core machine: all but MoE-RM-SRL and LM-RL run with -m slow
SLOW = pytest.mark.slow
TWO_LANE_METHODS = [("moe-rm-srl", {}), ("lm-rl", {}), *(pytest.param(m, o, marks=SLOW) for m, o in [
    ("rl", {}), ("sr-rl", {}), ("rm-rl", {}), ("mp-rl", {}), ("et-rl", {}), ("rule-based", {}),
    ("moe-rm-srl", {"no_mapping": True}), ("moe-rm-srl", {"no_moe": True}), ("moe-rm-srl", {"no_rm": True})])]
MOE_SCENES = [pytest.param(*scene, marks=SLOW)
              for scene in [("merge", False), ("exit", False), ("multi-lane", False), ("two-lane", True)]]


def _explain_vector_step(method: str, options: dict, scenario: str = "two-lane", adversarial: bool = False):
    # 2 envs at replay ratio 1/2: one update round (the rounds are the same graph, unrolled)
    trainer = Trainer(_config(method, options=options, scenario=scenario, adversarial=adversarial, envs=2,
                              replay_ratio=0.5), drain_every=1000)
    for _ in range(3):  # past the first observe and with rows in the buffers
        trainer.step()
    draws = trainer.draw()
    assert draws.learn and (draws.update is not None) == bool(trainer.trained.numel())
    return torch._dynamo.explain(trainer.vector_step)(draws)


@pytest.mark.parametrize("method, options", TWO_LANE_METHODS, ids=lambda v: v if isinstance(v, str) else
                         "+".join(v) or "-")
def test_static_vector_step_of_every_method_is_one_graph_without_a_break(method, options):
    explained = _explain_vector_step(method, options)
    assert (explained.graph_count, explained.graph_break_count) == (1, 0), explained.break_reasons


@pytest.mark.parametrize("scenario, adversarial", MOE_SCENES)
def test_static_vector_step_is_one_graph_without_a_break_in_every_scene(scenario, adversarial):
    explained = _explain_vector_step("moe-rm-srl", {}, scenario, adversarial)
    assert (explained.graph_count, explained.graph_break_count) == (1, 0), explained.break_reasons


def _follow(how, steps: int, unrolled: bool = False, **kw) -> None:
    eager = Trainer(_config(**kw), drain_every=4)
    compiled = Trainer(_config(compile=how, compile_unrolled=unrolled, **kw), drain_every=4)
    episodes = [[], []]
    try:
        for i in range(steps):
            episodes[0] += eager.step()
            # the same graphs for the whole run: nothing the step reads changes from step to step (a recompile
            # is an error; the first graph has a second version for the steps before learning_starts: none
            # here). Every guard is checked in the first half; in the second the graphs run settled, as in a
            # run (sim.compiled.call_settled), and must still follow eager.
            compiled_module.CHECK_GUARDS = i < steps // 2
            with torch._dynamo.config.patch(error_on_recompile=i > 0):
                episodes[1] += compiled.step()
    finally:
        compiled_module.CHECK_GUARDS = False
    assert int(eager.learner.adam_step.sum()) > 0  # updates ran
    torch.testing.assert_close(compiled.learner.online.flat, eager.learner.online.flat, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(compiled.learner.exp_avg_sq, eager.learner.exp_avg_sq, rtol=1e-3, atol=1e-9)
    assert torch.equal(compiled.learner.target_update_count, eager.learner.target_update_count)
    assert torch.equal(compiled.replay.storage["action"], eager.replay.storage["action"])
    assert torch.equal(compiled.usage, eager.usage) and torch.equal(compiled.world.state.lane, eager.world.state.lane)
    torch.testing.assert_close(compiled.method.state_dict(), eager.method.state_dict())  # LM-RL's λ
    torch.testing.assert_close(compiled.world.state.x, eager.world.state.x)
    assert [(e.step, e.length, e.collision) for e in episodes[1]] == [(e.step, e.length, e.collision)
                                                                      for e in episodes[0]]


@pytest.mark.parametrize("method, scenario, adversarial, unrolled, steps", [
    ("moe-rm-srl", "two-lane", False, False, 36), ("moe-rm-srl", "exit", True, False, 36),
    ("lm-rl", "two-lane", False, False, 12),  # a method with a tail (its dual ascent after the updates)
    ("moe-rm-srl", "two-lane", False, True, 12)])
def test_compiled_vector_step_follows_the_eager_static_step(method, scenario, adversarial, unrolled, steps):
    """Graph capture without code generation (aot_eager)."""
    _follow("aot_eager", steps=steps, unrolled=unrolled, method=method, scenario=scenario, adversarial=adversarial,
            traffic="C")


def test_compiled_step_follows_eager_across_the_start_of_learning():
    """The first graph gets its second version when the step starts to learn (Draws.learn), so its calls
    run settled (only the guards telling versions apart: sim.compiled.call_settled) only after that: were they
    settled earlier, the version without updates would go on running and the weights would not move."""
    kw = {"learning_starts": 12, "traffic": "C"}  # 4 envs: the third vector step is the first to learn
    eager, compiled = Trainer(_config(**kw), drain_every=4), Trainer(_config(compile="aot_eager", **kw), drain_every=4)
    for _ in range(10):
        eager.step()
        compiled.step()
    assert int(eager.learner.adam_step.sum()) > 0
    assert torch.equal(compiled.learner.adam_step, eager.learner.adam_step)
    torch.testing.assert_close(compiled.learner.online.flat, eager.learner.online.flat, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(compiled.world.state.x, eager.world.state.x)


def test_cuda_graph_bookkeeping_keeps_the_compiled_step_exact():
    """The CUDA-graph path's bookkeeping (state marked static, replaced state tensors copied back into the
    ones they replaced, the first graph's outputs copied) run on the CPU with graph capture: the trainer
    keeps its tensors' identities and follows the eager static step (LM-RL: a method with a tail)."""
    from highway_srl.agents.trainer import compile_vector_step, state_owners

    kw = {"method": "lm-rl", "traffic": "C"}
    eager, compiled = Trainer(_config(**kw), drain_every=4), Trainer(_config(**kw), drain_every=4)
    compiled.run_step = compile_vector_step(compiled, "aot_eager", keep_state=True)
    before = {(id(owner), name): value for owner in state_owners(compiled) for name, value in vars(owner).items()
              if isinstance(value, torch.Tensor)}
    for _ in range(12):
        eager.step()
        compiled.step()
    after = {(id(owner), name): value for owner in state_owners(compiled) for name, value in vars(owner).items()
             if isinstance(value, torch.Tensor)}
    assert all(after[key] is value for key, value in before.items())  # same tensor objects, written in place
    torch.testing.assert_close(compiled.learner.online.flat, eager.learner.online.flat, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(compiled.method.state_dict(), eager.method.state_dict())
    assert torch.equal(compiled.world.state.lane, eager.world.state.lane)


def test_compile_needs_the_static_step():
    with pytest.raises(ValueError, match="static"):
        Trainer(_config(compile="aot_eager", static=False))


@pytest.mark.slow
@pytest.mark.skipif(os.environ.get("HIGHWAY_SRL_INDUCTOR_TESTS") != "1",
                    reason="minutes of C++ compilation on a cold cache, more than the suite's budget; "
                           "run with HIGHWAY_SRL_INDUCTOR_TESTS=1 (docs/benchmarks.md)")
def test_inductor_compiled_training_follows_eager_to_float_rounding():
    _follow(True, steps=30)
