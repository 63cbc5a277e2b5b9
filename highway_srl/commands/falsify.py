"""The falsify subcommand: search for ego-avoidable collisions of the rule layer; replay a case."""

from __future__ import annotations

import json

from highway_srl.commands.arguments import adversary_name, levels, non_negative, positive, profile_name, unit_fraction
from highway_srl.constants import TRAFFIC_LEVELS


def _cmd_falsify(args) -> int:
    from highway_srl.experiments import falsify as fz

    if args.replay is not None:
        case = fz.load_case(args.replay)
        result = fz.replay_case(case, args.profile, args.substitute)
        if args.gif is not None:
            result["gif"] = [str(p) for p in fz.render_case(case, args.gif, args.profile, args.overwrite)]
        print(json.dumps(result, indent=2) if args.json else
              (f"replayed under {result['profile']}: " + (f"collision in step {result['step']} ({result['cause']}; "
               f"{'ego-avoidable' if result['ego_avoidable'] else 'unavoidable'}), "
               f"{'confirmed' if result['confirmed'] else 'NOT at the recorded step ' + str(result['expected_step'])}"
               if result["collided"] else "no collision: not confirmed")))
        if args.gif is not None and not args.json:
            print("\n".join(result["gif"]))
        return 0 if result["confirmed"] else 1
    settings, report = _search(args)
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    _print_report(args, settings, report)
    return 0


def _search(args):
    """The search the arguments ask for (breadth, learned adversary or cross-entropy): its settings and report."""
    from highway_srl.experiments import falsify as fz

    modes = {"nominal": False, "adversarial": True}
    names = [m.strip() for m in args.modes.split(",") if m.strip()]
    if not names or any(m not in modes for m in names):
        raise ValueError(f"--modes takes nominal, adversarial or both, got {args.modes!r}")
    settings = fz.FalsifySettings(
        scenes=tuple(x.strip() for x in args.scenes.split(",") if x.strip()), levels=tuple(args.levels),
        modes=tuple(modes[m] for m in names), profile=args.profile or "safe", policy=args.policy,
        episodes=args.episodes or 256, envs=args.envs or 256, seed=args.seed, steps=args.steps, adversary=args.adversary)
    if args.learn_steps is not None and args.policy != fz.LEARNED:
        raise ValueError("--learn-steps goes with --policy learned")
    if args.search == "ce":
        if args.policy == fz.LEARNED:
            raise ValueError("--policy learned goes with --search breadth")
        report = _ce_report(args, settings)
    elif args.policy == fz.LEARNED:
        from highway_srl.experiments.adversary import AdversaryConfig, falsify_learned

        check_breadth_arguments(args)
        config = AdversaryConfig() if args.learn_steps is None else AdversaryConfig(learn_steps=args.learn_steps)
        report = falsify_learned(settings, config, args.out, processes=args.processes)
    else:
        check_breadth_arguments(args)
        report = fz.falsify(settings, args.out, processes=args.processes)
    return settings, report


def _print_report(args, settings, report) -> None:
    if args.search == "ce":
        print(f"{report['episodes']:,} episodes in {len(report['iterations'])} iterations ({settings.profile} profile, "
              f"{settings.policy} ego, cross-entropy search): {report['collisions']:,} collisions, "
              f"{report['ego_avoidable']:,} ego-avoidable of {report['ego_avoidable_causes']} causes")
        for row in report["iterations"]:
            print(f"  iteration {row['iteration']}: {row['ego_avoidable']:5,d} ego-avoidable of {row['episodes']:,} "
                  f"episodes, mean score {row['mean_score']:.3f}")
    else:
        print(f"{report['episodes']:,} episodes ({settings.profile} profile, {settings.policy} ego): "
              f"{report['collisions']:,} collisions, {report['ego_avoidable']:,} ego-avoidable; 95 % upper bound on "
              f"the per-episode rate of ego-avoidable collisions {report['ego_avoidable_rate_upper_95']:.3g}")
    for t in report.get("adversary", {}).get("training", []):
        print(f"  adversary trained on {t['scene']}: {t['learn_steps']:,} steps in {t['seconds']:.0f} s, "
              f"{t['collisions']:,} collisions ({t['ego_avoidable']:,} ego-avoidable) in {t['episodes']:,} episodes")
    for reason, n in report["by_reason"].items():
        print(f"  {n:6,d}  {reason}")
    if args.search == "ce":  # every ego-avoidable collision is a case: their count, not a list
        print(f"  {len(report['cases'])} cases" + (f" in {args.out}" if args.out else " (not written: no --out)"))
        return
    for case in report["cases"]:
        print(f"  case {case.get('path', '(not written: no --out)')}: {case['cause']}")


def check_breadth_arguments(args) -> None:
    given = [f"--{name}" for name in ("iterations", "samples", "elite") if getattr(args, name) is not None]
    if given:
        raise ValueError(f"{', '.join(given)}: only with --search ce")


def _ce_report(args, settings) -> dict:
    """The cross-entropy search's report (experiments/scenario_search.py) for the parsed arguments."""
    from highway_srl.experiments import scenario_search as ss

    if args.episodes is not None or args.envs is not None:
        raise ValueError("--episodes and --envs go with --search breadth; --search ce takes --iterations and --samples")
    given = {name: getattr(args, name) for name in ("iterations", "samples", "elite") if getattr(args, name) is not None}
    return ss.ce_search(settings, ss.SearchSettings(**given), args.out, processes=args.processes)


def _add_search_arguments(p) -> None:
    """--search and the cross-entropy search's own arguments (experiments/scenario_search.py)."""
    p.add_argument("--search", choices=("breadth", "ce"), default="breadth", help="breadth: --episodes in every "
                   "scene, level and mode, drawn from the simulator's full ranges; ce: a cross-entropy search over "
                   "scene, level, mode and the initial scene's gaps, speeds, driver styles and cut-in parameters, "
                   "keeping every ego-avoidable collision as a case")
    p.add_argument("--iterations", type=positive, default=None, help="with --search ce: iterations (default 8)")
    p.add_argument("--samples", type=positive, default=None, help="with --search ce: scenarios an iteration "
                   "(default 256)")
    p.add_argument("--elite", type=unit_fraction, default=None, help="with --search ce: the fraction of the "
                   "samples the distribution is refitted to (default 0.2)")


def _add_falsify(sub) -> None:
    from highway_srl.experiments.falsify import LEARNED, POLICIES

    p = sub.add_parser("falsify", help="search for ego-avoidable collisions of the rule layer; replay a case",
                       description="Random (or adversarial) allowed actions over scenes x levels x nominal/"
                       "adversarial; counts collisions by cause, ego-avoidable ones, and the 95 % upper bound on "
                       "their per-episode rate; one replayable case per cause in --out. --search ce: a cross-entropy "
                       "search over scenario parameters instead, every ego-avoidable collision a case.")
    p.add_argument("--scenes", default="two-lane", help="comma-separated: two-lane, multi-lane, merge, exit")
    p.add_argument("--levels", type=levels, default=list(TRAFFIC_LEVELS), help="e.g. F, A,C,F or A..F (default A..F)")
    p.add_argument("--modes", default="nominal,adversarial", help="nominal, adversarial or both (default both)")
    p.add_argument("--profile", type=profile_name, default=None,
                   help="control profile: safe (default) or paper; with --replay: the case's own unless given")
    p.add_argument("--policy", choices=(*POLICIES, LEARNED), default="uniform", help="the ego: uniform among the "
                   "allowed actions, greedy-ttc (the allowed action with the soonest predicted contact), exg (ExG's "
                   "gate) or learned (a DQN over the allowed actions rewarded for ego-avoidable collisions, trained "
                   "per scene for --learn-steps first)")
    p.add_argument("--learn-steps", type=positive, default=None, metavar="N", help="with --policy learned: "
                   "environment steps of the adversary's training per scene (default 2e4)")
    p.add_argument("--adversary", type=adversary_name, default="paper", help="group-3 cut-ins of adversarial mode")
    p.add_argument("--episodes", type=positive, default=None, help="episodes per scene, level and mode (default 256)")
    p.add_argument("--envs", type=positive, default=None, help="episodes stepped together (default 256)")
    p.add_argument("--steps", type=positive, default=320, help="episode length in steps")
    p.add_argument("--seed", type=non_negative, default=0)
    p.add_argument("--out", default=None, help="folder for report.json and the cases (one per cause)")
    p.add_argument("--processes", type=positive, default=1, help="worker processes of one thread each, sharing "
                   "the batches (the report is the same for any count)")
    _add_search_arguments(p)
    p.add_argument("--replay", default=None, metavar="CASE.json", help="replay a case and confirm its collision "
                   "(exit status 1 if it does not recur)")
    p.add_argument("--substitute", action="store_true", help="with --replay: where the profile forbids a recorded "
                   "action, take the most cautious allowed one (Slower, Idle, LaneChange, Faster)")
    p.add_argument("--gif", default=None, metavar="OUT.gif", help="with --replay: draw the episode (a PNG beside it)")
    p.add_argument("--overwrite", action="store_true", help="with --gif: replace the GIF and PNG if they exist")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=_cmd_falsify)



def add_parsers(sub) -> None:
    """falsify on the CLI's subparsers."""
    _add_falsify(sub)
