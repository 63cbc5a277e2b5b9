"""Training logs: scalars.csv and TensorBoard carry loss, mean Q, TD error, ε, expert usage, episodes/s,
episode length, learning rate, gradient updates and per-episode points (one TensorBoard run per seed), and
no value is logged before it exists."""

import csv
import json
import sys

import pytest

from highway_srl.agents.dqn import DQNConfig
from highway_srl.agents.train_config import TrainConfig
from highway_srl.agents.trainer import Trainer
from highway_srl.experiments import train as train_mod, training_log

LEARNING_STARTS = 400
NEW_TAGS = {"loss", "q_mean", "td_error", "epsilon", "episodes_per_s", "steps_per_s", "usage/fallback", "usage/E1_1"}
EPISODE_TAGS = {"episode/return", "episode/collision", "episode/avg_speed", "episode/length"}
SEEDS = (0, 1)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("logs") / "run"
    mp = pytest.MonkeyPatch()
    mp.setattr(training_log, "LOG_EVERY", 200)
    try:
        cfg = TrainConfig(steps=1000, envs=2, seeds=SEEDS,
                          dqn=DQNConfig(learning_starts=LEARNING_STARTS, total_steps=1000))
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
    assert list(rows[0])[-3:] == ["mean_length", "lr", "updates"]  # appended: older columns keep their places
    first_end = min(e["step"] for e in episodes)
    assert [int(r["env_steps"]) for r in rows] == [200, 400, 600, 800, 1000]
    for r in rows:
        step = int(r["env_steps"])
        assert (r["mean_return"] != "") == (step >= first_end)  # never 0.0 before the first episode
        assert (r["collision_free"] != "") == (step >= first_end)
        assert (r["mean_length"] != "") == (step >= first_end)
        assert float(r["lr"]) == DQNConfig().lr
        if step < LEARNING_STARTS:
            assert r["loss"] == r["q_mean"] == r["td_error"] == ""
            assert r["updates"] == "0"
        assert r["epsilon"] != "" and r["usage/E1_1"] != ""
    assert all(rows[-1][k] != "" for k in ("loss", "q_mean", "td_error"))
    updates = [int(r["updates"]) for r in rows]
    assert updates == sorted(updates) and updates[-1] > 0
    window = episodes[-int(rows[-1]["episodes"]):]
    assert float(rows[-1]["mean_length"]) == pytest.approx(sum(e["length"] for e in window) / len(window), abs=1e-4)
    shares = [float(v) for k, v in rows[-1].items() if k.startswith("usage/")]
    assert sum(shares) == pytest.approx(1.0, abs=1e-4)


def _events(folder):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(folder), size_guidance={"scalars": 0})
    acc.Reload()
    return acc


def test_tensorboard_has_the_new_tags_and_no_point_before_its_value_exists(run):
    pytest.importorskip("tensorboard")
    out, episodes = run
    assert sorted(p.name for p in (out / "tb").iterdir()) == ["all-seeds", "seed-0", "seed-1"]
    acc = _events(out / "tb" / "all-seeds")
    tags = set(acc.Tags()["scalars"])
    assert NEW_TAGS | {"mean_return", "collision_free", "mean_length", "lr", "updates"} <= tags
    first = {tag: min(e.step for e in acc.Scalars(tag)) for tag in tags}
    assert first["mean_return"] >= min(e["step"] for e in episodes)
    assert min(first[t] for t in ("loss", "q_mean", "td_error")) >= LEARNING_STARTS


def test_each_seed_has_its_own_tensorboard_run_of_its_episodes(run):
    """Two seeds' episodes end at the same env steps; each seed's run holds its own, one point per step."""
    pytest.importorskip("tensorboard")
    out, episodes = run
    for seed in SEEDS:
        acc = _events(out / "tb" / f"seed-{seed}")
        assert set(acc.Tags()["scalars"]) == EPISODE_TAGS
        mine = [e for e in episodes if e["seed"] == seed]
        for tag, key in (("episode/return", "return"), ("episode/length", "length")):
            assert sorted((p.step, round(p.value, 3)) for p in acc.Scalars(tag)) == \
                sorted((e["step"], round(e[key], 3)) for e in mine)


def test_a_run_without_tensorboard_says_so_once_and_writes_no_tb(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "torch.utils.tensorboard", None)  # its import fails as if not installed
    monkeypatch.setattr(training_log, "LOG_EVERY", 100)
    cfg = TrainConfig(steps=300, envs=2, dqn=DQNConfig(learning_starts=100, total_steps=300))
    train_mod.train_run(cfg, tmp_path / "run", progress=False)
    notices = [line for line in capsys.readouterr().err.splitlines() if "TensorBoard" in line]
    assert len(notices) == 1 and notices[0].startswith("note: ") and "pip install tensorboard" in notices[0]
    assert not (tmp_path / "run" / "tb").exists()
    assert len((tmp_path / "run" / "scalars.csv").read_text().splitlines()) == 4  # the header and 3 rows


def test_a_checkpoint_window_without_episode_lengths_still_restores(tmp_path):
    """A resume checkpoint written before lengths were kept holds [return, collision] pairs: they load, and
    mean_length is over the entries that have a length; a bad length is one clear error."""
    trainer = Trainer(TrainConfig(steps=300, envs=2))
    log = training_log.TrainingLog(tmp_path, trainer)
    state = {"step": 0, "ended": 2, "recent": [[1.5, False], [2.5, True, 40]], "usage": [0] * len(log.usage)}
    log.restore(state, trainer, "meta.json: log")
    assert log.recent == [(1.5, False, None), (2.5, True, 40)]
    values = log.log(trainer)
    assert values["mean_length"] == 40 and values["mean_return"] == 2.0
    with pytest.raises(ValueError, match=r"meta.json: log: recent must be a list of up to \d+ \[return, collision, length\]"):
        log.restore({**state, "recent": [[1.5, False, -1]]}, trainer, "meta.json: log")
    log.close()
