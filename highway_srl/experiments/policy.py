"""A trained run as a driver for renderings: greedy actions, with the acting expert and safe set shown."""

from __future__ import annotations

import torch

from highway_srl.agents.dqn import DQNLearner
from highway_srl.agents.gating import EXPERT_NAMES
from highway_srl.agents.methods import make_method
from highway_srl.constants import OBS_DIM
from highway_srl.rules import ACTIONS, SafetyLayer


def load_policy(run, scenario: str | None):
    """(driver(world) -> ((lane, speed), text lines), scenario) for env 0 of a world, from a finished run."""
    from highway_srl.experiments.train import load_learner_state

    cfg, tensors, _ = load_learner_state(run)
    if scenario is not None and scenario != cfg.scenario:
        raise ValueError(f"run {str(run)!r} was trained on scenario {cfg.scenario!r}, not {scenario!r}")
    method = make_method(cfg.method, cfg.scenario, len(cfg.seeds), cfg.options)
    if len(cfg.seeds) > 1:
        raise ValueError(f"run {str(run)!r} holds {len(cfg.seeds)} seeds; render needs a single-seed run")
    learner = DQNLearner(method.num_members, method.action_mask(), cfg.dqn, "cpu", OBS_DIM, method.out_dim)
    learner.load_state_dict(tensors)
    state = {"layer": None}

    def driver(world):
        if state["layer"] is None:
            state["layer"] = SafetyLayer(world.road, **method.layer_options)
        layer = state["layer"]
        step = layer.observe(world)
        decision = method.decide(learner, step, torch.zeros(world.num_envs, dtype=torch.bool), None)
        model = step.select(decision.use_second)
        safe = [a for a, ok in zip(ACTIONS, model.mask[0].tolist()) if ok]
        member = int(decision.member[0])
        expert = EXPERT_NAMES[member % len(EXPERT_NAMES)] if member >= 0 and cfg.method == "moe-rm-srl" else (
            "fallback" if member < 0 else f"member {member}")
        text = [f"{ACTIONS[int(decision.action[0])]} by {expert}", "safe: " + ",".join(safe), f"u{int(model.rm_state[0]) + 1}"]
        return layer.act(decision.action, decision.use_second), text

    return driver, cfg.scenario
