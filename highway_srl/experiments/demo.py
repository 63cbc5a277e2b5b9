"""The main job (`make run`): a short MoE-RM-SRL training on two-lane level C, evaluation on levels A-F,
a rendering of the trained agent, and a small Markdown report with a plot."""

from __future__ import annotations

from pathlib import Path

from highway_srl.constants import TRAFFIC_LEVELS


def run_demo(out: Path, steps: int, envs: int, episodes: int, seed: int = 0) -> Path:
    from highway_srl.agents.dqn import DQNConfig
    from highway_srl.agents.trainer import TrainConfig
    from highway_srl.experiments.episodes import render_episode
    from highway_srl.experiments.evaluate import evaluate_run
    from highway_srl.experiments.train import train_run

    out.mkdir(parents=True, exist_ok=True)
    run = out / "run"
    if not (run / "metrics.json").exists():
        cfg = TrainConfig(steps=steps, envs=envs, seeds=(seed,),
                          dqn=DQNConfig(total_steps=steps, learning_starts=min(1000, steps // 10)))
        train_run(cfg, run, resume=(run / "config.json").exists())
    from highway_srl.experiments.runs import read_json

    metrics = read_json(run / "metrics.json")
    report = evaluate_run(run, traffics=list(TRAFFIC_LEVELS), episodes=episodes, out=out / "evaluation.json")
    render_episode(run, None, "C", False, "idm", seed, out / "two-lane-C.gif")
    plot = _plot(report, out / "deployment.png")
    lines = ["# highway-srl demo", "",
             f"MoE-RM-SRL trained for {metrics['env_steps_per_seed']:,} steps on two-lane level C "
             f"({metrics['wall_s']:.0f} s, {metrics['env_steps_per_s']:,.0f} env-steps/s); "
             f"training collision-free rate T_c = {_fmt(metrics['mean']['T_c'], 3)}, final return T_r = {_fmt(metrics['mean']['T_r'], 1)}.",
             "", f"Deployment, {episodes} episodes per level:", "",
             "| level | collision-free C_r | average speed (m/s) | R_r |", "|---|---|---|---|"]
    for level, r in report["levels"].items():
        lines.append(f"| {level} | {r['C_r']['value']:.1%} | {r['avg_speed']['value']:.2f} | {r['R_r']['value']:.1f} |")
    lines += ["", f"![deployment]({plot.name})", "", "Episode: `two-lane-C.gif`. Run folder: `run/`.", ""]
    (out / "report.md").write_text("\n".join(lines))
    print("\n".join(lines))
    print(f"report: {out / 'report.md'}")
    return out / "report.md"


def _fmt(value, digits: int) -> str:
    return "n/a (no episode finished)" if value is None else f"{value:.{digits}f}"


def _plot(report: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 4), dpi=100)
    for level, r in report["levels"].items():
        ax.scatter(r["avg_speed"]["value"], 100 * r["C_r"]["value"], s=40)
        ax.annotate(level, (r["avg_speed"]["value"], 100 * r["C_r"]["value"]), textcoords="offset points", xytext=(5, 3))
    ax.set_xlabel("average speed (m/s)")
    ax.set_ylabel("collision-free rate C_r (%)")
    ax.set_title("MoE-RM-SRL deployment, levels A-F")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
