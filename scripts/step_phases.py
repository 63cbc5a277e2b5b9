"""Where one eager world step's wall time goes, by the step's functions (neighbour search, MOBIL, recycling...).

    OMP_NUM_THREADS=1 python scripts/step_phases.py --envs 2048

Why not the profiler: it times each ATen operation with its own overhead added, which on small tensors is a
good part of the operation; here each function of the step is wrapped with a timer and the step runs as it
would (the `bench sim` harness: two-lane C, the ego holding its lane at 8 m/s, a reset where an episode
ends). A function's time excludes the wrapped functions it calls (each row is its own part), so the rows add
up to the step. Prints one JSON object: ms per step in all and per function, largest first.
"""

from __future__ import annotations

import argparse
import collections
import functools
import json
import time

import torch

from highway_srl.sim import World, dynamics, sv_drivers
from highway_srl.sim import step as step_module

# (module, function) pairs timed; each is looked up where the step calls it from
PHASES = [
    (sv_drivers, "find_neighbours"), (sv_drivers, "car_following"), (sv_drivers, "yield_to_mergers"),
    (sv_drivers, "abort_unsafe_changes"), (sv_drivers, "mobil_lane_changes"),
    (sv_drivers, "occupancy"), (sv_drivers, "sorted_order"), (sv_drivers, "neighbour_keys"),
    (sv_drivers, "inverse_order"), (dynamics, "ego_control"), (dynamics, "lateral"), (dynamics, "sv_contacts"),
    (step_module, "ego_collision"), (step_module, "stage_events"), (step_module, "recycle"),
    (step_module, "spawn"), (dynamics, "move_vehicles"), (step_module, "step_state"),
]


def instrument(times: collections.Counter) -> None:
    """Wrap each phase so that times[name] gathers its own seconds (its wrapped callees' taken out)."""
    stack: list[str] = []

    def wrap(module, name: str) -> None:
        fn = getattr(module, name)

        @functools.wraps(fn)
        def timed(*args, **kwargs):
            stack.append(name)
            start = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                spent = time.perf_counter() - start
                stack.pop()
                times[name] += spent
                if stack:
                    times[stack[-1]] -= spent

        setattr(module, name, timed)

    for module, name in PHASES:
        wrap(module, name)
    reset = World.reset

    def timed_reset(self, mask=None):
        stack.append("reset")
        start = time.perf_counter()
        try:
            return reset(self, mask)
        finally:
            spent = time.perf_counter() - start
            stack.pop()
            times["reset"] += spent

    World.reset = timed_reset


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--envs", type=int, default=2048)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--warmup", type=int, default=20)
    args = parser.parse_args()
    if args.envs < 1 or args.steps < 1 or args.warmup < 0:
        parser.error("--envs and --steps must be positive, --warmup at least 0")
    times: collections.Counter = collections.Counter()
    instrument(times)
    world = World("two-lane", "C", num_envs=args.envs, seed=0)
    speed = torch.full((args.envs,), 8.0)
    for _ in range(args.warmup):
        world.step_and_reset(world.ego_lane, speed)
    times.clear()
    start = time.perf_counter()
    for _ in range(args.steps):
        world.step_and_reset(world.ego_lane, speed)
    total = time.perf_counter() - start
    ms = lambda s: round(1e3 * s / args.steps, 4)  # noqa: E731
    print(json.dumps({"envs": args.envs, "steps": args.steps, "threads": torch.get_num_threads(),
                      "ms_per_step": ms(total), "env_steps_per_s": round(args.envs * args.steps / total),
                      "ms_per_step_by_function": {k: ms(v) for k, v in times.most_common() if v > 0}}))


if __name__ == "__main__":
    main()
