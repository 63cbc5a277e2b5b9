"""What a trained run's deployment collisions were: the ego into the car ahead, hit from behind, a side
contact or the road, and who was changing lanes (highway_srl.experiments.collisions).

    python scripts/collision_census.py RUN [--traffic E,F] [--episodes 100] [--profile paper|safe]

The census is evaluate's own (every evaluation on our simulator writes it into eval.json's levels); this
runs the evaluation without writing a file and prints each level's C_r beside what its collisions were.
One JSON object on stdout.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from highway_srl.experiments.evaluate import evaluate_run  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run", help="a trained run folder")
    p.add_argument("--traffic", default="E,F", help="comma-separated levels (default E,F)")
    p.add_argument("--episodes", type=int, default=100, help="per seed and level (default 100, as evaluate)")
    p.add_argument("--profile", default=None, help="control profile to deploy under (default: the run's)")
    args = p.parse_args(argv)
    try:
        report = evaluate_run(args.run, traffics=[t.strip() for t in args.traffic.split(",") if t.strip()],
                              episodes=args.episodes, profile=args.profile)
    except (ValueError, OSError) as err:
        p.error(str(err))
    out = {"run": args.run, "method": report["method"], "scenario": report["scenario"],
           "profile": report["profile"], "episodes_per_level": args.episodes, "levels": {}}
    for traffic, level in report["levels"].items():
        out["levels"][traffic] = {"C_r": level["C_r"]["value"], **level["collisions"]}
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
