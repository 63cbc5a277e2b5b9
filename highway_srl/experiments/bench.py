"""Throughput measurements (the numbers in docs/benchmarks.md come from here, never from timed tests)."""

from __future__ import annotations

import math
import os
import platform
import time

import torch

from highway_srl.constants import DT_S
from highway_srl.interrupts import held, quiet_worker
from highway_srl.sim import World, allocator


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def machine() -> dict:
    info = {"cpu": platform.processor() or platform.machine(), "threads": torch.get_num_threads(), "torch": torch.__version__,
            "malloc": allocator.setting(),  # glibc's thresholds change the CPU figures by 1.2x (sim/allocator.py)
            # torch's vectorised CPU kernels (AVX2, AVX512, ...): they move the figures and the last bits of a run
            "cpu_kernels": torch.backends.cpu.get_cpu_capability(),
            # MKL's reproducible mode (README: comparing runs across machines); "" when not set
            "mkl_cbwr": os.environ.get("MKL_CBWR", "")}
    if torch.cuda.is_available():
        info["gpu"] = torch.cuda.get_device_name(0)
    return info


# Peak memory of a World step over the bytes of its state, measured with `ru_maxrss` on 20,000 CPU envs at
# level F (two-lane 3.5, multi-lane 4.3: the step's temporaries); rounded up for a margin.
STEP_MEMORY_FACTOR = 5.0


def world_bytes_per_env(scenario: str, traffic: str, adversarial: bool = False) -> int:
    """Bytes of one env's World state, from a small world (the state grows linearly with envs)."""
    probe = 16
    world = World(scenario, traffic, adversarial=adversarial, num_envs=probe, device="cpu", seed=0)
    total = sum(t.numel() * t.element_size() for t in vars(world.state).values() if torch.is_tensor(t))
    return math.ceil(total / probe)


def available_bytes(device: str | torch.device) -> int | None:
    """Memory free for new tensors on the device: MemAvailable of /proc/meminfo, or the GPU's free memory."""
    dev = torch.device(device)
    if dev.type == "cuda":
        return torch.cuda.mem_get_info(dev)[0]
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def check_sim_memory(scenario: str, traffic: str, envs: int, device: str, adversarial: bool = False,
                     fewer: str = "use fewer --envs") -> int:
    """Estimated peak bytes of stepping `envs` worlds (`bench sim`, evaluate's episodes); refuses (one line)
    what would not fit, before allocating it (fewer: what the line advises)."""
    need = int(world_bytes_per_env(scenario, traffic, adversarial) * STEP_MEMORY_FACTOR * envs)
    check_memory(need, device, f"{envs:,} envs need about {need / 2**30:.1f} GiB ({need / envs / 1024:.0f} KiB "
                 "per env)", fewer)
    return need


def check_memory(need: int, device: str, what: str, fewer: str) -> None:
    """ValueError in one line (what, the device's free memory, fewer) if need bytes do not fit on device."""
    from highway_srl.sim.device import check_device

    dev = check_device(device)
    free = available_bytes(dev)
    if free is not None and need > free:
        raise ValueError(f"{what} but {dev} has {free / 2**30:.1f} GiB available; {fewer}")


def check_train_memory(cfg) -> int:
    """Estimated peak bytes of training cfg (a TrainConfig): the worlds' step (envs x seeds), the replay
    buffers (every member's, allocated at the start) and the networks with their targets and Adam
    moments; refuses (one line) what would not fit, before any of it is allocated."""
    from highway_srl.agents.registry import make_method
    from highway_srl.constants import OBS_DIM

    method = make_method(cfg.method, cfg.scenario, len(cfg.seeds), cfg.options, cfg.profile)
    envs = cfg.envs * len(cfg.seeds)
    world = world_bytes_per_env(cfg.scenario, cfg.traffic, cfg.adversarial) * STEP_MEMORY_FACTOR * envs
    row = (2 * OBS_DIM + 1 + int(method.uses_cost)) * 4 + 8 + 1  # obs, next_obs, reward, cost; action; done
    replay = method.num_members * cfg.dqn.buffer_capacity * row
    h = cfg.dqn.hidden
    networks = 4 * 4 * method.num_members * (OBS_DIM * h + h * h + h * method.out_dim + 2 * h + method.out_dim)
    need = int(world + replay + networks)
    check_memory(need, cfg.device, f"training {envs:,} envs ({cfg.envs:,} x {len(cfg.seeds)} seeds) with "
                 f"{method.num_members} replay buffers of {cfg.dqn.buffer_capacity:,} needs about "
                 f"{need / 2**30:.1f} GiB", "use fewer --envs or seeds")
    return need


def bench_sim(scenario: str, traffic: str, envs: int, steps: int, device: str, adversarial: bool = False,
              warmup: int = 10, compile: bool | str = False, processes: int = 1) -> dict:
    """Env-steps per second of World.step (+ resets) with the ego holding its lane at a constant 8 m/s.

    compile: see World; the warm-up steps then include the compilation, reported as warmup_s, and
    env_steps_per_s_with_compile counts them (compilation included) next to the steady rate.
    processes: see World (worker processes of one thread each; their start is in warmup_s)."""
    if steps < 1:
        raise ValueError(f"steps must be a positive integer, got {steps}")
    start = time.perf_counter()
    world = World(scenario, traffic, adversarial=adversarial, num_envs=envs, device=device, seed=0, compile=compile,
                  processes=processes)
    speed = torch.full((envs,), 8.0, device=world.device)

    def run(n: int) -> None:
        for _ in range(n):
            world.step_and_reset(world.ego_lane, speed)

    run(warmup)
    _sync(world.device)
    warm = time.perf_counter()
    run(steps)
    _sync(world.device)
    end = time.perf_counter()
    world.close()
    wall = end - warm
    rate = envs * steps / wall
    return {
        "what": "sim",
        "scenario": scenario,
        "traffic": traffic,
        "adversarial": adversarial,
        "envs": envs,
        "steps": steps,
        "device": str(world.device),
        "compile": compile,
        "processes": processes,
        "wall_s": round(wall, 4),
        "env_steps_per_s": round(rate, 1),
        "sim_s_per_wall_s": round(rate * DT_S, 1),
        "warmup_steps": warmup,
        "warmup_s": round(warm - start, 3),
        "env_steps_per_s_with_compile": round(envs * (steps + warmup) / (end - start), 1),
        "machine": machine(),
    }


def _spin() -> None:
    quiet_worker()  # Ctrl-C is the bench's to report; it ends the spinners itself
    while True:
        pass


def contended(measure, neighbours: int | None = None) -> dict:
    """measure() (a bench result dict) on an idle machine, then again beside `neighbours` busy processes
    (default: one per core; each spins in pure Python at the same priority, like another user's job).
    Returns {"idle": ..., "contended": ..., "ratio": contended / idle env-steps/s, "neighbours": n}."""
    import multiprocessing

    n = neighbours if neighbours is not None else (os.cpu_count() or 1)
    idle = measure()
    ctx = multiprocessing.get_context("spawn")  # a fork would copy torch's thread pools into the spinners
    spinners = []
    try:
        with held():  # the spinners start deaf to Ctrl-C (highway_srl/interrupts.py)
            for _ in range(n):
                spinners.append(ctx.Process(target=_spin, daemon=True))
                spinners[-1].start()
        time.sleep(0.5)  # let them be scheduled before the clock starts
        busy = measure()
    finally:
        for p in spinners:
            p.terminate()
        for p in spinners:
            p.join()
    return {"idle": idle, "contended": busy, "neighbours": n,
            "ratio": rate_of(busy) / max(rate_of(idle), 1e-9)}


def rate_of(result: dict) -> float:
    """The headline env-steps/s of a bench sim or bench train result (train: its first step form)."""
    if "env_steps_per_s" in result:
        return float(result["env_steps_per_s"])
    return float(next(iter(result["forms"].values()))["env_steps_per_s"])
