"""The train, evaluate, play and demo subcommands."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from highway_srl.commands.arguments import (
    adversary_name, levels, non_negative, non_negative_float, positive, positive_float, profile_name, seed_list,
    seed_number, step_form_args,
)
from highway_srl.constants import DEFAULT_ADVERSARY, DEFAULT_PROFILE, TRAFFIC_LEVELS
from highway_srl.interrupts import stop_reason
from highway_srl.scenarios import check_scenario


def train_config(args):
    from highway_srl.agents.dqn import DQNConfig
    from highway_srl.agents.train_config import TrainConfig
    from highway_srl.sim.device import check_device

    check_scenario(args.scenario)
    if args.traffic not in TRAFFIC_LEVELS:
        raise ValueError(f"unknown traffic level {args.traffic!r}; choose one of {', '.join(TRAFFIC_LEVELS)}")
    check_device(args.device)
    options = {k: True for k in ("no_mapping", "no_moe", "no_rm") if getattr(args, k, False)}
    dqn = DQNConfig(total_steps=args.steps)
    if args.learning_starts is not None:
        dqn.learning_starts = args.learning_starts
    return TrainConfig(method=args.method, scenario=args.scenario, traffic=args.traffic, adversarial=args.adversarial,
                       steps=args.steps, envs=args.envs, seeds=seed_list(args.seeds), device=args.device,
                       profile=args.profile, adversary=args.adversary,
                       replay_ratio=args.replay_ratio,
                       share_transitions=args.share_transitions, dqn=dqn, options=options,
                       static=getattr(args, "static", None), compile=getattr(args, "compile", False))


def _cmd_train(args) -> int:
    from highway_srl.agents.registry import make_method
    from highway_srl.experiments.train import finished, last_checkpoint_step, train_run

    out = Path(args.out)
    if args.drop_damaged and not args.resume:
        raise ValueError("--drop-damaged is for --resume (a new run has no logs to cut)")
    if args.resume:
        cfg = None
        if out.is_dir() and finished(out):
            print(f"run folder {args.out} is already finished (metrics.json); nothing to resume, nothing changed")
            return 0
    else:
        cfg = train_config(args)
        method = make_method(cfg.method, cfg.scenario, len(cfg.seeds), cfg.options)  # validate the name early
        if method.trains and cfg.dqn.learning_starts > cfg.steps:  # legal, but rarely what was meant
            print(f"note: learning starts after {cfg.dqn.learning_starts:,} env steps, more than --steps "
                  f"{cfg.steps:,}: this run takes no gradient step (set --learning-starts)", file=sys.stderr)
    try:
        metrics = train_run(cfg, out, resume=args.resume, checkpoint_every=args.checkpoint_every,
                            progress=not args.quiet, drop_damaged=args.drop_damaged)
    except KeyboardInterrupt as err:  # Ctrl-C or kill: say where a resume would continue
        word, code = stop_reason(err)
        step = last_checkpoint_step(out)
        where = f"its last checkpoint (step {step:,})" if step is not None else "step 0 (no checkpoint was written yet)"
        print(f"highway-srl: {word}; continue from {where} with: highway-srl train --resume --out {args.out}",
              file=sys.stderr)
        return code
    m = metrics["mean"]
    tc = "n/a" if m["T_c"] is None else f"{m['T_c']:.3f}"
    tr = "n/a" if m["T_r"] is None else f"{m['T_r']:.1f}"
    rise = "n/a" if m["rise_time_steps"] is None else f"{m['rise_time_steps']:,.0f} steps"
    print(f"trained {metrics['method']} on {metrics['scenario']} level {metrics['traffic']}: T_c {tc}, T_r {tr}, "
          f"rise time {rise}, {metrics['wall_s']:.0f} s ({metrics['env_steps_per_s']:,.0f} env-steps/s)")
    print(f"run folder: {args.out}")
    return 0


def format_report(report: dict) -> str:
    lines = [f"{report['method']} on {report['scenario']}{' (adversarial)' if report['adversarial'] else ''}, "
             f"{report['episodes_per_level']} episodes per level, backend {report['backend']}:"]
    for level, r in report["levels"].items():
        s = f"  level {level}: C_r {r['C_r']['value']:.1%} [{r['C_r']['low']:.1%}, {r['C_r']['high']:.1%}]" \
            f"  speed {r['avg_speed']['value']:.2f} m/s  R_r {r['R_r']['value']:.1f} ± {r['R_r']['value'] - r['R_r']['low']:.1f}"
        if "R_s" in r:
            s += f"  R_s {r['R_s']['value']:.1%}"
        kinds = (r.get("collisions") or {}).get("by_kind")
        if kinds:  # what the collisions were (experiments/collisions.py)
            s += "  collisions: " + ", ".join(f"{n} {kind}" for kind, n in kinds.items())
        lines.append(s)
    return "\n".join(lines)


def _cmd_evaluate(args) -> int:
    from highway_srl.experiments.policy import read_model
    from highway_srl.experiments.runs import claim_outputs, progress_bar
    from highway_srl.sim.device import check_device

    from highway_srl.experiments.evaluate import check_evaluation_memory

    cfg = read_model(args.run)[0]  # the run, its config and its model (finite weights) checked before the bar
    check_device(args.device)
    if args.backend == "ours":
        check_evaluation_memory(cfg, args.traffic, args.episodes, args.device, True if args.adversarial else None)
    out = args.out or str(Path(args.run) / f"eval-{args.backend}.json")  # as given: "new/" names a folder
    with claim_outputs([out], args.overwrite):  # checked before the work, locked until written
        out = Path(out)
        report = _evaluate(args, out, progress_bar(1, "evaluate", enabled=not args.json))
    print(json.dumps(report, indent=2) if args.json else format_report(report))
    if not args.json:
        print(f"written to {out}")
    return 0


def _evaluate(args, out: Path, bar) -> dict:
    from highway_srl.experiments.evaluate import evaluate_run

    def progress(done: int, total: int) -> None:
        if bar is not None:
            bar.total = total
            bar.update(done - bar.n)

    try:
        report = evaluate_run(args.run, scenario=args.scenario, traffics=args.traffic, episodes=args.episodes,
                              adversarial=True if args.adversarial else None, device=args.device,
                              backend=args.backend, out=out, seed=args.seed, progress=progress,
                              profile=args.profile, adversary=args.adversary, overwrite=args.overwrite)
    finally:
        if bar is not None:
            bar.close()
    return report


def _cmd_demo(args) -> int:
    from highway_srl.experiments.demo import run_demo

    run_demo(Path(args.out), steps=args.steps, envs=args.envs, episodes=args.episodes, seed=args.seed,
             overwrite=args.overwrite)
    return 0


def check_display() -> None:
    """play opens a window: on a Linux machine without a display, say so at once (SDL would print an
    error and pygame then wait for key presses that can never come)."""
    import importlib.util

    try:
        installed = importlib.util.find_spec("pygame") is not None
    except ValueError:  # in sys.modules but unimportable
        installed = False
    if not installed:
        raise ValueError("play needs pygame, which is not installed: pip install highway-srl[play]")
    if not sys.platform.startswith("linux"):
        return
    if not any(os.environ.get(k) for k in ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER")):
        raise ValueError("play needs a display (DISPLAY and WAYLAND_DISPLAY are unset); run it on a desktop, "
                         "over ssh -X, or set SDL_VIDEODRIVER")


def _cmd_play(args) -> int:
    check_display()
    from highway_srl.experiments.play import play

    report = play(args.scenario, args.traffic, args.out, adversarial=args.adversarial, episodes=args.episodes,
                  seed=args.seed, fps=args.fps)
    print(format_report(report) if report["levels"] else "no episode finished; nothing to report")
    print(f"run folder: {args.out}")
    return 0


def _add_train(sub, scenario_args) -> None:
    p = sub.add_parser("train", help="train a method; writes a run folder")
    p.add_argument("--method", default="moe-rm-srl")
    scenario_args(p)
    p.add_argument("--steps", type=positive, default=500_000, help="environment steps per seed (paper: 5e5)")
    p.add_argument("--envs", type=positive, default=16, help="environments per seed stepped together")
    p.add_argument("--seeds", default="0", help="comma-separated seeds trained together, e.g. 0,1,2,3")
    p.add_argument("--device", default="cpu")
    p.add_argument("--profile", type=profile_name, default=DEFAULT_PROFILE,
                   help="control profile of the rule layer: paper (Eqs. 31-35 as printed, the default) or safe "
                   "(our additions: abort unsafe changes, brake while changing, change window, straddle, 1 m margin, "
                   "SVs turning in)")
    p.add_argument("--adversary", type=adversary_name, default=DEFAULT_ADVERSARY,
                   help="group-3 cut-ins with --adversarial: paper (§4.3 as printed, the default) or mild (ours)")
    p.add_argument("--replay-ratio", type=non_negative_float, default=1.0,
                   help="gradient steps (batch n_b) per environment step, each for the member that acted there "
                   "(Algorithm 1: 1, the default; 16 envs x 1 = 16 updates per vector step)")
    p.add_argument("--learning-starts", type=non_negative, default=None, help="env steps before the first update")
    p.add_argument("--share-transitions", action="store_true",
                   help="store each transition in every expert whose action set holds the executed action")
    p.add_argument("--no-mapping", action="store_true", help="ablation: without the ID/rule/action/control mappings")
    p.add_argument("--no-moe", action="store_true", help="ablation: one DQN over A*, no gated experts")
    p.add_argument("--no-rm", action="store_true", help="ablation: reward without the reward machine")
    step_form_args(p)
    p.add_argument("--checkpoint-every", type=positive, default=50_000, help="env steps between resume checkpoints")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint, "
                   "with every setting it was started with (config.json); the other options are then ignored")
    p.add_argument("--drop-damaged", action="store_true",
                   help="with --resume: where episodes.jsonl or scalars.csv has a damaged line, keep the rows before "
                        "it and continue (says how many were dropped) instead of refusing")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--out", required=True, help="run folder")
    p.set_defaults(func=_cmd_train)


def _add_evaluate(sub) -> None:
    p = sub.add_parser("evaluate", help="deployment metrics of a trained run")
    p.add_argument("run")
    p.add_argument("--scenario", default=None)
    p.add_argument("--traffic", type=levels, default=None,
                   help="levels, e.g. C, A..F or A,C,F (default: the training level)")
    p.add_argument("--adversarial", action="store_true")
    p.add_argument("--episodes", type=positive, default=100)
    p.add_argument("--backend", default="ours", help="ours, sumo or highway-env")
    p.add_argument("--device", default="cpu")
    p.add_argument("--seed", type=seed_number, default=0, help="offset of the evaluation episodes' seeds")
    p.add_argument("--profile", type=profile_name, default=None, help="control profile (default: the run's own)")
    p.add_argument("--adversary", type=adversary_name, default=None,
                   help="cut-ins of adversarial episodes (default: the run's own)")
    p.add_argument("--out", default=None, help="JSON file (default: RUN/eval-BACKEND.json); never replaced "
                   "without --overwrite")
    p.add_argument("--overwrite", action="store_true", help="replace the --out file if it exists")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=_cmd_evaluate)


def _add_play(sub, scenario_args) -> None:
    p = sub.add_parser("play", help="drive the ego yourself (the Manual baseline); needs pygame")
    scenario_args(p)
    p.add_argument("--episodes", type=positive, default=1)
    p.add_argument("--seed", type=seed_number, default=0, help="traffic seed of the first episode")
    p.add_argument("--fps", type=positive_float, default=8.0, help="decisions per second (the paper's 8 Hz)")
    p.add_argument("--out", required=True, help="run folder: config.json, episodes.jsonl, metrics.json")
    p.set_defaults(func=_cmd_play)


def _add_demo(sub) -> None:
    p = sub.add_parser("demo", help="the main job: train MoE-RM-SRL briefly, evaluate on levels A-F, write a report")
    p.add_argument("--steps", type=positive, default=30_000)
    p.add_argument("--envs", type=positive, default=16)
    p.add_argument("--episodes", type=positive, default=50)
    p.add_argument("--seed", type=seed_number, default=0)
    p.add_argument("--out", default="out", help="demo folder; a run already there is reused only if it was "
                   "trained with the same --steps, --envs and --seed")
    p.add_argument("--overwrite", action="store_true", help="replace the report, evaluation and pictures of an "
                   "earlier demo in --out (refused without it)")
    p.set_defaults(func=_cmd_demo)



def add_parsers(sub, scenario_args) -> None:
    """train, evaluate, play and demo on the CLI's subparsers; scenario_args(p) adds --scenario, --traffic and
    --adversarial."""
    _add_train(sub, scenario_args)
    _add_evaluate(sub)
    _add_play(sub, scenario_args)
    _add_demo(sub)
