"""Throughput of every backend on one configuration, printed as a markdown table.

    python scripts/backends_bench.py                      # two-lane, level C
    python scripts/backends_bench.py --scenario merge --traffic D --seconds 5

Each run is the loop an agent drives: a step (the ego keeps its lane at a constant target speed) and the
neighbour snapshot of its lane and the next one, with episodes reset when they end. Reported: decision
steps per wall-clock second (env-steps for the batched World) and simulated seconds per wall second
(x δt = 0.125 s). Backends whose extra is not installed are listed as skipped.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from importlib import metadata

import torch

from highway_srl.backends import make_backend, missing_modules
from highway_srl.constants import DT_S
from highway_srl.sim.world import World

CRUISE_MPS = 7.0


def _loop(backend, seconds: float, warmup_steps: int = 20) -> tuple[float, int]:
    """Steps per second of step + neighbours over about `seconds` of wall time."""
    b = backend.num_envs
    speed = torch.full((b,), CRUISE_MPS)
    minus_one = torch.full((b,), -1, dtype=torch.long)

    def one() -> None:
        lane = backend.ego_lane
        ev = backend.step(lane, speed)
        adj = torch.where(lane + 1 < backend.road.num_lanes, lane + 1, minus_one)
        backend.neighbours(lane, adj)
        done = ev.terminated | ev.truncated
        if bool(done.any()):
            backend.reset(done if b > 1 else None)

    for _ in range(warmup_steps):
        one()
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        one()
        n += 1
    return n / (time.perf_counter() - t0), n


def _version(dist: str) -> str:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "not installed"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenario", default="two-lane")
    p.add_argument("--traffic", default="C")
    p.add_argument("--seconds", type=float, default=4.0, help="wall time per measurement")
    p.add_argument("--batch", type=int, default=4096, help="envs of the batched World")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)

    runs = [
        ("ours (World)", "1 env", lambda: World(args.scenario, args.traffic, num_envs=1, seed=args.seed)),
        ("ours (World)", f"{args.batch} envs", lambda: World(args.scenario, args.traffic, num_envs=args.batch, seed=args.seed)),
        ("SUMO (libsumo)", "1 env", lambda: make_backend("sumo", args.scenario, args.traffic, seed=args.seed)),
        ("highway-env", "1 env, 8 Hz physics", lambda: make_backend("highway-env", args.scenario, args.traffic, seed=args.seed)),
        ("highway-env", "1 env, 16 Hz physics", lambda: make_backend("highway-env", args.scenario, args.traffic,
                                                                      seed=args.seed, frames_per_step=2)),
    ]
    load = os.getloadavg()
    rows = []
    for name, config, build in runs:
        backend_name = "sumo" if name.startswith("SUMO") else "highway-env" if name.startswith("highway") else "ours"
        missing = missing_modules(backend_name)
        if missing:
            rows.append((name, config, "skipped", f"extra not installed ({', '.join(missing)})"))
            continue
        backend = build()
        steps_per_s, _ = _loop(backend, args.seconds)
        env_steps = steps_per_s * backend.num_envs
        rows.append((name, config, f"{env_steps:,.0f}", f"{env_steps * DT_S:,.0f}"))
        if hasattr(backend, "close"):
            backend.close()
        print(f"measured {name} {config}: {env_steps:,.0f} env-steps/s", file=sys.stderr)

    print(f"Scenario {args.scenario}, traffic level {args.traffic} ({args.seconds:g} s per row); step + neighbour "
          f"snapshot per decision; {os.cpu_count()} CPUs ({platform.processor() or platform.machine()}), "
          f"torch {torch.__version__} with {torch.get_num_threads()} threads, eclipse-sumo/libsumo "
          f"{_version('libsumo')}, highway-env {_version('highway-env')}; load average before the run "
          f"{load[0]:.1f} (other processes on the machine slow every row alike).\n")
    print("| simulator | configuration | env-steps/s | simulated s per wall s |")
    print("|---|---|---|---|")
    for r in rows:
        print("| " + " | ".join(r) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
