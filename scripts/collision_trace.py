"""Through which decision a trained run's deployment collisions came about: what the rule layer allowed in
the last second before each one and what was executed (highway_srl.experiments.collisions.DecisionTrace).

    python scripts/collision_trace.py RUN [--traffic C] [--episodes 100] [--show 3] [--set OPTION=VALUE]

The episodes are evaluate's own (the same world seeds, greedy, the run's profile). The census
(scripts/collision_census.py) says what was hit; this puts each collision in the first class that its last
8 decisions (one second) match: an action the safe mask forbade (methods without the
gate); a lane change allowed and executed while R*1 = 0 (Table 1 allows it on R*2 and R*4 alone; the paper's
control mapping holds the speed through it); Faster or Idle allowed at a bumper gap under 0.5 m; other.

`--set OPTION=VALUE` (repeatable) deploys the same weights with one of the safe profile's additions
(rules.ControlProfile's fields) set over the run's profile, e.g. `--set brake_while_changing=true`, to test
a cause. One JSON object on stdout; `--show N` also prints the last decisions before the first N collisions
of each level to stderr.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import fields
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from highway_srl.constants import TRAFFIC_LEVELS  # noqa: E402
from highway_srl.experiments.collisions import VERDICT_WINDOW, DecisionTrace, show_decisions  # noqa: E402
from highway_srl.experiments.evaluate import evaluation_seeds, run_episodes  # noqa: E402
from highway_srl.experiments.policy import load_policy  # noqa: E402
from highway_srl.rules import ControlProfile  # noqa: E402
from highway_srl.sim import World  # noqa: E402


def parse_set(items: list[str]) -> dict:
    """--set values: the safe profile's additions (ControlProfile's fields), each over the run's profile."""
    known = [f.name for f in fields(ControlProfile)]
    options = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name:
            raise ValueError(f"--set takes OPTION=VALUE, got {item!r}")
        if name not in known:
            raise ValueError(f"--set: unknown option {name!r}; choose from {', '.join(known)}")
        low = value.lower()
        if low in ("true", "false"):
            options[name] = low == "true"
        else:
            try:
                options[name] = float(value)
            except ValueError:
                raise ValueError(f"--set {name}: {value!r} is neither true/false nor a number") from None
    return options


def trace(run: str, traffics: list[str], episodes: int, window: int, show: int, options: dict) -> dict:
    for t in traffics:
        if t not in TRAFFIC_LEVELS:
            raise ValueError(f"unknown traffic level {t!r}; choose from {', '.join(TRAFFIC_LEVELS)}")
    policy = load_policy(run, None, "cpu", None)
    cfg, method, learner = policy.config, policy.method, policy.learner
    method.layer_options = {**method.layer_options, **options}
    out = {"run": run, "method": cfg.method, "scenario": cfg.scenario, "profile": method.profile,
           "options": options, "episodes_per_level": episodes * len(cfg.seeds), "window": window, "levels": {}}
    for traffic in traffics:
        env_seeds = evaluation_seeds(len(cfg.seeds), episodes)  # evaluate's episodes
        world = World(cfg.scenario, traffic, cfg.adversarial, len(env_seeds), "cpu", env_seeds,
                      adversary=cfg.adversary)
        recorder = DecisionTrace(method, window)
        results = run_episodes(world, method, learner, after_step=recorder.after_step, on_transition=recorder)
        for record in recorder.records[:show]:
            print(show_decisions(record), file=sys.stderr)
        out["levels"][traffic] = {"C_r": round(float(1.0 - results["collided"].float().mean()), 4),
                                  "collisions": len(recorder.records), "by_decision": recorder.counts(),
                                  **recorder.verdicts()}
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog=Path(__file__).name, description=__doc__.splitlines()[0])
    p.add_argument("run", help="a trained run folder")
    p.add_argument("--traffic", default="C", help="comma-separated levels (default C)")
    p.add_argument("--episodes", type=int, default=100, help="per seed and level (default 100, as evaluate)")
    p.add_argument("--window", type=int, default=VERDICT_WINDOW,
                   help=f"decisions kept before each collision (default {VERDICT_WINDOW}: the ego-avoidable verdict "
                        "reads them all, the class the last 8)")
    p.add_argument("--show", type=int, default=0, help="print the last decisions of this many collisions per level")
    p.add_argument("--set", action="append", default=[], metavar="OPTION=VALUE",
                   help="a safe-profile addition over the run's profile, e.g. brake_while_changing=true")
    args = p.parse_args(argv)
    if args.episodes < 1 or args.window < 1 or args.show < 0:
        p.error("--episodes and --window must be positive, --show not negative")
    try:
        out = trace(args.run, [t.strip() for t in args.traffic.split(",") if t.strip()], args.episodes,
                    args.window, args.show, parse_set(args.set))
    except (ValueError, OSError) as err:
        p.error(str(err))
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
