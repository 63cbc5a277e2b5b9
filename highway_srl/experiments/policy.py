"""A trained run as a driver for renderings: greedy actions, with the acting expert and safe set shown."""

from __future__ import annotations

import torch

from highway_srl.agents.dqn import DQNLearner
from highway_srl.agents.gating import EXPERT_NAMES
from highway_srl.agents.methods import make_method
from highway_srl.constants import OBS_DIM


# The reward machine's states (rules/reward_machine.py, §3.2) in words: K = keeping the target lane,
# R1 = the rule on the vehicle ahead, R1-R4 = all four surrounding-vehicle rules.
RM_MEANINGS = ("in lane, R1 kept", "in lane, R1 broken", "changing lane, R1-R4 kept", "changing lane, a rule broken")


def rm_label(state: int) -> str:
    return f"RM state u{state + 1}: {RM_MEANINGS[state]}"


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
    method.load_state_dict({k[len("method."):]: v for k, v in tensors.items() if k.startswith("method.")})
    state = {"layer": None}

    def driver(world):
        if state["layer"] is None:
            state["layer"] = method.make_layer(world.road)
        layer = state["layer"]
        step = layer.observe(world)
        decision = method.decide(learner, step, torch.zeros(world.num_envs, dtype=torch.bool), None)
        model = step.select(decision.use_second)
        safe = [a for a, ok in zip(method.action_names, method.safe_mask(model)[0].tolist()) if ok]
        member = int(decision.member[0])
        expert = EXPERT_NAMES[member % len(EXPERT_NAMES)] if member >= 0 and cfg.method == "moe-rm-srl" else (
            "fallback" if member < 0 else f"member {member}")
        text = [f"{method.action_names[int(decision.action[0])]} by {expert}", "safe: " + ",".join(safe), rm_label(int(model.rm_state[0]))]
        return layer.act(decision.action, decision.use_second), text

    return driver, cfg.scenario
