"""Checkpoints: an interrupted run resumed from its last checkpoint ends exactly where an uninterrupted one does."""

import json

import pytest
import torch

from highway_srl.agents.trainer import Trainer
from highway_srl.experiments import train as train_mod
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
