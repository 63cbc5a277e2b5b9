"""metrics.json splits the training collisions by the ego-avoidable verdict (rules.avoidable), judged by the
decision trace where each collision's episode ends (the compact step: no extra host read elsewhere)."""

from __future__ import annotations

import json

from highway_srl.agents.dqn import DQNConfig
from highway_srl.agents.trainer import VERDICT_KEY, TrainConfig, Trainer
from highway_srl.experiments.collisions import DecisionTrace
from highway_srl.experiments.train import train_run


def _config(steps: int = 600) -> TrainConfig:
    # the paper profile at level F: the lane-change cycle and creeping make collisions within a few episodes
    return TrainConfig(method="mp-rl", scenario="two-lane", traffic="F", steps=steps, envs=4, seeds=(0, 1),
                       dqn=DQNConfig(learning_starts=64, batch_size=16, buffer_capacity=1024, total_steps=steps))


def test_metrics_split_every_training_collision_into_ego_avoidable_and_unavoidable(tmp_path):
    metrics = train_run(_config(), tmp_path / "run", progress=False)
    rows = [json.loads(line) for line in (tmp_path / "run" / "episodes.jsonl").read_text().splitlines()]
    split = metrics["collision_verdicts"]
    assert json.loads((tmp_path / "run" / "metrics.json").read_text())["collision_verdicts"] == split
    for seed in ("0", "1"):
        part = split["per_seed"][seed]
        assert part["collisions"] == metrics["per_seed"][seed]["collisions"]
        assert part["ego_avoidable"] + part["unavoidable"] == part["collisions"] and part["not_judged"] == 0
    assert split["all"]["collisions"] == sum(r["collision"] for r in rows) >= 1


def test_the_trainer_hands_each_collision_its_verdict_and_checkpoints_the_counts():
    trainer = Trainer(_config(600))
    trace = trainer.collision_trace = DecisionTrace(trainer.method)
    starts, judged = {}, []  # each env's first decision of its running episode; the records handed over
    restart, judge = trace.episodes_restart, trace.judge_ended

    def episodes_restart(world, done):
        starts.update(dict.fromkeys(done.nonzero().flatten().tolist(), trace.step))
        restart(world, done)

    def judge_ended(world, collision):
        records = judge(world, collision)
        judged.extend((rec, starts.get(rec["env"], 0)) for rec in records)
        return records

    trace.episodes_restart, trace.judge_ended = episodes_restart, judge_ended
    episodes = []
    while trainer.env_steps < 600:
        episodes += trainer.step()
    episodes += trainer.drain()
    # a collision is judged on the decisions of its own episode only, oldest first, up to the collision
    assert judged and all(rec["decisions"] and rec["decisions"][0]["step"] >= start and
                          rec["decisions"][-1]["step"] == rec["step"] for rec, start in judged)
    assert any(start > 0 for _, start in judged), [(rec["step"], start) for rec, start in judged]  # after a restart
    collided = [e for e in episodes if e.collision]
    assert collided and all(isinstance(e.ego_avoidable, bool) for e in collided)
    assert all(e.ego_avoidable is None for e in episodes if not e.collision)
    assert not trainer.verdicts  # every verdict went to its episode
    state = trainer.state_dict()
    assert int(state[VERDICT_KEY].sum()) == len(collided) and int(state[VERDICT_KEY][:, 2].sum()) == 0
    fresh = Trainer(_config(600))
    fresh.load_state_dict(state)
    assert fresh.verdict_counts.tolist() == trainer.verdict_counts.tolist()
