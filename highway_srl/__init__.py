"""highway-srl: safe reinforcement learning of autonomous highway driving (MoE-RM-SRL and baselines).

    import highway_srl
    env = highway_srl.make("merge", traffic="C")          # Gymnasium Env with the paper's 37 inputs
    world = highway_srl.World("two-lane", num_envs=4096)   # the raw batched simulator
"""

__version__ = "0.1.0"


def make(scenario: str = "two-lane", traffic: str = "C", adversarial: bool = False, num_envs: int = 1,
         device: str = "cpu", seed: int | None = None):
    """A Gymnasium Env (num_envs = 1) or VectorEnv (num_envs > 1); see highway_srl.env."""
    from highway_srl.env import make as _make

    return _make(scenario, traffic, adversarial, num_envs, device, seed)


def __getattr__(name):
    if name == "World":
        from highway_srl.sim import World

        return World
    raise AttributeError(f"module 'highway_srl' has no attribute {name!r}")


def _register() -> None:
    import gymnasium

    ids = {"two-lane": "TwoLane", "multi-lane": "MultiLane", "merge": "Merge", "exit": "Exit"}
    for scenario, name in ids.items():
        env_id = f"highway-srl/{name}-v0"
        if env_id not in gymnasium.registry:
            gymnasium.register(env_id, entry_point="highway_srl.env:HighwayEnv", kwargs={"scenario": scenario})


_register()
