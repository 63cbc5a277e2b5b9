"""A trained run's policy: one loader for `evaluate`, `render` and the tests, and a driver for renderings."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from highway_srl.agents.checkpoint import (
    MODEL_FILE, CheckpointError, first_non_finite, load_checkpoint, split_policy_tensors,
)
from highway_srl.agents.dqn import DQNLearner
from highway_srl.agents.gating import EXPERT_NAMES
from highway_srl.agents.methods import Method
from highway_srl.agents.registry import make_method
from highway_srl.agents.train_config import TrainConfig
from highway_srl.constants import OBS_DIM
from highway_srl.experiments.runs import run_folder, train_config


# The reward machine's states (rules/reward_machine.py, §3.2) in words: K = keeping the target lane,
# R1 = the rule on the vehicle ahead, R1-R4 = all four surrounding-vehicle rules.
RM_MEANINGS = ("in lane, R1 kept", "in lane, R1 broken", "changing lane, R1-R4 kept", "changing lane, a rule broken")


def rm_label(state: int) -> str:
    return f"RM state u{state + 1}: {RM_MEANINGS[state]}"


@dataclass
class Policy:
    config: TrainConfig  # the run's training configuration
    method: Method  # with its own state loaded (e.g. LM-RL's λ)
    learner: DQNLearner  # the trained networks, on the device asked for
    meta: dict  # the model's meta.json


def read_model(run: str | Path, expect: dict | None = None) -> tuple[TrainConfig, dict[str, torch.Tensor], dict]:
    """(TrainConfig, the model's tensors as saved, meta) of a finished run; clear errors for anything wrong."""
    folder = run_folder(run)
    cfg = train_config(folder)
    if not (folder / "model").exists():
        raise CheckpointError(f"run {str(folder)!r} has no final model yet (interrupted? resume it with --resume)")
    expected = {"method": cfg.method, "scenario": cfg.scenario}
    if expect:
        expected.update(expect)
    tensors, meta = load_checkpoint(folder / "model", expect=expected)
    bad = first_non_finite(tensors)
    if bad is not None:
        raise CheckpointError(f"{folder / 'model' / MODEL_FILE}: {bad} holds NaN or infinite values; "
                              "a diverged model is not evaluated")
    return cfg, tensors, meta


def load_policy(run: str | Path, scenario: str | None = None, device: str = "cpu", profile: str | None = None) -> Policy:
    """The trained policy of a finished run; scenario, if given, must be the one it was trained on.
    profile: the control profile its rule layer acts through (None: the run's own, config.json)."""
    cfg, tensors, meta = read_model(run)
    if scenario is not None and scenario != cfg.scenario:
        raise ValueError(f"run {str(run)!r} was trained on scenario {cfg.scenario!r}, not {scenario!r}")
    method = make_method(cfg.method, cfg.scenario, len(cfg.seeds), cfg.options, profile or cfg.profile)
    learner = DQNLearner(method.num_members, method.action_mask(), cfg.dqn, device, OBS_DIM, method.out_dim)
    learner_state, method_state = split_policy_tensors(tensors)
    learner.load_state_dict(learner_state)
    method.load_state_dict(method_state)
    return Policy(cfg, method, learner, meta)


def load_driver(run, scenario: str | None, profile: str | None = None):
    """(driver(world) -> ((lane, speed), text lines), scenario) for env 0 of a world, from a finished run
    (profile: None = the run's own)."""
    policy = load_policy(run, scenario, profile=profile)
    cfg, method, learner = policy.config, policy.method, policy.learner
    if len(cfg.seeds) > 1:
        raise ValueError(f"run {str(run)!r} holds {len(cfg.seeds)} seeds; render needs a single-seed run")
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
