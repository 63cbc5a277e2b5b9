"""highway-srl: safe reinforcement learning of autonomous highway driving (MoE-RM-SRL and baselines).

    import highway_srl
    env = highway_srl.make("merge", traffic="C")          # Gymnasium Env with the paper's 37 inputs
    envs = highway_srl.make("merge", num_envs=64)         # batched Gymnasium VectorEnv
    world = highway_srl.World("two-lane", num_envs=4096)   # the raw batched simulator
"""

from highway_srl.interrupts import quiet_start

quiet_start()  # first: run as the command, Ctrl-C while the imports below run is one line (interrupts.py)

from highway_srl.scenarios import ENV_IDS  # noqa: E402 - leaf data, no torch; scenario -> <name> of highway-srl/<name>-v0

__version__ = "0.1.0"


def make(*args, **kwargs):
    """A Gymnasium Env (num_envs = 1) or VectorEnv (num_envs > 1, or vector=True at any N): highway_srl.env.make,
    which takes scenario, traffic, adversarial, num_envs, device, seed, vector, render_mode and profile=,
    adversary=, max_episode_steps=, config= (docs/envs.md), autoreset_mode=, processes=."""
    from highway_srl.env import make as make_env

    return make_env(*args, **kwargs)


def __getattr__(name):
    if name == "World":
        from highway_srl.sim import World

        return World
    raise AttributeError(f"module 'highway_srl' has no attribute {name!r}")


def _register() -> None:
    """The four ids; gymnasium.make_vec builds the batched HighwayVectorEnv through vector_entry_point. No
    max_episode_steps is registered: the envs truncate their episodes themselves (config max_episode_steps,
    320 by default) and their spec reports it, so gymnasium.make adds no TimeLimit of another length.
    Without gymnasium (a bare GPU machine) the simulator, agents and benches still import; only
    highway_srl.make and the env need it."""
    try:
        import gymnasium
    except ImportError:
        return

    for scenario, name in ENV_IDS.items():
        env_id = f"highway-srl/{name}-v0"
        if env_id not in gymnasium.registry:
            gymnasium.register(env_id, entry_point="highway_srl.env:HighwayEnv",
                               vector_entry_point="highway_srl.env:HighwayVectorEnv",
                               kwargs={"scenario": scenario})


_register()
