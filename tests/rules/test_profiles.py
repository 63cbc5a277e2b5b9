"""Control profiles of the SafetyLayer (docs/paper-notes.md, "Profiles: paper vs safe").

`paper` = Eqs. 31-35 as printed plus the hold of a lane change under way; `safe` = today's behaviour with
our thirteen additions. One crafted situation per addition where the two profiles differ exactly as documented,
and a golden test of Eqs. 31-35 under `paper`.
"""

import pytest
import torch

from highway_srl.constants import DEFAULT_PROFILE
from highway_srl.rules import PROFILES, RM_STATES, SafetyLayer, control_profile
from highway_srl.rules.mappings import NO_LANE, crossing_toward, reaching_over, stopping_speed
from highway_srl.rules.third_lane import third_lane
from highway_srl.rules.raw import RawSafetyLayer
from highway_srl.rules.avoidable import proper_lateral_speed
from highway_srl.rules.safe_actions import FASTER, IDLE, LANE_CHANGE, SLOWER
from highway_srl.sim import HOLD_LANE
from highway_srl.sim.road import make_road

W = 3.5


def layers(road, **kwargs):
    return {name: SafetyLayer(road, profile=name, **kwargs) for name in ("paper", "safe")}


def test_the_default_profile_is_every_entry_points_and_each_profile_sets_its_additions():
    # one default in one place: the layer's is the CLI's, the envs' and the study's (constants.DEFAULT_PROFILE)
    assert SafetyLayer(make_road("two-lane")).profile == DEFAULT_PROFILE
    assert RawSafetyLayer(make_road("two-lane")).mapped.profile == DEFAULT_PROFILE
    layer = SafetyLayer(make_road("two-lane"), profile="safe")
    options = lambda lay: (lay.abort_unsafe_change, lay.brake_while_changing, lay.finish_in_window,  # noqa: E731
                           lay.straddle_grouping, lay.standstill_gap_m, lay.turning_in_is_near, lay.last_resort_stops,
                           lay.reaching_over_is_near, lay.watch_third_lane, lay.ego_body_straddles, lay.lanes_by_body,
                           lay.back_out_of_entry, lay.hold_lateral)
    assert options(layer) == (True, True, True, True, 1.0, True, True, True, True, True, True, True, True)
    paper = SafetyLayer(make_road("two-lane"), profile="paper")
    assert options(paper) == (False, False, False, False, 0.0, False, False, False, False, False, False, False, False)
    assert paper.hold_lane_change and layer.hold_lane_change  # both hold a change under way
    assert set(PROFILES) == {"paper", "safe"}


def test_an_explicit_option_overrides_the_profile():
    layer = SafetyLayer(make_road("two-lane"), profile="paper", brake_while_changing=True, standstill_gap_m=0.5)
    assert layer.brake_while_changing and layer.standstill_gap_m == 0.5 and not layer.finish_in_window


def test_unknown_profile_is_a_value_error_naming_the_choices():
    with pytest.raises(ValueError, match="paper, safe"):
        SafetyLayer(make_road("two-lane"), profile="strict")
    with pytest.raises(ValueError, match="paper, safe"):
        control_profile("")


def test_raw_layer_takes_the_profiles_standstill_margin():
    road = make_road("two-lane")
    assert RawSafetyLayer(road, profile="safe").standstill_gap_m == 1.0
    assert RawSafetyLayer(road, profile="paper").standstill_gap_m == 0.0
    assert RawSafetyLayer(road, profile="paper").mapped.profile == "paper"


# ----------------------------------------------------------------------------- one situation per addition
def test_held_change_is_aborted_when_the_target_turns_unsafe_only_under_safe(hand_world):
    """abort_unsafe_change: LaneChange, then an SV appears 1 m behind the ego's rear bumper in the target lane
    at 12 m/s (R4 = 0); Idle holds the change under paper and returns to C_ID under safe."""
    road = make_road("two-lane")
    for name, expected in (("paper", 1), ("safe", 0)):
        world = hand_world(road, [{"ego": (0.0, 0.0, 8.0, 0.0), "svs": []}])
        layer = SafetyLayer(road, profile=name)
        layer.observe(world)
        assert layer.act(torch.tensor([LANE_CHANGE]))[0].tolist() == [1]
        world.scenes[0]["svs"].append((-6.0, W, 12.0, 0.0))
        step = layer.observe(world)
        assert step.primary.r_star[0, 3].item() is False
        assert layer.act(torch.tensor([IDLE]))[0].tolist() == [expected], name


def test_an_ego_entering_a_lane_that_turns_unsafe_backs_out_only_under_safe(hand_world):
    """back_out_of_entry: LaneChange from lane 0 to 1; the ego's centre has crossed the line (y 2.0), its body
    not yet (its lower edge at 1.0 m); a car turns up 1 m behind its rear bumper in lane 1 at 12 m/s (R3 = 0)
    while lane 0 stays empty. Idle holds the change under paper and takes the ego back to lane 0 under safe;
    centred in lane 1 (y 3.5) the same car changes nothing: the ego has entered, and R*3 is Slower's matter."""
    road = make_road("two-lane")
    for name, expected in (("paper", [1, 1]), ("safe", [0, 1])):
        world = hand_world(road, [{"ego": (0.0, 0.0, 8.0, 0.0), "svs": []}, {"ego": (0.0, 0.0, 8.0, 0.0), "svs": []}])
        layer = SafetyLayer(road, profile=name)
        layer.observe(world)
        assert layer.act(torch.tensor([LANE_CHANGE] * 2))[0].tolist() == [1, 1]
        world.scenes[0].update(ego=(2.0, 2.0, 8.0, 0.1), svs=[(-4.0, W, 12.0, 0.0)])
        world.scenes[1].update(ego=(2.0, W, 8.0, 0.0), svs=[(-4.0, W, 12.0, 0.0)])
        step = layer.observe(world)
        assert step.primary.r_star[:, 2].tolist() == [False, False] and step.primary.lanes.c_id.tolist() == [1, 1]
        assert layer.act(torch.tensor([IDLE] * 2))[0].tolist() == expected, name


def test_an_entering_ego_with_no_way_back_holds_its_lateral_position_only_under_safe(hand_world):
    """hold_lateral: the scene of the test above with a car 1 m behind in lane 0 too (R*4 = 0: no way back):
    paper settles on into lane 1, safe commands HOLD_LANE with the speed capped so that the lateral speed falls
    by RSS's 0.8 m/s² (proper_lateral_speed; 8 m/s at 0.1 rad); the layer keeps lane 1 as the change's target,
    so the change resumes once that lane is safe again. Off (hold_lateral=False) the ego settles on."""
    road = make_road("two-lane")
    for name, opts, expected in (("paper", {}, 1), ("safe", {}, HOLD_LANE), ("safe", {"hold_lateral": False}, 1)):
        world = hand_world(road, [{"ego": (0.0, 0.0, 8.0, 0.0), "svs": []}])
        layer = SafetyLayer(road, profile=name, **opts)
        layer.observe(world)
        layer.act(torch.tensor([LANE_CHANGE]))
        world.scenes[0].update(ego=(2.0, 2.0, 8.0, 0.1), svs=[(-4.0, W, 12.0, 0.0), (-4.0, 0.0, 12.0, 0.0)])
        step = layer.observe(world)
        assert step.primary.r_star[0].tolist() == [True, True, False, False]
        lane, speed = layer.act(torch.tensor([IDLE]))
        assert int(lane) == expected and int(layer.target_lane) == 1, (name, opts)
        cap = float(proper_lateral_speed(torch.tensor([8.0]), torch.tensor([0.1])))
        assert float(speed) == pytest.approx(cap if expected == HOLD_LANE else 8.0, rel=1e-5), (name, opts)


def test_lane_change_behind_an_unsafe_leader_brakes_only_under_safe(hand_world):
    """brake_while_changing: SV1 3 m ahead at 5 m/s, ego 10 m/s (R*1 = 0, Table 1 row 9 allows LaneChange):
    paper keeps the speed (LaneChange is not a speed action), safe brakes as Slower (10 - 6 x 0.125)."""
    road = make_road("two-lane")
    scene = [{"ego": (0.0, 0.0, 10.0, 0.0), "svs": [(8.0, 0.0, 5.0, 0.0)]}]
    for name, layer in layers(road).items():
        layer.observe(hand_world(road, scene))
        lane, speed = layer.act(torch.tensor([LANE_CHANGE]))
        assert lane.tolist() == [1]
        assert speed.tolist() == ([10.0] if name == "paper" else [9.25]), name


def test_change_into_the_closing_window_starts_only_under_paper(hand_world):
    """finish_in_window: 15 m before the exit's gore at 8 m/s (a change needs 24 m): paper starts it, safe
    keeps the lane."""
    road = make_road("exit")
    x2 = road.zones["diverging"][1]
    scene = [{"ego": (x2 - 15.0, W, 8.0, 0.0), "svs": []}]
    for name, layer in layers(road).items():
        layer.observe(hand_world(road, scene))
        assert layer.act(torch.tensor([LANE_CHANGE]))[0].tolist() == ([2] if name == "paper" else [1]), name


def test_ego_near_the_boundary_occupies_both_lanes_only_under_safe(hand_world):
    """straddle_grouping: ego 0.25 m from the boundary (m*_L,EV = 1), a standing car 10 m (bumper) ahead in
    the other lane (R2 = 0), nothing in its own lane (R1 = 1): paper allows Faster (R*1 = R'1 = 1),
    safe does not (R*1 = R1 ∧ R2 = 0)."""
    road = make_road("two-lane")
    scene = [{"ego": (0.0, 1.5, 10.0, 0.0), "svs": [(15.0, W, 0.0, 0.0)]}]
    for name, layer in layers(road).items():
        p = layer.observe(hand_world(road, scene)).primary
        assert p.m_l_ego.tolist() == [True] and p.r_sv[0].tolist() == [True, False, True, True]
        assert p.r_star[0, 0].item() is (name == "paper"), name
        assert p.mask[0, FASTER].item() is (name == "paper"), name


def test_standstill_margin_holds_a_standing_ego_half_a_metre_behind_a_standing_car_only_under_safe(hand_world):
    """standstill_gap_m: both stand, bumper gap 0.5 m. The SD rule (point masses, Faster allowed during δt:
    ½ 3.5 x 0.125² = 2.7 cm) says safe; with the 1 m margin the gap is -0.5 m, unsafe."""
    road = make_road("two-lane")
    scene = [{"ego": (0.0, 0.0, 0.0, 0.0), "svs": [(5.5, 0.0, 0.0, 0.0)]}]
    for name, layer in layers(road).items():
        p = layer.observe(hand_world(road, scene)).primary
        assert p.r_sv[0, 0].item() is (name == "paper"), name
        assert p.mask[0, FASTER].item() is (name == "paper"), name


def test_an_sv_turning_in_steeply_ahead_counts_as_near_the_boundary_only_under_safe(hand_world):
    """turning_in_is_near: the traced mild-adversary crash. Ego in lane 1 at 8 m/s; a forced SV crawls at
    1.5 m/s 7.5 m ahead (2.5 m bumper gap, R2 = 0) in lane 0, centre 0.62 m off its lane centre, turning in
    at 0.541 rad (its nose over the line, Eq. 31 flags no corner). Nothing ahead in the ego's lane (R1 = 1):
    paper allows Faster (R*1 = R1), safe groups the SV (R*1 = R'1 ∧ R'2 = 0). lanes_by_body off: by body the
    SV is the ego's lane's car too and R1 = 0 by itself."""
    road = make_road("two-lane")
    scene = [{"ego": (0.0, W, 8.0, 0.0), "svs": [(7.5, 0.62, 1.5, 0.541)]}]
    for name, layer in layers(road, lanes_by_body=False).items():
        p = layer.observe(hand_world(road, scene)).primary
        assert p.r_sv[0, :2].tolist() == [True, False], name
        assert p.mask[0, FASTER].item() is (name == "paper"), name


def test_a_car_with_its_tail_over_the_line_counts_as_near_the_boundary_only_under_safe(hand_world):
    """reaching_over_is_near: the traced two-lane F case. Ego in lane 0 at 1.2 m/s; a car stands in lane 1
    5.3 m ahead (0.3 m bumper gap, R2 = 0), centre 1.15 m beyond the line, heading away at 0.453 rad: its
    tail is 0.84 m into the ego's lane, no corner within ε_p of the line, so Eq. 31 and turning_in_is_near
    miss it. Nothing ahead in the ego's lane (R1 = 1): paper, and safe without the addition, allow Faster;
    safe groups the car (R*1 = R'1 ∧ R'2 = 0). lanes_by_body off, as above."""
    road = make_road("two-lane")
    scene = [{"ego": (0.0, 0.0, 1.2, 0.0), "svs": [(5.3, 2.9, 0.0, 0.453)]}]
    cases = {**layers(road, lanes_by_body=False),
             "safe without it": SafetyLayer(road, reaching_over_is_near=False, lanes_by_body=False)}
    for name, layer in cases.items():
        p = layer.observe(hand_world(road, scene)).primary
        assert p.r_sv[0, :2].tolist() == [True, False], name
        assert p.mask[0, FASTER].item() is (name != "safe"), name


def test_an_ego_with_its_nose_over_the_line_occupies_both_lanes_only_under_safe(hand_world):
    """ego_body_straddles: the traced multi-lane F case in two lanes. The ego drifts from lane 1 toward lane
    0 at -0.541 rad, centre 0.95 m from the line, its nose 1.2 m over it; Eq. 31 flags none of its corners
    (the nearest 0.52 m from the line). A car stands 5.6 m ahead in lane 0 (R2 = 0), nothing ahead in lane 1
    (R1 = 1): paper, and safe without the addition, allow Faster; safe joins R2 to R*1."""
    road = make_road("two-lane")
    scene = [{"ego": (0.0, W - 0.8, 2.1, -0.541), "svs": [(5.6, 0.0, 0.0, 0.0)]}]
    cases = {**layers(road), "safe without it": SafetyLayer(road, ego_body_straddles=False)}
    for name, layer in cases.items():
        p = layer.observe(hand_world(road, scene)).primary
        assert p.m_l_ego.tolist() == [False] and p.r_sv[0, :2].tolist() == [True, False], name
        assert p.mask[0, FASTER].item() is (name != "safe"), name


def test_reaching_over_takes_the_car_whose_centre_has_crossed_whichever_way_it_heads():
    """Ego at y_local 0 (line at 1.75). A car 1.15 m beyond the line at ±0.453 rad has its body across the
    line: reaching over either way, turning in only toward the ego. A leader leaving the ego's lane (centre
    0.6 m short of the line, heading away) is neither; a car straight in its lane centre is neither."""
    y = torch.tensor([2.9, 2.9, 1.15, 3.5])
    heading = torch.tensor([0.453, -0.453, 0.453, 0.0])
    ego = torch.zeros(4)
    assert reaching_over(y, heading, ego).tolist() == [True, True, False, False]
    assert crossing_toward(y, heading, ego).tolist() == [False, True, False, False]


def test_the_third_lane_is_the_one_beside_the_pair_where_it_exists():
    multi, two, merge = make_road("multi-lane"), make_road("two-lane"), make_road("merge")
    x = torch.tensor([50.0, 50.0])
    assert third_lane(multi, torch.tensor([0, 1]), x).tolist() == [2, 0]
    assert third_lane(two, torch.tensor([0, 0]), x).tolist() == [NO_LANE, NO_LANE]
    far = torch.tensor([merge.lane_end_m[2] + 10.0])  # past the end of the merge's ramp lane
    assert third_lane(merge, torch.tensor([0]), far).tolist() == [NO_LANE]


def test_a_third_lane_car_reaching_into_the_near_lane_joins_its_rules_only_under_safe(hand_world):
    """watch_third_lane: the traced multi-lane cases. A car of lane 2 stands turned in at -0.476 rad, centre
    at y 6.31 (its nose 1 m over the line into lane 1). Env 0: the ego in lane 0 (pair (0, 1): lane 2 is not
    in its view), the car 6 m ahead: paper allows LaneChange, safe forbids it (R*2 = 0, the car's bumper gap
    1 m). Env 1: the ego in the middle lane at 2.5 m/s, the car 1.5 m ahead (alongside): the primary model
    (0, 1) allows Faster under paper; under safe R*1 = 0."""
    road = make_road("multi-lane")
    scenes = [{"ego": (0.0, 0.0, 5.0, 0.0), "svs": [(6.0, 6.31, 0.0, -0.476)]},
              {"ego": (0.0, W, 2.5, 0.0), "svs": [(1.5, 6.31, 0.0, -0.476)]}]
    cases = {**layers(road), "safe without it": SafetyLayer(road, watch_third_lane=False)}
    for name, layer in cases.items():
        p = layer.observe(hand_world(road, scenes)).primary
        assert p.lanes.base_lane.tolist() == [0, 0], name
        assert p.mask[0, LANE_CHANGE].item() is (name != "safe"), name
        assert p.mask[1, FASTER].item() is (name != "safe"), name
        assert p.mask[0, FASTER].item(), name  # the ego's own lane is free


def test_the_egos_body_over_the_line_into_the_third_lane_makes_its_cars_the_egos_only_under_safe(hand_world):
    """watch_third_lane, the other way round: the traced nominal multi-lane E case. The ego in the middle lane
    at 2 m/s, heading 0, centre y 5.15 (its body 0.9 m over the line into lane 2) acts on the pair (0, 1);
    a car stands in lane 2, 6.4 m ahead (1.4 m bumper to bumper). Lane 1 ahead is free, so paper and safe
    without the addition allow Faster; under safe the car is the ego's lane's car ahead: R*1 = 0, and Idle's
    last-resort room is 1.4 - 1 m."""
    road = make_road("multi-lane")
    scene = [{"ego": (0.0, 5.15, 2.0, 0.0), "svs": [(6.4, 2 * W, 0.0, 0.0)]}]
    cases = {**layers(road), "safe without it": SafetyLayer(road, watch_third_lane=False)}
    for name, layer in cases.items():
        p = layer.observe(hand_world(road, scene)).primary
        assert (p.lanes.base_lane.item(), p.lanes.c_id.item()) == (0, 1), name
        assert p.mask[0, FASTER].item() is (name != "safe"), name
    room = cases["safe"].last.primary.front_room_m
    assert room.item() == pytest.approx(6.4 - 5.0 - 1.0, abs=1e-5)


def test_a_car_across_the_line_behind_the_nearest_of_its_lane_joins_the_egos_lane_only_under_safe(hand_world):
    """lanes_by_body: the traced multi-lane D case on two lanes. A car stopped mid-change at 0.6 rad, centre
    y 2.27 in lane 1, its tail 1.7 m into lane 0, 12 m ahead of an ego at 10 m/s; a car of lane 1 at 9 m/s
    8 m ahead is SV2, so no slot holds the stopped one and lane 0 looks free: paper, and safe without the
    addition, allow Faster. By body it is lane 0's car ahead, 7 m bumper to bumper, below the 10.4 m + 1 m
    the ego needs to stop behind it: R*1 = 0, and Idle at the last resort brakes to stand within 7 - 1 m."""
    road = make_road("two-lane")
    scene = [{"ego": (0.0, 0.0, 10.0, 0.0), "svs": [(12.0, 2.27, 0.0, 0.6), (8.0, W, 9.0, 0.0)]}]
    cases = {**layers(road), "safe without it": SafetyLayer(road, lanes_by_body=False)}
    for name, layer in cases.items():
        p = layer.observe(hand_world(road, scene)).primary
        assert p.mask[0, FASTER].item() is (name != "safe"), name
        assert p.gaps_m[0, 1].item() == pytest.approx(3.0), name  # the observation keeps the paper's SV2
    room = cases["safe"].last.primary.front_room_m
    assert room.item() == pytest.approx(12.0 - 5.0 - 1.0)


def test_the_front_room_is_computed_only_where_idle_stops_at_the_last_resort(hand_world):
    road = make_road("two-lane")
    scene = [{"ego": (0.0, 0.0, 5.0, 0.0), "svs": [(10.0, 0.0, 0.0, 0.0)]}]
    for name, layer in layers(road).items():
        assert (layer.observe(hand_world(road, scene)).primary.front_room_m is None) is (name == "paper"), name
    raw = RawSafetyLayer(road, profile="paper")
    assert raw.observe(hand_world(road, scene)).primary.front_room_m is None


def test_idle_as_the_last_resort_brakes_to_stand_within_the_room_ahead_only_under_safe(hand_world):
    """last_resort_stops: a follower 1 m behind at 4 m/s (R*3 = 0) and a car standing 1 m ahead in the other
    lane (R*2 = 0) leave Idle as Table 1's only action wherever R*1 = 0. Golden from Eq. 20 solved for the
    deceleration, a = v² / 2 room, room = bumper gap - 1 m margin + v_SV1² / (2 x 6), capped at 6 m/s²:
      ego 2.5 behind a standing car, gap 1.7: room 0.7, a = 4.4643, 2.5 - a δt = 1.941964;
      ego 2.5 behind a standing car, gap 1.2: room 0.2, a = 15.6 -> 6, Slower's 1.75;
      ego 6 behind a car at 6 m/s, gap 1.2: room 0.2 + 3 = 3.2, a = 5.625, 5.296875;
      ego standing, gap 0.5: room < 0, stays at 0.
    paper (and safe with the addition off) keeps the speed, Eq. 34 as printed."""
    road = make_road("two-lane")
    rows = [(2.5, 1.7, 0.0, 1.941964), (2.5, 1.2, 0.0, 1.75), (6.0, 1.2, 6.0, 5.296875), (0.0, 0.5, 0.0, 0.0)]
    scenes = [{"ego": (0.0, 0.0, v, 0.0), "svs": [(5.0 + gap, 0.0, v1, 0.0), (-6.0, 0.0, 4.0, 0.0), (6.0, W, 0.0, 0.0)]}
              for v, gap, v1, _ in rows]
    idle = torch.full((len(rows),), IDLE)
    for layer in (SafetyLayer(road, profile="safe"), SafetyLayer(road, profile="safe", last_resort_stops=False)):
        p = layer.observe(hand_world(road, scenes)).primary
        assert p.mask.tolist() == [[False, True, False, False]] * len(rows)  # Idle alone
        expected = [r[3] for r in rows] if layer.last_resort_stops else [r[0] for r in rows]
        assert layer.act(idle)[1].tolist() == pytest.approx(expected, abs=1e-5)
    paper = SafetyLayer(road, profile="paper")
    paper.observe(hand_world(road, scenes))
    assert paper.act(idle)[1].tolist() == pytest.approx([r[0] for r in rows])


def test_stopping_speed_holds_the_deceleration_that_ends_at_the_room():
    """mappings.stopping_speed: v - a δt with a = v² / (2 room); driven at that a the ego covers exactly room
    (v² / 2a); the limit (Slower) where that needs more than 6 m/s² or no room is left."""
    v = torch.tensor([4.0, 4.0, 4.0, 0.0])
    room = torch.tensor([2.0, 1.0, -0.5, 0.0])
    speed = stopping_speed(v, room)
    a = (v - speed) / 0.125
    assert speed.tolist() == pytest.approx([3.5, 3.25, 3.25, 0.0])
    assert float(v[0] ** 2 / (2 * a[0])) == pytest.approx(2.0)


# ----------------------------------------------------------------------------- Eqs. 31-35 golden, paper
def _rear(dx, lane, v):
    return (dx, lane * W, v, 0.0)


SAFE_BEHIND, UNSAFE_BEHIND = -45.0, -6.0  # 40 m bumper gap at 8 m/s / 1 m gap at 12 m/s behind an 8 m/s ego


def test_eqs_31_to_35_golden_under_the_paper_profile(hand_world):
    """Two-lane, ego in lane 0 (C_ID = 0) at 8 m/s, heading 0. Rows: (ego y, SVs, action) -> m*_L,EV (Eq. 31),
    R*_SV3, R*_SV4 (Eq. 32), T*_ID (Eqs. 34-35), target speed (§3.1 Δv_A = 3.5 δt, Δv_D = 6 δt)."""
    road = make_road("two-lane")
    rows = [
        # Eq. 34: centred (m*_L = 0), LaneChange -> 1 - C_ID whatever the rear rules say
        (0.0, [_rear(UNSAFE_BEHIND, 0, 12.0), _rear(UNSAFE_BEHIND, 1, 12.0)], LANE_CHANGE, False, (0, 0), 1, 8.0),
        # Eq. 34: Faster / Slower -> C_ID
        (0.0, [], FASTER, False, (1, 1), 0, 8.4375),
        (0.0, [], SLOWER, False, (1, 1), 0, 7.25),
        # Eq. 31: centre 1.5 m from the line at y = 1.75: the corner clause (0.5 m) -> m*_L = 1
        # Eq. 35 row 1: ¬R*3 ∧ R*4 -> 1 - C_ID
        (1.5, [_rear(UNSAFE_BEHIND, 0, 12.0), _rear(SAFE_BEHIND, 1, 8.0)], LANE_CHANGE, True, (0, 1), 1, 8.0),
        # Eq. 35 row 2: R*3 ∧ ¬R*4 -> C_ID
        (1.5, [_rear(SAFE_BEHIND, 0, 8.0), _rear(UNSAFE_BEHIND, 1, 12.0)], LANE_CHANGE, True, (1, 0), 0, 8.0),
        # Eq. 35 rows 3-4: both unsafe; Δx3 = 6 > Δx4 = 5.5 -> C_ID; Δx3 = 5.5 < Δx4 = 6 -> 1 - C_ID
        (1.5, [_rear(-6.0, 0, 12.0), _rear(-5.5, 1, 12.0)], LANE_CHANGE, True, (0, 0), 0, 8.0),
        (1.5, [_rear(-5.5, 0, 12.0), _rear(-6.0, 1, 12.0)], LANE_CHANGE, True, (0, 0), 1, 8.0),
        # Eq. 35 "otherwise": both safe -> C_ID
        (1.5, [_rear(SAFE_BEHIND, 0, 8.0), _rear(SAFE_BEHIND, 1, 8.0)], LANE_CHANGE, True, (1, 1), 0, 8.0),
        # Eq. 31: 1.6 m from the line, corners 0.6 m: neither clause -> m*_L = 0, Eq. 34 applies
        (0.15, [_rear(SAFE_BEHIND, 0, 8.0), _rear(UNSAFE_BEHIND, 1, 12.0)], LANE_CHANGE, False, (1, 0), 1, 8.0),
        # Eq. 32 R': ego near the boundary, SV4 slower 8 m behind (R4 = 1) but SV2 unsafe and |Δx4| < ε_s:
        # R'4 = 0, so R*4 = 0 -> Eq. 35 row 2 -> C_ID
        (1.5, [(6.0, W, 0.0, 0.0), _rear(-8.0, 1, 4.0)], LANE_CHANGE, True, (1, 0), 0, 8.0),
    ]
    scenes = [{"ego": (0.0, y, 8.0, 0.0), "svs": svs} for y, svs, *_ in rows]
    layer = SafetyLayer(road, profile="paper")
    p = layer.observe(hand_world(road, scenes)).primary
    lane, speed = layer.act(torch.tensor([r[2] for r in rows]))
    for b, (_, _, _, m_l, (r3, r4), t_id, v) in enumerate(rows):
        assert p.m_l_ego[b].item() is m_l, b
        assert p.r_star[b, 2:].tolist() == [bool(r3), bool(r4)], b
        assert int(lane[b]) == t_id, b
        assert float(speed[b]) == pytest.approx(v), b
    assert p.r_sv[9, 3].item() is True  # the last row: R4 itself holds, only R' clears it


def test_eq32_grouping_of_a_front_vehicle_near_the_boundary_under_paper(hand_world):
    """Eq. 32: SV2 cutting in over the boundary (y = 2.0, its corner 0.25 m from the line) is near it, so
    R*1 = R*2 = R'1 ∧ R'2 (a standing SV2 10 m ahead makes R2 = 0, and so Faster unsafe), also under paper."""
    road = make_road("two-lane")
    scene = [{"ego": (0.0, 0.0, 10.0, 0.0), "svs": [(15.0, 2.0, 0.0, 0.0)]}]
    world = hand_world(road, scene)
    p = SafetyLayer(road, profile="paper").observe(world).primary
    assert p.m_l_ego.tolist() == [False] and p.r_sv[0, :2].tolist() == [True, False]
    assert p.r_star[0, :2].tolist() == [False, False] and p.mask[0, FASTER].item() is False
    assert int(p.rm_state[0]) == RM_STATES.index("u2")
