"""A training run's scalars.csv and TensorBoard events (TrainingLog), and each member's share of the decisions."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import torch

from highway_srl.agents.checkpoint import naming, write_atomic
from highway_srl.agents.dqn import UpdateLog
from highway_srl.agents.trainer import Episode, Trainer
from highway_srl.experiments.records import check_fields, scalar_rows
from highway_srl.experiments.runs import Named, is_finite_number, is_int

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
                        "episodes", *UpdateLog.FIELDS, *usage_tags(usage_shares(trainer.usage.cpu(), trainer)),
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
            values.update(usage_tags(usage_shares(usage - self.usage, trainer)))
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


def usage_tags(shares: dict[str, float]) -> dict[str, float]:
    """usage/NAME for each member's share; an expert's "E1,1" becomes "E1_1" (a CSV column, a TensorBoard tag)."""
    return {f"usage/{name.replace(',', '_')}": v for name, v in shares.items()}



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
