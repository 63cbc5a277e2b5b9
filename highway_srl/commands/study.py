"""The reproduce and transfer subcommands: the paper's study and the transfer study."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from highway_srl.commands.arguments import positive, seed_list


def _cmd_reproduce(args) -> int:
    from highway_srl.study.runner import report_only, reproduce

    if args.page and not args.report_only:
        raise ValueError("--page goes with --report-only: the summary is written from the finished jobs' records")
    if args.report_only:
        report = report_only(args.out, args.budget)
        print(f"report: {report}")
        if args.page:
            from highway_srl.study.report import write_page

            write_page(args.page, (report.parent / "summary.md").read_text())
            print(f"summary written into: {args.page}")
        return 0
    if args.budget is None:
        raise ValueError("choose a budget: --budget smoke, quick or paper (see highway-srl reproduce --help)")
    executor = args.executor or "local"
    if executor == "local":  # on Ray the workers' devices count, not this machine's
        from highway_srl.sim.device import check_device

        check_device(args.device)
    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip()) if args.methods else None
    scenes = tuple(s.strip() for s in args.scenes.split(",") if s.strip()) if args.scenes else None
    seeds = seed_list(args.seeds) if args.seeds else None
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
    p.add_argument("--profiles", default=None, help="control profiles, comma-separated, paper (if named) first: "
                   "paper (the reproduction) and safe (our safety additions, reported as 'beyond the paper'); "
                   "safe alone runs a chunk of its jobs only; default: the budget's (smoke: paper; quick and "
                   "paper: paper,safe)")
    p.add_argument("--report-only", action="store_true", help="run nothing: write the tables, figures and "
                   "report of the study in --out from the jobs finished so far (say, while it runs in another "
                   "process); the other options are not needed")
    p.add_argument("--page", default=None, metavar="FILE.md", help="with --report-only: also put the study's "
                   "summary.md (setting, MoE-RM-SRL's printed cells side by side, every verdict) into FILE.md "
                   "between its two marker lines (docs/results.md has them), the rest of the file untouched")
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



def add_parsers(sub) -> None:
    """reproduce and transfer on the CLI's subparsers."""
    _add_reproduce(sub)
    _add_transfer(sub)
