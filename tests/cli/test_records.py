"""Run-folder records read back: finite numbers or a stop, one schema for every file, nothing lost. Each bad
case is one line on stderr with exit status 2 and every file that was there unchanged (hashes before/after)."""

import json
import shutil
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file, save_file
from cli_runs import hashes, interrupted_run, one_line_error, run

from highway_srl.agents.dqn import DQNConfig
from highway_srl.agents.trainer import TrainConfig, check_config
from highway_srl.experiments import train as train_mod


def _copy(run_dir: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "r"
    shutil.copytree(run_dir, copy)
    return copy


def _edit_config(folder: Path, edit) -> None:
    data = json.loads((folder / "config.json").read_text())
    edit(data["config"])
    (folder / "config.json").write_text(json.dumps(data))


# ---------------------------------------------------------------- finite numbers or a stop
@pytest.mark.parametrize("setting, value, needle", [
    ("lr", float("nan"), "dqn.lr"), ("lr", float("inf"), "dqn.lr"), ("gamma", -0.5, "dqn.gamma"),
    ("batch_size", 0, "dqn.batch_size"), ("hidden", -5, "dqn.hidden"), ("hidden", "256", "dqn.hidden"),
    ("adam_betas", (1.5, 0.9), "dqn.adam_betas"),
])
def test_a_dqn_setting_no_run_can_have_is_one_line_naming_it(setting, value, needle):
    with pytest.raises(ValueError, match=needle):
        check_config(TrainConfig(dqn=DQNConfig(**{setting: value})))


@pytest.mark.parametrize("edit, needle", [
    (lambda c: c["dqn"].__setitem__("lr", float("nan")), "dqn.lr"),
    (lambda c: c["dqn"].__setitem__("lr", float("inf")), "dqn.lr"),
    (lambda c: c.__setitem__("steps", float("inf")), "steps"),
    (lambda c: c.__setitem__("steps", "4000"), "steps"),
    (lambda c: c.__setitem__("dqn", None), "dqn"),
    (lambda c: c["dqn"].__setitem__("batch_size", 0), "dqn.batch_size"),
    (lambda c: c.__setitem__("seeds", None), "seeds"),
    (lambda c: c.__setitem__("seeds", [2**63]), "seeds"),
    (lambda c: c["dqn"].__setitem__("hidden", -5), "dqn.hidden"),
])
@pytest.mark.parametrize("command", ["evaluate", "resume"])
def test_a_config_json_no_run_can_have_is_one_line(capsys, finished_run, tmp_path, edit, needle, command):
    run_dir = _copy(finished_run, tmp_path)
    (run_dir / "metrics.json").unlink()  # so that --resume does not stop at "finished"
    _edit_config(run_dir, edit)
    before = hashes(run_dir)
    argv = {"evaluate": ["evaluate", run_dir, "--episodes", "1", "--out", tmp_path / "e.json"],
            "resume": ["train", "--resume", "--quiet", "--out", run_dir]}[command]
    code, _, err = run(capsys, *argv)
    one_line_error(code, err, needle)
    assert "config.json" in err and hashes(run_dir) == before


def test_training_stops_at_the_first_non_finite_weight_naming_step_and_expert(tmp_path, monkeypatch):
    """NaN put into expert E2,1's weights at env step 96: the row at 160 (LOG_EVERY 80) stops the run."""
    monkeypatch.setattr(train_mod, "LOG_EVERY", 80)
    real_step = train_mod.Trainer.step

    def poisoned(self):
        if self.env_steps == 96:
            self.learner.online.flat.data[1, 0] = float("nan")  # member 1 of MoE-RM-SRL: E2,1
        return real_step(self)

    monkeypatch.setattr(train_mod.Trainer, "step", poisoned)
    cfg = TrainConfig(traffic="A", steps=400, envs=8, dqn=DQNConfig(learning_starts=64))
    with pytest.raises(train_mod.TrainingDiverged, match=r"env step 160: the weights of expert E2,1 \(seed 0\)"
                                                          r" became NaN or infinite after step 80"):
        train_mod.train_run(cfg, tmp_path / "run", progress=False)
    assert not (tmp_path / "run" / "model").exists() and not (tmp_path / "run" / "metrics.json").exists()


def test_training_stops_at_a_non_finite_loss(tmp_path, monkeypatch):
    monkeypatch.setattr(train_mod, "LOG_EVERY", 80)
    real_log = train_mod.TrainingLog.log
    monkeypatch.setattr(train_mod.TrainingLog, "log", lambda self, t: {**real_log(self, t), "loss": float("inf")})
    cfg = TrainConfig(traffic="A", steps=400, envs=8, dqn=DQNConfig(learning_starts=64))
    with pytest.raises(train_mod.TrainingDiverged, match="env step 80: the loss, Q-value or TD error"):
        train_mod.train_run(cfg, tmp_path / "run", progress=False)


def test_evaluate_refuses_a_model_with_non_finite_weights(capsys, finished_run, tmp_path):
    run_dir = _copy(finished_run, tmp_path)
    path = run_dir / "model" / "model.safetensors"
    tensors = load_file(path)
    tensors["learner.online.flat"][0, 3] = float("nan")
    save_file(tensors, path)
    before = hashes(run_dir)
    code, _, err = run(capsys, "evaluate", run_dir, "--episodes", "1", "--out", tmp_path / "e.json")
    one_line_error(code, err, "learner.online.flat holds NaN or infinite values")
    assert hashes(run_dir) == before and not (tmp_path / "e.json").exists()


def test_resume_refuses_a_checkpoint_with_non_finite_weights(capsys, tmp_path, monkeypatch):
    out, code, _ = interrupted_run(tmp_path, monkeypatch, capsys)
    assert code == 130
    path = out / "resume" / "model.safetensors"
    tensors = load_file(path)
    tensors["learner.online.flat"][0, 0] = float("inf")
    save_file(tensors, path)
    before = hashes(out)
    code, _, err = run(capsys, "train", "--resume", "--quiet", "--out", out)
    one_line_error(code, err, "learner.online.flat holds NaN or infinite values")
    assert hashes(out) == before
    assert torch.isinf(load_file(path)["learner.online.flat"][0, 0])
