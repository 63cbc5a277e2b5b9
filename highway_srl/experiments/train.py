"""`highway-srl train`: a run folder with config, episode log, checkpoints and training metrics.

Run folder layout:
  config.json        the TrainConfig, seed(s), checkpoint_every, version and commit (--resume reads its settings here)
  .lock              advisory lock (flock) held while a process trains here
  episodes.jsonl     one line per finished training episode
  scalars.csv        a row every 2,000 env steps: speed, ε, return, collision-free rate, loss, Q, TD error, expert
                     usage, episode length, learning rate, gradient updates (TrainingLog)
  tb/                TensorBoard, if it is installed: tb/all-seeds the rows of scalars.csv, tb/seed-N a point per
                     finished episode of seed N
  model/             final weights (model.safetensors + meta.json), what evaluate and render load
  resume/            full state at the last checkpoint (weights, optimiser, buffers, worlds, RNG; meta.json also the
                     training log's cadence and running window and the episodes logged); removed at the end
  metrics.json       T_c, T_r, rise time, wall time, steps/s (per seed and their mean)
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import torch

from highway_srl.agents.checkpoint import (
    MODEL_FILE, CheckpointError, first_non_finite, load_checkpoint, naming, policy_tensors, save_checkpoint,
    write_atomic,
)
from highway_srl.agents.dqn import UpdateLog
from highway_srl.agents.trainer import OPTIONAL_KEYS, Episode, Trainer, TrainConfig, check_config
from highway_srl.experiments.bench import check_train_memory
from highway_srl.experiments.records import check_fields, read_episode_log, scalar_rows
from highway_srl.experiments.runs import (
    Named, append_jsonl, check_output_folder, holds_other_files, is_finite_number, is_int, lock_run, progress_bar,
    provenance, read_json, run_config, train_config, write_json, write_jsonl,
)

SMOOTH_EPISODES = 20


def rise_time(steps: list[int], smoothed: list[float], fraction: float = 0.9, from_min: bool = False) -> int:
    """§4.2's rise time: the first of `steps` at which `smoothed` (the smoothed episode return, one value per
    step) reaches `fraction` of its peak. A peak <= 0 (an agent that never earns more than it loses) cannot
    be reached at 90 % of itself from below, so the level is peak - (1 - fraction) |peak|, which is
    fraction x peak for every positive peak. from_min=True is our earlier variant, min + fraction (peak - min)
    of the curve (reported as rise_time_range_steps)."""
    hi, lo = max(smoothed), min(smoothed)
    if from_min:
        level = lo + fraction * (hi - lo)
    else:
        level = fraction * hi if hi >= 0 else (2.0 - fraction) * hi
    return next(step for step, value in zip(steps, smoothed) if value >= level)


def training_metrics(episodes: list[dict], seeds: list[int]) -> dict:
    """T_c, T_r and rise time (§4.2) per seed and averaged.

    T_c: share of training episodes without a collision. T_r: mean return of the last 10% of episodes
    (at least one), in the method's own training reward; T_r_rm: the same mean of the paper's RM return
    (one scale for every method; None for logs written before it existed). Rise time: first env step at which the moving average of returns (20 episodes) reaches
    90 % of its peak (`rise_time`); rise_time_range_steps: where it reaches min + 0.9 (peak - min).
    """
    per_seed = {}
    for seed in seeds:
        eps = [e for e in episodes if e["seed"] == seed]
        if not eps:
            per_seed[seed] = {"episodes": 0, "T_c": None, "T_r": None, "T_r_rm": None, "rise_time_steps": None,
                              "rise_time_range_steps": None}
            continue
        rets = [e["return"] for e in eps]
        tail = rets[-max(1, len(rets) // 10):]
        smooth = [sum(rets[max(0, i - SMOOTH_EPISODES + 1): i + 1]) / len(rets[max(0, i - SMOOTH_EPISODES + 1): i + 1])
                  for i in range(len(rets))]
        steps = [e["step"] for e in eps]
        per_seed[seed] = {
            "episodes": len(eps),
            "T_c": sum(not e["collision"] for e in eps) / len(eps),
            "T_r": sum(tail) / len(tail),
            "T_r_rm": _tail_mean([e.get("rm_return") for e in eps]),
            "rise_time_steps": rise_time(steps, smooth),
            "rise_time_range_steps": rise_time(steps, smooth, from_min=True),
            "collisions": sum(e["collision"] for e in eps),
            "avg_speed": sum(e["avg_speed"] for e in eps) / len(eps),
        }
    mean = {}
    for key in ("T_c", "T_r", "T_r_rm", "rise_time_steps", "rise_time_range_steps", "avg_speed"):
        vals = [m[key] for m in per_seed.values() if m.get(key) is not None]
        mean[key] = sum(vals) / len(vals) if vals else None
    return {"per_seed": {str(k): v for k, v in per_seed.items()}, "mean": mean}


def _tail_mean(values: list) -> float | None:
    """Mean of the last 10 % (at least one) of values; None if any is missing (an old episode log)."""
    if not values or any(v is None for v in values):
        return None
    tail = values[-max(1, len(values) // 10):]
    return sum(tail) / len(tail)


def _episode_row(e: Episode) -> dict:
    return {"seed": e.seed, "step": e.step, "return": round(e.ret, 4), "length": e.length, "collision": e.collision,
            "avg_speed": round(e.avg_speed, 4), "success": e.success, "deploy_reward": round(e.deploy_reward, 4),
            "rm_return": round(e.rm_return, 4)}


def _meta(cfg: TrainConfig, trainer: Trainer, code: dict) -> dict:
    return {"method": cfg.method, "scenario": cfg.scenario, "traffic": cfg.traffic, "adversarial": cfg.adversarial,
            "profile": cfg.profile, "adversary": cfg.adversary, "seeds": list(cfg.seeds), "env_steps": trainer.env_steps,
            "config": cfg.to_dict(), **code}


LOG_EVERY = 2000  # env steps per seed between two rows of scalars.csv (and TensorBoard points)
RECENT_EPISODES = 100  # mean_return and collision_free are over the last this many episodes


class TrainingLog:
    """scalars.csv and, if tensorboard is installed, TensorBoard events (OUT/tb) of a training run.

    A row every LOG_EVERY env steps: env_steps (per seed), steps_per_s (env steps/s, all seeds),
    episodes_per_s, epsilon, mean_return and collision_free (the last RECENT_EPISODES episodes), episodes
    (how many that is), loss, q_mean, td_error (means per member update since the last row), usage/NAME
    (each expert's share of the decisions since the last row, all seeds; usage/fallback: no expert acted),
    mean_length (env steps per episode over the same window as mean_return), lr (the learning rate),
    updates (gradient updates of all members so far); later columns are appended after these, so a
    reader that takes the cells by the header's names reads every version. A value that does not exist
    yet (no episode has ended, no update was made) is an empty cell and no TensorBoard point. TensorBoard
    runs: tb/all-seeds gets the rows (values over all seeds), tb/seed-N a point per finished episode of
    seed N at its env step: episode/return, episode/collision, episode/avg_speed, episode/length (one run
    per seed, so two seeds' points at one step do not collide). Reading the values
    is the row's host read (the learner's stats are summed on the device), with check_finite's of the
    weights beside it. Its state (state(), restore()) is part of the resume checkpoint, so that a resumed
    run writes the rows an uninterrupted one does.
    """

    def __init__(self, out: Path, trainer: Trainer, keep_until: int | None = None, state: dict | None = None,
                 drop_damaged: bool = False):
        """keep_until: on a resume, the checkpoint's step; rows logged after it are dropped (they are logged
        again), state: the checkpoint's log state (state()), drop_damaged: records.scalar_rows'. Everything
        is checked before scalars.csv is rewritten; self.note tells what was dropped besides later rows."""
        self.columns = ["env_steps", "steps_per_s", "episodes_per_s", "epsilon", "mean_return", "collision_free",
                        "episodes", *UpdateLog.FIELDS, *_usage_tags(usage_shares(trainer.usage.cpu(), trainer)),
                        "mean_length", "lr", "updates"]
        self.path = out / "scalars.csv"
        # (return, collision, length) of the last RECENT_EPISODES episodes (length None: restored from a
        # checkpoint written before lengths were kept)
        self.recent: list[tuple[float, bool, int | None]] = []
        self.ended, self.step, self.time = 0, trainer.env_steps, time.perf_counter()
        self.usage = trainer.usage.cpu().clone()  # a copy: on the CPU .cpu() is the counter itself
        kept, self.note = self._kept_rows(keep_until, drop_damaged)
        if state is not None:
            self.restore(state, trainer, f"{out / 'resume' / 'meta.json'}: log")
            last = int(kept[-1].split(",", 1)[0]) if kept else 0
            if last != self.step and not drop_damaged:
                raise ValueError(f"{self.path}: its last row up to the checkpoint is at env step {last:,}, the "
                                 f"checkpoint's at {self.step:,} (the file was cut or edited); nothing was changed "
                                 "(--drop-damaged continues with the rows it holds)")
        write_atomic(self.path, (",".join(self.columns) + "\n" + "".join(kept)).encode())
        self.tb, self.tb_seeds = tensorboard_writers(out / "tb", trainer.config.seeds, keep_until)

    def _kept_rows(self, keep_until: int | None, drop_damaged: bool) -> tuple[list[str], str | None]:
        """On a resume, the rows up to keep_until (checked: records.scalar_rows), each value under its column's
        name (a run started by an older version has fewer columns: theirs stay empty); a fresh run: none."""
        if keep_until is None:
            return [], None
        if not self.path.exists():
            raise ValueError(f"{self.path} is missing; the run cannot be continued exactly")
        header, rows, note = scalar_rows(self.path, keep_until, drop_damaged)
        kept = []
        for cells in rows:
            row = dict(zip(header, cells))
            kept.append(",".join(row.get(c, "") for c in self.columns) + "\n")
        return kept, note

    def state(self) -> dict:
        """What the next rows depend on besides the trainer (the resume checkpoint's meta "log"): the step of
        the last row (the cadence), the running window and the usage counts at the last row. JSON floats
        round-trip exactly, so a resumed run's rows equal an uninterrupted run's."""
        return {"step": self.step, "ended": self.ended, "recent": [list(e) for e in self.recent],
                "usage": [int(u) for u in self.usage]}

    def restore(self, state: dict, trainer: Trainer, where: str) -> None:
        """Continue from state() saved at trainer's checkpoint; one line naming the field if it is damaged
        (where: the file and the key it is under)."""
        check_fields(state, {"step": "count", "ended": "count"}, where)
        recent, usage = state.get("recent"), state.get("usage")
        if state["step"] > trainer.env_steps:
            raise ValueError(f"{where}: step {state['step']:,} is past the checkpoint's step {trainer.env_steps:,}")
        if not (isinstance(recent, list) and len(recent) <= RECENT_EPISODES and all(_window_entry(e) for e in recent)):
            raise ValueError(f"{where}: recent must be a list of up to {RECENT_EPISODES} [return, collision, length] "
                             "entries")
        if not (isinstance(usage, list) and len(usage) == len(self.usage) and all(is_int(u) and u >= 0 for u in usage)):
            raise ValueError(f"{where}: usage must be a list of {len(self.usage)} non-negative counts")
        self.step, self.ended = state["step"], state["ended"]
        self.recent = [(float(e[0]), e[1], e[2] if len(e) == 3 else None) for e in recent]
        self.usage = torch.tensor(usage, dtype=self.usage.dtype)

    def due(self, trainer: Trainer) -> bool:
        """Whether a row is due: LOG_EVERY env steps since the last one."""
        return trainer.env_steps - self.step >= LOG_EVERY

    def episodes(self, finished_eps: list[Episode]) -> None:
        self.recent = (self.recent + [(e.ret, e.collision, e.length) for e in finished_eps])[-RECENT_EPISODES:]
        self.ended += len(finished_eps)
        for e in finished_eps:
            if e.seed in self.tb_seeds:
                tb = self.tb_seeds[e.seed]
                tb.add_scalar("episode/return", e.ret, e.step)
                tb.add_scalar("episode/collision", float(e.collision), e.step)
                tb.add_scalar("episode/avg_speed", e.avg_speed, e.step)
                tb.add_scalar("episode/length", e.length, e.step)

    def log(self, trainer: Trainer) -> dict:
        """Write one row at trainer.env_steps; returns its values (only those that exist)."""
        now, step, usage = time.perf_counter(), trainer.env_steps, trainer.usage.cpu().clone()
        wall = max(now - self.time, 1e-9)
        values = {"steps_per_s": (step - self.step) * len(trainer.config.seeds) / wall,
                  "episodes_per_s": self.ended / wall, "epsilon": trainer.config.dqn.epsilon(step)}
        if self.recent:
            values["mean_return"] = sum(e[0] for e in self.recent) / len(self.recent)
            values["collision_free"] = sum(not e[1] for e in self.recent) / len(self.recent)
        lengths = [e[2] for e in self.recent if e[2] is not None]
        if lengths:
            values["mean_length"] = sum(lengths) / len(lengths)
        values["episodes"] = len(self.recent)
        values.update(trainer.update_log.read())
        if int((usage - self.usage).sum()) > 0:
            values.update(_usage_tags(usage_shares(usage - self.usage, trainer)))
        values["lr"] = trainer.config.dqn.lr
        values["updates"] = int(trainer.learner.adam_step.double().sum())  # float32 counts, exact per member
        self.ended, self.step, self.time, self.usage = 0, step, now, usage
        with naming(self.path), open(self.path, "a") as f:  # a full disk names the file
            f.write(",".join([str(step)] + [_cell(k, values[k]) if k in values else "" for k in self.columns[1:]]) + "\n")
        if self.tb is not None:
            for k, v in values.items():
                self.tb.add_scalar(k, v, step)
        return values

    def flush(self) -> None:
        """TensorBoard's queued events to disk (before a checkpoint: a kill after it loses none of them)."""
        for tb in self.writers():
            tb.flush()

    def close(self) -> None:
        for tb in self.writers():
            tb.close()  # flushes the events

    def writers(self) -> list:
        return ([] if self.tb is None else [self.tb]) + list(self.tb_seeds.values())


def _cell(column: str, value) -> str:
    """A scalars.csv cell: floats to 5 decimals, the learning rate (often below 1e-5) to 6 significant digits."""
    if column == "lr":
        return f"{value:.6g}"
    return str(round(value, 5)) if isinstance(value, float) else str(value)


def _window_entry(entry) -> bool:
    """A checkpoint's running-window entry: [return, collision, length], or [return, collision] from a
    checkpoint written before lengths were kept."""
    return (isinstance(entry, list) and len(entry) in (2, 3) and is_finite_number(entry[0])
            and isinstance(entry[1], bool) and (len(entry) == 2 or (is_int(entry[2]) and entry[2] >= 0)))


def tensorboard_writers(folder: Path, seeds, keep_until: int | None) -> tuple:
    """(the writer of folder/all-seeds, {seed: the writer of folder/seed-N}); (None, {}) and a one-line
    notice on stderr when TensorBoard cannot be loaded (it is optional: scalars.csv holds the rows).
    keep_until: a resume's checkpoint step; the events after it are dropped (those at it were logged
    before it was saved)."""
    try:
        from torch.utils.tensorboard import SummaryWriter
    except Exception as err:  # noqa: BLE001 - not installed (ImportError) or a broken install: the CSV is enough
        reason = str(err).splitlines()[0] if str(err) else type(err).__name__
        print(f"note: {folder} is not written: TensorBoard cannot be loaded ({reason}); "
              "pip install tensorboard for it", file=sys.stderr)
        return None, {}
    purge = None if keep_until is None else keep_until + 1

    def writer(name: str):  # its OSErrors (a full disk) name its folder
        return Named(SummaryWriter(str(folder / name), purge_step=purge), folder / name)

    return writer("all-seeds"), {seed: writer(f"seed-{seed}") for seed in seeds}


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
                    "replay_ratio": cfg.replay_ratio, "updates_per_step": cfg.updates_per_step, "env_steps_per_seed": trainer.env_steps, "seeds": list(cfg.seeds),
                    "wall_s": round(wall, 2), "env_steps_per_s": round(trainer.env_steps * len(cfg.seeds) / max(wall, 1e-9), 1),
                    "device": str(trainer.device), "member_usage": _usage(trainer), **code})
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


def _usage_tags(shares: dict[str, float]) -> dict[str, float]:
    """usage/NAME for each member's share; an expert's "E1,1" becomes "E1_1" (a CSV column, a TensorBoard tag)."""
    return {f"usage/{name.replace(',', '_')}": v for name, v in shares.items()}


def _postfix(values: dict) -> dict[str, str]:
    """The progress bar's few numbers, of those that exist yet."""
    shown = {"mean_return": ("ret", "{:.1f}"), "collision_free": ("free", "{:.2f}"), "epsilon": ("eps", "{:.2f}"),
             "loss": ("loss", "{:.3g}")}
    return {name: fmt.format(values[k]) for k, (name, fmt) in shown.items() if k in values}


def _usage(trainer: Trainer) -> dict:
    """Share of decisions made by each member over the run (metrics.json's member_usage)."""
    return usage_shares(trainer.usage.cpu(), trainer)


def usage_shares(counts: torch.Tensor, trainer: Trainer) -> dict[str, float]:
    """Share of the decisions counted in counts (M + 1,) (slot 0: the fallback) made by each member, summed
    over the seeds and named by expert for MoE: {"fallback": ..., NAME: ...} (rounded to 6 digits)."""
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
