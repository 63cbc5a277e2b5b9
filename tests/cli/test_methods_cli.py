"""The baselines through the CLI: train/evaluate run folders, `play` headless, and one-line errors."""

import json
import sys

import pytest
import torch

from highway_srl.cli import main
from highway_srl.constants import DEFAULT_ADVERSARY, DEFAULT_PROFILE


# tiny networks: one thread for every test here (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("one_thread")


def test_unknown_method_is_a_one_line_cli_error(tmp_path, capsys):
    assert main(["train", "--method", "no-such-method", "--out", str(tmp_path / "run"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "unknown method 'no-such-method'" in err and "sr-rl" in err and "rule-based" in err
    assert main(["train", "--method", "sr-rl", "--no-moe", "--out", str(tmp_path / "run"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "no_moe" in err


def test_rule_based_trains_by_just_driving_and_evaluates(tmp_path, capsys):
    run = tmp_path / "rule"
    # 4 envs x 330 steps: every env finishes one 320-step episode, so T_c is logged
    assert main(["train", "--method", "rule-based", "--traffic", "A", "--steps", "1320", "--envs", "4",
                 "--out", str(run), "--quiet"]) == 0
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["per_seed"]["0"]["episodes"] == 4 and metrics["mean"]["T_c"] == 1.0
    capsys.readouterr()
    assert main(["evaluate", str(run), "--episodes", "6", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["method"] == "rule-based" and report["levels"]["A"]["C_r"]["value"] == 1.0


def test_lm_rl_saves_its_lagrange_multiplier_with_the_model(tmp_path):
    from highway_srl.agents.dqn import DQNConfig
    from highway_srl.agents.train_config import TrainConfig
    from highway_srl.experiments.evaluate import evaluate_run
    from highway_srl.experiments.policy import load_policy, read_model
    from highway_srl.experiments.train import train_run

    cfg = TrainConfig(method="lm-rl", traffic="A", steps=64, envs=4, options={"lambda_init": 0.7},
                      dqn=DQNConfig(learning_starts=32, batch_size=16, total_steps=64, buffer_capacity=64))
    train_run(cfg, tmp_path / "lm", progress=False)
    _, tensors, _ = read_model(tmp_path / "lm")
    assert torch.allclose(tensors["method.lambda"], torch.tensor([0.7]))
    assert torch.allclose(load_policy(tmp_path / "lm").method.lam, torch.tensor([0.7]))
    report = evaluate_run(tmp_path / "lm", episodes=2)
    assert report["method"] == "lm-rl"


def _press(pygame, key, up=True):
    pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=key))
    if up:
        pygame.event.post(pygame.event.Event(pygame.KEYUP, key=key))


def test_play_drives_headless_with_scripted_keys_and_logs_like_every_method(tmp_path, monkeypatch):
    pygame = pytest.importorskip("pygame")
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    import highway_srl.experiments.play as play_module

    worlds, seen = [], {}

    class Recorded(play_module.World):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            worlds.append(self)

    monkeypatch.setattr(play_module, "World", Recorded)

    def script(episode, step):
        world = worlds[0]
        if step == 0:
            seen[episode] = (int(world.ego_lane[0]), float(world.ego_speed[0]))
            _press(pygame, pygame.K_DOWN, up=False)  # hold down: brake
        if step == 3:
            pygame.event.post(pygame.event.Event(pygame.KEYUP, key=pygame.K_DOWN))  # then nothing: Idle
        if step == 8:
            seen[(episode, "slowed")] = float(world.ego_speed[0])
            _press(pygame, pygame.K_LEFT if seen[episode][0] == 1 else pygame.K_RIGHT)  # one tap commits a change
        if step == 60:
            seen[(episode, "lane")] = int(world.ego_lane[0])

    report = play_module.play("two-lane", "A", tmp_path / "human", episodes=2, seed=4, fps=0, wait_for_key=False,
                              on_tick=script)
    for episode in (0, 1):
        start_lane, start_speed = seen[episode]
        assert seen[(episode, "slowed")] == pytest.approx(start_speed - 3 * 0.75, abs=0.01)  # three Slower steps
        assert seen[(episode, "lane")] == 1 - start_lane
    rows = [json.loads(line) for line in (tmp_path / "human" / "episodes.jsonl").read_text().splitlines()]
    assert len(rows) == 2
    assert set(rows[0]) == {"seed", "step", "return", "length", "collision", "avg_speed", "success", "deploy_reward"}
    assert all(r["length"] == 320 and not r["collision"] for r in rows)
    assert rows[1]["step"] == 640
    assert report["method"] == "manual" and report["levels"]["A"]["episodes"] == 2
    config = json.loads((tmp_path / "human" / "config.json").read_text())["config"]
    assert config["method"] == "manual" and config["scenario"] == "two-lane"
    assert (config["profile"], config["adversary"]) == (DEFAULT_PROFILE, DEFAULT_ADVERSARY)  # one default, recorded


@pytest.mark.parametrize("driver", ["dummy", "offscreen"])
def test_play_on_a_video_driver_without_keys_refuses_at_once_and_writes_nothing(tmp_path, monkeypatch, capsys, driver):
    # such a driver reads no key: play would wait for the first key press forever
    pytest.importorskip("pygame")
    monkeypatch.setenv("SDL_VIDEODRIVER", driver)
    code = main(["play", "--out", str(tmp_path / "manual")])
    err = capsys.readouterr().err
    assert code == 2 and err == (f"highway-srl: error: play needs a window that takes key presses, and SDL's video "
                                 f"driver '{driver}' has none (SDL_VIDEODRIVER set so, or DISPLAY names no running "
                                 "X server)\n"), err
    assert not (tmp_path / "manual").exists()


def test_play_keys_map_to_the_five_actions_at_each_tick():
    pygame = pytest.importorskip("pygame")
    from highway_srl.experiments.play import Keys
    from highway_srl.rules.raw import FIVE_ACTIONS

    keys = Keys(pygame)
    assert FIVE_ACTIONS[keys.action()] == "Idle"
    keys.feed(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_UP))
    assert FIVE_ACTIONS[keys.action()] == "Faster" and FIVE_ACTIONS[keys.action()] == "Faster"  # held
    keys.feed(pygame.event.Event(pygame.KEYUP, key=pygame.K_UP))
    assert FIVE_ACTIONS[keys.action()] == "Idle"
    keys.feed(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_DOWN))
    keys.feed(pygame.event.Event(pygame.KEYUP, key=pygame.K_DOWN))
    assert FIVE_ACTIONS[keys.action()] == "Slower"  # a tap inside one tick still counts, once
    assert FIVE_ACTIONS[keys.action()] == "Idle"
    keys.feed(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_RIGHT))
    assert FIVE_ACTIONS[keys.action()] == "LaneRight"


def test_play_without_pygame_names_the_extra_to_install(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "pygame", None)  # import pygame now raises ImportError
    assert main(["play", "--scenario", "two-lane", "--traffic", "C", "--out", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "pip install highway-srl[play]" in err
