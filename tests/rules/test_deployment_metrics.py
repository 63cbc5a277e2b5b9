"""Deployment metrics (§4.2, the R_r formulas under Tables 5-6) and their confidence intervals."""

import math

import pytest
import torch

from highway_srl.rules import (
    average_speed,
    collision_free_rate,
    deployment_episode_reward,
    deployment_step_reward,
    mean_interval,
    success_rate,
    wilson_interval,
)
from highway_srl.rules.metrics import _T975, t_quantile


def test_expressway_step_reward_is_half_ratio_plus_quarter_r1_and_r2():
    r_star = torch.tensor([[True, True, False, False], [False, True, True, True]])
    r = deployment_step_reward("two-lane", torch.tensor([1.0, 0.5]), r_star=r_star)
    assert torch.allclose(r, torch.tensor([1.0, 0.5]))  # ½ + ¼ + ¼;  ¼ + 0 + ¼


def test_merge_and_exit_step_rewards_keep_the_papers_weights():
    ratio = torch.tensor([1.0])
    assert torch.allclose(deployment_step_reward("merge", ratio, r_merge=torch.tensor([1.0])), torch.tensor([1.0]))
    ex = deployment_step_reward("exit", ratio, r_exit1=torch.tensor([1.0]), r_exit2=torch.tensor([1.0]))
    assert torch.allclose(ex, torch.tensor([1.1]))  # ½ + 3/10 * 2: the exit formula can exceed 1 per step


def test_episode_reward_subtracts_n_max_on_collision_and_masks_dead_steps():
    steps = torch.ones(4, 2)
    alive = torch.tensor([[1, 1], [1, 1], [1, 0], [1, 0]], dtype=torch.bool)
    r = deployment_episode_reward(steps, torch.tensor([False, True]), alive)
    assert r.tolist() == [4.0, 2.0 - 320.0]


def test_average_speed_over_alive_steps():
    v = torch.tensor([[4.0, 6.0], [8.0, 100.0]])
    alive = torch.tensor([[True, True], [True, False]])
    assert average_speed(v, alive).tolist() == [6.0, 6.0]


def test_wilson_interval_of_8_in_10():
    e = wilson_interval(8, 10)
    # p=0.8, z=1.95996: centre (0.8 + 0.19208)/1.38415 = 0.71674, half 1.96*0.16001/1.38415 = 0.22657
    assert e.value == 0.8 and abs(e.low - 0.4902) < 1e-3 and abs(e.high - 0.9433) < 1e-3


def test_collision_free_and_success_rates_with_all_or_none():
    e = collision_free_rate(torch.zeros(100, dtype=torch.bool))
    assert e.value == 1.0 and e.high == 1.0 and 0.95 < e.low < 0.97  # Wilson never gives a zero-width interval
    s = success_rate(torch.tensor([True, False, True, True]))
    assert s.value == 0.75 and s.n == 4
    with pytest.raises(ValueError):
        wilson_interval(3, 0)


def test_t_quantile_expansion_agrees_with_table_and_exact_cases():
    for dof in range(5, 31):
        approx = t_quantile(0.950000001, dof)  # bypasses the table
        assert abs(approx - _T975[dof - 1]) < 2e-3
    assert abs(t_quantile(0.95, 1) - 12.7062) < 1e-3
    assert abs(t_quantile(0.95, 2) - 4.3027) < 1e-3
    assert abs(t_quantile(0.95, 10_000) - 1.95996) < 1e-3


def test_mean_interval_uses_student_t():
    e = mean_interval(torch.tensor([1.0, 2.0, 3.0, 4.0, 5.0]))
    half = 2.7764 * math.sqrt(2.5) / math.sqrt(5)
    assert e.value == 3.0 and abs(e.high - (3 + half)) < 1e-3 and abs(e.low - (3 - half)) < 1e-3
    assert mean_interval(torch.tensor([2.0])).low == 2.0
