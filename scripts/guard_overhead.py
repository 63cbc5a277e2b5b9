"""Host time of dynamo's guard checks on the compiled graphs, all guards checked vs settled (only the guards
that tell a graph's versions apart: sim.world.call_settled), alternated in one process.

    python scripts/guard_overhead.py world   # one env, World(compile=True): inductor, minutes on a cold cache
    python scripts/guard_overhead.py train   # MoE-RM-SRL, 16 envs, replay ratio 1, captured with aot_eager

Prints one JSON line: steps/s of three alternated runs per setting and the guards' time per step (the torch
profiler's "TorchDynamo Cache Lookup" self time); train also the CUDA-graph bookkeeping's time a call
(trainer.state_keeping_call). docs/benchmarks.md has the figures."""

from __future__ import annotations

import argparse
import json
import time

import torch
from torch.profiler import profile

from highway_srl.sim import world as world_module


def guard_us_per_step(run, steps: int) -> float:
    with profile() as prof:
        for _ in range(steps):
            run()
    lookups = [e for e in prof.key_averages() if "Cache Lookup" in e.key]
    return round(sum(e.self_cpu_time_total for e in lookups) / steps, 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("what", choices=("world", "train"))
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.what == "world":
        world = world_module.World("two-lane", "C", num_envs=1, seed=0, compile=True)
        lane, speed = world.ego_lane.clone(), torch.full((1,), 25.0)
        run, steps = (lambda: world.step_and_reset(lane, speed)), 3000
    else:
        from highway_srl.agents.dqn import DQNConfig
        from highway_srl.agents.trainer import TrainConfig, Trainer

        cfg = TrainConfig(method="moe-rm-srl", scenario="two-lane", traffic="C", envs=16, seeds=(0,), device="cpu",
                          steps=10**9, replay_ratio=1.0, static=True, compile="aot_eager",
                          dqn=DQNConfig(learning_starts=0, batch_size=32, buffer_capacity=512))
        trainer = Trainer(cfg, drain_every=50)
        while int(trainer.replay.size.max()) < cfg.dqn.batch_size:
            trainer.step()
        run, steps = trainer.step, 10
    for _ in range(5):  # compiled, and past the calls that check every guard
        run()
    out: dict[str, list[float] | float] = {}
    try:
        for _ in range(3):
            for check in (True, False):
                world_module.CHECK_GUARDS = check
                start = time.perf_counter()
                for _ in range(steps):
                    run()
                out.setdefault(f"steps_per_s_check_guards_{check}", []).append(
                    round(steps / (time.perf_counter() - start), 1))
        for check in (True, False):
            world_module.CHECK_GUARDS = check
            out[f"guard_us_per_step_check_guards_{check}"] = guard_us_per_step(run, min(steps, 300))
    finally:
        world_module.CHECK_GUARDS = False
    if args.what == "train":  # the CUDA-graph bookkeeping around each trainer call, on an empty graph
        from highway_srl.agents.trainer import state_keeping_call

        keeping = state_keeping_call(trainer)
        keeping(lambda: None)  # the first call imports the CUDA-graph machinery
        start = time.perf_counter()
        for _ in range(2000):
            keeping(lambda: None)
        out["state_keeping_call_us"] = round((time.perf_counter() - start) / 2000 * 1e6, 1)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
