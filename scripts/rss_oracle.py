"""Where do our ego-avoidable verdicts and Intel's ad-rss disagree? Falsify's breadth search (every collision
of allowed-action episodes) judged twice: by rules.avoidable and by rules.rss_oracle (RSS's longitudinal
responsibility rule with ad-rss's safe distance). Prints one JSON object: the counts of agreement and of
each direction of disagreement, and the first disagreements with their cell, env and reasons.

    python scripts/rss_oracle.py --profile paper --episodes 256 --levels C,F
    python scripts/rss_oracle.py --profile safe --policy greedy-ttc

Needs the [rss] extra (ad-rss, Python 3.11).
"""

from __future__ import annotations

import argparse
import json

from highway_srl.constants import EPISODE_STEPS, SCENARIOS
from highway_srl.experiments.falsify import POLICIES, FalsifySettings, sweep_batch
from highway_srl.rules.rss_oracle import compare, load_ad_rss, rss_verdict


def judge(args) -> dict:
    settings = FalsifySettings(profile=args.profile, policy=args.policy, steps=EPISODE_STEPS)
    records, shown = [], []
    for scene in args.scenes.split(","):
        for level in args.levels.split(","):
            for adversarial in (False, True):
                _, cases = sweep_batch(scene, level, adversarial, settings, args.seed, args.episodes)
                for case in cases:
                    rec = case.record
                    records.append(rec)
                    verdict = rss_verdict(rec["kind"], rec["ego_changing"], rec["sv_changing"], rec["decisions"])
                    if verdict is not None and verdict != rec["ego_avoidable"] and len(shown) < args.show:
                        shown.append({"scene": scene, "level": level, "adversarial": adversarial, "seed": args.seed,
                                      "env": rec["env"], "ours": rec["reason"], "rss_holds_ego_responsible": verdict})
    return {"profile": args.profile, "policy": args.policy, "episodes_per_cell": args.episodes,
            **compare(records), "disagreements": shown}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--profile", default="paper", choices=("paper", "safe"))
    p.add_argument("--policy", default="uniform", choices=POLICIES)
    p.add_argument("--scenes", default=",".join(SCENARIOS))
    p.add_argument("--levels", default="C,F")
    p.add_argument("--episodes", type=int, default=256, help="episodes per scene, level and mode")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--show", type=int, default=5, help="disagreements listed")
    args = p.parse_args()
    try:
        load_ad_rss()
    except ValueError as missing:
        raise SystemExit(str(missing)) from None
    print(json.dumps(judge(args), indent=1))


if __name__ == "__main__":
    main()
