"""highway-srl: safe reinforcement learning of autonomous highway driving (MoE-RM-SRL and baselines)."""

__version__ = "0.1.0"
