"""The envs' configuration: one dict in highway-env's style, checked once, readable back as env.unwrapped.config.

    highway_srl.make("merge", config={"traffic": "E", "adversarial": True})
    gymnasium.make("highway-srl/Merge-v0", config={"vehicles_count": 20, "max_episode_steps": 200})

The keys, their defaults and their highway-env counterparts are in docs/envs.md. A key may also be given
as a keyword (traffic=, adversarial=, profile=, adversary=, max_episode_steps=); one given both ways with
two values, an unknown key or a bad value is one ValueError naming the key and what it accepts.
"""

from __future__ import annotations

import math
from numbers import Real

import numpy as np
import torch

from highway_srl.constants import (
    DEFAULT_ADVERSARY,
    DEFAULT_PROFILE,
    EPISODE_STEPS,
    STYLE_NAMES,
    TRAFFIC_LEVELS,
)
from highway_srl.rules import COLLISION_REWARD, PROFILES
from highway_srl.rules.reward_machine import weighted_sum
from highway_srl.scenarios import RewardTerm, scenario_spec
from highway_srl.sim import StageFlags
from highway_srl.sim.adversary import ADVERSARIES
from highway_srl.sim.world import MAX_VEHICLES

DEFAULTS = {
    "traffic": "C",  # Table 4's level: number of surrounding vehicles and their initial headways
    "adversarial": False,  # group 3: SVs cut in ahead of the ego
    "profile": DEFAULT_PROFILE,  # control profile of the rule layer (rules.PROFILES)
    "adversary": DEFAULT_ADVERSARY,  # which cut-ins run when adversarial (sim.adversary.ADVERSARIES)
    "vehicles_count": None,  # surrounding vehicles; None: the traffic level's
    "style": None,  # None: each SV's driving style drawn from Table 3's three; or one style for all
    "max_episode_steps": EPISODE_STEPS,  # decisions per episode at 8 Hz, then truncated
    "collision_reward": COLLISION_REWARD,  # the reward of the collision step (§4.3: -320)
    "reward_weights": None,  # None: the scenario's (§4.3); or {"rm": w, <stage flag>: w, ...}
}


def term_key(term: RewardTerm) -> str:
    """A reward term's key in reward_weights: its input, or its inputs joined by '+'."""
    return "+".join(term.inputs)


def default_weights(scenario: str) -> dict[str, float]:
    """The scenario's training reward weights (§4.3): "rm" on r_RM, then one per stage-flag term."""
    spec = scenario_spec(scenario)
    return {"rm": spec.training_main_weight, **{term_key(t): t.weight for t in spec.training_terms}}


def _is_int(value) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _is_number(value) -> bool:
    return isinstance(value, Real) and not isinstance(value, (bool, np.bool_)) and math.isfinite(value)


def _choice(key: str, value, choices) -> str:
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"config {key!r} must be one of {', '.join(choices)}, got {value!r}")
    return value


def _weights(scenario: str, value) -> dict[str, float]:
    weights = default_weights(scenario)
    if value is None:
        return weights
    if not isinstance(value, dict):
        raise ValueError(f"config 'reward_weights' must be a dict over {', '.join(weights)}, got {value!r}")
    for key, weight in value.items():
        if key not in weights:
            raise ValueError(f"config 'reward_weights' of {scenario!r} takes {', '.join(weights)}, got {key!r}")
        if not _is_number(weight):
            raise ValueError(f"config 'reward_weights' {key!r} must be a finite number, got {weight!r}")
        weights[key] = float(weight)
    return weights


def _checked(scenario: str, c: dict) -> dict:
    """c with every value checked and in its plain form (str, bool, int, float, dict)."""
    _choice("traffic", c["traffic"], TRAFFIC_LEVELS)
    if not isinstance(c["adversarial"], (bool, np.bool_)):
        raise ValueError(f"config 'adversarial' must be True or False, got {c['adversarial']!r}")
    _choice("profile", c["profile"], PROFILES)
    _choice("adversary", c["adversary"], ADVERSARIES)
    count = c["vehicles_count"]
    if count is not None and not (_is_int(count) and 1 <= count < MAX_VEHICLES):
        raise ValueError(f"config 'vehicles_count' must be None or an integer in 1..{MAX_VEHICLES - 1}, got {count!r}")
    if c["style"] is not None:
        _choice("style", c["style"], STYLE_NAMES)
    if not (_is_int(c["max_episode_steps"]) and c["max_episode_steps"] >= 1):
        raise ValueError(f"config 'max_episode_steps' must be a positive integer, got {c['max_episode_steps']!r}")
    if not _is_number(c["collision_reward"]):
        raise ValueError(f"config 'collision_reward' must be a finite number, got {c['collision_reward']!r}")
    return {**c, "adversarial": bool(c["adversarial"]), "vehicles_count": None if count is None else int(count),
            "max_episode_steps": int(c["max_episode_steps"]), "collision_reward": float(c["collision_reward"]),
            "reward_weights": _weights(scenario, c["reward_weights"])}


def env_config(scenario: str, config: dict | None = None, **given) -> dict:
    """The full, checked configuration of an env of `scenario`: DEFAULTS, updated by `config` and by the
    keywords in `given` that are not None (the same key both ways must have the same value)."""
    scenario_spec(scenario)  # the one-line error naming the scenarios
    if config is None:
        config = {}
    if not isinstance(config, dict):
        raise ValueError(f"config must be a dict, got {type(config).__name__}")
    unknown = sorted(set(config) - set(DEFAULTS), key=str)
    if unknown:
        raise ValueError(f"unknown config key {unknown[0]!r}; the keys are {', '.join(DEFAULTS)}")
    c = {**DEFAULTS, **config}
    for key, value in given.items():
        if value is None:
            continue
        if key in config and config[key] != value:
            raise ValueError(f"{key} given twice: {value!r} as a keyword and {config[key]!r} in config")
        c[key] = value
    return _checked(scenario, c)


class TrainingReward:
    """The training reward of a configuration (§4.3 with its weights): collision_reward on a collision step,
    else weights["rm"] r_RM plus each stage-flag term's weight; with the default weights the numbers of
    rules.scenario_reward."""

    def __init__(self, scenario: str, config: dict):
        spec = scenario_spec(scenario)
        w = config["reward_weights"]
        self.main_weight = w["rm"]
        self.terms = tuple(RewardTerm(w[term_key(t)], t.inputs) for t in spec.training_terms)
        self.collision_reward = config["collision_reward"]

    def __call__(self, r_rm: torch.Tensor, collided: torch.Tensor, flags: StageFlags) -> torch.Tensor:
        given = {"merged": flags.merged, "exit1": flags.exit1, "exit2": flags.exit2}
        r = weighted_sum(self.main_weight, r_rm, self.terms, given)
        return torch.where(collided.bool(), torch.full_like(r, self.collision_reward), r)
