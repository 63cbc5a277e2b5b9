"""The one entry point: `highway-srl <command>`.

Every user error (unknown name, out-of-range number, missing or mismatched run folder) ends as one line
on stderr and exit status 2, never a traceback; a file that cannot be written (a full disk) is one line
naming it and exit status 1; Ctrl-C as "highway-srl: interrupted" and exit status 130,
`kill` as "highway-srl: terminated" and 143.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
from pathlib import Path

from highway_srl import __version__
from highway_srl.constants import SCENARIOS, TRAFFIC_LEVELS
from highway_srl.interrupts import interrupts_raised, stop_reason


class Parser(argparse.ArgumentParser):
    """argparse with its errors as one line (the usage block stays in --help)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message}\n")


def _scenario(p: argparse.ArgumentParser, default: str | None = "two-lane") -> None:
    from highway_srl.commands.arguments import level

    p.add_argument("--scenario", default=default, help=f"one of {', '.join(SCENARIOS)}")
    p.add_argument("--traffic", type=level, default="C", help=f"traffic level, one of {', '.join(TRAFFIC_LEVELS)}")
    p.add_argument("--adversarial", action="store_true", help="group-3 adversarial cut-ins")


def _cmd_render(args) -> int:
    from highway_srl.experiments.renderings import render_episode
    from highway_srl.experiments.runs import claim_outputs, run_folder

    if args.run is not None:
        run_folder(args.run)
    with claim_outputs([args.out, Path(args.out).with_suffix(".png")], args.overwrite):  # locked until written
        paths = render_episode(
            run=args.run, scenario=args.scenario, traffic=args.traffic, adversarial=args.adversarial,
            policy=args.policy, seed=args.seed, out=Path(args.out), steps=args.steps, backend=args.backend,
            progress=not args.quiet, profile=args.profile, adversary=args.adversary, overwrite=args.overwrite,
        )
    for p in paths:
        print(p)
    return 0


def _bench_sim(args) -> tuple[dict, str]:
    from highway_srl.experiments import bench

    bench.check_sim_memory(args.scenario, args.traffic, args.envs, args.device, args.adversarial)
    result = bench.bench_sim(args.scenario, args.traffic, args.envs, args.steps, args.device, args.adversarial,
                             compile=args.compile, processes=args.processes)
    line = (f"{result['scenario']} level {result['traffic']}: {result['envs']} envs x {result['steps']} steps on "
            f"{result['device']}: {result['env_steps_per_s']:,.0f} env-steps/s = "
            f"{result['sim_s_per_wall_s']:,.0f} simulated s per wall s"
            + (f" ({args.processes} processes)" if args.processes > 1 else ""))
    return result, line


def _bench_train(args) -> tuple[dict, str]:
    if args.processes > 1:
        raise ValueError("--processes is for bench sim (training steps its world in its own process)")
    from highway_srl.experiments.train import bench_train

    result = bench_train(method=args.method, scenario=args.scenario, traffic=args.traffic, envs=args.envs,
                         steps=args.steps, device=args.device, seeds=args.seeds, compile=args.compile,
                         static=args.static)
    rates = ", ".join(f"{name} {form['env_steps_per_s']:,.0f} ({form['env_steps_per_s_with_compile']:,.0f} with "
                      f"{form['warmup_s']:.0f} s warm-up)" for name, form in result["forms"].items())
    line = (f"train {result['method']} on {result['scenario']} ({result['envs']} envs, {result['seeds']} seed(s), "
            f"{result['device']}): env-steps/s {rates}; "
            f"projected {result['projected_paper_run_min']:.1f} min for 5e5 steps")
    return result, line


# bench all: the figures of docs/benchmarks.md that one command refreshes (what it measures, bench's arguments)
ALL_BENCHES = (
    ("Simulator, 4,096 envs, eager", ["sim", "--envs", "4096", "--steps", "200"]),
    ("Simulator, one env, eager", ["sim", "--envs", "1", "--steps", "1000"]),
    ("Training MoE-RM-SRL, 16 envs, one seed", ["train", "--envs", "16", "--steps", "150"]),
)


def _bench_all(args) -> tuple[list, str]:
    """Every bench of ALL_BENCHES on args.device: the results, and one Markdown row each in the form of
    docs/benchmarks.md's table (what, figure, command, machine, commit)."""
    import torch

    from highway_srl.experiments import bench
    from highway_srl.experiments.runs import commit
    from highway_srl.study.runner import cpuinfo

    info = bench.machine()
    where = f"{cpuinfo('model name') or info['cpu']} ({info['cpu_kernels']}), {torch.get_num_threads()} thread(s)"
    head = commit()
    code = f"{head[:7]}{' (dirty)' if head.endswith('-dirty') else ''}" if head else f"highway-srl {__version__}"
    parser, results, rows = build_parser(), [], []
    for what, argv in ALL_BENCHES:
        one = parser.parse_args(["bench", *argv, "--device", args.device])
        result, line = (_bench_sim if one.what == "sim" else _bench_train)(one)
        command = f"highway-srl bench {' '.join(argv)}"
        results.append({"row": what, "command": command, **result})
        rows.append(f"| {what} | {line} | `{command}` | {where} | {code} |")
    return results, "\n".join(rows)


def _cmd_bench(args) -> int:
    from highway_srl.experiments import bench

    if args.what == "all":
        if args.contended:
            raise ValueError("--contended measures one bench: give sim or train with it")
        result, line = _bench_all(args)
        print(json.dumps(result) if args.json else line)
        return 0
    run = _bench_sim if args.what == "sim" else _bench_train
    if not args.contended:
        result, line = run(args)
    else:  # idle, then beside a busy process on every core (what a shared machine does to the figure)
        lines = []

        def measure() -> dict:
            one, text = run(args)
            lines.append(text)
            return one

        result = bench.contended(measure)
        line = (f"idle: {lines[0]}\ncontended ({result['neighbours']} busy processes): {lines[1]}\n"
                f"contended / idle: {result['ratio']:.2f} ({bench.machine()['threads']} thread(s))")
    print(json.dumps(result) if args.json else line)
    return 0


def build_parser() -> argparse.ArgumentParser:
    from highway_srl import commands  # the training / evaluation / study commands, argument types
    from highway_srl.commands.arguments import adversary_name, positive, profile_name, seed_number, step_form_args

    parser = Parser(prog="highway-srl", description="Safe RL of autonomous highway driving (MoE-RM-SRL).")
    parser.add_argument("--version", action="version", version=f"highway-srl {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("render", help="draw an episode as a GIF and a PNG frame")
    p.add_argument("run", nargs="?", default=None, help="a trained run folder (omit to use --policy)")
    _scenario(p, default=None)
    p.add_argument("--policy", default="idm", help="built-in ego when no run is given: idm")
    p.add_argument("--backend", default="ours", help="simulator: ours, sumo, highway-env")
    p.add_argument("--seed", type=seed_number, default=0)
    p.add_argument("--steps", type=positive, default=320)
    p.add_argument("--out", default="episode.gif", help="GIF path; the PNG goes beside it")
    p.add_argument("--overwrite", action="store_true", help="replace the GIF and PNG if they exist")
    p.add_argument("--profile", type=profile_name, default=None, help="control profile (default: the run's own)")
    p.add_argument("--adversary", type=adversary_name, default=None,
                   help="cut-ins with --adversarial (default: the run's own; paper without a run)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_render)

    p = sub.add_parser("bench", help="measure throughput")
    p.add_argument("what", choices=["sim", "train", "all"],
                   help="all: the standard figures, one Markdown row each for docs/benchmarks.md")
    _scenario(p)
    p.add_argument("--method", default="moe-rm-srl")
    p.add_argument("--envs", type=positive, default=4096)
    p.add_argument("--steps", type=positive, default=200)
    p.add_argument("--seeds", type=positive, default=1, help="independent agents trained at once (bench train)")
    p.add_argument("--processes", type=positive, default=1,
                   help="processes stepping the world's envs, this one and P - 1 workers, one thread each "
                        "(bench sim, CPU)")
    p.add_argument("--device", default="cpu")
    step_form_args(p)
    p.add_argument("--json", action="store_true")
    p.add_argument("--contended", action="store_true",
                   help="measure idle, then beside a busy process on every core, and report both")
    p.set_defaults(func=_cmd_bench)

    commands.add_parsers(sub, _scenario)
    for p in sub.choices.values():
        p.add_argument("--threads", type=positive, default=None,
                       help="torch intra-op threads in this process (default: OMP_NUM_THREADS if set, else 1; "
                            "parallelism comes from processes: --jobs, --processes)")
    return parser


def set_threads(requested: int | None) -> int:
    """This process's torch threads by the one rule (experiments.runs.default_threads); exported as
    OMP_NUM_THREADS so that worker processes (reproduce --jobs, bench --processes) take the same count."""
    import os

    import torch

    from highway_srl.experiments.runs import default_threads

    threads = default_threads(requested)
    torch.set_num_threads(threads)
    os.environ["OMP_NUM_THREADS"] = str(threads)
    return threads


def _thread_error(args) -> None:
    """threading.excepthook: a thread that keeps its error for its owner to raise (TensorBoard's writer does,
    on a full disk) says nothing; the owner's next call fails with it and the command reports it in one line."""
    if getattr(args.thread, "exception", None) is not args.exc_value:
        threading.__excepthook__(args)


def main(argv: list[str] | None = None) -> int:
    threading.excepthook = _thread_error
    try:
        with interrupts_raised():  # `kill` ends the command as Ctrl-C does, with its own word and status
            return _run(argv)
    except KeyboardInterrupt as err:  # at any moment, parsing included; workers stay quiet (interrupts.py)
        word, code = stop_reason(err)
        print(f"highway-srl: {word}", file=sys.stderr)
        return code


def _run(argv: list[str] | None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as done:  # --help, --version, or a one-line usage error (Parser.error) already printed
        return done.code if isinstance(done.code, int) else 2
    try:
        set_threads(args.threads)
        return args.func(args)
    except (ValueError, FileNotFoundError, FileExistsError, NotADirectoryError, IsADirectoryError,
            PermissionError) as err:  # user errors: one line, no traceback
        print(f"highway-srl: error: {err}", file=sys.stderr)
        return 2
    except OSError as err:  # the machine, not the command line (a full disk, a failing device): status 1
        where = f"{err.filename}: " if err.filename else ""
        print(f"highway-srl: error: {where}{err.strerror or err}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
