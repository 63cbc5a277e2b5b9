"""The reward machine (§2.4), the highway RM (Eqs. U1-U4, r_RM, v*) and the scenario rewards (§4.3)."""

import pytest
import torch

from highway_srl.rules import (
    COLLISION_REWARD,
    D_ACC_M,
    HighwayPropositions,
    RewardMachine,
    desired_speed,
    highway_reward_machine,
    reward_machine_state,
    rm_reward,
    scenario_reward,
    speed_ratio,
)
from highway_srl.rules.reward_machine import U1, U2, U3, U4

W = 3.5
ALL = torch.tensor([[True, True, True, True]])


def state(m_l, d_vl, r):
    return int(reward_machine_state(torch.tensor([m_l]), torch.tensor([d_vl]), torch.tensor([r])))


def test_eq_u1_lane_keeping_and_front_safe():
    assert state(False, 0.3, [True, False, False, False]) == U1  # only R1 matters while keeping the lane


def test_eq_u2_lane_keeping_and_front_unsafe():
    assert state(False, 0.3, [False, True, True, True]) == U2


def test_eq_u3_lane_changing_and_all_safe():
    assert state(True, 0.3, [True] * 4) == U3  # near the boundary
    assert state(False, 1.75, [True] * 4) == U3  # d_VL >= w_L/2: not aligned with the target lane


def test_eq_u4_lane_changing_and_any_unsafe():
    for i in range(4):
        r = [True] * 4
        r[i] = False
        assert state(True, 0.0, r) == U4
        assert state(False, 3.5, r) == U4


def test_u3_u4_brackets_make_the_states_a_partition():
    # the unbracketed U3 = m_L ∨ (...∧...) would put (m_L, some R false) in both u3 and u4
    assert state(True, 0.0, [False, True, True, True]) == U4


def test_rm_reward_pays_speed_ratio_in_u1_and_u3_only():
    u = torch.tensor([U1, U2, U3, U4])
    r = rm_reward(u, torch.full((4,), 5.0), torch.full((4,), 10.0))
    assert r.tolist() == [0.5, 0.0, 0.5, 0.0]


def test_desired_speed_follows_sv1_only_when_close_and_some_rule_fails():
    gap = torch.tensor([10.0, 10.0, 30.0])
    v1 = torch.tensor([4.0, 4.0, 4.0])
    r = torch.tensor([[True, True, False, True], [True] * 4, [True, True, False, True]])
    assert desired_speed(gap, v1, r).tolist() == [4.0, 10.0, 10.0]
    assert D_ACC_M == 20.0
    assert desired_speed(torch.tensor([20.0]), torch.tensor([4.0]), ~ALL).tolist() == [4.0]  # gap <= d_ACC


def test_speed_ratio_guards_zero_desired_speed_and_clips_at_one():
    v = torch.tensor([0.0, 3.0, 8.0, 5.0])
    v_star = torch.tensor([0.0, 0.0, 4.0, 10.0])
    assert speed_ratio(v, v_star).tolist() == [1.0, 1.0, 1.0, 0.5]
    assert torch.isfinite(speed_ratio(v, v_star)).all()


def test_generic_reward_machine_step_is_batched_and_passes_the_state():
    # a two-state counter: move to state 1 on proposition p, pay 1 on the transition 0 -> 1
    rm = RewardMachine(("a", "b"), 0, lambda u, p: torch.where(p, 1, u), lambda u, un, p: ((u == 0) & (un == 1)).float())
    u = rm.initial(3)
    u, r = rm.step(u, torch.tensor([True, False, True]))
    assert u.tolist() == [1, 0, 1] and r.tolist() == [1.0, 0.0, 1.0]
    u, r = rm.step(u, torch.tensor([True, True, False]))
    assert u.tolist() == [1, 1, 1] and r.tolist() == [0.0, 1.0, 0.0]
    with pytest.raises(ValueError):
        RewardMachine(("a",), 3, rm.transition, rm.reward)


def test_highway_rm_is_state_based_u_next_ignores_u():
    rm = highway_reward_machine()
    p = HighwayPropositions(torch.tensor([False, True]), torch.tensor([0.1, 0.1]), ALL.repeat(2, 1),
                            torch.tensor([5.0, 5.0]), torch.tensor([10.0, 10.0]))
    for u0 in (U1, U2, U3, U4):
        u, r = rm.step(torch.full((2,), u0), p)
        assert u.tolist() == [U1, U3] and r.tolist() == [0.5, 0.5]


def test_scenario_rewards_merge_exit_and_collision():
    r_rm = torch.tensor([0.8, 0.8, 0.8])
    no = torch.tensor([False, False, True])
    one = torch.ones(3)
    assert torch.allclose(scenario_reward("two-lane", r_rm, no), torch.tensor([0.8, 0.8, -320.0]))
    assert torch.allclose(scenario_reward("multi-lane", r_rm, no), torch.tensor([0.8, 0.8, -320.0]))
    merge = scenario_reward("merge", r_rm, no, r_merge=torch.tensor([0.0, 1.0, 1.0]))
    assert torch.allclose(merge, torch.tensor([0.56, 0.86, -320.0]))  # 0.7*0.8 (+ 0.3)
    exit_ = scenario_reward("exit", r_rm, no, r_exit1=one, r_exit2=torch.tensor([0.0, 1.0, 1.0]))
    assert torch.allclose(exit_, torch.tensor([0.65, 0.9, -320.0]))  # 0.5*0.8 + 0.25 (+ 0.25)
    assert COLLISION_REWARD == -320.0
    with pytest.raises(ValueError, match="r_merge"):
        scenario_reward("merge", r_rm, no)
    with pytest.raises(ValueError, match="scenario"):
        scenario_reward("roundabout", r_rm, no)
