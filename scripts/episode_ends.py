"""Where a trained run's deployment episodes end: success, collision, another terminal failure, or out of
time, and for the episodes that ran out of time, how far the ego got, in which lane, at what speed and
whether a car was ahead of it in its lane.

    python scripts/episode_ends.py RUN [--traffic C] [--episodes 50] [--seed 0]

Same episodes as `highway-srl evaluate RUN --traffic T --episodes N --seed S` (evaluate's env seeds, nominal
traffic, the run's own profile). Why it exists: in the exit scene success ends the episode at x3 = 220 m in
the off-ramp lane, while the stage flags pay every step once latched, so a policy can earn more by stopping
short of the line than by crossing it; this shows whether it does. Prints one JSON object.
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from highway_srl.experiments.evaluate import evaluation_seeds, run_episodes  # noqa: E402
from highway_srl.experiments.policy import load_policy  # noqa: E402
from highway_srl.sim import World  # noqa: E402


def episode_ends(run: str, traffic: str, episodes: int, seed: int) -> dict:
    policy = load_policy(run)
    cfg, seeds = policy.config, len(policy.config.seeds)
    world = World(cfg.scenario, traffic, False, episodes * seeds, "cpu", evaluation_seeds(seeds, episodes, seed),
                  adversary=cfg.adversary)
    b = world.num_envs
    last = {"x": torch.zeros(b), "v": torch.zeros(b), "lane": torch.zeros(b, dtype=torch.long),
            "car_ahead": torch.zeros(b, dtype=torch.bool), "truncated": torch.zeros(b, dtype=torch.bool)}

    def after_step(w, events, alive):  # the state each episode ended in (later steps of an ended env ignored)
        s = w.state
        ahead = (s.lane[:, 1:] == s.lane[:, :1]) & (s.x[:, 1:] > s.x[:, :1])  # an SV ahead in the ego's lane
        now = {"x": s.x[:, 0], "v": s.v[:, 0], "lane": s.lane[:, 0], "car_ahead": ahead.any(dim=1),
               "truncated": events.truncated & ~events.terminated}
        for key, value in now.items():
            last[key] = torch.where(alive, value, last[key])

    results = run_episodes(world, policy.method, policy.learner, after_step=after_step)
    success, collided = results["success"].bool(), results["collided"].bool()
    timed_out = last["truncated"] & ~success & ~collided
    def deciles(values):  # 10th, 50th and 90th percentiles of the out-of-time episodes' values
        q = torch.quantile(values[timed_out], torch.tensor([0.1, 0.5, 0.9])).tolist() if bool(timed_out.any()) else []
        return [round(v, 2) for v in q]
    return {"run": run, "method": cfg.method, "scenario": cfg.scenario, "traffic": traffic,
            "episodes": world.num_envs, "success": int(success.sum()), "collision": int(collided.sum()),
            "other_terminal": int((~success & ~collided & ~last["truncated"]).sum()),
            "out_of_time": int(timed_out.sum()),
            "out_of_time_x_m_p10_p50_p90": deciles(last["x"]),
            "out_of_time_speed_mps_p10_p50_p90": deciles(last["v"]),
            "out_of_time_no_car_ahead": int((timed_out & ~last["car_ahead"]).sum()),
            "out_of_time_by_lane": dict(sorted(collections.Counter(last["lane"][timed_out].tolist()).items())),
            "avg_speed_mps": round(float(results["avg_speed"].mean()), 3)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="episode_ends.py", description=__doc__.splitlines()[0])
    p.add_argument("run", help="a trained run folder (config.json and model/)")
    p.add_argument("--traffic", default="C", help="traffic level A-F (default C)")
    p.add_argument("--episodes", type=int, default=50, help="episodes per trained seed (default 50)")
    p.add_argument("--seed", type=int, default=0, help="evaluate's seed (default 0)")
    args = p.parse_args(argv)
    if args.episodes < 1:
        p.error(f"--episodes must be positive, got {args.episodes}")
    if not (Path(args.run) / "config.json").is_file():
        p.error(f"{args.run} is not a trained run folder (no config.json)")
    try:
        print(json.dumps(episode_ends(args.run, args.traffic, args.episodes, args.seed), indent=1))
    except (ValueError, FileNotFoundError) as err:
        p.error(str(err))
    return 0


if __name__ == "__main__":
    sys.exit(main())
