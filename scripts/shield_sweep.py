"""How safe is the shield on its own? Random actions (ExG's distribution) through the MoE gate, every scenario
and level, nominal and adversarial: collision-free rate and lane changes per episode. Prints a Markdown table.

    python scripts/shield_sweep.py --episodes 256 --levels A,C,F
    python scripts/shield_sweep.py --levels C --profile safe --set straddle_grouping=false   # one addition off
"""

from __future__ import annotations

import argparse
import time

from highway_srl.constants import EPISODE_STEPS, SCENARIOS
from highway_srl.experiments.falsify import FalsifySettings, sweep_batch


def sweep(scenario: str, level: str, adversarial: bool, episodes: int, seed: int, profile: str = "safe",
          **layer_options) -> dict:
    """ExG's random safe actions in `episodes` envs (falsify's breadth search with policy exg, the mild
    adversary): the collision-free share and the share of episodes with a lane change."""
    settings = FalsifySettings(profile=profile, policy="exg", steps=EPISODE_STEPS, adversary="mild")
    counts, _ = sweep_batch(scenario, level, adversarial, settings, seed, episodes, **layer_options)
    return {"collision_free": 1.0 - counts["collisions"] / episodes, "changed_lane": counts["changed_lane"] / episodes}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--episodes", type=int, default=256)
    p.add_argument("--levels", default="A,C,F")
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--scenarios", default=",".join(SCENARIOS))
    p.add_argument("--modes", default="nominal,adversarial")
    p.add_argument("--profile", default="safe", help="SafetyLayer profile: paper or safe")
    p.add_argument("--set", action="append", default=[], metavar="OPTION=VALUE",
                   help="a SafetyLayer option over the profile, e.g. finish_in_window=false, standstill_gap_m=0")
    args = p.parse_args()
    options = {"profile": args.profile}
    for item in args.set:
        name, _, value = item.partition("=")
        options[name] = {"true": True, "false": False}.get(value.lower(), None)
        if options[name] is None:
            options[name] = float(value)
    t0 = time.time()
    print("| scenario | mode | level | episodes | collision-free | episodes with a lane change |")
    print("|---|---|---|---|---|---|")
    for scenario in args.scenarios.split(","):
        for adversarial in [m == "adversarial" for m in args.modes.split(",")]:
            for level in args.levels.split(","):
                r = sweep(scenario, level, adversarial, args.episodes, args.seed, **options)
                mode = "adversarial" if adversarial else "nominal"
                print(f"| {scenario} | {mode} | {level} | {args.episodes} | {r['collision_free']:.1%} | {r['changed_lane']:.0%} |",
                      flush=True)
    print(f"\n{time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
