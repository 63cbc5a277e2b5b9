"""EpisodeStats: a crafted sequence of steps gives the hand-computed return, R_r, collision penalty,
average speed and success (merge: the latched merged flag)."""

from types import SimpleNamespace

import pytest
import torch

from highway_srl.rules.episode import EpisodeStats
from highway_srl.sim import StageFlags

T, F = True, False


def _step(stats, *, collision, success=None, merged=None, speed_ratio, ego_speed, reward=None, r_star=None, alive=None,
          r_rm=None):
    b = len(collision)
    rm = torch.tensor(r_rm if r_rm is not None else [0.0] * b)
    flag = lambda v: torch.tensor(v if v is not None else [F] * b)  # noqa: E731
    events = SimpleNamespace(collision=torch.tensor(collision), success=flag(success))
    flags = StageFlags(merged=flag(merged), exit1=flag(None), exit2=flag(None))
    view = SimpleNamespace(speed_ratio=torch.tensor(speed_ratio),
                           r_star=None if r_star is None else torch.tensor(r_star), scoring_r_rm=lambda: rm)
    stats.add(events, flags, view, torch.tensor(ego_speed), None if reward is None else torch.tensor(reward),
              None if alive is None else torch.tensor(alive))


def test_two_lane_episode_sums_return_and_r_r_and_charges_320_for_a_collision():
    stats = EpisodeStats("two-lane", 2, "cpu", max_steps=320)
    # R_r step term (two-lane): 0.5 v/v* + 0.25 R*_SV1 + 0.25 R*_SV2
    _step(stats, collision=[F, F], speed_ratio=[0.5, 1.0], ego_speed=[10.0, 20.0], reward=[1.0, 2.0],
          r_star=[[T, T, F, F], [F, F, T, T]])  # R_r terms 0.75, 0.5
    _step(stats, collision=[F, T], speed_ratio=[1.0, 0.0], ego_speed=[30.0, 0.0], reward=[1.0, -320.0],
          r_star=[[T, F, F, F], [F, F, F, F]])  # R_r terms 0.75, 0.0
    first, second = stats.finish(torch.tensor([T, T]))
    assert (first.env, first.ret, first.length, first.collision, first.avg_speed, first.success, first.deploy_reward) \
        == (0, 2.0, 2, False, 20.0, False, 1.5)
    assert (second.env, second.ret, second.length, second.collision, second.avg_speed, second.deploy_reward) \
        == (1, -318.0, 2, True, 10.0, 0.5 - 320.0)


def test_merge_succeeds_once_merged_even_without_the_success_event_but_never_with_a_collision():
    stats = EpisodeStats("merge", 3, "cpu", max_steps=320)
    # env 0: the success event on the step it merges; env 1: only the latched flag; env 2: merged, then crashed
    _step(stats, collision=[F, F, F], success=[T, F, T], merged=[T, F, T], speed_ratio=[1.0, 1.0, 1.0],
          ego_speed=[20.0, 20.0, 20.0])
    _step(stats, collision=[F, F, T], success=[F, F, F], merged=[T, T, T], speed_ratio=[0.5, 0.5, 0.5],
          ego_speed=[10.0, 10.0, 10.0])
    rows = stats.finish(torch.tensor([T, T, T]))
    assert [r.success for r in rows] == [True, True, False]
    # R_r step term (merge): 0.7 v/v* + 0.3 r_merge
    assert [r.deploy_reward for r in rows] == pytest.approx([1.0 + 0.65, 0.7 + 0.65, 1.0 + 0.65 - 320.0])
    assert rows[0].ret == 0.0  # no training reward given: evaluate's case


def test_finish_reads_only_the_finished_envs_and_restarts_them():
    stats = EpisodeStats("two-lane", 2, "cpu", max_steps=320)
    _step(stats, collision=[T, F], speed_ratio=[1.0, 1.0], ego_speed=[5.0, 7.0], reward=[3.0, 4.0],
          r_star=[[F] * 4, [F] * 4])
    (row,) = stats.finish(torch.tensor([T, F]))
    assert row.env == 0 and row.collision and row.ret == 3.0
    assert stats.ret.tolist() == [0.0, 4.0] and stats.length.tolist() == [0, 1]
    assert stats.collision.tolist() == [False, False] and stats.speed.tolist() == [0.0, 7.0]


def test_steps_of_envs_no_longer_alive_do_not_count():
    stats = EpisodeStats("two-lane", 2, "cpu", max_steps=320)
    _step(stats, collision=[F, F], speed_ratio=[1.0, 1.0], ego_speed=[10.0, 10.0], r_star=[[F] * 4] * 2, alive=[T, T])
    _step(stats, collision=[T, T], speed_ratio=[1.0, 1.0], ego_speed=[30.0, 30.0], r_star=[[F] * 4] * 2, alive=[T, F])
    r = stats.results()
    assert r["length"].tolist() == [2, 1] and r["collision"].tolist() == [True, False]
    assert r["avg_speed"].tolist() == [20.0, 10.0] and r["deploy_reward"].tolist() == [1.0 - 320.0, 0.5]


def test_float64_sums_equal_python_float_sums_of_the_float32_step_values():
    stats = EpisodeStats("two-lane", 1, "cpu", max_steps=320, dtype=torch.float64)
    total, rewards = 0.0, torch.rand(50, generator=torch.Generator().manual_seed(0))
    for r in rewards:
        _step(stats, collision=[F], speed_ratio=[0.3], ego_speed=[1.0], reward=[float(r)], r_star=[[F] * 4])
        total += float(torch.tensor([float(r)])[0])
    assert stats.finish(torch.tensor([T]))[0].ret == total


def test_rm_return_sums_the_papers_rm_reward_whatever_the_training_reward():
    # two-lane: r_RM per step, -320 replacing the step's reward on the collision step (§4.3)
    stats = EpisodeStats("two-lane", 2, "cpu", max_steps=320)
    _step(stats, collision=[F, F], speed_ratio=[1.0, 1.0], ego_speed=[9.0, 9.0], reward=[0.9, 0.9],
          r_star=[[T] * 4, [T] * 4], r_rm=[0.8, 0.5])
    _step(stats, collision=[F, T], speed_ratio=[1.0, 1.0], ego_speed=[9.0, 9.0], reward=[0.9, -320.0],
          r_star=[[T] * 4, [T] * 4], r_rm=[1.0, 1.0])
    first, second = stats.finish(torch.tensor([T, T]))
    assert first.rm_return == pytest.approx(1.8) and first.ret == pytest.approx(1.8)
    assert second.rm_return == pytest.approx(0.5 - 320.0)
    # merge: 0.7 r_RM + 0.3 r_merge
    stats = EpisodeStats("merge", 1, "cpu", max_steps=320)
    _step(stats, collision=[F], merged=[F], speed_ratio=[1.0], ego_speed=[9.0], r_rm=[1.0])
    _step(stats, collision=[F], merged=[T], speed_ratio=[1.0], ego_speed=[9.0], r_rm=[0.5])
    (row,) = stats.finish(torch.tensor([T]))
    assert row.rm_return == pytest.approx(0.7 + 0.35 + 0.3) and row.ret == 0.0
