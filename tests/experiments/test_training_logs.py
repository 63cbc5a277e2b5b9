"""Training logs (issue 14): scalars.csv and TensorBoard carry loss, mean Q, TD error, ε, expert usage,
episodes/s and per-episode points, and no value is logged before it exists."""

import csv
import json

import pytest

from highway_srl.agents.dqn import DQNConfig
from highway_srl.agents.trainer import TrainConfig
from highway_srl.experiments import train as train_mod

LEARNING_STARTS = 400
NEW_TAGS = {"loss", "q_mean", "td_error", "epsilon", "episodes_per_s", "steps_per_s", "usage/fallback", "usage/E1_1"}
EPISODE_TAGS = {"episode/return", "episode/collision", "episode/avg_speed"}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("logs") / "run"
    mp = pytest.MonkeyPatch()
    mp.setattr(train_mod, "LOG_EVERY", 200)
    try:
        cfg = TrainConfig(steps=1000, envs=2, dqn=DQNConfig(learning_starts=LEARNING_STARTS, total_steps=1000))
        train_mod.train_run(cfg, out, progress=False)
    finally:
        mp.undo()
    episodes = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    assert episodes, "the run must finish some episodes for these tests"
    return out, episodes


def test_scalars_csv_has_the_new_columns_and_leaves_a_value_empty_until_it_exists(run):
    out, episodes = run
    rows = list(csv.DictReader((out / "scalars.csv").open()))
    assert NEW_TAGS <= set(rows[0]) and {"mean_return", "collision_free"} <= set(rows[0])
    first_end = min(e["step"] for e in episodes)
    assert [int(r["env_steps"]) for r in rows] == [200, 400, 600, 800, 1000]
    for r in rows:
        step = int(r["env_steps"])
        assert (r["mean_return"] != "") == (step >= first_end)  # never 0.0 before the first episode
        assert (r["collision_free"] != "") == (step >= first_end)
        if step < LEARNING_STARTS:
            assert r["loss"] == r["q_mean"] == r["td_error"] == ""
        assert r["epsilon"] != "" and r["usage/E1_1"] != ""
    assert all(rows[-1][k] != "" for k in ("loss", "q_mean", "td_error"))
    shares = [float(v) for k, v in rows[-1].items() if k.startswith("usage/")]
    assert sum(shares) == pytest.approx(1.0, abs=1e-4)


def test_tensorboard_has_the_new_tags_and_no_point_before_its_value_exists(run):
    pytest.importorskip("tensorboard")
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out, episodes = run
    acc = EventAccumulator(str(out / "tb"), size_guidance={"scalars": 0})
    acc.Reload()
    tags = set(acc.Tags()["scalars"])
    assert NEW_TAGS | EPISODE_TAGS | {"mean_return", "collision_free"} <= tags
    first = {tag: min(e.step for e in acc.Scalars(tag)) for tag in tags}
    assert first["mean_return"] >= min(e["step"] for e in episodes)
    assert min(first[t] for t in ("loss", "q_mean", "td_error")) >= LEARNING_STARTS
    points = acc.Scalars("episode/return")
    assert sorted((p.step, round(p.value, 3)) for p in points) == \
        sorted((e["step"], round(e["return"], 3)) for e in episodes)
