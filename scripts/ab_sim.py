"""The simulator's speed in two or more checkouts (or settings), compared fairly on a noisy machine.

    OMP_NUM_THREADS=1 python scripts/ab_sim.py OLD_CHECKOUT NEW_CHECKOUT --envs 4096
    python scripts/ab_sim.py . . --env-a HIGHWAY_SRL_DEFAULT_MALLOC=1      # one setting against another
    python scripts/ab_sim.py . --envs 512,1024,2048,4096                   # one checkout, batch sizes
    python scripts/ab_sim.py . . --env-b AB_WORLD_PROCESSES=2             # World(processes=2) against 1

Why not one `bench sim` run after another: on a shared 2-core machine the same command varies 1.3-1.7x
from minute to minute, and processes of one command differ by themselves (a process's memory layout
decides part of its speed). So each side runs in --processes persistent worker processes (a World
stepped with the ego holding its lane, as `bench sim` does), and the workers step --block steps in turn,
in a shuffled order each round, so that every side sees the same minutes. Prints one JSON object: per
side, each process's median env-steps/s and their mean, and each side's mean over the first's.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import statistics
import subprocess
import sys
import time


def worker(args) -> None:
    """Step a World --block steps per line read from stdin; print the seconds each block took."""
    import torch

    from highway_srl.sim import World

    # AB_WORLD_PROCESSES: the World's own worker processes (World(processes=...)), a setting like any other
    processes = int(os.environ.get("AB_WORLD_PROCESSES", "1"))
    extra = {"processes": processes} if processes > 1 else {}  # older checkouts lack the keyword
    world = World(args.scenario, args.traffic, num_envs=args.envs, seed=0, **extra)
    speed = torch.full((args.envs,), 8.0)
    for _ in range(10):
        world.step_and_reset(world.ego_lane, speed)
    print("ready", flush=True)
    for line in sys.stdin:
        start = time.perf_counter()
        for _ in range(int(line)):
            world.step_and_reset(world.ego_lane, speed)
        print(time.perf_counter() - start, flush=True)


def compare(args) -> dict:
    sides = [(os.path.abspath(c), args.env_b if i > 0 else args.env_a, envs)
             for i, c in enumerate(args.checkouts) for envs in args.envs]
    procs = []
    for side, (checkout, extra, envs) in enumerate(sides):
        env = dict(os.environ, PYTHONPATH=checkout)
        env.update(kv.split("=", 1) for kv in extra)
        for _ in range(args.processes):
            cmd = [sys.executable, os.path.abspath(__file__), "--worker", "--envs", str(envs),
                   "--scenario", args.scenario, "--traffic", args.traffic]
            p = subprocess.Popen(cmd, cwd=checkout, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
            if p.stdout.readline().strip() != "ready":
                raise SystemExit(f"error: the worker in {checkout} did not start")
            procs.append((side, p, []))
    rng = random.Random(0)
    for _ in range(args.rounds):
        for side, p, times in rng.sample(procs, len(procs)):
            p.stdin.write(f"{block(args, sides[side][2])}\n")
            p.stdin.flush()
            times.append(float(p.stdout.readline()))
    for _, p, _ in procs:
        p.stdin.close()
        p.wait()
    out = {"scenario": args.scenario, "traffic": args.traffic, "block": args.block, "rounds": args.rounds,
           "threads": os.environ.get("OMP_NUM_THREADS", "(torch default)"), "sides": []}
    for side, (checkout, extra, envs) in enumerate(sides):
        steps = envs * block(args, envs)
        medians = [round(steps / statistics.median(t)) for s, _, t in procs if s == side]
        out["sides"].append({"checkout": checkout, "env": extra, "envs": envs, "process_medians": medians,
                             "mean_env_steps_per_s": round(statistics.mean(medians))})
    base = out["sides"][0]["mean_env_steps_per_s"]
    for s in out["sides"]:
        s["over_first"] = round(s["mean_env_steps_per_s"] / base, 3)
    return out


def block(args, envs: int) -> int:
    """Steps per turn: --block at the largest batch, more at smaller ones (the same env-steps per turn)."""
    return max(1, args.block * max(args.envs) // envs)


def env_counts(text: str) -> list[int]:
    try:
        counts = [int(c) for c in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"--envs takes positive integers separated by commas, got {text!r}") from None
    if not counts or min(counts) < 1:
        raise argparse.ArgumentTypeError(f"--envs takes positive integers separated by commas, got {text!r}")
    return counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkouts", nargs="*", help="source trees (the first is the reference)")
    parser.add_argument("--envs", type=env_counts, default=[4096], help="batch size(s), e.g. 4096 or 512,4096")
    parser.add_argument("--scenario", default="two-lane")
    parser.add_argument("--traffic", default="C")
    parser.add_argument("--processes", type=int, default=3, help="worker processes per side")
    parser.add_argument("--block", type=int, default=8, help="steps a worker takes per turn at the largest --envs")
    parser.add_argument("--rounds", type=int, default=12)
    parser.add_argument("--env-a", nargs="*", default=[], metavar="K=V", help="environment of the first side")
    parser.add_argument("--env-b", nargs="*", default=[], metavar="K=V", help="environment of the other sides")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        args.envs = args.envs[0]
        return worker(args)
    if len(args.checkouts) * len(args.envs) < 2:
        parser.error("give two checkouts (the same one twice to compare --env-a with --env-b) or several --envs")
    for c in args.checkouts:
        if not os.path.isdir(os.path.join(c, "highway_srl")):
            parser.error(f"{c} is not a highway-srl checkout (no highway_srl folder)")
    for kv in args.env_a + args.env_b:
        if "=" not in kv:
            parser.error(f"environment settings are K=V, got {kv!r}")
    print(json.dumps(compare(args)))


if __name__ == "__main__":
    main()
