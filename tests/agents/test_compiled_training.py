"""The static training step compiled: the update round is one graph with no break, and the compiled step
follows the eager static step to float rounding."""

from __future__ import annotations

import os

import pytest
import torch

from highway_srl.agents.dqn import DQNConfig
from highway_srl.agents.trainer import TrainConfig, Trainer


def _config(method: str = "moe-rm-srl", **kw) -> TrainConfig:
    dqn = DQNConfig(total_steps=400, learning_starts=0, batch_size=8, buffer_capacity=512)
    kw.setdefault("static", True)
    return TrainConfig(method=method, scenario="two-lane", traffic="A", steps=400, envs=4, dqn=dqn, **kw)


@pytest.mark.parametrize("method", ["moe-rm-srl", "lm-rl"])
def test_update_round_is_one_graph_without_a_break(method):
    trainer = Trainer(_config(method))
    for _ in range(3):  # some rows in the buffers
        trainer.step()
    members = trainer.trained
    u = torch.rand(members.shape[0], trainer.config.dqn.batch_size)
    mask = torch.arange(members.shape[0]) % 2 == 0
    explained = torch._dynamo.explain(trainer.eager_update_round)(members, u, mask)
    assert (explained.graph_count, explained.graph_break_count) == (1, 0), explained.break_reasons


# torch._dynamo.explain(Trainer.step) of the static step on two-lane (4 envs, torch 2.11, CPU), graphs / breaks:
# before the layer's and the methods' static forms (5c38dfd) MoE-RM-SRL 24 / 23, LM-RL 26 / 25 (host reads of
# two_models, torch.equal of the snapshot lanes, the action check, LM-RL's done.any()); now 11 / 10 and 13 / 12,
# every break a random draw with a generator object (the ε draw, the methods' random actions, the update
# samples), which dynamo does not take (docs/benchmarks.md)
@pytest.mark.parametrize("method, most_breaks", [("moe-rm-srl", 10), ("lm-rl", 12)])
def test_static_step_breaks_only_at_generator_draws(method, most_breaks):
    trainer = Trainer(_config(method), drain_every=1000)
    for _ in range(3):  # past the first observe and with rows in the buffers
        trainer.step()
    explained = torch._dynamo.explain(trainer.step)()
    assert explained.graph_break_count <= most_breaks, explained.break_reasons
    for reason in explained.break_reasons:  # no host read of a tensor's value is left: only draws
        assert "generator" in reason.reason or "proxy" in reason.reason, reason
        assert reason.user_stack[-1].name in ("step", "_update", "random_expert_actions", "random_allowed"), reason


def _follow(how, steps: int) -> None:
    eager, compiled = Trainer(_config()), Trainer(_config(compile=how))
    for _ in range(steps):
        eager.step()
        compiled.step()
    assert int(eager.learner.adam_step.sum()) > 0  # updates ran
    torch.testing.assert_close(compiled.learner.online.flat, eager.learner.online.flat, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(compiled.learner.exp_avg_sq, eager.learner.exp_avg_sq, rtol=1e-3, atol=1e-9)
    assert torch.equal(compiled.learner.target_update_count, eager.learner.target_update_count)
    assert torch.equal(compiled.replay.storage["action"], eager.replay.storage["action"])


def test_compiled_step_follows_the_eager_static_step():
    """Graph capture without code generation (aot_eager): the world step and the update round compiled."""
    _follow("aot_eager", steps=8)


def test_compile_needs_the_static_step():
    with pytest.raises(ValueError, match="static"):
        Trainer(_config(compile="aot_eager", static=False))


@pytest.mark.slow
@pytest.mark.skipif(os.environ.get("HIGHWAY_SRL_INDUCTOR_TESTS") != "1",
                    reason="minutes of C++ compilation on a cold cache, more than the suite's budget; "
                           "run with HIGHWAY_SRL_INDUCTOR_TESTS=1 (docs/benchmarks.md)")
def test_inductor_compiled_training_follows_eager_to_float_rounding():
    _follow(True, steps=30)
