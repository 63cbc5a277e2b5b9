"""Throughput measurements (the numbers in docs/benchmarks.md come from here, never from timed tests)."""

from __future__ import annotations

import platform
import time

import torch

from highway_srl.constants import DT_S
from highway_srl.sim import World


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def machine() -> dict:
    info = {"cpu": platform.processor() or platform.machine(), "threads": torch.get_num_threads(), "torch": torch.__version__}
    if torch.cuda.is_available():
        info["gpu"] = torch.cuda.get_device_name(0)
    return info


def bench_sim(scenario: str, traffic: str, envs: int, steps: int, device: str, adversarial: bool = False,
              warmup: int = 10) -> dict:
    """Env-steps per second of World.step (+ resets) with the ego holding its lane at a constant 8 m/s."""
    if steps < 1:
        raise ValueError(f"steps must be a positive integer, got {steps}")
    world = World(scenario, traffic, adversarial=adversarial, num_envs=envs, device=device, seed=0)
    speed = torch.full((envs,), 8.0, device=world.device)

    def run(n: int) -> None:
        for _ in range(n):
            events = world.step(world.ego_lane, speed)
            done = events.terminated | events.truncated
            if bool(done.any()):
                world.reset(done)

    run(warmup)
    _sync(world.device)
    start = time.perf_counter()
    run(steps)
    _sync(world.device)
    wall = time.perf_counter() - start
    rate = envs * steps / wall
    return {
        "what": "sim",
        "scenario": scenario,
        "traffic": traffic,
        "adversarial": adversarial,
        "envs": envs,
        "steps": steps,
        "device": str(world.device),
        "wall_s": round(wall, 4),
        "env_steps_per_s": round(rate, 1),
        "sim_s_per_wall_s": round(rate * DT_S, 1),
        "machine": machine(),
    }
