"""A training run's settings (TrainConfig), their checks (one-line ValueErrors naming the setting), and the one
conversion of a config written by an older version (upgrade_config)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

from highway_srl.agents.dqn import DQNConfig
from highway_srl.agents.methods import MoERMSRL
from highway_srl.agents.registry import make_method
from highway_srl.constants import DEFAULT_ADVERSARY, DEFAULT_PROFILE
from highway_srl.rules import control_profile
from highway_srl.sim.adversary import ADVERSARIES


@dataclass
class TrainConfig:
    method: str = "moe-rm-srl"
    scenario: str = "two-lane"
    traffic: str = "C"
    adversarial: bool = False
    steps: int = 500_000  # environment steps per seed (Table 2's T_total)
    envs: int = 16  # environments per seed, stepped together
    seeds: tuple[int, ...] = (0,)
    device: str = "cpu"
    profile: str = DEFAULT_PROFILE  # control profile of the method's rule layer: "paper" or "safe" (rules.PROFILES)
    adversary: str = DEFAULT_ADVERSARY  # group-3 cut-ins when adversarial: "paper" (§4.3 as printed) or "mild" (ours)
    # Algorithm 1: gradient steps per environment step, each on the acting member (see Trainer.update_counts)
    replay_ratio: float = 1.0
    share_transitions: bool = False  # store each transition in every expert whose set holds the action
    # the static-shape vector step (Trainer.static): None = on CUDA or when compiled, compact on the CPU, where
    # the masked update of every member is 13x slower: `bench train --envs 16 --steps 200`, 1 thread, loaded
    # 2-core machine, 51.8 env-steps/s compact vs 3.9 static (docs/benchmarks.md). The two draw different
    # samples (so different numbers), the same rate and semantics.
    static: bool | None = None
    # torch.compile the static vector step (compile_vector_step): False, True (CUDA graphs on CUDA), or a
    # torch.compile mode or backend name (tests: "aot_eager"); as three graphs (the step, one update round
    # called per round, the method's tail) or, compile_unrolled, one graph with the rounds unrolled
    compile: bool | str = False
    compile_unrolled: bool = False
    dqn: DQNConfig = field(default_factory=DQNConfig)
    options: dict = field(default_factory=dict)  # method-specific switches (ablations)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["seeds"] = list(self.seeds)
        return d

    @staticmethod
    def from_dict(d: dict) -> "TrainConfig":
        """A config from its dict; one written by an older version reads as what it ran under (upgrade_config)."""
        if not isinstance(d, dict):
            raise ValueError(f"config must be an object of settings, got {type(d).__name__}")
        known = set(TrainConfig.__dataclass_fields__)
        unknown = sorted(set(d) - known - {"updates_per_step"})
        if unknown:
            raise ValueError(f"unknown config keys {unknown}; allowed: {sorted(known)}")
        d = upgrade_config(d)
        dqn = d.pop("dqn", {})
        if not isinstance(dqn, dict):
            raise ValueError(f"config dqn must be an object of DQN settings, got {dqn!r}")
        unknown = sorted(set(dqn) - set(DQNConfig.__dataclass_fields__))
        if unknown:
            raise ValueError(f"unknown dqn config keys {unknown}; allowed: {sorted(DQNConfig.__dataclass_fields__)}")
        if isinstance(dqn.get("adam_betas"), list):
            dqn["adam_betas"] = tuple(dqn["adam_betas"])
        if isinstance(d.get("seeds", ()), list):
            d["seeds"] = tuple(d["seeds"])
        cfg = TrainConfig(dqn=DQNConfig(**dqn), **d)
        check_config(cfg)
        return cfg


# What a config.json written before these keys existed ran under: the rule layer's profile was today's
# "safe" one and the adversary today's "mild" one, its vector step the compact eager one (replay_ratio: see
# upgrade_config).
LEGACY = {"profile": "safe", "adversary": "mild", "static": False, "compile": False}
LEGACY_UPDATES_PER_STEP = 4  # the update rate of a config written before replay_ratio and updates_per_step


def upgrade_config(d: dict) -> dict:
    """The one conversion of a config written by an older version into today's settings (a new dict).

    A setting it lacks reads as what it ran under (LEGACY). Its update rate before replay_ratio,
    `updates_per_step` (4 where neither key was written), gave that many gradient steps to every member that
    acted in a vector step; it becomes the replay_ratio it equals (legacy_replay_ratio), or the config is
    refused in one line where none does. `updates_per_step` null (written beside replay_ratio) is dropped."""
    d = dict(d)
    for key, value in LEGACY.items():
        d.setdefault(key, value)
    updates = d.pop("updates_per_step", None)
    if "replay_ratio" not in d:
        d["replay_ratio"] = None
        updates = LEGACY_UPDATES_PER_STEP if updates is None else updates
    if updates is not None:
        if d["replay_ratio"] is not None:
            raise ValueError("config sets both replay_ratio and updates_per_step (the older rate): keep replay_ratio")
        d["replay_ratio"] = legacy_replay_ratio(d.get("method", TrainConfig.method), d.get("options", {}),
                                                d.get("envs", TrainConfig.envs), updates)
    return d


def legacy_replay_ratio(method: str, options: dict, envs: int, updates_per_step: int) -> float:
    """The replay_ratio equal to the older rate of updates_per_step gradient steps for every member that acted
    in a vector step of `envs` envs per seed: updates_per_step / envs, where one network per seed acts in
    every env (every method but the mixture of experts; exactly, where the ratio times envs is the count).
    The mixture's experts each took updates_per_step whatever their share of the envs, which no replay_ratio
    expresses: ValueError, as for a rate that is not a count."""
    if not isinstance(method, str):
        raise ValueError(f"config method must be str, got {method!r}")
    if not (_is_int(updates_per_step) and updates_per_step >= 0 and _is_int(envs) and envs >= 1):
        raise ValueError(f"config updates_per_step must be a non-negative integer (envs a positive one), got "
                         f"{updates_per_step!r} (envs {envs!r})")
    if not isinstance(options, dict):
        raise ValueError(f"config options must be dict, got {options!r}")
    ratio = updates_per_step / envs
    if isinstance(make_method(method, "two-lane", 1, options), MoERMSRL) or ratio * envs != updates_per_step:
        raise ValueError(f"config updates_per_step={updates_per_step} ({method}, {envs} envs: that many gradient "
                         "steps for every member that acted in a vector step) has no replay_ratio equal to it; "
                         "train it again with --replay-ratio")
    return ratio


MAX_SEED = 2**32 - 1  # a seed's env streams (seed x 1,000,003 + env) stay well inside a 64-bit generator seed


def check_config(cfg: TrainConfig) -> None:
    """ValueError in one line, naming the setting, for settings no run can have: wrong types (a JSON
    config's "4000" or null), NaN or infinite numbers, and values out of range."""
    _check_types(cfg)
    if cfg.steps < 1 or cfg.envs < 1:
        raise ValueError("steps and envs must be positive")
    if not cfg.seeds or len(set(cfg.seeds)) != len(cfg.seeds) or not all(0 <= s <= MAX_SEED for s in cfg.seeds):
        raise ValueError(f"seeds must be distinct integers from 0 to {MAX_SEED}, got {list(cfg.seeds)!r}")
    control_profile(cfg.profile)
    if cfg.adversary not in ADVERSARIES:
        raise ValueError(f"unknown adversary {cfg.adversary!r}; choose one of {', '.join(ADVERSARIES)}")
    if cfg.compile and cfg.static is False:
        raise ValueError("compile needs the static step (static=False was set)")
    if not (cfg.replay_ratio >= 0 and math.isfinite(cfg.replay_ratio)):
        raise ValueError(f"replay_ratio must be a non-negative number, got {cfg.replay_ratio!r}")
    check_dqn_config(cfg.dqn)


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _check_types(cfg: TrainConfig) -> None:
    """Each setting of the type it must have (a config read from JSON can hold anything)."""
    kinds = {"method": str, "scenario": str, "traffic": str, "adversarial": bool, "steps": int, "envs": int,
             "device": str, "profile": str, "adversary": str, "replay_ratio": float,
             "share_transitions": bool, "static": (bool, None),
             "compile": (bool, str), "compile_unrolled": bool, "dqn": DQNConfig, "options": dict}
    for name, kind in kinds.items():
        value, kinds_ok = getattr(cfg, name), kind if isinstance(kind, tuple) else (kind,)
        if not any(_of_kind(value, k) for k in kinds_ok):
            want = " or ".join("null" if k is None else k.__name__ for k in kinds_ok)
            raise ValueError(f"config {name} must be {want}, got {value!r}")
    if not isinstance(cfg.seeds, (tuple, list)) or not all(_is_int(s) for s in cfg.seeds):
        raise ValueError(f"config seeds must be a list of integers, got {cfg.seeds!r}")


def _of_kind(value, kind) -> bool:
    """value is of kind (None: null; int: an integer, not a bool; float: any number but a bool)."""
    if kind is None:
        return value is None
    if kind is int:
        return _is_int(value)
    if kind is float:
        return _is_number(value)
    return isinstance(value, kind)


# DQNConfig's numbers: (integer?, lowest, highest); every one finite
DQN_RANGES = {"lr": (False, 0.0, 1.0), "gamma": (False, 0.0, 1.0), "batch_size": (True, 1, 2**20),
              "total_steps": (True, 1, 2**53), "hidden": (True, 1, 2**16), "buffer_capacity": (True, 1, 2**40),
              "learning_starts": (True, 0, 2**53), "target_update_interval": (True, 1, 2**53),
              "eps_start": (False, 0.0, 1.0), "eps_end": (False, 0.0, 1.0), "exploration_fraction": (False, 0.0, 1.0),
              "grad_clip_norm": (False, -math.inf, math.inf), "adam_eps": (False, 0.0, 1.0)}


def check_dqn_config(dqn: DQNConfig) -> None:
    """ValueError in one line naming the DQN setting that is of the wrong type, not finite or out of range."""
    for name, (integer, lo, hi) in DQN_RANGES.items():
        value = getattr(dqn, name)
        if not (_is_int(value) if integer else _is_number(value)) or not math.isfinite(value):
            raise ValueError(f"config dqn.{name} must be a finite {'integer' if integer else 'number'}, got {value!r}")
        if not lo <= value <= hi or (name in ("lr", "adam_eps") and value == 0):
            raise ValueError(f"config dqn.{name} must be {'above' if name in ('lr', 'adam_eps') else 'at least'} "
                             f"{lo} and at most {hi}, got {value!r}")
    betas = dqn.adam_betas
    if not (isinstance(betas, (tuple, list)) and len(betas) == 2 and all(_is_number(b) and 0 <= b < 1 for b in betas)):
        raise ValueError(f"config dqn.adam_betas must be two numbers in [0, 1), got {betas!r}")
    if not isinstance(dqn.huber, bool):
        raise ValueError(f"config dqn.huber must be true or false, got {dqn.huber!r}")
