"""The mappings of §3.3 (ID, rule Eqs. 31-32, action/control Eqs. 34-35) and SV_i,Def of §3.1."""

import math

import torch

from highway_srl.rules import (
    default_virtual_vehicles,
    id_mapping,
    crossing_toward,
    near_boundary,
    rule_mapping,
    target_lane_local,
    target_speed,
)
from highway_srl.rules.safe_actions import FASTER, IDLE, LANE_CHANGE, SLOWER
from highway_srl.sim.road import EXIT_X, make_road

L = lambda *v: torch.tensor(v, dtype=torch.long)  # noqa: E731
X = lambda *v: torch.tensor(v, dtype=torch.float32)  # noqa: E731


def B(*v):
    """bool tensor from B(a, b, ...) or B([a, b, ...])."""
    return torch.tensor(v[0] if len(v) == 1 and isinstance(v[0], list) else v, dtype=torch.bool)


def fields(model):
    return (model.base_lane.tolist(), model.c_id.tolist(), model.current_lane.tolist(), model.adjacent_lane.tolist(),
            model.default_adjacent.tolist())


# ----------------------------------------------------------------- ID mapping
def test_id_mapping_two_lane_is_the_standard_indexing():
    ids = id_mapping(make_road("two-lane"), X(0.0, 0.0), L(0, 1))
    assert fields(ids.primary) == ([0, 0], [0, 1], [0, 1], [1, 0], [False, False])
    assert not ids.two_models.any()


def test_id_mapping_three_lanes_left_middle_right():
    ids = id_mapping(make_road("multi-lane"), X(0.0, 0.0, 0.0), L(0, 1, 2))
    # left: pair (0,1) c 0; middle: model A pair (0,1) c 1 and model B pair (1,2) c 0; right: pair (1,2) c 1
    assert fields(ids.primary) == ([0, 0, 1], [0, 1, 1], [0, 1, 2], [1, 0, 1], [False] * 3)
    assert ids.two_models.tolist() == [False, True, False]
    assert ids.second.base_lane[1] == 1 and ids.second.c_id[1] == 0 and ids.second.adjacent_lane[1] == 2


def test_id_mapping_middle_lane_during_a_lane_change_uses_the_pair_holding_the_target():
    ids = id_mapping(make_road("multi-lane"), X(0.0, 0.0), L(1, 1), target_lane=L(2, 0))
    assert ids.two_models.tolist() == [False, False]
    assert ids.primary.base_lane.tolist() == [1, 0] and ids.primary.c_id.tolist() == [0, 1]


def test_id_mapping_merge_on_ramp_merging_zone_and_stability_zone():
    road = make_road("merge")  # on-ramp [0, 60), merging [60, 160), stability [160, inf)
    ids = id_mapping(road, X(30.0, 100.0, 100.0, 200.0, 200.0), L(2, 2, 1, 1, 0))
    p = ids.primary
    # on-ramp: local 1 with mainline lane 1 as local 0, SV2/SV4 default (barrier)
    assert (p.base_lane[0], p.c_id[0], p.adjacent_lane[0], bool(p.default_adjacent[0])) == (1, 1, -1, True)
    # merging zone on the ramp: local 1, lane 1 adjacent and real
    assert (p.base_lane[1], p.c_id[1], p.adjacent_lane[1], bool(p.default_adjacent[1])) == (1, 1, 1, False)
    # merging zone, already in lane 1: same pair (no frame jump mid-merge), lane 2 adjacent
    assert (p.base_lane[2], p.c_id[2], p.adjacent_lane[2]) == (1, 0, 2)
    # stability zone: standard lanes 0/1
    assert (p.base_lane[3], p.c_id[3], p.adjacent_lane[3]) == (0, 1, 0)
    assert (p.base_lane[4], p.c_id[4], p.adjacent_lane[4]) == (0, 0, 1)


def test_id_mapping_exit_preparation_diverging_off_ramp_and_continuation():
    road = make_road("exit")  # preparation [0, x1), diverging [x1, x2), off-ramp / continuation [x2, x3)
    prep, div, after = 0.5 * EXIT_X["x1"], 0.5 * (EXIT_X["x1"] + EXIT_X["x2"]), 0.5 * (EXIT_X["x2"] + EXIT_X["x3_suc"])
    ids = id_mapping(road, X(prep, div, div, div, after, after), L(1, 1, 0, 2, 2, 1))
    p = ids.primary
    assert (p.base_lane[0], p.c_id[0], p.adjacent_lane[0]) == (0, 1, 0)  # preparation: standard
    assert (p.base_lane[1], p.c_id[1], p.adjacent_lane[1]) == (1, 0, 2)  # diverging: current local 0, right adjacent
    assert (p.base_lane[2], p.c_id[2], p.adjacent_lane[2]) == (0, 0, 1)  # diverging, in lane 0: standard
    assert (p.base_lane[3], p.c_id[3], p.adjacent_lane[3]) == (1, 1, 1)  # deceleration lane beside lane 1
    # off-ramp: local 1, left lane local 0, SV2/SV4 default
    assert (p.base_lane[4], p.c_id[4], p.adjacent_lane[4], bool(p.default_adjacent[4])) == (1, 1, -1, True)
    assert (p.base_lane[5], p.c_id[5], p.adjacent_lane[5]) == (0, 1, 0)  # mainline continuation: standard


def test_id_mapping_missing_lane_gets_default_vehicles():
    # exit preparation zone, lane 1 would see lane 2 only from x1 on
    ids = id_mapping(make_road("exit"), X(0.5 * EXIT_X["x1"]), L(1), target_lane=L(2))
    assert ids.primary.adjacent_lane.tolist() == [-1] and ids.primary.default_adjacent.tolist() == [True]


# ----------------------------------------------------------------- default virtual vehicles (§3.1)
def test_default_virtual_vehicles_match_section_3_1():
    x, y, vx, vy, h = default_virtual_vehicles(X(100.0), X(3.5), L(1))
    # C_ID = 1: (1 - 2 C_ID) = -1, so the adjacent defaults sit one lane to the left (y = 0)
    assert x.tolist() == [[150.0, 150.0, 50.0, 50.0]]
    assert y.tolist() == [[3.5, 0.0, 3.5, 0.0]]
    assert vx.tolist() == [[10.0, 10.0, 0.0, 0.0]]
    assert vy.abs().sum() == 0 and h.abs().sum() == 0
    _, y0, _, _, _ = default_virtual_vehicles(X(0.0), X(0.0), L(0))
    assert y0.tolist() == [[0.0, 3.5, 0.0, 3.5]]


# ----------------------------------------------------------------- rule mapping, Eq. 31
def test_eq31_m_l_corner_and_centre_clauses():
    y = X(0.0, 0.2, 0.3, 1.75, 2.3, 3.5)
    m = near_boundary(y, torch.zeros(6))
    # corners at y ± 1: δ_min = |y + 1 - 1.75|: 0.75, 0.55, 0.45 (<0.5); centre on the line (|0|<0.6);
    # y = 2.3: corner 1.3 is 0.45 from the line; lane-1 centre: 0.75
    assert m.tolist() == [False, False, True, True, True, False]


def test_eq31_heading_rotates_the_corners_towards_the_boundary():
    # y = 0, φ = 0.2: front-right corner at 2.5 sin 0.2 + 1 cos 0.2 = 1.4768, 0.273 from the line
    assert near_boundary(X(0.0), X(0.2)).tolist() == [True]
    assert abs(2.5 * math.sin(0.2) + math.cos(0.2) - 1.4768) < 1e-4


def test_eq31_misses_a_car_turning_in_steeply_which_crossing_toward_flags():
    # the traced two-lane crash (docs/paper-notes.md, profiles): centre y = 0.62, heading 0.541 rad. Corners
    # y ± 2.5 sin φ ± 1 cos φ: front-left 0.62 + 1.287 + 0.857 = 2.764 (1.01 over the line at 1.75),
    # front-right 1.050 (0.70 short), rear corners 0.19 and -1.52: no δ_k < 0.5, centre 1.13 away
    y, h = X(0.62, 0.62, 0.62, 0.62), X(0.541, -0.541, 0.0, 0.541)
    assert near_boundary(y, h).tolist() == [False, False, True, False]
    ego_y = X(3.5, 3.5, 3.5, -3.5)  # ego in the other lane, except the last (behind the SV's back)
    # heading toward the ego and crossing: flagged; turning away (its nose crosses nothing: corners <= 1.05),
    # straight (no corner over the line) and heading away from the ego's side: not
    assert crossing_toward(y, h, ego_y).tolist() == [True, False, False, False]
    assert abs(0.62 + 2.5 * math.sin(0.541) + math.cos(0.541) - 2.764) < 1e-3


# ----------------------------------------------------------------- rule mapping, Eq. 32
def test_eq32_r_prime_clears_close_adjacent_vehicles_when_adjacent_lane_unsafe():
    r = B([True, True, True, False])  # R2 ∧ R4 false
    dx = X(20.0, 5.0, -20.0, -30.0)
    r_prime, _ = rule_mapping(r[None], B(True), B([False] * 4)[None], dx[None])
    assert r_prime[0].tolist() == [True, False, True, False]  # SV2 within ε_s = 10 m is cleared
    r_prime, _ = rule_mapping(r[None], B(False), B([False] * 4)[None], dx[None])
    assert r_prime[0].tolist() == r.tolist()  # ego not near the boundary: unchanged


def test_eq32_r_star_grouped_and_per_index_readings():
    r = B([True, False, True, True])[None]
    m_sv = B([False, True, False, False])[None]  # SV2 cutting in over the boundary
    dx = X(20.0, 30.0, -20.0, -20.0)[None]
    _, grouped = rule_mapping(r, B(False), m_sv, dx)
    assert grouped[0].tolist() == [False, False, True, True]  # R*1 = R*2 = R'1 ∧ R'2
    _, per_index = rule_mapping(r, B(False), m_sv, dx, grouped=False)
    assert per_index[0].tolist() == [True, False, True, True]
    _, rear = rule_mapping(B([True, True, False, True])[None], B(False), B([False, False, False, True])[None], dx)
    assert rear[0].tolist() == [True, True, False, False]


# ----------------------------------------------------------------- action and control mapping, Eqs. 34-35
def test_eq34_keep_actions_target_the_current_lane_and_lane_change_the_other():
    a = L(FASTER, IDLE, SLOWER, LANE_CHANGE, LANE_CHANGE)
    c = L(0, 1, 0, 0, 1)
    t = target_lane_local(a, c, B(*[False] * 5), B(*[True] * 5), B(*[True] * 5), X(*[10.0] * 5), X(*[10.0] * 5))
    assert t.tolist() == [0, 1, 0, 1, 0]


def test_eq35_lane_change_near_the_boundary_refined_by_rear_rules():
    n = 6
    a = L(*[LANE_CHANGE] * n)
    c = L(*[0] * n)
    r3 = B(False, True, False, False, True, False)
    r4 = B(True, False, False, False, True, False)
    dx3 = X(10.0, 10.0, 20.0, 5.0, 10.0, 7.0)
    dx4 = X(10.0, 10.0, 5.0, 20.0, 10.0, 7.0)
    t = target_lane_local(a, c, B(*[True] * n), r3, r4, dx3, dx4)
    # ¬R3∧R4 -> change; R3∧¬R4 -> stay; both unsafe: SV3 farther -> stay, SV4 farther -> change;
    # both safe -> C_ID (completes a change once the centre has crossed, aborts it before); tie -> C_ID
    assert t.tolist() == [1, 0, 0, 1, 0, 0]


def test_hold_reading_keeps_the_previous_target_for_keep_actions():
    t = target_lane_local(L(IDLE, LANE_CHANGE), L(0, 0), B(True, False), B(True, True), B(True, True),
                          X(1.0, 1.0), X(1.0, 1.0), previous_target=L(1, 0))
    assert t.tolist() == [1, 1]


def test_target_speed_steps_and_clips():
    a = L(FASTER, IDLE, SLOWER, LANE_CHANGE, FASTER, SLOWER)
    v = X(5.0, 5.0, 5.0, 5.0, 9.8, 0.5)
    assert torch.allclose(target_speed(a, v), X(5.4375, 5.0, 4.25, 5.0, 10.0, 0.0))
