"""The learning core: MoE gating, a batched ensemble of MLPs, per-expert replay, DQN, checkpoints."""

from highway_srl.agents.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from highway_srl.agents.dqn import DQNConfig, DQNLearner
from highway_srl.agents.ensemble import MLPEnsemble
from highway_srl.agents.gating import EXPERT_ACTION_SETS, EXPERT_NAMES, explore_gate, polite_gate
from highway_srl.agents.replay import ExpertReplay

__all__ = [
    "EXPERT_ACTION_SETS",
    "EXPERT_NAMES",
    "polite_gate",
    "explore_gate",
    "MLPEnsemble",
    "ExpertReplay",
    "DQNConfig",
    "DQNLearner",
    "save_checkpoint",
    "load_checkpoint",
    "CheckpointError",
]
