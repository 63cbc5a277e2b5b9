"""Where a World(processes=P) step's time goes: each slice's own step, and the rest (the round trip).

    OMP_NUM_THREADS=1 python scripts/processes_timing.py --envs 4096 --processes 2

Wraps World.step_and_reset before the world forks its workers, so that every slice's view (the one this
process steps and the workers') times its own step into a shared buffer. Prints one JSON object: the mean
step (ms, as the caller sees it), each slice's mean busy time, the mean of the slowest slice's, and the
step's time beyond the slowest slice (waking, waiting, the commands and events through shared buffers).
"""

from __future__ import annotations

import argparse
import json
import time

import torch

from highway_srl.sim import World
from highway_srl.sim.processes import slices


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--envs", type=int, default=4096)
    p.add_argument("--processes", type=int, default=2)
    p.add_argument("--steps", type=int, default=300)
    args = p.parse_args()
    if args.steps < 1 or not 2 <= args.processes <= args.envs:
        p.error(f"need --steps >= 1 and 2 <= --processes <= --envs, got {args.steps}, {args.processes}, {args.envs}")
    torch.set_num_threads(1)
    busy = torch.zeros(args.processes, args.steps, dtype=torch.float64).share_memory_()
    count = torch.zeros(args.processes, dtype=torch.long).share_memory_()
    first_seed = {}  # each slice's first env's seed -> its slice number (seeds are 0, 1, ..., envs - 1)
    plain = World.step_and_reset

    def timed(world, lane, speed):
        start = time.perf_counter()
        events = plain(world, lane, speed)
        if world.num_envs < args.envs:  # a slice's view, not the whole world
            i = first_seed[int(world.state.seed[0])]
            busy[i, int(count[i]) % args.steps] = time.perf_counter() - start
            count[i] += 1
        return events

    first_seed.update({lo: i for i, (lo, _) in enumerate(slices(args.envs, args.processes))})
    World.step_and_reset = timed
    world = World("two-lane", "C", num_envs=args.envs, seed=0, processes=args.processes)
    speed = torch.full((args.envs,), 8.0)
    for _ in range(30):
        world.step_and_reset(world.ego_lane, speed)
    count.zero_()
    steps = []
    for _ in range(args.steps):
        start = time.perf_counter()
        world.step_and_reset(world.ego_lane, speed)
        steps.append(time.perf_counter() - start)
    world.close()
    step, b = torch.tensor(steps, dtype=torch.float64) * 1e3, busy * 1e3
    print(json.dumps({"envs": args.envs, "processes": args.processes, "steps": args.steps,
                      "step_ms": round(float(step.mean()), 3),
                      "slice_busy_ms": [round(float(x), 3) for x in b.mean(1)],
                      "slowest_slice_ms": round(float(b.max(0).values.mean()), 3),
                      "beyond_slowest_ms": round(float((step - b.max(0).values).mean()), 3),
                      "env_steps_per_s": round(args.envs / float(step.mean()) * 1e3)}))


if __name__ == "__main__":
    main()
