"""Where the static world step spends its time, per part, eager and compiled: each of the step's functions
(neighbour search, car following, MOBIL, lateral control, contacts, recycling, ...) and the resets' full
spawn, compiled on its own (inductor, fullgraph, static shapes) or run eagerly in the static form.

    OMP_NUM_THREADS=2 python scripts/compiled_parts.py --envs 4096

Prints one JSON line: ms per step of each part, eager static and compiled (minutes of compilation on a cold
cache). docs/benchmarks.md has the figures."""

from __future__ import annotations

import argparse
import json
import time

import torch

from highway_srl.sim import dynamics, traffic_model
from highway_srl.sim import world as world_module

PARTS = {traffic_model: ("find_neighbours", "car_following", "yield_to_mergers", "abort_unsafe_changes",
                         "mobil_lane_changes"),
         dynamics: ("lateral", "sv_contacts", "ego_control"),
         world_module: ("ego_collision", "stage_events", "recycle", "spawn")}


def timed_parts(compiled: bool, totals: dict[str, float]) -> None:
    """Replace each part by a timed (and, if compiled, torch.compile'd) version of itself."""
    for module, names in PARTS.items():
        for name in names:
            fn = getattr(module, name)
            run = torch.compile(fn, fullgraph=True, dynamic=False) if compiled else fn

            def timed(*args, _run=run, _name=name, **kwargs):
                start = time.perf_counter()
                out = _run(*args, **kwargs)
                totals[_name] = totals.get(_name, 0.0) + time.perf_counter() - start
                return out

            setattr(module, name, timed)


def measure(envs: int, steps: int, compiled: bool) -> dict:
    originals = {(m, n): getattr(m, n) for m, names in PARTS.items() for n in names}
    totals: dict[str, float] = {}
    timed_parts(compiled, totals)
    try:
        world = world_module.World("two-lane", "C", num_envs=envs, seed=0)
        world.static = True
        lane, speed = world.ego_lane.clone(), torch.full((envs,), 25.0)
        for _ in range(3):  # compiled (when compiled) and warm
            events = world.step(lane, speed)
            world.reset_where(events.terminated | events.truncated)
        totals.clear()
        start = time.perf_counter()
        for _ in range(steps):
            events = world.step(lane, speed)
            world.reset_where(events.terminated | events.truncated)
        wall = time.perf_counter() - start
    finally:
        for (module, name), fn in originals.items():
            setattr(module, name, fn)
    parts = {name: round(1e3 * t / steps, 2) for name, t in sorted(totals.items(), key=lambda kv: -kv[1])}
    return {"ms_per_step": round(1e3 * wall / steps, 2), "parts_ms": parts}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--envs", type=int, default=4096)
    parser.add_argument("--steps", type=int, default=10)
    args = parser.parse_args()
    out = {"envs": args.envs, "threads": torch.get_num_threads(),
           "eager_static": measure(args.envs, args.steps, False),
           "compiled_parts": measure(args.envs, args.steps, True)}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
