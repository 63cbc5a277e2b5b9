"""Golden vectors for the safe distance (Eqs. 19-27), computed by hand in the comments.

δt = 0.125 s throughout, so δt² = 0.015625 and ½·6·δt² = 0.046875.
"""

import pytest
import torch

from highway_srl.rules import rule_indicator, safe_distance
from highway_srl.rules.safe_distance import (
    braking_displacement,
    case_d_literal,
    case_e_literal,
    condition_follower_leader,
    condition_front_literal,
    condition_rear_literal,
    reaction_displacement,
    residual_speed,
    safe_distances_follower_leader,
    safe_distances_front_literal,
    safe_distances_rear_literal,
    stopping_distance,
    stopping_time,
)
from highway_srl.rules.worst_case import worst_case_collides

DT = 0.125
T = lambda *x: torch.tensor(x, dtype=torch.float64)  # noqa: E731


def close(a, b, tol=1e-9):
    return torch.allclose(torch.as_tensor(a, dtype=torch.float64), torch.as_tensor(b, dtype=torch.float64), atol=tol)


# ----------------------------------------------------------------- Eq. 19, 20, 23 building blocks
def test_eq19_braking_displacement_moving_and_clamped_at_stop():
    # v=10, |a|=6: 10*0.125 - 0.046875 = 1.203125 (moving all through δt)
    assert close(braking_displacement(T(10.0), 6.0, DT), [1.203125])
    # v=0.5 stops after 0.0833 s < δt: clamped 0.5²/12 = 0.0208333; literal 0.0625 - 0.046875 = 0.015625
    assert close(braking_displacement(T(0.5), 6.0, DT), [0.25 / 12])
    assert close(braking_displacement(T(0.5), 6.0, DT, clamp_at_stop=False), [0.015625])
    # v=0.2 literal goes backwards: 0.025 - 0.046875 = -0.021875
    assert close(braking_displacement(T(0.2), 6.0, DT, clamp_at_stop=False), [-0.021875])


def test_eq19_reaction_displacement_constant_speed_and_accelerating():
    assert close(reaction_displacement(T(8.0), DT), [1.0])  # 8*0.125
    assert close(reaction_displacement(T(8.0), DT, 3.5), [1.02734375])  # 1 + ½*3.5*0.015625


def test_eq19_residual_speed_both_branches():
    assert close(residual_speed(T(10.0), 6.0, DT), [9.25])  # 10 - 0.75
    assert close(residual_speed(T(0.5), 6.0, DT), [0.0])  # clamped
    assert close(residual_speed(T(0.5), 6.0, DT, clamp_at_stop=False), [-0.25])


def test_eq20_eq23_stopping_distance_and_time():
    assert close(stopping_distance(T(12.0), 6.0), [12.0])  # 144/12
    assert close(stopping_time(T(12.0), 6.0), [2.0])


# ----------------------------------------------------------------- Eqs. 21-22 conditions (literal)
def test_eq21_front_condition_true_and_false():
    # v_EV=10 |a_EV|=8, v_SV=8 |a_SV|=4: Δx_SV=1-0.03125=0.96875 <= d_EV=6.25; 4<8; v_res=7.5<10;
    # t_EV=1.25 < t*_SV=7.5/4=1.875 -> true
    assert bool(condition_front_literal(T(10.0), T(8.0), 8.0, 4.0, DT))
    # equal brakes: |a_SV| < |a_EV| fails
    assert not bool(condition_front_literal(T(10.0), T(8.0), 6.0, 6.0, DT))


def test_eq22_rear_condition_true_and_false():
    # v_EV=2 |a_EV|=4, v_SV=10 |a_SV|=8: d_EV=0.5 <= Δx_SV=1.25-0.0625=1.1875; 4<8; 2<v_res=9;
    # t_EV=0.5 < t*_SV=9/8=1.125 -> true
    assert bool(condition_rear_literal(T(2.0), T(10.0), 4.0, 8.0, DT))
    assert not bool(condition_rear_literal(T(2.0), T(10.0), 6.0, 6.0, DT))


# ----------------------------------------------------------------- Eq. 24 front distances (literal)
def test_eq24_front_literal_branch_c():
    # v_EV=10, v_SV=5, 6/6: Δx_EV=1.25, d_EV=8.3333, Δx_SV=0.578125, d_SV=25/12=2.08333
    # d1 = 9.583333, d2 = 9.583333-0.578125 = 9.005208, d3 = C_F - d_SV = 9.583333 - 2.083333 = 7.5
    sd = safe_distances_front_literal(T(10.0), T(5.0), 6.0, 6.0, DT)
    assert close(sd.d1, [1.25 + 100 / 12]) and close(sd.d2, [1.25 + 100 / 12 - 0.578125]) and close(sd.d3, [7.5])
    assert not bool(sd.condition)


def test_eq24_front_literal_branch_b_has_the_sign_slip():
    # v_EV=10 |a_EV|=8, v_SV=8 |a_SV|=4 (condition true): B_F = 1.25 - (7.5-10)²/(2*4) = 0.46875,
    # d3 = B_F - Δx_SV = 0.46875 - 0.96875 = -0.5; d1 = 1.25 + 6.25 = 7.5; d2 = 7.5 - 0.96875 = 6.53125
    sd = safe_distances_front_literal(T(10.0), T(8.0), 8.0, 4.0, DT)
    assert bool(sd.condition)
    assert close(sd.d1, [7.5]) and close(sd.d2, [6.53125]) and close(sd.d3, [-0.5])


# ----------------------------------------------------------------- Eq. 25 rear distances (literal)
def test_eq25_rear_literal_branch_c():
    # v_EV=5, v_SV=10, 6/6: Δx_SV=1.203125, d_SV=8.333333: d1 = 9.536458,
    # d2 = d1 - 5*0.125 - 0.046875 = 8.864583, d3 = C_R + v_SV δt = (8.333333-2.083333) + 1.25 = 7.5
    sd = safe_distances_rear_literal(T(5.0), T(10.0), 6.0, 6.0, DT)
    d1 = 1.203125 + 100 / 12
    assert close(sd.d1, [d1]) and close(sd.d2, [d1 - 0.625 - 0.046875]) and close(sd.d3, [7.5])
    assert not bool(sd.condition)


def test_eq25_rear_literal_branch_b():
    # v_EV=2 |a_EV|=4, v_SV=10 |a_SV|=8 (condition true): B_R = (2 - 0.5 - 10)²/(2*4) = 72.25/8 = 9.03125,
    # d3 = B_R - v_EV δt = 9.03125 - 0.25 = 8.78125; d1 = Δx_SV + d_SV = (1.25 - 0.0625) + 100/16 = 7.4375;
    # d2 = d1 - v_EV δt - ½|a_EV|δt² = 7.4375 - 0.25 - 0.03125 = 7.15625
    sd = safe_distances_rear_literal(T(2.0), T(10.0), 4.0, 8.0, DT)
    assert bool(sd.condition)
    assert close(sd.d1, [7.4375]) and close(sd.d2, [7.15625]) and close(sd.d3, [8.78125])


# ----------------------------------------------------------------- Eq. 27 cases D and E (literal)
def test_eq27_case_d_literal_both_branches():
    # Δv = 5 - 10 = -5: threshold -5*0.125 + 0.046875 = -0.578125, so only gap <= 0 is D
    assert bool(case_d_literal(T(0.0), T(-5.0), 6.0, DT)) and not bool(case_d_literal(T(0.1), T(-5.0), 6.0, DT))
    # Δv = +2: threshold 0.25 + 0.046875 = 0.296875
    assert bool(case_d_literal(T(0.29), T(2.0), 6.0, DT)) and not bool(case_d_literal(T(0.3), T(2.0), 6.0, DT))


def test_eq27_case_e_literal_both_clauses():
    sd = safe_distances_front_literal(T(10.0), T(5.0), 6.0, 6.0, DT)  # d1 = 9.5833, d2 = 9.0052
    t_sv = stopping_time(T(5.0), 6.0)  # 0.8333 >= δt
    assert bool(case_e_literal(T(9.6), sd, t_sv, DT))  # > d1
    assert bool(case_e_literal(T(9.1), sd, t_sv, DT))  # > d2 and δt <= t_SV,Stop
    assert not bool(case_e_literal(T(9.1), sd, T(0.1), DT))  # the SV stops within δt: second clause off
    assert not bool(case_e_literal(T(8.9), sd, t_sv, DT))


# ----------------------------------------------------------------- Eq. 26 the indicator (literal)
def test_eq26_literal_indicator_front_around_d3():
    kw = dict(front=True, literal=True)
    assert not bool(rule_indicator(7.4, 10.0, 5.0, **kw))  # 7.4 < d3 = 7.5
    assert bool(rule_indicator(7.6, 10.0, 5.0, **kw))
    assert bool(rule_indicator(9.1, 10.0, 5.0, **kw))  # E


def test_eq26_literal_accepts_a_gap_the_worst_case_closes():
    """Counterexample (front, |a_EV| > |a_SV|): B_F's sign slip accepts gap 0.1 m; the sound rule needs 1.0625 m."""
    assert bool(rule_indicator(0.1, 10.0, 8.0, front=True, ego_brake=8.0, other_brake=4.0, literal=True))
    collides, min_gap = worst_case_collides(T(0.1), T(10.0), T(8.0), front=True, ego_brake=8.0, other_brake=4.0,
                                            reaction_accel=0.0)
    assert bool(collides) and float(min_gap) < -0.9


def test_eq26_literal_rear_counterexample_with_the_papers_brakes():
    """Counterexample (rear, 6/6): the ego stands, the SV at 10 m/s keeps its speed for δt and needs
    1.25 + 100/12 = 9.5833 m, but the literal E accepts gap > d2 = 1.203125 + 8.333333 - 0.046875 = 9.4896."""
    assert bool(rule_indicator(9.5, 0.0, 10.0, front=False, literal=True))
    assert not bool(rule_indicator(9.5, 0.0, 10.0, front=False))
    collides, _ = worst_case_collides(T(9.5), T(0.0), T(10.0), front=False, reaction_accel=0.0)
    assert bool(collides)


# ----------------------------------------------------------------- the sound reading (default)
def test_sound_condition_and_branch_b_distance():
    # follower v=10 |a|=8, leader v=8 |a|=4, no reaction acceleration:
    # d3 = Δx_F - Δx_L + (v_F1 - v_Lres)²/(2(8-4)) = 1.25 - 0.96875 + 6.25/8 = 1.0625
    assert bool(condition_follower_leader(T(10.0), T(8.0), 8.0, 4.0, DT))
    sd, d_thr = safe_distances_follower_leader(T(10.0), T(8.0), 8.0, 4.0, DT)
    assert close(sd.d3, [1.0625]) and close(d_thr, [0.28125])
    # with 3.5 m/s² during δt: v_F1 = 10.4375, Δx_F = 1.27734375,
    # d3 = 1.27734375 - 0.96875 + 2.9375²/8 = 0.30859375 + 1.07861328125 = 1.38720703125
    assert close(safe_distance(10.0, 8.0, front=True, ego_brake=8.0, other_brake=4.0), [1.38720703125], 1e-6)
    assert close(safe_distance(10.0, 8.0, front=True, ego_brake=8.0, other_brake=4.0, reaction_accel=0.0),
                 [1.0625], 1e-6)


def test_sound_branch_c_front_default_assumes_faster_during_reaction():
    # v_EV=10, v_SV=5, 6/6, ego at +3.5 for δt: Δx_F = 1.27734375, v_F1 = 10.4375,
    # d3 = 1.27734375 + 10.4375²/12 - 25/12 = 8.2724609375 (constant speed: 7.5, same as the literal C)
    assert close(safe_distance(10.0, 5.0, front=True), [8.2724609375], 1e-5)
    assert close(safe_distance(10.0, 5.0, front=True, reaction_accel=0.0), [7.5], 1e-5)


def test_sound_rear_uses_sv_as_follower_and_ego_as_leader():
    # v_EV=5 (leader), v_SV=10 (follower, keeps speed for δt), 6/6: d3 = 1.25 + 100/12 - 25/12 = 7.5
    assert close(safe_distance(5.0, 10.0, front=False), [7.5], 1e-5)
    # swapped brakes give the branch-B number of the front case: 1.0625
    assert close(safe_distance(8.0, 10.0, front=False, ego_brake=4.0, other_brake=8.0), [1.0625], 1e-6)


def test_sound_case_d_gap_closed_within_reaction_time_is_unsafe():
    # v_EV=10 behind a standing SV, constant speed: D threshold 1.25, d3 = 9.5833
    r = rule_indicator(T(1.0, 9.5, 9.6), 10.0, 0.0, front=True, reaction_accel=0.0)
    assert r.tolist() == [False, False, True]


def test_sound_equal_speeds_need_only_the_reaction_closing():
    # both at 10 m/s, 6/6, constant speed: d3 = d1 - d_L = 1.25 (both brake alike afterwards)
    r = rule_indicator(T(1.2, 1.3), 10.0, 10.0, front=True, reaction_accel=0.0)
    assert r.tolist() == [False, True]


def test_default_rule_is_exactly_gap_greater_than_safe_distance():
    g = torch.Generator().manual_seed(0)
    n = 20000
    gap = torch.rand(n, generator=g, dtype=torch.float64) * 40
    v_e, v_o = (torch.rand(n, generator=g, dtype=torch.float64) * 15 for _ in range(2))
    a_e, a_o = (3 + 6 * torch.rand(n, generator=g, dtype=torch.float64) for _ in range(2))
    front = torch.rand(n, generator=g) < 0.5
    r = rule_indicator(gap, v_e, v_o, front=front, ego_brake=a_e, other_brake=a_o)
    d = safe_distance(v_e, v_o, front=front, ego_brake=a_e, other_brake=a_o)
    assert torch.equal(r, gap > d)


def test_rule_indicator_broadcasts_and_batched_equals_one_by_one():
    gaps = T(0.5, 5.0, 12.0, 30.0)
    v_e = T(3.0, 8.0, 10.0, 13.0)
    v_o = T(0.0, 9.0, 4.0, 6.0)
    for literal in (False, True):
        for front in (True, False):
            batch = rule_indicator(gaps, v_e, v_o, front=front, literal=literal)
            one = [bool(rule_indicator(float(gaps[i]), float(v_e[i]), float(v_o[i]), front=front, literal=literal))
                   for i in range(4)]
            assert batch.tolist() == one
    grid = rule_indicator(gaps[:, None], v_e[None, :], 5.0, front=True)
    assert grid.shape == (4, 4)
    mixed = rule_indicator(gaps, v_e, v_o, front=torch.tensor([True, False, True, False]))
    assert mixed.tolist() == [bool(rule_indicator(gaps[i], v_e[i], v_o[i], front=bool(i % 2 == 0))) for i in range(4)]


def test_rule_indicator_names_a_bad_brake():
    with pytest.raises(ValueError, match="ego_brake"):
        rule_indicator(5.0, 1.0, 1.0, front=True, ego_brake=0.0)


def test_negative_or_zero_gap_is_never_safe():
    r = rule_indicator(T(-1.0, 0.0), 0.0, 0.0, front=True)
    assert not r.any()
    # a standing ego may choose Faster: ½·3.5·δt² = 0.02734375 m during δt, then (0.4375)²/12 = 0.01595 m
    # of braking: it needs gap > 0.043294 m
    assert rule_indicator(T(0.043, 0.0434), 0.0, 0.0, front=True).tolist() == [False, True]
    assert bool(rule_indicator(T(0.01), 0.0, 0.0, front=True, reaction_accel=0.0))
