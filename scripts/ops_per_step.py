"""How many tensor operations one world step runs (eager, compact form), and in which functions.

    python scripts/ops_per_step.py --envs 4096

Why count: on the CPU each eager operation costs a fixed 5-10 us of dispatch (Python, argument parsing,
the kernel's setup) whatever its size, so at small batches the step's time is its operation count; and a
count, unlike a timing, does not depend on how busy the machine is. Views (reshape, select, expand, ...) are
not counted: they launch no kernel. Prints one JSON object: the mean count per step and the count per
innermost highway_srl function. --times adds where the time goes: the wall time per step (timed alone)
and, from the torch profiler over as many steps, each ATen operation's calls and self time per step (the
time inside the operation, dispatch included; the profiler itself slows the step a little).
"""

from __future__ import annotations

import argparse
import collections
import json
import time
import traceback

import torch
from torch.utils._python_dispatch import TorchDispatchMode

from highway_srl.sim import World

VIEWS = {"view", "reshape", "select", "slice", "expand", "unsqueeze", "squeeze", "t", "transpose", "as_strided",
         "_unsafe_view", "permute", "detach", "alias", "unbind", "split", "_reshape_alias"}


class CountOps(TorchDispatchMode):
    def __init__(self) -> None:
        super().__init__()
        self.by_function: collections.Counter = collections.Counter()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        name = func.overloadpacket.__name__
        if name not in VIEWS:
            frames = [f for f in traceback.extract_stack() if "highway_srl" in f.filename]
            self.by_function[frames[-1].name if frames else "?"] += 1
        return func(*args, **(kwargs or {}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--envs", type=int, default=4096)
    parser.add_argument("--scenario", default="two-lane")
    parser.add_argument("--traffic", default="C")
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--times", action="store_true", help="also the wall time per step and the profiler's "
                        "self time per operation")
    args = parser.parse_args()
    if args.envs < 1 or args.steps < 1:
        parser.error("--envs and --steps are positive integers")
    world = World(args.scenario, args.traffic, num_envs=args.envs, seed=0)
    speed = torch.full((args.envs,), 8.0)
    for _ in range(10):  # past the first steps' one-off work
        world.step_and_reset(world.ego_lane, speed)
    counter = CountOps()
    with counter:
        for _ in range(args.steps):
            world.step_and_reset(world.ego_lane, speed)
    per_step = {k: round(v / args.steps, 1) for k, v in counter.by_function.most_common()}
    result = {"envs": args.envs, "scenario": args.scenario, "traffic": args.traffic,
              "ops_per_step": round(sum(counter.by_function.values()) / args.steps, 1), "by_function": per_step}
    if args.times:
        result.update(step_times(world, speed, args.steps))
    print(json.dumps(result))


def step_times(world: World, speed: torch.Tensor, steps: int) -> dict:
    """Wall ms per step, and per ATen operation its calls and self ms per step under the profiler (top 20)."""
    from torch.profiler import ProfilerActivity, profile

    t0 = time.perf_counter()
    for _ in range(steps):
        world.step_and_reset(world.ego_lane, speed)
    wall_ms = 1e3 * (time.perf_counter() - t0) / steps
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(steps):
            world.step_and_reset(world.ego_lane, speed)
    ops = [e for e in prof.key_averages() if e.key.startswith("aten::")]
    ops.sort(key=lambda e: -e.self_cpu_time_total)
    return {"wall_ms_per_step": round(wall_ms, 2),
            "profiled_self_ms_per_step": round(sum(e.self_cpu_time_total for e in ops) / 1e3 / steps, 2),
            "by_op": {e.key[6:]: {"calls": round(e.count / steps, 1),
                                  "self_ms": round(e.self_cpu_time_total / 1e3 / steps, 3)} for e in ops[:20]}}


if __name__ == "__main__":
    main()
