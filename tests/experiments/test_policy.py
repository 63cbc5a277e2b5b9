"""load_policy: a trained run's policy comes back as it was saved, from model/ and under one key scheme."""

import json

import pytest
import torch

from highway_srl.agents.checkpoint import policy_tensors, save_checkpoint, split_policy_tensors
from highway_srl.agents.dqn import DQNConfig
from highway_srl.agents.train_config import TrainConfig
from highway_srl.agents.trainer import Trainer
from highway_srl.experiments.policy import load_policy, read_model
from highway_srl.experiments.train import train_run


def _lm_config(steps=64):
    return TrainConfig(method="lm-rl", traffic="A", steps=steps, envs=4, options={"lambda_init": 0.7},
                       dqn=DQNConfig(learning_starts=32, batch_size=16, total_steps=steps, buffer_capacity=64))


def test_policy_tensors_split_back_into_the_learner_and_method_state():
    trainer = Trainer(_lm_config())
    for _ in range(10):
        trainer.step()
    learner, method = split_policy_tensors(policy_tensors(trainer.learner, trainer.method))
    assert learner.keys() == trainer.learner.state_dict().keys()
    assert all(torch.equal(v, trainer.learner.state_dict()[k]) for k, v in learner.items())
    assert torch.equal(method["lambda"], trainer.method.state_dict()["lambda"])


def test_resume_checkpoint_holds_the_same_policy_keys_as_the_final_model():
    trainer = Trainer(_lm_config())
    full = trainer.state_dict()
    learner, method = split_policy_tensors(full)
    assert set(learner) == set(trainer.learner.state_dict())
    assert torch.equal(method["lambda"], trainer.method.lam)


def test_trained_run_loads_with_its_weights_and_method_state(tmp_path):
    train_run(_lm_config(), tmp_path / "lm", progress=False)
    policy = load_policy(tmp_path / "lm")
    _, tensors, meta = read_model(tmp_path / "lm")
    assert policy.config.method == "lm-rl" and meta["method"] == "lm-rl"
    assert torch.equal(policy.learner.online.flat, tensors["learner.online.flat"])
    assert torch.allclose(policy.method.lam, torch.tensor([0.7]))
    with pytest.raises(ValueError, match="trained on scenario 'two-lane', not 'merge'"):
        load_policy(tmp_path / "lm", scenario="merge")


def test_a_run_folder_written_with_the_literal_key_names_still_loads(tmp_path):
    """Runs saved before load_policy existed: model.safetensors keys 'learner.<name>' and 'method.<name>'."""
    cfg = _lm_config()
    trainer = Trainer(cfg)
    tensors = {f"learner.{k}": v for k, v in trainer.learner.state_dict().items()}
    tensors["method.lambda"] = torch.tensor([0.25])
    run = tmp_path / "old"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"config": cfg.to_dict()}))
    save_checkpoint(run / "model", tensors, {"method": cfg.method, "scenario": cfg.scenario})
    policy = load_policy(run)
    assert torch.equal(policy.learner.online.flat, trainer.learner.online.flat)
    assert torch.allclose(policy.method.lam, torch.tensor([0.25]))
