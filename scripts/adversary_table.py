"""Group 3 per scene: triggers and cut-ins per episode, and the share of cut-ins that end in a collision, for
the rule-based driver (agents/rule_based.py through the mapped SafetyLayer) under each adversary. Prints a
Markdown table (docs/paper-notes.md, "The paper's adversary").

    python scripts/adversary_table.py --episodes 100 --level C --adversaries mild,paper --profile safe

A cut-in "ends in a collision" when the ego collides within --window-s seconds of the cut-in's start (a
collision ends the episode, so an episode counts at most one).
"""

from __future__ import annotations

import argparse
import time

import torch

from highway_srl.agents.registry import make_method
from highway_srl.constants import DT_S, SCENARIOS
from highway_srl.experiments.evaluate import EVAL_SEED_BASE
from highway_srl.rules import SafetyLayer
from highway_srl.sim import World


def adversary_stats(scenario: str, level: str, adversary: str, episodes: int, profile: str = "safe",
                    window_s: float = 5.0, seed: int = EVAL_SEED_BASE) -> dict:
    """One episode per env of the rule-based driver; counts per episode and collisions after cut-ins."""
    world = World(scenario, level, True, episodes, "cpu", seed, adversary=adversary)
    method = make_method("rule-based", scenario, 1)
    layer = SafetyLayer(world.road, profile=profile, **method.layer_options)
    alive = torch.ones(episodes, dtype=torch.bool)
    collided = torch.zeros(episodes, dtype=torch.bool)
    after_cut_in = torch.zeros(episodes, dtype=torch.bool)
    last_cut_in = torch.full((episodes,), -10**6)
    counts = {k: torch.zeros(episodes, dtype=torch.long) for k in ("triggers", "cut_ins")}
    no_explore = torch.zeros(episodes, dtype=torch.bool)
    step = layer.observe(world)
    window = round(window_s / DT_S)
    for t in range(world.max_steps):
        decision = method.decide(None, step, no_explore, None)
        before = world.adversary_counts()["cut_ins"]
        events = world.step(*layer.act(decision.action, decision.use_second))
        step = layer.observe(world)
        now = world.adversary_counts()
        last_cut_in = torch.where(alive & (now["cut_ins"] > before), t, last_cut_in)
        for k in counts:
            counts[k] = torch.where(alive, now[k], counts[k])
        hit = alive & events.collision
        collided |= hit
        after_cut_in |= hit & (t - last_cut_in <= window)
        alive &= ~(events.terminated | events.truncated)
        if not bool(alive.any()):
            break
    cut_ins = int(counts["cut_ins"].sum())
    return {"triggers": float(counts["triggers"].float().mean()), "cut_ins": float(counts["cut_ins"].float().mean()),
            "cut_in_collisions": int(after_cut_in.sum()), "cut_ins_total": cut_ins,
            "collision_share": int(after_cut_in.sum()) / cut_ins if cut_ins else float("nan"),
            "C_r": float((~collided).float().mean()), "collisions": int(collided.sum())}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--level", default="C")
    p.add_argument("--scenarios", default=",".join(SCENARIOS))
    p.add_argument("--adversaries", default="mild,paper")
    p.add_argument("--profile", default="safe", help="the rule-based driver's SafetyLayer profile")
    p.add_argument("--window-s", type=float, default=5.0)
    args = p.parse_args()
    torch.set_num_threads(1)
    t0 = time.time()
    print(f"rule-based driver, level {args.level}, {args.episodes} episodes per cell, profile {args.profile}, "
          f"seeds {EVAL_SEED_BASE}+\n")
    print("| scene | adversary | triggers / episode | cut-ins / episode | cut-ins ending in a collision | C_r |")
    print("|---|---|---|---|---|---|")
    for scenario in args.scenarios.split(","):
        for adversary in args.adversaries.split(","):
            r = adversary_stats(scenario, args.level, adversary, args.episodes, args.profile, args.window_s)
            share = "–" if not r["cut_ins_total"] else f"{r['collision_share']:.0%} ({r['cut_in_collisions']} of {r['cut_ins_total']})"
            print(f"| {scenario} | {adversary} | {r['triggers']:.2f} | {r['cut_ins']:.2f} | {share} | "
                  f"{r['C_r']:.0%} ({r['collisions']} of {args.episodes} collide) |", flush=True)
    print(f"\n{time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
