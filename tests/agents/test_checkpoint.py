"""Checkpoint folders: round trips, and one-line errors for every way a folder can be wrong."""

from __future__ import annotations

import json

import pytest
import torch

from highway_srl.agents import CheckpointError, DQNConfig, DQNLearner, load_checkpoint, save_checkpoint
from highway_srl.agents.gating import expert_action_mask

META = {"method": "moe-rm-srl", "scenario": "two-lane", "step": 1200}


def _save(tmp_path):
    folder = tmp_path / "run"
    tensors = {"a": torch.arange(6.0).reshape(2, 3), "mask": torch.tensor([True, False]), "n": torch.tensor([3, 4])}
    save_checkpoint(folder, tensors, META)
    return folder, tensors


def test_round_trip_keeps_tensors_and_meta_and_leaves_no_temporary_files(tmp_path):
    folder, tensors = _save(tmp_path)
    loaded, meta = load_checkpoint(folder, expect={"method": "moe-rm-srl", "scenario": "two-lane"})
    assert meta == META
    assert loaded.keys() == tensors.keys()
    for key, value in tensors.items():
        assert torch.equal(loaded[key], value) and loaded[key].dtype == value.dtype
    assert sorted(p.name for p in folder.iterdir()) == ["meta.json", "model.safetensors"]
    save_checkpoint(folder, {"a": torch.zeros(1)}, {**META, "step": 2400})  # overwrite in place
    assert load_checkpoint(folder)[1]["step"] == 2400


def test_learner_saved_and_loaded_gives_identical_q_values(tmp_path):
    cfg = DQNConfig(hidden=16)
    learner = DQNLearner(11, expert_action_mask(), cfg, obs_dim=5, generator=torch.Generator().manual_seed(0))
    save_checkpoint(tmp_path / "ckpt", learner.state_dict(), {"method": "moe-rm-srl"})
    other = DQNLearner(11, expert_action_mask(), cfg, obs_dim=5)
    other.load_state_dict(load_checkpoint(tmp_path / "ckpt", {"method": "moe-rm-srl"})[0])
    obs = torch.randn(8, 5)
    assert torch.equal(learner.q_values(obs), other.q_values(obs))


def _one_line(err: pytest.ExceptionInfo) -> str:
    message = str(err.value)
    assert "\n" not in message
    return message


def test_missing_folder_or_file(tmp_path):
    with pytest.raises(CheckpointError) as err:
        load_checkpoint(tmp_path / "nope")
    assert "does not exist" in _one_line(err) and "nope" in str(err.value)
    folder, _ = _save(tmp_path)
    (folder / "model.safetensors").unlink()
    with pytest.raises(CheckpointError) as err:
        load_checkpoint(folder)
    assert "model.safetensors" in _one_line(err)


@pytest.mark.parametrize("damage", ["truncate", "garbage", "empty"])
def test_truncated_or_corrupt_model_file(tmp_path, damage):
    folder, _ = _save(tmp_path)
    path = folder / "model.safetensors"
    data = path.read_bytes()
    path.write_bytes({"truncate": data[: len(data) - 5], "garbage": b"\xff" * len(data), "empty": b""}[damage])
    with pytest.raises(CheckpointError) as err:
        load_checkpoint(folder)
    assert "model.safetensors" in _one_line(err) and "truncated or corrupt" in str(err.value)
    assert isinstance(err.value, ValueError)


def test_meta_that_is_not_json(tmp_path):
    folder, _ = _save(tmp_path)
    (folder / "meta.json").write_text('{"method": "moe-rm-srl",')
    with pytest.raises(CheckpointError) as err:
        load_checkpoint(folder)
    assert "meta.json is not valid JSON" in _one_line(err)


def test_mismatched_or_missing_meta_key_names_both_values(tmp_path):
    folder, _ = _save(tmp_path)
    (folder / "meta.json").write_text(json.dumps({**META, "method": "rl"}))
    with pytest.raises(CheckpointError) as err:
        load_checkpoint(folder, expect={"method": "moe-rm-srl"})
    assert _one_line(err) == f"checkpoint {folder} was trained with method 'rl', not 'moe-rm-srl'"
    with pytest.raises(CheckpointError) as err:
        load_checkpoint(folder, expect={"seed": 3})
    assert "no 'seed'" in _one_line(err)


def test_meta_must_be_serialisable_before_anything_is_written(tmp_path):
    with pytest.raises(TypeError):
        save_checkpoint(tmp_path / "bad", {"a": torch.zeros(1)}, {"when": object()})
    assert not any((tmp_path / "bad").iterdir())
