"""Adapters to simulators we did not write, behind the Backend protocol of sim/protocol.py.

    make_backend("sumo", "merge", "C", adversarial=False, seed=0)         # Eclipse SUMO via libsumo
    make_backend("highway-env", "exit", "C", adversarial=True, seed=3)    # highway-env
    make_backend("ours", "two-lane", "C", seed=0)                          # our World with one env

Each backend runs one env (num_envs = 1) on the CPU and yields the same StepEvents and Snapshot
semantics as our World; docs/backends.md lists what still differs. The simulators are optional
extras (`pip install 'highway-srl[sumo]'`, `'highway-srl[highway-env]'`) imported only when asked for.
"""

from __future__ import annotations

import importlib
import importlib.util

from highway_srl.constants import EPISODE_STEPS
from highway_srl.sim.protocol import Backend

BACKENDS = ("ours", "sumo", "highway-env")
# backend -> (modules it imports, pip extra)
EXTRAS = {"sumo": (("libsumo",), "sumo"), "highway-env": (("highway_env",), "highway-env")}


def missing_modules(name: str) -> list[str]:
    """The modules a backend needs that are not installed (empty when it can run)."""
    if name not in BACKENDS:
        raise ValueError(f"unknown backend {name!r}; choose one of {', '.join(BACKENDS)}")
    modules = EXTRAS.get(name, ((), ""))[0]
    return [m for m in modules if importlib.util.find_spec(m) is None]


def available_backends() -> tuple[str, ...]:
    """The backends whose simulators are installed here."""
    return tuple(b for b in BACKENDS if not missing_modules(b))


def make_backend(
    name: str,
    scenario: str = "two-lane",
    traffic: str = "C",
    adversarial: bool = False,
    seed: int = 0,
    max_steps: int = EPISODE_STEPS,
    **kwargs,
) -> Backend:
    """A one-env backend of scenario / traffic level; raises ValueError naming the allowed backends, or the
    pip extra to install when its simulator is missing. kwargs go to the backend's constructor (style,
    num_vehicles; SUMO: api; highway-env: frames_per_step, ego_speed_time_constant_s)."""
    missing = missing_modules(name)
    if missing:
        extra = EXTRAS[name][1]
        raise ValueError(
            f"backend {name!r} needs the {extra} extra (module {', '.join(missing)} not installed): "
            f"pip install 'highway-srl[{extra}]'"
        )
    if name == "ours":
        from highway_srl.sim.world import World

        return World(scenario, traffic, adversarial, num_envs=1, seed=seed, max_steps=max_steps, **kwargs)
    try:
        if name == "sumo":
            from highway_srl.backends.sumo import SumoBackend as cls
        else:
            from highway_srl.backends.highway_env import HighwayEnvBackend as cls
        return cls(scenario, traffic, adversarial, seed=seed, max_steps=max_steps, **kwargs)
    except ImportError as e:  # installed but broken (a missing shared library, an incompatible version)
        extra = EXTRAS[name][1]
        raise ValueError(f"backend {name!r} could not be loaded ({e}); reinstall: pip install 'highway-srl[{extra}]'") from e


__all__ = ["BACKENDS", "available_backends", "make_backend", "missing_modules"]
