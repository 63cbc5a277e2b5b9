"""§4.2's T_r on one scale: every run logs the paper's RM return beside its own training return."""

import json

import pytest
import torch

from highway_srl.agents.dqn import DQNConfig
from highway_srl.agents.train_config import TrainConfig
from highway_srl.experiments.train import train_run
from highway_srl.rules import SafetyLayer
from highway_srl.rules.raw import RawSafetyLayer
from highway_srl.sim import World


def test_the_raw_view_is_scored_with_the_mapped_layers_rm_reward():
    world = World("two-lane", "C", num_envs=8, seed=5)
    raw = RawSafetyLayer(world.road, profile="paper").observe(world).primary
    mapped = SafetyLayer(world.road, profile="paper").observe(world).primary
    assert torch.equal(raw.scoring_r_rm(), mapped.r_rm) and torch.equal(mapped.scoring_r_rm(), mapped.r_rm)


@pytest.mark.parametrize("method, same", [("moe-rm-srl", True), ("rl", False)])
def test_metrics_report_the_own_return_and_the_rm_return(tmp_path, method, same):
    cfg = TrainConfig(method=method, traffic="A", steps=640, envs=2, replay_ratio=0.25,
                      dqn=DQNConfig(total_steps=640, learning_starts=64, batch_size=16, buffer_capacity=1024))
    metrics = train_run(cfg, tmp_path / method, progress=False)
    rows = [json.loads(line) for line in (tmp_path / method / "episodes.jsonl").read_text().splitlines()]
    assert rows and all("rm_return" in r for r in rows)
    assert (metrics["mean"]["T_r"] == pytest.approx(metrics["mean"]["T_r_rm"], abs=1e-3)) == same
