"""What a trained run's greedy policy does: the share of each action it picks over a fixed rollout, and for
ET-RL the DQN's proposals and how often the expert takes over.

    python scripts/action_census.py results/quick/runs/two-lane/et-rl [RUN ...] [--traffic C] [--steps 320]

Each run drives 8 envs per seed of its own scenario (nominal) for --steps steps, exploration off, finished
episodes reset; env seeds 1000, 1001, ... (not the training seeds).
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from highway_srl.experiments.policy import load_policy  # noqa: E402
from highway_srl.rules.episode import advance  # noqa: E402
from highway_srl.sim import World  # noqa: E402

ENVS_PER_SEED = 8


def census(run: str, traffic: str, steps: int) -> dict:
    policy = load_policy(run)
    method, learner, cfg = policy.method, policy.learner, policy.config
    batch = ENVS_PER_SEED * len(cfg.seeds)
    world = World(cfg.scenario, traffic, False, batch, "cpu", list(range(1000, 1000 + batch)), adversary=cfg.adversary)
    layer = method.make_layer(world.road)
    executed, proposed, takeovers = collections.Counter(), collections.Counter(), 0
    greedy = torch.zeros(batch, dtype=torch.bool)
    for _ in range(steps):
        decision = method.decide(learner, layer.observe(world), greedy, None)
        executed.update(decision.action.tolist())
        if hasattr(method, "takeover"):  # ET-RL keeps its DQN's proposal and whether the expert overrode it
            proposed.update(method.proposal.tolist())
            takeovers += int(method.takeover.sum())
        events, _, _ = advance(world, layer, decision.action, decision.use_second)
        done = events.terminated | events.truncated
        if bool(done.any()):
            world.reset(done)
            layer.reset(done)
    n = steps * batch
    names = method.action_names
    out = {"run": run, "method": cfg.method, "scenario": cfg.scenario, "traffic": traffic, "decisions": n,
           "executed": {names[a]: round(c / n, 4) for a, c in sorted(executed.items())}}
    if proposed:
        out["proposed"] = {names[a]: round(c / n, 4) for a, c in sorted(proposed.items())}
        out["takeover_share"] = round(takeovers / n, 4)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", help="finished run folders")
    p.add_argument("--traffic", default="C", help="traffic level A-F (default C)")
    p.add_argument("--steps", type=int, default=320, help="steps of the rollout (default 320, one episode)")
    args = p.parse_args(argv)
    if args.steps < 1:
        p.error(f"--steps must be positive, got {args.steps}")
    torch.set_num_threads(1)
    for run in args.runs:
        try:
            print(json.dumps(census(run, args.traffic, args.steps)))
        except (ValueError, OSError) as err:
            print(f"action_census: {run}: {err}", file=sys.stderr)
            return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
