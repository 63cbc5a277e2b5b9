"""Subcommands for training, evaluation and the study; registered on the CLI's parser."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

from highway_srl.constants import DEFAULT_ADVERSARY, DEFAULT_PROFILE, TRAFFIC_LEVELS
from highway_srl.scenarios import check_scenario


def levels(text: str) -> list[str]:
    """--traffic for evaluate: 'C', 'c', 'A,C,F', 'A..F' or 'A-F' (either direction), in the order A..F.

    Anything else, an empty text or ',,' included, is an error rather than the training level."""
    t = text.replace(" ", "").upper()
    names = list(TRAFFIC_LEVELS)
    for sep in ("..", "-"):
        if sep in t:
            a, b = t.split(sep, 1)
            if a not in names or b not in names:
                raise argparse.ArgumentTypeError(f"unknown traffic range {text!r}; levels are {', '.join(names)}, "
                                                 "a range is written A..F")
            lo, hi = sorted((names.index(a), names.index(b)))
            return names[lo: hi + 1]
    parts = t.split(",")
    for x in parts:
        if x not in names:
            what = "an empty level" if not x else f"unknown traffic level {x!r}"
            raise argparse.ArgumentTypeError(f"{what} in {text!r}; choose from {', '.join(names)} (e.g. C, A,C,F or A..F)")
    return sorted(set(parts), key=names.index)


def level(text: str) -> str:
    """--traffic for the commands that run one level: 'C' or 'c'."""
    t = text.strip().upper()
    if t not in TRAFFIC_LEVELS:
        raise argparse.ArgumentTypeError(f"unknown traffic level {text!r}; choose one of {', '.join(TRAFFIC_LEVELS)}")
    return t


def _integer(text: str) -> int:
    """An integer, also written like 5e5 or 500_000 (the help texts quote the paper's 5e5)."""
    try:
        return _bounded(int(text), text)
    except ValueError:
        pass
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if not math.isfinite(value) or not value.is_integer():
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}")
    return _bounded(int(value), text)


MAX_INTEGER = 2**53  # no count or number of steps comes near; above it a float's integers have gaps


def _bounded(value: int, text: str) -> int:
    if abs(value) > MAX_INTEGER:
        raise argparse.ArgumentTypeError(f"expected an integer of at most 2^53, got {text!r}")
    return value


def seed_number(text: str) -> int:
    """A seed: an integer from 0 to trainer.MAX_SEED (its streams stay inside a 64-bit generator seed)."""
    from highway_srl.agents.trainer import MAX_SEED

    value = _integer(text)
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"expected a seed from 0 to {MAX_SEED:,}, got {text!r}")
    return value


def positive(text: str) -> int:
    value = _integer(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def non_negative(text: str) -> int:
    value = _integer(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}")
    return value


def _number(text: str, what: str, ok) -> float:
    """A finite float for which ok(value) holds, else an argparse error "expected WHAT"."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if not math.isfinite(value) or not ok(value):
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    return value


def positive_float(text: str) -> float:
    return _number(text, "a positive number", lambda v: v > 0)


def non_negative_float(text: str) -> float:
    return _number(text, "a non-negative number", lambda v: v >= 0)


def profile_name(text: str) -> str:
    from highway_srl.rules import PROFILES

    if text not in PROFILES:
        raise argparse.ArgumentTypeError(f"unknown profile {text!r}; choose one of {', '.join(PROFILES)}")
    return text


def adversary_name(text: str) -> str:
    from highway_srl.sim.adversary import ADVERSARIES

    if text not in ADVERSARIES:
        raise argparse.ArgumentTypeError(f"unknown adversary {text!r}; choose one of {', '.join(ADVERSARIES)}")
    return text


def _seeds(text: str) -> tuple[int, ...]:
    try:
        seeds = tuple(int(s) for s in text.split(",") if s.strip())
    except ValueError:
        raise ValueError(f"--seeds takes comma-separated integers, got {text!r}") from None
    if not seeds or len(set(seeds)) != len(seeds) or min(seeds) < 0:
        raise ValueError(f"--seeds needs distinct non-negative integers, got {text!r}")
    return seeds


def train_config(args):
    from highway_srl.agents.dqn import DQNConfig
    from highway_srl.agents.trainer import TrainConfig
    from highway_srl.sim.device import check_device

    check_scenario(args.scenario)
    if args.traffic not in TRAFFIC_LEVELS:
        raise ValueError(f"unknown traffic level {args.traffic!r}; choose one of {', '.join(TRAFFIC_LEVELS)}")
    check_device(args.device)
    options = {k: True for k in ("no_mapping", "no_moe", "no_rm") if getattr(args, k, False)}
    dqn = DQNConfig(total_steps=args.steps)
    if args.learning_starts is not None:
        dqn.learning_starts = args.learning_starts
    legacy = args.updates_per_step is not None  # the old per-vector-step count, kept for old scripts
    return TrainConfig(method=args.method, scenario=args.scenario, traffic=args.traffic, adversarial=args.adversarial,
                       steps=args.steps, envs=args.envs, seeds=_seeds(args.seeds), device=args.device,
                       profile=args.profile, adversary=args.adversary,
                       replay_ratio=None if legacy else args.replay_ratio, updates_per_step=args.updates_per_step,
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
    except KeyboardInterrupt:
        step = last_checkpoint_step(out)
        where = f"its last checkpoint (step {step:,})" if step is not None else "step 0 (no checkpoint was written yet)"
        print(f"highway-srl: interrupted; continue from {where} with: highway-srl train --resume --out {args.out}",
              file=sys.stderr)
        return 130
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


def _cmd_reproduce(args) -> int:
    from highway_srl.study.runner import report_only, reproduce

    if args.report_only:
        print(f"report: {report_only(args.out, args.budget)}")
        return 0
    if args.budget is None:
        raise ValueError("choose a budget: --budget smoke, quick or paper (see highway-srl reproduce --help)")
    executor = args.executor or "local"
    if executor == "local":  # on Ray the workers' devices count, not this machine's
        from highway_srl.sim.device import check_device

        check_device(args.device)
    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip()) if args.methods else None
    scenes = tuple(s.strip() for s in args.scenes.split(",") if s.strip()) if args.scenes else None
    seeds = _seeds(args.seeds) if args.seeds else None
    profiles = tuple(p.strip() for p in args.profiles.split(",") if p.strip()) if args.profiles else None
    state = reproduce(args.budget, args.out, jobs=args.jobs, executor=executor, address=args.address,
                      device=args.device, methods=methods, scenes=scenes, seeds=seeds, profiles=profiles,
                      progress=True)
    failed = [j for j in state["jobs"].values() if j.get("status") == "failed"]
    return 1 if failed else 0


def _reproduce_epilog() -> str:
    import textwrap

    from highway_srl.study.jobs import BUDGETS

    return "budgets:\n" + "\n".join(textwrap.fill(b.expected_cost, 100, initial_indent=f"  {b.name:7s}",
                                                   subsequent_indent=" " * 9) for b in BUDGETS.values())


def _cmd_transfer(args) -> int:
    from highway_srl.study.transfer import TransferSettings, run_transfer

    def names(text: str) -> tuple[str, ...]:
        return tuple(x.strip() for x in text.split(",") if x.strip())

    settings = TransferSettings(steps=args.steps, envs=args.envs, seed=args.seed, episodes=args.episodes)
    run_transfer(args.out, settings, methods=names(args.methods), scenes=names(args.scenes),
                 simulators=names(args.simulators), jobs=args.jobs)
    print((Path(args.out) / "transfer.md").read_text())
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


def step_form_args(p) -> None:
    """--static and --compile of train and bench: the form of the step (off by default on the CPU: compiling
    takes minutes and pays only over long runs, docs/benchmarks.md)."""
    p.add_argument("--static", action=argparse.BooleanOptionalAction, default=None,
                   help="the static-shape, sync-free step (masked resets and update rounds); default: on CUDA and "
                   "with --compile, the compact step on the CPU (faster there)")
    p.add_argument("--compile", action=argparse.BooleanOptionalAction, default=False,
                   help="torch.compile the static step (CUDA graphs on CUDA; a C++ compiler on the CPU, minutes of "
                   "compiling; eager is the reference); bench train reports eager and compiled side by side")


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
    rate = p.add_mutually_exclusive_group()
    rate.add_argument("--replay-ratio", type=non_negative_float, default=1.0,
                      help="gradient steps (batch n_b) per environment step, each for the member that acted there "
                      "(Algorithm 1: 1, the default; 16 envs x 1 = 16 updates per vector step)")
    rate.add_argument("--updates-per-step", type=positive, default=None,
                      help="legacy rate: gradient steps per acting member per vector step (before --replay-ratio)")
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


def _add_reproduce(sub) -> None:
    p = sub.add_parser("reproduce", help="run the paper's whole study (groups 1-3, Tables 5-6, figures, report)",
                       description="Train and evaluate every method on every scene of the paper's study, then write "
                       "tables (CSV, Markdown), figures (PNG, SVG) and OUT/report.md + report.html. Finished jobs "
                       "are kept: run the same command again to resume an interrupted study.",
                       epilog=_reproduce_epilog(), formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--budget", default=None, help="smoke, quick or paper (see below)")
    p.add_argument("--out", default="results", help="study folder (default: results)")
    p.add_argument("--jobs", type=positive, default=None,
                   help="jobs at a time (local: worker processes; default: the number of cores)")
    p.add_argument("--executor", default=None, help="what runs the jobs: local (processes on this machine, the "
                   "default) or ray")
    p.add_argument("--address", default=None, help="Ray cluster address (e.g. auto, ray://HOST:10001); "
                   "default: start a local Ray with --jobs CPUs. Workers need highway-srl installed and --out "
                   "on a shared file system (the tables' files also travel back with each result)")
    p.add_argument("--device", default="cpu", help="cpu or cuda")
    p.add_argument("--methods", default=None, help="only these methods, comma-separated (default: all)")
    p.add_argument("--scenes", default=None, help="only these scenes, comma-separated: two-lane, merge, exit, "
                   "adv-two-lane, adv-merge, adv-exit, multi-lane, adv-multi-lane (default: all)")
    p.add_argument("--seeds", default=None, help="seeds instead of the budget's, comma-separated, e.g. 0 or 0,1,2")
    p.add_argument("--profiles", default=None, help="control profiles, comma-separated, paper first: paper (the "
                   "reproduction) and safe (our safety additions, reported as 'beyond the paper'); default: the "
                   "budget's (smoke: paper; quick and paper: paper,safe)")
    p.add_argument("--report-only", action="store_true", help="run nothing: write the tables, figures and "
                   "report of the study in --out from the jobs finished so far (say, while it runs in another "
                   "process); the other options are not needed")
    p.set_defaults(func=_cmd_reproduce)


def _add_transfer(sub) -> None:
    from highway_srl.study import transfer as tr

    p = sub.add_parser("transfer", help="train in our simulator, deploy in SUMO and highway-env; a side-by-side table",
                       description="Train each method on each scenario in our simulator (level C, one seed), then "
                       "evaluate the same greedy policy on the same episode seeds in every simulator. Writes "
                       "OUT/transfer.md and transfer.csv; run the same command again to resume.")
    p.add_argument("--methods", default=",".join(tr.TRANSFER_METHODS))
    p.add_argument("--scenes", default=",".join(tr.TRANSFER_SCENES))
    p.add_argument("--simulators", default=",".join(tr.SIMULATORS))
    p.add_argument("--steps", type=int, default=tr.TransferSettings.steps, help="training env steps per run")
    p.add_argument("--envs", type=int, default=tr.TransferSettings.envs)
    p.add_argument("--episodes", type=positive, default=tr.TransferSettings.episodes,
                   help="deployment episodes per simulator")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--jobs", type=positive, default=1, help="jobs at a time (worker processes, one thread each)")
    p.add_argument("--out", default="results/transfer")
    p.set_defaults(func=_cmd_transfer)


def _cmd_falsify(args) -> int:
    from highway_srl.experiments import falsify as fz

    if args.replay is not None:
        case = fz.load_case(args.replay)
        result = fz.replay_case(case, args.profile)
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
    modes = {"nominal": False, "adversarial": True}
    names = [m.strip() for m in args.modes.split(",") if m.strip()]
    if not names or any(m not in modes for m in names):
        raise ValueError(f"--modes takes nominal, adversarial or both, got {args.modes!r}")
    settings = fz.FalsifySettings(
        scenes=tuple(x.strip() for x in args.scenes.split(",") if x.strip()), levels=tuple(args.levels),
        modes=tuple(modes[m] for m in names), profile=args.profile or "safe", policy=args.policy,
        episodes=args.episodes, envs=args.envs, seed=args.seed, steps=args.steps, adversary=args.adversary)
    report = fz.falsify(settings, args.out)
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"{report['episodes']:,} episodes ({settings.profile} profile, {settings.policy} ego): "
          f"{report['collisions']:,} collisions, {report['ego_avoidable']:,} ego-avoidable; 95 % upper bound on the "
          f"per-episode rate of ego-avoidable collisions {report['ego_avoidable_rate_upper_95']:.3g}")
    for reason, n in report["by_reason"].items():
        print(f"  {n:6,d}  {reason}")
    for case in report["cases"]:
        print(f"  case {case.get('path', '(not written: no --out)')}: {case['cause']}")
    return 0


def _add_falsify(sub) -> None:
    from highway_srl.experiments.falsify import POLICIES

    p = sub.add_parser("falsify", help="search for ego-avoidable collisions of the rule layer; replay a case",
                       description="Random (or adversarial) allowed actions over scenes x levels x nominal/"
                       "adversarial; counts collisions by cause, ego-avoidable ones, and the 95 %% upper bound on "
                       "their per-episode rate; one replayable case per cause in --out.")
    p.add_argument("--scenes", default="two-lane", help="comma-separated: two-lane, multi-lane, merge, exit")
    p.add_argument("--levels", type=levels, default=list(TRAFFIC_LEVELS), help="e.g. F, A,C,F or A..F (default A..F)")
    p.add_argument("--modes", default="nominal,adversarial", help="nominal, adversarial or both (default both)")
    p.add_argument("--profile", type=profile_name, default=None,
                   help="control profile: safe (default) or paper; with --replay: the case's own unless given")
    p.add_argument("--policy", choices=POLICIES, default="uniform", help="the ego: uniform among the allowed "
                   "actions, greedy-ttc (the allowed action with the soonest predicted contact) or exg (ExG's gate)")
    p.add_argument("--adversary", type=adversary_name, default="paper", help="group-3 cut-ins of adversarial mode")
    p.add_argument("--episodes", type=positive, default=256, help="episodes per scene, level and mode")
    p.add_argument("--envs", type=positive, default=256, help="episodes stepped together")
    p.add_argument("--steps", type=positive, default=320, help="episode length in steps")
    p.add_argument("--seed", type=non_negative, default=0)
    p.add_argument("--out", default=None, help="folder for report.json and the cases (one per cause)")
    p.add_argument("--replay", default=None, metavar="CASE.json", help="replay a case and confirm its collision "
                   "(exit status 1 if it does not recur)")
    p.add_argument("--gif", default=None, metavar="OUT.gif", help="with --replay: draw the episode (a PNG beside it)")
    p.add_argument("--overwrite", action="store_true", help="with --gif: replace the GIF and PNG if they exist")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=_cmd_falsify)


def add_parsers(sub, scenario_args) -> None:
    """Register the subcommands on the CLI's subparsers; scenario_args(p) adds --scenario, --traffic and --adversarial."""
    _add_train(sub, scenario_args)
    _add_evaluate(sub)
    _add_play(sub, scenario_args)
    _add_demo(sub)
    _add_reproduce(sub)
    _add_transfer(sub)
    _add_falsify(sub)
