"""Checkpoints: an interrupted run resumed from its last checkpoint ends exactly where an uninterrupted one does."""

import csv
import dataclasses
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from highway_srl.agents.trainer import Trainer
from highway_srl.experiments import train as train_mod, training_log
from highway_srl.experiments.policy import load_policy
from highway_srl.experiments.train import train_run


def _run(trainer, steps):
    while trainer.env_steps < steps:
        trainer.step()


def test_state_dict_round_trip_continues_bit_for_bit(trainer_config):
    cfg = trainer_config(steps=800)
    a = Trainer(cfg)
    _run(a, 800)
    b = Trainer(cfg)
    _run(b, 400)
    state = {k: v.clone() for k, v in b.state_dict().items()}
    c = Trainer(cfg)
    c.load_state_dict(state)
    _run(c, 800)
    assert torch.equal(a.learner.online.flat, c.learner.online.flat)
    assert torch.equal(a.world.state.x, c.world.state.x)


def test_killed_run_resumes_from_checkpoint_with_same_final_model(tmp_path, monkeypatch, trainer_config):
    cfg = trainer_config(steps=800)
    train_run(cfg, tmp_path / "straight", checkpoint_every=400, progress=False)

    real_step, calls = Trainer.step, {"n": 0}

    def dying_step(self):
        calls["n"] += 1
        if self.env_steps >= 560:  # after the checkpoint at 400 steps, before the end
            raise KeyboardInterrupt
        return real_step(self)

    monkeypatch.setattr(Trainer, "step", dying_step)
    with pytest.raises(KeyboardInterrupt):
        train_run(cfg, tmp_path / "killed", checkpoint_every=400, progress=False)
    assert (tmp_path / "killed" / "resume" / "model.safetensors").exists()
    monkeypatch.setattr(Trainer, "step", real_step)
    train_run(None, tmp_path / "killed", resume=True, checkpoint_every=400, progress=False)

    straight, resumed = load_policy(tmp_path / "straight").learner, load_policy(tmp_path / "killed").learner
    assert torch.equal(straight.online.flat, resumed.online.flat)
    log = lambda p: [json.loads(line) for line in (p / "episodes.jsonl").read_text().splitlines()]  # noqa: E731
    assert log(tmp_path / "straight") == log(tmp_path / "killed")
    assert not (tmp_path / "killed" / "resume").exists()


def test_saved_model_gives_the_same_greedy_actions(tmp_path, trainer_config):
    cfg = trainer_config(steps=400)
    train_run(cfg, tmp_path / "run", progress=False)
    trainer = Trainer(cfg)
    _run(trainer, 400)
    policy = load_policy(tmp_path / "run")
    obs = trainer.current.primary.obs
    assert torch.equal(trainer.learner.greedy(obs), policy.learner.greedy(obs))
    meta = policy.meta
    assert meta["method"] == "moe-rm-srl" and meta["scenario"] == "two-lane" and "commit" in meta
    assert train_mod.read_json(tmp_path / "run" / "metrics.json")["env_steps_per_seed"] == 400


# the child that trains and is killed (SIGKILL: no finally, no flush) some steps after its first checkpoint
KILLED_CHILD = """
import json, os, signal, sys
import torch
from highway_srl.agents.train_config import TrainConfig
from highway_srl.agents.trainer import Trainer
from highway_srl.experiments import train as train_mod, training_log
torch.set_num_threads(1)
cfg, out, kill_at = TrainConfig.from_dict(json.loads(sys.argv[1])), sys.argv[2], int(sys.argv[3])
training_log.LOG_EVERY, training_log.RECENT_EPISODES = int(sys.argv[4]), int(sys.argv[5])
real_step = Trainer.step
def dying_step(self):
    if self.env_steps >= kill_at:
        os.kill(os.getpid(), signal.SIGKILL)
    return real_step(self)
Trainer.step = dying_step
train_mod.train_run(cfg, out, checkpoint_every=int(sys.argv[6]), progress=False)
"""
TIMED = {"steps_per_s", "episodes_per_s"}  # wall-clock rates: the only values two runs cannot share
TIMED_KEYS = {"wall_s", "env_steps_per_s"}


def _without_time(value):
    """A JSON value with its wall-clock fields removed (metrics.json, model/meta.json)."""
    if isinstance(value, dict):
        return {k: _without_time(v) for k, v in value.items() if k not in TIMED_KEYS}
    return value


def _scalars(path: Path) -> list[dict]:
    return [{k: v for k, v in row.items() if k not in TIMED} for row in csv.DictReader(path.open())]


def _tb_scalars(folder: Path) -> dict:
    """Every TensorBoard scalar tag's (step, value) points as a reader sees them (purged events dropped)."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(folder), size_guidance={"scalars": 0})
    acc.Reload()
    return {tag: [(e.step, e.value) for e in acc.Scalars(tag)] for tag in acc.Tags()["scalars"]
            if tag not in TIMED}


def _same_run_folder(a: Path, b: Path) -> None:
    """Every file of two run folders the same: bytes, or (metrics.json, model/meta.json, scalars.csv) every
    value but the wall-clock ones; tb/ the same scalars (its event files are named by time and host)."""
    files = lambda f: sorted(str(p.relative_to(f)) for p in f.rglob("*")  # noqa: E731
                             if p.is_file() and p.relative_to(f).parts[0] != "tb")
    assert files(a) == files(b)
    for name in files(a):
        if name == ".lock":  # the holder's pid
            continue
        if name.endswith(".json"):
            assert _without_time(json.loads((a / name).read_text())) == _without_time(json.loads((b / name).read_text())), name
        elif name == "scalars.csv":
            assert _scalars(a / name) == _scalars(b / name)
        else:
            assert (a / name).read_bytes() == (b / name).read_bytes(), name
    if (a / "tb").exists() or (b / "tb").exists():
        runs = sorted(p.name for p in (a / "tb").iterdir())  # tb/all-seeds and one run per seed
        assert runs == sorted(p.name for p in (b / "tb").iterdir()) and "all-seeds" in runs
        for run in runs:
            assert _tb_scalars(a / "tb" / run) == _tb_scalars(b / "tb" / run), run


def test_run_killed_after_a_checkpoint_resumes_to_the_same_files(tmp_path, monkeypatch, trainer_config):
    """SIGKILL 400 env steps after the checkpoint at 700 (2 envs: two episodes end at 640, two at 1280; rows
    every 152 steps, which the checkpoint does not fall on; a 3-episode window, which at the end spans the
    resume): the resumed folder equals the uninterrupted one, scalars.csv rows, running windows and
    TensorBoard scalars included."""
    cfg = dataclasses.replace(trainer_config(steps=1400), envs=2)
    log_every, window, every, kill_at = 151, 3, 700, 1100
    monkeypatch.setattr(training_log, "LOG_EVERY", log_every)
    monkeypatch.setattr(training_log, "RECENT_EPISODES", window)
    train_run(cfg, tmp_path / "straight", checkpoint_every=every, progress=False)
    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": str(root), "OMP_NUM_THREADS": "1"}
    args = [json.dumps(cfg.to_dict()), str(tmp_path / "killed"), kill_at, log_every, window, every]
    child = subprocess.run([sys.executable, "-c", KILLED_CHILD, *map(str, args)], env=env, capture_output=True)
    assert child.returncode == -signal.SIGKILL, child.stderr.decode()[-2000:]
    assert train_mod.last_checkpoint_step(tmp_path / "killed") == 700
    train_run(None, tmp_path / "killed", resume=True, progress=False)
    _same_run_folder(tmp_path / "straight", tmp_path / "killed")
    rows = _scalars(tmp_path / "killed" / "scalars.csv")
    assert [int(r["env_steps"]) for r in rows] == [152 * i for i in range(1, 10)] + [1400]
    assert rows[-1]["episodes"] == str(window)
