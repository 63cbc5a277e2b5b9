"""`highway-srl train`: a run folder with config, episode log, checkpoints and training metrics.

Run folder layout:
  config.json        the TrainConfig, seed(s), checkpoint_every, version and commit (--resume reads its settings here)
  .lock              advisory lock (flock) held while a process trains here
  episodes.jsonl     one line per finished training episode
  scalars.csv        a row every 2,000 env steps: speed, ε, return, collision-free rate, loss, Q, TD error, expert
                     usage, episode length, learning rate, gradient updates (training_log.TrainingLog)
  tb/                TensorBoard, if it is installed: tb/all-seeds the rows of scalars.csv, tb/seed-N a point per
                     finished episode of seed N
  model/             final weights (model.safetensors + meta.json), what evaluate and render load
  resume/            full state at the last checkpoint (weights, optimiser, buffers, worlds, RNG; meta.json also the
                     training log's cadence and running window and the episodes logged); removed at the end
  metrics.json       T_c, T_r, rise time (training_metrics), wall time, steps/s (per seed and their mean); the
                     training collisions split into ego-avoidable and unavoidable (collision_verdicts)
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import torch

from highway_srl.agents.checkpoint import (
    MODEL_FILE, CheckpointError, first_non_finite, load_checkpoint, policy_tensors, save_checkpoint,
)
from highway_srl.agents.dqn import UpdateLog
from highway_srl.agents.train_config import TrainConfig, check_config
from highway_srl.agents.trainer import OPTIONAL_KEYS, VERDICT_COLUMNS, Episode, Trainer
from highway_srl.experiments.bench import check_train_memory
from highway_srl.experiments.collisions import DecisionTrace
from highway_srl.experiments.records import check_fields, read_episode_log
from highway_srl.experiments.runs import (
    append_jsonl, check_output_folder, holds_other_files, is_int, lock_run, progress_bar, provenance,
    read_json, run_config, train_config, write_json, write_jsonl,
)
from highway_srl.experiments.training_log import TrainingLog, usage_shares
from highway_srl.experiments.training_metrics import training_metrics

def _episode_row(e: Episode) -> dict:
    return {"seed": e.seed, "step": e.step, "return": round(e.ret, 4), "length": e.length, "collision": e.collision,
            "avg_speed": round(e.avg_speed, 4), "success": e.success, "deploy_reward": round(e.deploy_reward, 4),
            "rm_return": round(e.rm_return, 4)}


def collision_verdicts(trainer: Trainer) -> dict:
    """metrics.json's split of the training collisions by the ego-avoidable verdict (rules.avoidable), per
    seed and in all: collisions, ego_avoidable, unavoidable, not_judged (the static step reads nothing
    back, so its collisions are not judged)."""
    counts = trainer.verdict_counts.tolist()
    per_seed = {str(seed): {"collisions": sum(row), **dict(zip(VERDICT_COLUMNS, row))}
                for seed, row in zip(trainer.config.seeds, counts)}
    total = [sum(col) for col in zip(*counts)]
    return {"per_seed": per_seed, "all": {"collisions": sum(total), **dict(zip(VERDICT_COLUMNS, total))}}


def _meta(cfg: TrainConfig, trainer: Trainer, code: dict) -> dict:
    return {"method": cfg.method, "scenario": cfg.scenario, "traffic": cfg.traffic, "adversarial": cfg.adversarial,
            "profile": cfg.profile, "adversary": cfg.adversary, "seeds": list(cfg.seeds), "env_steps": trainer.env_steps,
            "config": cfg.to_dict(), **code}


def finished(out: Path) -> bool:
    """A run folder whose training ran to the end (metrics.json is written last but for the resume/ cleanup)."""
    return (out / "metrics.json").exists()


def last_checkpoint_step(out: Path) -> int | None:
    """env steps per seed of the resume checkpoint in a run folder, None if there is none (or it is unreadable)."""
    try:
        return int(read_json(out / "resume" / "meta.json")["env_steps"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def saved_checkpoint_every(out: Path, default: int) -> int:
    """checkpoint_every as config.json records it (a positive integer), default where it records none."""
    value = run_config(out).get("checkpoint_every", default)
    if not is_int(value) or value < 1:
        raise ValueError(f"{out / 'config.json'} is damaged (checkpoint_every must be a positive integer, got {value!r})")
    return value


def _check_target(out: Path, resume: bool) -> None:
    """Refuse, before anything is written, a run folder that this command must not touch."""
    check_output_folder(out)
    if resume:
        if not (out / "config.json").exists():
            raise FileNotFoundError(f"cannot resume: {str(out)!r} has no config.json")
        if finished(out):
            raise ValueError(f"run folder {str(out)!r} is already finished (metrics.json); nothing to resume")
    elif (out / "config.json").exists():
        raise FileExistsError(f"{str(out)!r} already holds a run; use --resume to continue it or choose another --out")
    elif holds_other_files(out):
        raise ValueError(f"--out {str(out)!r} holds files but no run (config.json); choose an empty or new folder")


def _load_resume(trainer: Trainer, folder: Path, cfg: TrainConfig) -> dict:
    """Load resume/ into a fresh trainer; a checkpoint that does not fit the run's config is one clear line."""
    tensors, meta = load_checkpoint(folder, expect={"method": cfg.method, "scenario": cfg.scenario})
    fresh = {k: v for k, v in trainer.state_dict().items()  # replay checks itself
             if not k.startswith("replay.") and not (k in OPTIONAL_KEYS and k not in tensors)}
    missing = sorted(set(fresh) - set(tensors))
    if missing:
        raise CheckpointError(f"{folder} lacks {len(missing)} tensor(s), e.g. {missing[0]!r}; it is not this run's checkpoint")
    for key, want in fresh.items():
        got = tensors[key]
        if got.shape != want.shape or got.dtype != want.dtype:
            raise CheckpointError(f"{folder}: {key} is {tuple(got.shape)} {got.dtype}, this run's config "
                                  f"(envs {cfg.envs}, seeds {list(cfg.seeds)}) needs {tuple(want.shape)} {want.dtype}")
    counters = tensors.get("counters.vector_steps"), tensors.get("counters.usage")
    if counters[0] is not None and counters[0].numel() == 1 and not 0 <= int(counters[0]) * cfg.envs < cfg.steps:
        raise CheckpointError(f"{folder / MODEL_FILE}: counters.vector_steps {int(counters[0])} x {cfg.envs} envs is "
                              f"not a step before the run's end ({cfg.steps:,}); it cannot be resumed")
    if counters[1] is not None and bool((counters[1] < 0).any()):
        raise CheckpointError(f"{folder / MODEL_FILE}: counters.usage holds negative counts; it cannot be resumed")
    bad = first_non_finite(tensors, nan_only=("world.",))
    if bad is not None:
        raise CheckpointError(f"{folder / MODEL_FILE}: {bad} holds NaN or infinite values; it cannot be resumed")
    try:
        trainer.load_state_dict(tensors)
    except (RuntimeError, ValueError, KeyError, TypeError, IndexError) as err:
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise CheckpointError(f"{folder} does not fit this run: {first}") from None
    return meta


def train_run(cfg: TrainConfig | None, out: str | Path, resume: bool = False, checkpoint_every: int = 50_000,
              progress: bool = True, drop_damaged: bool = False) -> dict:
    """Train and write the run folder; returns metrics.json's content.

    resume: continue the run in `out` with every setting it was started with (config.json holds the
    TrainConfig and checkpoint_every; `cfg` and `checkpoint_every` are then ignored; drop_damaged: continue
    from the rows before a damaged line of its logs instead of refusing, _resume_logs). The folder is locked
    while this runs (a second process gets a one-line error); nothing is written before every check passed.
    """
    out = Path(out)
    code = provenance()  # the code that runs is the code loaded now, not what is checked out at the end
    _check_target(out, resume)
    if resume:
        cfg = train_config(out)
        checkpoint_every = saved_checkpoint_every(out, checkpoint_every)
    check_config(cfg)  # a setting no run can have is refused before any folder is made
    check_train_memory(cfg)  # and one that would not fit in memory
    out.mkdir(parents=True, exist_ok=True)
    with lock_run(out):
        _check_target(out, resume)  # again, under the lock: another process may have finished meanwhile
        return _train_locked(cfg, out, resume, checkpoint_every, progress, code, drop_damaged)


# vector steps between two reads of the finished episodes (the progress bar and episodes.jsonl lag by up to
# this many; checkpoints drain first, so a resume is exact)
DRAIN_EVERY = 50


def max_episode_step(cfg: TrainConfig) -> int:
    """The last env step (per seed) an episode of a run can end at: the last vector step may pass cfg.steps."""
    return cfg.steps + cfg.envs - 1


def _resume_logs(trainer: Trainer, out: Path, cfg: TrainConfig, drop_damaged: bool) -> tuple[TrainingLog, float, int]:
    """Load resume/ into the trainer and keep what its checkpoint covers of episodes.jsonl and scalars.csv:
    (the training log, the wall time so far, the episodes logged). Every file is checked (records.py) before
    any is rewritten; one that does not match the checkpoint is refused, or with drop_damaged cut at its
    first damaged line (a note on stderr says how much was dropped)."""
    meta = _load_resume(trainer, out / "resume", cfg)
    meta_path = out / "resume" / "meta.json"
    check_fields(meta, {"wall_s": "number", "episodes_logged": "count"}, str(meta_path),
                 optional=("wall_s", "episodes_logged"))  # checkpoints written before these existed lack them
    log = out / "episodes.jsonl"
    rows, note = read_episode_log(log, cfg.seeds, max_episode_step(cfg), drop_damaged)
    rows = [r for r in rows if r["step"] <= trainer.env_steps]
    if len(rows) != meta.get("episodes_logged", len(rows)) and not drop_damaged:
        raise ValueError(f"{log} holds {len(rows)} episodes up to the checkpoint's step {trainer.env_steps:,}, the "
                         f"checkpoint counted {meta['episodes_logged']} (the log was cut or edited); nothing was "
                         "changed (--drop-damaged continues with the rows it holds)")
    scalars = TrainingLog(out, trainer, trainer.env_steps, meta.get("log"), drop_damaged)
    write_jsonl(log, rows)
    for line in (note, scalars.note):
        if line is not None:
            print(f"note: {line}", file=sys.stderr)
    return scalars, meta.get("wall_s", 0.0), len(rows)


def _train_locked(cfg: TrainConfig, out: Path, resume: bool, checkpoint_every: int, progress: bool, code: dict,
                  drop_damaged: bool = False) -> dict:
    trainer = Trainer(cfg, drain_every=DRAIN_EVERY)
    if not trainer.static:  # the static step reads nothing back: its collisions stay unjudged
        trainer.collision_trace = DecisionTrace(trainer.method)
    log = out / "episodes.jsonl"
    started = time.perf_counter()
    if resume and (out / "resume").exists():
        scalars, prior_wall, logged = _resume_logs(trainer, out, cfg, drop_damaged)
    else:
        logged = 0
        log.unlink(missing_ok=True)  # a resume before the first checkpoint starts afresh
        prior_wall = 0.0
        write_json(out / "config.json", {"config": cfg.to_dict(), "checkpoint_every": checkpoint_every, **code})
        scalars = TrainingLog(out, trainer)
    log.touch()
    bar = progress_bar(cfg.steps, f"train {cfg.method}", enabled=progress, initial=min(trainer.env_steps, cfg.steps))
    last_ckpt = trainer.env_steps
    try:
        while trainer.env_steps < cfg.steps:
            finished_eps = trainer.step()
            at_end = trainer.env_steps >= cfg.steps
            checkpoint = trainer.env_steps - last_ckpt >= checkpoint_every and not at_end
            if at_end or checkpoint or scalars.due(trainer):
                finished_eps += trainer.drain()  # everything up to this step is in the log before it is written
            if finished_eps:
                append_jsonl(log, [_episode_row(e) for e in finished_eps])
                logged += len(finished_eps)
                scalars.episodes(finished_eps)
            if bar is not None:  # tqdm redraws on its own clock (mininterval); no tensor is read here
                bar.update(min(trainer.env_steps, cfg.steps) - bar.n)
            if scalars.due(trainer) or at_end:
                since = scalars.step
                values = scalars.log(trainer)
                check_finite(trainer, values, since)
                if bar is not None:
                    bar.set_postfix(_postfix(values), refresh=False)
            if checkpoint:
                wall = prior_wall + time.perf_counter() - started
                check_finite(trainer, {}, last_ckpt)  # a checkpoint never holds a diverged state
                scalars.flush()
                save_checkpoint(out / "resume", trainer.state_dict(),
                                {**_meta(cfg, trainer, code), "wall_s": wall, "log": scalars.state(),
                                 "episodes_logged": logged})
                last_ckpt = trainer.env_steps
    finally:
        scalars.close()
        if bar is not None:
            bar.close()  # ends the bar's line, so a message after an interrupt starts on its own line
    return _finish(cfg, trainer, out, prior_wall + time.perf_counter() - started, code)


def _finish(cfg: TrainConfig, trainer: Trainer, out: Path, wall: float, code: dict) -> dict:
    """The model, then metrics.json from the episode log (checked: records.py); resume/ removed last."""
    save_checkpoint(out / "model", policy_tensors(trainer.learner, trainer.method), {**_meta(cfg, trainer, code), "wall_s": wall})
    rows, note = read_episode_log(out / "episodes.jsonl", cfg.seeds, max_episode_step(cfg))
    if note is not None:
        print(f"note: {note}", file=sys.stderr)
    metrics = training_metrics(rows, list(cfg.seeds))
    metrics.update({"method": cfg.method, "scenario": cfg.scenario, "traffic": cfg.traffic,
                    "adversarial": cfg.adversarial, "profile": cfg.profile, "adversary": cfg.adversary,
                    "replay_ratio": cfg.replay_ratio, "env_steps_per_seed": trainer.env_steps, "seeds": list(cfg.seeds),
                    "wall_s": round(wall, 2), "env_steps_per_s": round(trainer.env_steps * len(cfg.seeds) / max(wall, 1e-9), 1),
                    "device": str(trainer.device), "member_usage": _usage(trainer),
                    "collision_verdicts": collision_verdicts(trainer), **code})
    write_json(out / "metrics.json", metrics)
    _remove_resume(out / "resume")
    return metrics


class TrainingDiverged(ValueError):
    """A loss, Q-value or weight became NaN or infinite: the run stops (the CLI's one-line error)."""


def check_finite(trainer: Trainer, values: dict, since: int) -> None:
    """TrainingDiverged at the first non-finite update statistic (values: a scalars.csv row's loss, q_mean,
    td_error) or weight (any member's, then the rest of the policy: targets, Adam moments, the method's
    state). Called at each scalars.csv row, whose update statistics are read anyway, and before each
    checkpoint: one host read per member's weights there, none per gradient step, so the step named is
    the check's, the divergence lies between `since` and it."""
    step, bad = trainer.env_steps, None
    members = (~trainer.learner.online.flat.isfinite().all(1)).nonzero().flatten().tolist()
    if members:
        bad = f"the weights of {member_name(trainer, members[0])}"
    elif any(not math.isfinite(values[k]) for k in UpdateLog.FIELDS if k in values):
        bad = "the loss, Q-value or TD error of the updates (" + ", ".join(
            f"{k} {values[k]}" for k in UpdateLog.FIELDS if k in values) + ")"
    elif (key := first_non_finite(policy_tensors(trainer.learner, trainer.method))) is not None:
        bad = f"the policy's {key}"
    if bad is not None:
        raise TrainingDiverged(f"training stopped at env step {step}: {bad} became NaN or infinite after step "
                               f"{since} (checked at each scalars.csv row and checkpoint); the run stops, its last checkpoint is kept")


def member_name(trainer: Trainer, member: int) -> str:
    """A learner member in words: "expert E2,1 (seed 3)" for MoE, "member 0 (seed 0)" otherwise."""
    per_seed = trainer.method.num_members // len(trainer.config.seeds)
    names = getattr(trainer.method, "member_names", None)
    name = f"expert {names[member % per_seed]}" if names else f"member {member % per_seed}"
    return f"{name} (seed {trainer.config.seeds[member // per_seed]})"


def _postfix(values: dict) -> dict[str, str]:
    """The progress bar's few numbers, of those that exist yet."""
    shown = {"mean_return": ("ret", "{:.1f}"), "collision_free": ("free", "{:.2f}"), "epsilon": ("eps", "{:.2f}"),
             "loss": ("loss", "{:.3g}")}
    return {name: fmt.format(values[k]) for k, (name, fmt) in shown.items() if k in values}


def _usage(trainer: Trainer) -> dict:
    """Share of decisions made by each member over the run (metrics.json's member_usage)."""
    return usage_shares(trainer.usage.cpu(), trainer)


def _remove_resume(path: Path) -> None:
    if path.exists():
        for f in path.iterdir():
            f.unlink()
        path.rmdir()


def bench_train(method: str, scenario: str, traffic: str, envs: int, steps: int, device: str, seeds: int = 1,
                compile: bool | str = False, static: bool | None = None) -> dict:
    """Env-steps/s of the full training loop (updates included, at Algorithm 1's rate: replay_ratio 1, batch
    256, from the first timed step) without running to the end. compile: also the compiled step (True, or a
    torch.compile mode / backend), measured after the eager one: both are reported under "forms", and the
    top-level figures are the compiled ones. static: the eager step's form (None: the device's default).
    Each form's warm-up (buffers filled to a batch, then 5 steps) includes its compilation: warmup_s, and
    env_steps_per_s_with_compile counts it."""
    from highway_srl.experiments.bench import machine

    forms = {"eager": bench_train_form(method, scenario, traffic, envs, steps, device, seeds, False, static)}
    if compile:
        forms["compiled"] = bench_train_form(method, scenario, traffic, envs, steps, device, seeds, compile, True)
    top = forms["compiled" if compile else "eager"]
    rate = top["env_steps_per_s"]
    return {"what": "train", "method": method, "scenario": scenario, "traffic": traffic, "envs": envs, "seeds": seeds,
            "vector_steps": steps, "device": top["device"], "compile": compile, "static": top["static"],
            "wall_s": top["wall_s"], "env_steps_per_s": rate,
            "projected_paper_run_min": round(5e5 * seeds / rate / 60, 2) if rate > 0 else math.inf,
            "replay_ratio": 1.0, "forms": forms, "machine": machine()}


def bench_train_form(method: str, scenario: str, traffic: str, envs: int, steps: int, device: str, seeds: int,
                     compile: bool | str, static: bool | None, batch_size: int = 256,
                     buffer_capacity: int | None = None, unrolled: bool = False) -> dict:
    """One form of bench_train: {device, static, compile, warmup_s, wall_s, env_steps_per_s,
    env_steps_per_s_with_compile}. batch_size: Table 2's 256, buffer_capacity: DQNConfig's per member
    (scripts/device_check.py's smoke run: less of both); unrolled: TrainConfig.compile_unrolled."""
    from highway_srl.agents.dqn import DQNConfig

    start = time.perf_counter()
    cfg = TrainConfig(method=method, scenario=scenario, traffic=traffic, envs=envs, seeds=tuple(range(seeds)),
                      device=device, steps=10**9, replay_ratio=1.0, static=static, compile=compile,
                      compile_unrolled=unrolled,
                      dqn=DQNConfig(learning_starts=0, batch_size=batch_size,
                                    buffer_capacity=buffer_capacity or DQNConfig.buffer_capacity))
    check_train_memory(cfg)
    trainer = Trainer(cfg, drain_every=DRAIN_EVERY)
    sync = torch.cuda.synchronize if trainer.device.type == "cuda" else (lambda: None)
    # fill every acting member's buffer past one batch so updates run from the first timed step
    while int(trainer.replay.size.max()) < cfg.dqn.batch_size:
        trainer.step()
    for _ in range(5):
        trainer.step()
    sync()
    warm = time.perf_counter()
    warm_steps = trainer.vector_steps
    for _ in range(steps):
        trainer.step()
    sync()
    end = time.perf_counter()
    batch = envs * seeds
    return {"device": str(trainer.device), "static": trainer.static, "compile": compile,
            "warmup_s": round(warm - start, 3), "wall_s": round(end - warm, 3),
            "env_steps_per_s": round(steps * batch / (end - warm), 1),
            "env_steps_per_s_with_compile": round((warm_steps + steps) * batch / (end - start), 1)}
