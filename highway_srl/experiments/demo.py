"""The main job (`make run`): a short MoE-RM-SRL training on two-lane level C, evaluation on levels A-F,
a rendering of the trained agent, and a small Markdown report with a plot."""

from __future__ import annotations

from pathlib import Path

from highway_srl.agents.checkpoint import write_atomic
from highway_srl.constants import TRAFFIC_LEVELS

# The demo's update rate: a quarter of Algorithm 1's one gradient step per env step, so that `make run`
# trains in about a minute on 2 cores; its report says so.
DEMO_REPLAY_RATIO = 0.25


# what a demo writes besides its run folder (refused if there, unless overwrite)
DEMO_OUTPUTS = ("report.md", "evaluation.json", "evaluation-safe.json", "two-lane-C.gif", "two-lane-C.png",
                "deployment.png")
# the agent is deployed under its own (the paper's) profile and under ours, side by side
SAFE_PROFILE = "safe"


def run_demo(out: Path, steps: int, envs: int, episodes: int, seed: int = 0, overwrite: bool = False) -> Path:
    """Train (or reuse the run in OUT/run), evaluate, render and report; the outputs are checked before any
    work and locked until written (runs.claim_outputs), each written atomically."""
    from highway_srl.experiments.runs import check_output_folder, claim_outputs

    from highway_srl.experiments.bench import check_sim_memory

    check_output_folder(out)
    check_sim_memory("two-lane", "F", episodes, "cpu", fewer="use fewer --episodes")  # the densest level's world
    with claim_outputs([out / name for name in DEMO_OUTPUTS], overwrite):
        return _run_demo(out, steps, envs, episodes, seed, overwrite)


def _run_demo(out: Path, steps: int, envs: int, episodes: int, seed: int, overwrite: bool) -> Path:
    from highway_srl.agents.dqn import DQNConfig
    from highway_srl.agents.train_config import TrainConfig
    from highway_srl.experiments.renderings import drawn, render_episode
    from highway_srl.experiments.evaluate import evaluate_run
    from highway_srl.experiments.train import train_run

    from highway_srl.experiments.records import read_metrics
    from highway_srl.experiments.runs import check_output_folder, holds_other_files, progress_bar, run_config

    run = out / "run"
    cfg = TrainConfig(steps=steps, envs=envs, seeds=(seed,), replay_ratio=DEMO_REPLAY_RATIO,
                      dqn=DQNConfig(total_steps=steps, learning_starts=min(1000, steps // 10)))
    check_output_folder(out)
    if (run / "config.json").exists():  # a demo run is reused (or resumed) only if it has these very settings
        old = run_config(run)["config"]
        want = {"steps": steps, "envs": envs, "seeds": [seed], "replay_ratio": DEMO_REPLAY_RATIO,
                "profile": cfg.profile}
        have = {k: old.get(k) for k in want}
        if have != want:
            raise ValueError(f"{str(run)!r} holds a demo run with other settings ({_settings(have)}), not "
                             f"{_settings(want)}; choose another --out or move it away")
        print(f"reusing the demo run in {run}" if (run / "metrics.json").exists() else f"resuming the demo run in {run}")
    elif holds_other_files(out, ignore=(f".{DEMO_OUTPUTS[0]}.lock",)):  # claim_outputs' lock
        raise ValueError(f"--out {str(out)!r} holds files but no demo run ({run}/config.json); choose an empty or new folder")
    out.mkdir(parents=True, exist_ok=True)
    if not (run / "metrics.json").exists():
        train_run(cfg, run, resume=(run / "config.json").exists())
    metrics = read_metrics(run / "metrics.json")
    report = _evaluate(run, episodes, out / "evaluation.json", None, overwrite)
    safe = _evaluate(run, episodes, out / "evaluation-safe.json", SAFE_PROFILE, overwrite)
    render_episode(run, None, "C", False, "idm", seed, out / "two-lane-C.gif", progress=True, overwrite=overwrite)
    plot = drawn(out / "deployment.png", lambda tmp: _plot(report, tmp, {f"{SAFE_PROFILE} profile": safe}), overwrite)
    lines = ["# highway-srl demo", "",
             f"MoE-RM-SRL trained for {metrics['env_steps_per_seed']:,} steps on two-lane level C "
             f"({metrics['wall_s']:.0f} s, {metrics['env_steps_per_s']:,.0f} env-steps/s) under the {cfg.profile} "
             f"control profile, with {DEMO_REPLAY_RATIO:g} gradient steps per env step (Algorithm 1 takes 1; "
             "lowered to keep the demo short); "
             f"training collision-free rate T_c = {_fmt(metrics['mean']['T_c'], 3)}, final return T_r = {_fmt(metrics['mean']['T_r'], 1)}.",
             "", f"Deployment under the {cfg.profile} profile (the paper's equations as printed), {episodes} "
             "episodes per level:", "", *deployment_table(report), "",
             f"The same weights deployed under the {SAFE_PROFILE} profile (ours: the printed mappings' two holes, the "
             "lane-change cycle and the near-zero safe distance at standstill, closed; docs/paper-notes.md "
             "\"Profiles\"):", "", *deployment_table(safe), "",
             "`highway-srl falsify --profile paper` and `--profile safe` search for ego-avoidable collisions under "
             "each (docs/paper-notes.md, \"Ego-avoidable collisions\")."]
    lines += ["", f"![deployment]({plot.name})", "", "Episode: `two-lane-C.gif`. Run folder: `run/`.", ""]
    write_atomic(out / "report.md", "\n".join(lines).encode(), replace=overwrite)
    print("\n".join(lines))
    print(f"report: {out / 'report.md'}")
    return out / "report.md"


def _evaluate(run: Path, episodes: int, out: Path, profile: str | None, overwrite: bool) -> dict:
    """evaluate_run at levels A-F with a progress bar; profile None: the run's own."""
    from highway_srl.experiments.evaluate import evaluate_run
    from highway_srl.experiments.runs import progress_bar

    bar = progress_bar(1, f"evaluate levels A-F ({profile or 'own'} profile)")

    def progress(done: int, total: int) -> None:
        bar.total = total
        bar.update(done - bar.n)

    try:
        return evaluate_run(run, traffics=list(TRAFFIC_LEVELS), episodes=episodes, out=out, progress=progress,
                            profile=profile, overwrite=overwrite)
    finally:
        bar.close()


def deployment_table(report: dict) -> list[str]:
    """report.md's Markdown table: every value with the 95 % interval that evaluation.json holds."""
    lines = ["Each value with its 95 % interval in brackets (Wilson for the rate C_r); the collisions by what "
             "they were (experiments/collisions.py: the ego into the car ahead, hit from behind, side, road).", "",
             "| level | collision-free C_r | average speed (m/s) | R_r | collisions |", "|---|---|---|---|---|"]
    for level, r in report["levels"].items():
        kinds = (r.get("collisions") or {}).get("by_kind") or {}
        what = ", ".join(f"{n} {kind}" for kind, n in kinds.items()) or "none"
        lines.append(f"| {level} | {_ci(r['C_r'], '.1%')} | {_ci(r['avg_speed'], '.2f')} | {_ci(r['R_r'], '.1f')} "
                     f"| {what} |")
    return lines


def _settings(d: dict) -> str:
    return (f"--steps {d['steps']}, --envs {d['envs']}, --seed {','.join(map(str, d['seeds'] or []))}, "
            f"replay ratio {d.get('replay_ratio')}, profile {d.get('profile')}")


def _ci(stat: dict, spec: str) -> str:
    """'value [low, high]' of an evaluation statistic."""
    return f"{stat['value']:{spec}} [{stat['low']:{spec}}, {stat['high']:{spec}}]"


def _fmt(value, digits: int) -> str:
    return "n/a (no episode finished)" if value is None else f"{value:.{digits}f}"


def _plot(report: dict, path: Path, others: dict[str, dict] | None = None) -> Path:
    plt, fig = deployment_figure(report, others)
    fig.savefig(path)
    plt.close(fig)
    return path


def deployment_figure(report: dict, others: dict[str, dict] | None = None):
    """(pyplot, figure): C_r against average speed per level, with 95 % intervals on both axes; others:
    more evaluations of the same agent (label -> report), drawn beside it with hollow markers."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 4), dpi=100)
    series = {"as trained": report, **(others or {})}
    for (label, rep), marker in zip(series.items(), "osD^"):
        _draw_levels(ax, rep, marker, label if others else None)
    low = min(100 * r["C_r"]["low"] for rep in series.values() for r in rep["levels"].values())
    ax.set_ylim(max(0.0, low - 5.0), 100.0)  # a rate's axis ends at 100 %
    if others:
        ax.legend(loc="lower left", fontsize="small")
    ax.set_xlabel("average speed (m/s)")
    ax.set_ylabel("collision-free rate C_r (%), 95 % interval")
    ax.set_title("MoE-RM-SRL deployment, levels A-F")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return plt, fig


def _draw_levels(ax, report: dict, marker: str, label: str | None) -> None:
    """One evaluation's levels as points with 95 % intervals (Wilson for the rate, never past 0-100 %; the
    mean's interval for the speed); hollow markers for every series but the first."""
    hollow = marker != "o"
    for i, (level, r) in enumerate(report["levels"].items()):
        cr, v = r["C_r"], r["avg_speed"]
        x, y = v["value"], 100 * cr["value"]
        ax.errorbar(x, y, yerr=[[y - 100 * cr["low"]], [100 * cr["high"] - y]], xerr=[[x - v["low"]], [v["high"] - x]],
                    fmt=marker, ms=6, capsize=3, clip_on=False, color=f"C{i}", mfc="none" if hollow else None,
                    label=label if i == 0 else None)
        ax.annotate(level, (x, y), textcoords="offset points", xytext=(6, -12))
