"""The built-in ego drivers' gap rule (2 m + speed terms) against a 6 m rule and no gap check at all.

    OMP_NUM_THREADS=1 .venv/bin/python scripts/gap_rule_table.py --what world        # about 3 + 5 min
    OMP_NUM_THREADS=1 .venv/bin/python scripts/gap_rule_table.py --what rule-based   # about 1.5 min a rule
    OMP_NUM_THREADS=1 .venv/bin/python scripts/gap_rule_table.py --what backends     # about 10 min a rule

Each part runs once per rule (--rules, default "2m,6m"; "none" = no gap check at
all) by putting that rule in the place of sim/ego_driver.room_to_change and prints one JSON object:
  world       idm_ego and idm_ego_backend on World, 200 envs' first episodes of merge / exit x A / C / F x
              nominal (seeds 5000+) / adversarial (6000+): success, collision and failure rates in %
  rule-based  the rule-based method's evaluation (evaluate_run, 200 episodes per level A / C / F, nominal
              and adversarial) on merge and exit: C_r, R_s, R_r, average speed
  backends    idm_ego_backend in SUMO and highway-env, one nominal episode of each seed 0-9 of merge / exit
              x A / C: successes, collisions, mean steps to the end
The rules (gaps bumper to bumper, v the ego's speed, v_a / v_b the cars ahead / behind in the target lane):
  2m  ahead  gap > 2 + 0.5 v + 2.5 (v - v_a)+,  behind  gap > 2 + 0.5 v_b + 2.5 (v_b - v)+   (the one in use)
  6m  ahead  gap > 6 + 1.0 v,                   behind  gap > 6 + 2.0 (v_b - v)+
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import torch

from highway_srl.agents import rule_based
from highway_srl.sim import World, ego_driver


def rule_6m(gap_a, v_a, gap_b, v_b, v):
    return (gap_a > 6.0 + 1.0 * v) & (gap_b > 6.0 + (v_b - v).clamp(min=0) * 2.0)


def rule_none(gap_a, v_a, gap_b, v_b, v):
    return torch.ones_like(gap_a, dtype=torch.bool)


RULES = {"2m": ego_driver.room_to_change, "6m": rule_6m, "none": rule_none}


def use(rule: str) -> None:
    ego_driver.room_to_change = RULES[rule]
    rule_based.room_to_change = RULES[rule]


def first_episodes(world: World, driver) -> dict:
    """Success / collision / failure rate (%) of each env's first episode."""
    alive = torch.ones(world.num_envs, dtype=torch.bool)
    hit = {k: torch.zeros(world.num_envs, dtype=torch.bool) for k in ("success", "collision", "failure")}
    for _ in range(world.max_steps):
        ev = world.step(*driver(world))
        for k in hit:
            hit[k] |= alive & getattr(ev, k)
        alive &= ~(ev.terminated | ev.truncated)
        if not bool(alive.any()):
            break
    return {f"{k}%": round(100 * float(v.float().mean()), 1) for k, v in hit.items()}


def world_drivers(envs: int = 200) -> dict:
    out = {}
    for name in ("idm_ego", "idm_ego_backend"):
        for scenario in ("merge", "exit"):
            for level in ("A", "C", "F"):
                for adversarial in (False, True):
                    world = World(scenario, level, adversarial, envs, "cpu", seed=6000 if adversarial else 5000)
                    key = f"{name} {scenario} {level}{' adv' if adversarial else ''}"
                    out[key] = first_episodes(world, getattr(ego_driver, name))
    return out


def rule_based_method(episodes: int = 200) -> dict:
    from highway_srl.cli import main
    from highway_srl.experiments.evaluate import evaluate_run

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for scenario in ("merge", "exit"):
            run = Path(tmp) / scenario
            main(["train", "--method", "rule-based", "--scenario", scenario, "--steps", "8", "--envs", "4",
                  "--out", str(run), "--quiet"])
            for adversarial in (False, True):
                report = evaluate_run(run, traffics=["A", "C", "F"], episodes=episodes, adversarial=adversarial)
                for level, m in report["levels"].items():
                    out[f"rule-based {scenario} {level}{' adv' if adversarial else ''}"] = {
                        k: round(m[k]["value"], 3) for k in ("C_r", "R_s", "R_r", "avg_speed")}
    return out


def backends(seeds=range(10)) -> dict:
    from highway_srl.backends import make_backend

    out = {}
    for name in ("sumo", "highway-env"):
        for scenario in ("merge", "exit"):
            for level in ("A", "C"):
                success = collision = steps = 0
                for seed in seeds:
                    b = make_backend(name, scenario=scenario, traffic=level, seed=seed)
                    for t in range(b.max_steps):
                        ev = b.step(*ego_driver.idm_ego_backend(b))
                        collision += int(ev.collision[0])
                        success += int(ev.success[0])
                        if bool(ev.terminated[0] | ev.truncated[0] | ev.success[0]):
                            break
                    steps += t
                    if hasattr(b, "close"):
                        b.close()
                out[f"{name} {scenario} {level}"] = {"success": f"{success}/{len(seeds)}",
                                                     "collision": f"{collision}/{len(seeds)}",
                                                     "mean_steps": steps / len(seeds)}
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--what", choices=("world", "rule-based", "backends"), required=True)
    p.add_argument("--rules", default="2m,6m", help="comma-separated: 2m, 6m, none")
    args = p.parse_args()
    torch.set_num_threads(1)
    part = {"world": world_drivers, "rule-based": rule_based_method, "backends": backends}[args.what]
    for rule in args.rules.split(","):
        t0 = time.time()
        use(rule)
        print(json.dumps({"rule": rule, **part(), "seconds": round(time.time() - t0)}, indent=1), flush=True)


if __name__ == "__main__":
    main()
