"""`highway-srl train`: a run folder with config, episode log, checkpoints and training metrics.

Run folder layout:
  config.json        the TrainConfig, seed(s), version and commit
  episodes.jsonl     one line per finished training episode
  scalars.csv        env_steps, steps/s, return, collision-free rate, expert usage (TensorBoard too, if installed)
  model/             final weights (model.safetensors + meta.json), what evaluate and render load
  resume/            full state at the last checkpoint (weights, optimiser, buffers, worlds, RNG); removed at the end
  metrics.json       T_c, T_r, rise time, wall time, steps/s (per seed and their mean)
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import torch

from highway_srl.agents.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from highway_srl.agents.trainer import Episode, Trainer, TrainConfig
from highway_srl.experiments.runs import append_jsonl, provenance, read_json, read_jsonl, truncate_jsonl, write_json

SMOOTH_EPISODES = 20


def training_metrics(episodes: list[dict], seeds: list[int]) -> dict:
    """T_c, T_r and rise time (§4.2) per seed and averaged.

    T_c: share of training episodes without a collision. T_r: mean return of the last 10% of episodes
    (at least one). Rise time: first env step at which the moving average of returns (20 episodes) reaches
    min + 0.9 (peak - min) of that curve, a form of "90% of peak" that also works for negative returns.
    """
    per_seed = {}
    for seed in seeds:
        eps = [e for e in episodes if e["seed"] == seed]
        if not eps:
            per_seed[seed] = {"episodes": 0, "T_c": None, "T_r": None, "rise_time_steps": None}
            continue
        rets = [e["return"] for e in eps]
        tail = rets[-max(1, len(rets) // 10):]
        smooth = [sum(rets[max(0, i - SMOOTH_EPISODES + 1): i + 1]) / len(rets[max(0, i - SMOOTH_EPISODES + 1): i + 1])
                  for i in range(len(rets))]
        lo, hi = min(smooth), max(smooth)
        level = lo + 0.9 * (hi - lo)
        rise = next(e["step"] for e, s in zip(eps, smooth) if s >= level)
        per_seed[seed] = {
            "episodes": len(eps),
            "T_c": sum(not e["collision"] for e in eps) / len(eps),
            "T_r": sum(tail) / len(tail),
            "rise_time_steps": rise,
            "collisions": sum(e["collision"] for e in eps),
            "avg_speed": sum(e["avg_speed"] for e in eps) / len(eps),
        }
    mean = {}
    for key in ("T_c", "T_r", "rise_time_steps", "avg_speed"):
        vals = [m[key] for m in per_seed.values() if m.get(key) is not None]
        mean[key] = sum(vals) / len(vals) if vals else None
    return {"per_seed": {str(k): v for k, v in per_seed.items()}, "mean": mean}


def _episode_row(e: Episode) -> dict:
    return {"seed": e.seed, "step": e.step, "return": round(e.ret, 4), "length": e.length, "collision": e.collision,
            "avg_speed": round(e.avg_speed, 4), "success": e.success, "deploy_reward": round(e.deploy_reward, 4)}


def _meta(cfg: TrainConfig, trainer: Trainer, code: dict) -> dict:
    return {"method": cfg.method, "scenario": cfg.scenario, "traffic": cfg.traffic, "adversarial": cfg.adversarial,
            "seeds": list(cfg.seeds), "env_steps": trainer.env_steps, "config": cfg.to_dict(), **code}


class _Scalars:
    def __init__(self, out: Path):
        self.path = out / "scalars.csv"
        if not self.path.exists():
            self.path.write_text("env_steps,steps_per_s,epsilon,mean_return,collision_free,episodes\n")
        self.tb = None
        try:  # TensorBoard is optional
            from torch.utils.tensorboard import SummaryWriter

            self.tb = SummaryWriter(str(out / "tb"))
        except Exception:  # noqa: BLE001 - tensorboard not installed: the CSV is enough
            self.tb = None

    def log(self, step: int, values: dict) -> None:
        with open(self.path, "a") as f:
            f.write(",".join(str(round(values[k], 5)) if isinstance(values[k], float) else str(values[k])
                             for k in ("steps_per_s", "epsilon", "mean_return", "collision_free", "episodes")
                             ).join([f"{step},", "\n"]))
        if self.tb is not None:
            for k, v in values.items():
                self.tb.add_scalar(k, v, step)


def train_run(cfg: TrainConfig, out: str | Path, resume: bool = False, checkpoint_every: int = 50_000,
              progress: bool = True) -> dict:
    """Train and write the run folder; returns metrics.json's content."""
    out = Path(out)
    code = provenance()  # the code that runs is the code loaded now, not what is checked out at the end
    if resume:
        if not (out / "config.json").exists():
            raise FileNotFoundError(f"cannot resume: {str(out)!r} has no config.json")
        saved = read_json(out / "config.json")
        cfg = TrainConfig.from_dict(saved["config"])
    elif (out / "config.json").exists():
        raise FileExistsError(f"{str(out)!r} already holds a run; use --resume to continue it or choose another --out")
    trainer = Trainer(cfg)
    out.mkdir(parents=True, exist_ok=True)
    log = out / "episodes.jsonl"
    started = time.perf_counter()
    if resume and (out / "resume").exists():
        tensors, meta = load_checkpoint(out / "resume", expect={"method": cfg.method, "scenario": cfg.scenario})
        trainer.load_state_dict(tensors)
        truncate_jsonl(log, lambda r: r["step"] <= trainer.env_steps)
        prior_wall = meta.get("wall_s", 0.0)
    else:
        if resume:
            log.unlink(missing_ok=True)
        prior_wall = 0.0
        write_json(out / "config.json", {"config": cfg.to_dict(), **code})
    log.touch()
    scalars = _Scalars(out)
    recent: list[Episode] = []
    bar = _progress(cfg.steps, trainer.env_steps, progress)
    last_ckpt, last_log, t_log, s_log = trainer.env_steps, trainer.env_steps, time.perf_counter(), trainer.env_steps
    while trainer.env_steps < cfg.steps:
        finished = trainer.step()
        if finished:
            append_jsonl(log, [_episode_row(e) for e in finished])
            recent = (recent + finished)[-100:]
        if trainer.env_steps - last_log >= 2000 or trainer.env_steps >= cfg.steps:
            now = time.perf_counter()
            rate = (trainer.env_steps - s_log) * len(cfg.seeds) / max(now - t_log, 1e-9)
            stats = {
                "steps_per_s": rate,
                "epsilon": cfg.dqn.epsilon(trainer.env_steps),
                "mean_return": sum(e.ret for e in recent) / len(recent) if recent else 0.0,
                "collision_free": sum(not e.collision for e in recent) / len(recent) if recent else 1.0,
                "episodes": len(recent),
            }
            scalars.log(trainer.env_steps, stats)
            if bar is not None:
                share = trainer.usage.float() / trainer.usage.sum().clamp(min=1)
                bar.set_postfix(sps=f"{rate:,.0f}", ret=f"{stats['mean_return']:.1f}",
                                free=f"{stats['collision_free']:.2f}", eps=f"{stats['epsilon']:.2f}",
                                first=f"{float(share[1::trainer.method.num_members // len(cfg.seeds)].sum()):.0%}")
                bar.update(trainer.env_steps - last_log)
            last_log, t_log, s_log = trainer.env_steps, now, trainer.env_steps
        if trainer.env_steps - last_ckpt >= checkpoint_every and trainer.env_steps < cfg.steps:
            wall = prior_wall + time.perf_counter() - started
            save_checkpoint(out / "resume", trainer.state_dict(), {**_meta(cfg, trainer, code), "wall_s": wall})
            last_ckpt = trainer.env_steps
    if bar is not None:
        bar.close()
    wall = prior_wall + time.perf_counter() - started
    learner_state = {f"learner.{k}": v for k, v in trainer.learner.state_dict().items()}
    learner_state.update({f"method.{k}": v for k, v in trainer.method.state_dict().items()})  # e.g. LM-RL's λ
    save_checkpoint(out / "model", learner_state, {**_meta(cfg, trainer, code), "wall_s": wall})
    metrics = training_metrics(read_jsonl(log), list(cfg.seeds))
    metrics.update({"method": cfg.method, "scenario": cfg.scenario, "traffic": cfg.traffic,
                    "adversarial": cfg.adversarial, "env_steps_per_seed": trainer.env_steps, "seeds": list(cfg.seeds),
                    "wall_s": round(wall, 2), "env_steps_per_s": round(trainer.env_steps * len(cfg.seeds) / max(wall, 1e-9), 1),
                    "device": str(trainer.device), "member_usage": _usage(trainer), **code})
    write_json(out / "metrics.json", metrics)
    _remove_resume(out / "resume")
    return metrics


def _usage(trainer: Trainer) -> dict:
    """Share of decisions made by each member (per seed, by expert name for MoE), and by the fallback."""
    counts = trainer.usage.cpu()
    total = max(int(counts.sum()), 1)
    per_seed = trainer.method.num_members // len(trainer.config.seeds)
    names = getattr(trainer.method, "member_names", None) or [f"member{i}" for i in range(per_seed)]
    out = {"fallback": round(int(counts[0]) / total, 6)}
    for i, name in enumerate(names):
        out[name] = round(int(counts[1 + i::per_seed].sum()) / total, 6)
    return out


def _remove_resume(path: Path) -> None:
    if path.exists():
        for f in path.iterdir():
            f.unlink()
        path.rmdir()


def _progress(total: int, start: int, enabled: bool):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, initial=start, unit="step", dynamic_ncols=True, mininterval=1.0)


def load_learner_state(run: str | Path, expect: dict | None = None):
    """(TrainConfig, learner tensors, meta) of a finished run; clear errors for anything wrong."""
    from highway_srl.experiments.runs import run_folder

    folder = run_folder(run)
    cfg = TrainConfig.from_dict(read_json(folder / "config.json")["config"])
    if not (folder / "model").exists():
        raise CheckpointError(f"run {str(folder)!r} has no final model yet (interrupted? resume it with --resume)")
    expected = {"method": cfg.method, "scenario": cfg.scenario}
    if expect:
        expected.update(expect)
    tensors, meta = load_checkpoint(folder / "model", expect=expected)
    state = {k[len("learner."):]: v for k, v in tensors.items() if k.startswith("learner.")}
    state.update({k: v for k, v in tensors.items() if k.startswith("method.")})  # the learner ignores these keys
    return cfg, state, meta


def bench_train(method: str, scenario: str, traffic: str, envs: int, steps: int, device: str, seeds: int = 1) -> dict:
    """Env-steps/s of the full training loop (updates included, past learning_starts) without running to the end."""
    from highway_srl.agents.dqn import DQNConfig
    from highway_srl.experiments.bench import machine

    cfg = TrainConfig(method=method, scenario=scenario, traffic=traffic, envs=envs, seeds=tuple(range(seeds)),
                      device=device, steps=10**9, dqn=DQNConfig(learning_starts=0, batch_size=256))
    trainer = Trainer(cfg)
    # fill every acting member's buffer past one batch so updates run from the first timed step
    while int(trainer.replay.size.max()) < cfg.dqn.batch_size:
        trainer.step()
    for _ in range(5):
        trainer.step()
    if trainer.device.type == "cuda":
        torch.cuda.synchronize()
    t0 = time.perf_counter()
    for _ in range(steps):
        trainer.step()
    if trainer.device.type == "cuda":
        torch.cuda.synchronize()
    wall = time.perf_counter() - t0
    rate = steps * envs * seeds / wall
    return {"what": "train", "method": method, "scenario": scenario, "traffic": traffic, "envs": envs, "seeds": seeds,
            "vector_steps": steps, "device": str(trainer.device), "wall_s": round(wall, 3),
            "env_steps_per_s": round(rate, 1),
            "projected_paper_run_min": round(5e5 * seeds / rate / 60, 2) if rate > 0 else math.inf,
            "updates_per_step": cfg.updates_per_step, "machine": machine()}
