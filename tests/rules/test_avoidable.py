"""The ego-avoidable verdict and the RSS safe distance (rules/avoidable.py): golden values and cases."""

from __future__ import annotations

import math

import pytest
import torch

from highway_srl.rules.avoidable import (
    CUT_IN,
    EGO_CHANGED,
    EGO_MOVED_IN,
    FORBIDDEN_ACTION,
    NEEDLESS_BRAKE,
    RAN_INTO,
    REAR,
    ROAD,
    SIDE_KEEPING,
    SIDE_ROOM,
    SIDE_SWIPE,
    STOOD,
    in_path,
    braked_sideways,
    ego_avoidable,
    lateral_danger_from,
    lateral_safe_distance,
    proper_lateral_speed,
    rss_safe_distance,
    stopping_distance_steps,
)
from highway_srl.rules.safe_distance import safe_distance

ALL = ["Faster", "Idle", "Slower", "LaneChange"]


def test_rss_safe_distance_golden_values():
    # Lemma 2 by hand: 10·0.125 + ½·3.5·0.125² + (10 + 0.4375)²/12 - 0 = 1.25 + 0.02734375 + 9.07845052...
    assert float(rss_safe_distance(10.0, 0.0)) == pytest.approx(10.355794270833334, abs=1e-12)
    assert float(rss_safe_distance(10.0, 10.0)) == pytest.approx(10.355794270833334 - 100 / 12, abs=1e-12)
    assert float(rss_safe_distance(0.0, 10.0)) == 0.0  # the leader is faster: [.]_+ clamps
    # ρ = 1 s, a_max,accel = 2, a_min,brake = 4, a_max,brake = 8: 5 + 1 + 7²/8 - 5²/16 = 10.5625
    assert float(rss_safe_distance(5.0, 5.0, response_s=1.0, accel_max=2.0, brake_min=4.0, brake_max=8.0)) == 10.5625
    with pytest.raises(ValueError, match="positive decelerations"):
        rss_safe_distance(5.0, 5.0, brake_min=0.0)


def test_rss_equals_the_sound_front_safe_distance_on_the_papers_parameters():
    """Equal brakes (6/6), ρ = δt, the follower may accelerate at 3.5 during ρ: the sound Eqs. 19-27 and
    RSS's Lemma 2 are the same number (case C of Eq. 24 is Lemma 2; case B needs |a_L| < |a_F|)."""
    v = torch.linspace(0.0, 10.0, 41, dtype=torch.float64)
    ve, vo = torch.meshgrid(v, v, indexing="ij")
    assert torch.allclose(safe_distance(ve, vo, front=True), rss_safe_distance(ve, vo), atol=1e-9)


def test_stopping_distance_steps_matches_the_simulators_integration():
    """Braking at 6 m/s² every step of the simulator's own integration (sim.dynamics.integrate_speed, exact
    kinematics where a car stops within a step) covers v² / (2 · 6) to the stop."""
    from highway_srl.sim.dynamics import integrate_speed

    def stepped(v, brake=6.0, dt=0.125):
        d, speed = 0.0, torch.tensor([[v]], dtype=torch.float64)
        while float(speed) > 0:
            speed, mean = integrate_speed(speed, torch.tensor([[-brake]], dtype=torch.float64), dt, 30.0)
            d += float(mean) * dt
        return d

    assert stopping_distance_steps(0.75) == pytest.approx(0.046875)
    assert stopping_distance_steps(10.0) == pytest.approx(100 / 12)  # 13 full steps, then 0.25 m/s to the stop
    assert stopping_distance_steps(0.0) == 0.0
    for v in (0.1, 0.4, 0.44, 3.3, 7.5, 9.99, 10.0):
        assert stopping_distance_steps(v) == pytest.approx(stepped(v), abs=1e-9)


def row(dx, dy=0.0, v=8.0, v_sv=6.0, action="Idle", allowed=ALL, r1=True):
    return {"action": action, "allowed": list(allowed), "r1": r1, "v": v, "dx": dx, "dy": dy, "v_sv": v_sv}


def test_a_forced_cut_in_at_zero_metres_is_unavoidable():
    rows = [row(5.5, dy=3.5), row(5.0, dy=3.2), row(4.8, dy=2.9), row(4.6, dy=2.5)]  # bumper gap 0 m on entry
    assert ego_avoidable("front", False, True, rows) == (False, CUT_IN)
    # into the path during the colliding step itself: no decision could answer it
    assert ego_avoidable("front", False, True, rows[:1]) == (False, CUT_IN)


def test_a_car_coming_in_from_beside_or_behind_is_unavoidable_however_fast_it_is():
    """The falsifier's exit B case: the ego stands centred in its lane, a car from the next lane 3.5 m behind
    at 11.6 m/s turns in and meets its side. At the entry its centre is 2.2 m behind the ego's (bumper gap
    -7.2 m): room_to_stop, meant for a leader, would credit the car's own 8.6 m braking distance and call it
    room; a car not ahead of the ego's front leaves none."""
    rows = [row(-4.86, dy=-3.5, v=0.0, v_sv=11.64, action="Slower"), row(-3.46, dy=-3.36, v=0.0, v_sv=10.89),
            row(-2.2, dy=-3.12, v=0.44, v_sv=10.14, action="Faster"), row(-1.08, dy=-2.88, v=0.88, v_sv=9.39)]
    assert ego_avoidable("side", False, True, rows) == (False, SIDE_SWIPE)
    assert ego_avoidable("front", False, True, rows) == (False, CUT_IN)


def test_a_car_that_drove_up_from_behind_in_the_path_all_along_is_unavoidable():
    """The 10^6-episode sweep's two-lane A case: the ego stands 0.31 m off its lane's centre after an aborted
    change (so a car centred in the next lane is 3.2 m aside, inside the path margin, all along) with Faster
    allowed; a car of the next lane drives up from 9.6 to 4.0 m behind and turns into its side. Never ahead of
    the ego, it is the rear car and the lateral mover: RSS's. A car standing beside while the ego creeps away
    from it (the multi-lane F case: 1.8 -> 2.0 m behind, speed 0) did not drive up: doubt, avoidable."""
    dx = [-9.6 + 0.24 * k for k in range(24)]
    drove_up = [row(d, dy=3.2 if k < 20 else 3.0, v=0.0 if k < 18 else 0.4, v_sv=2.0, allowed=["Faster", "Idle"])
                for k, d in enumerate(dx)]
    assert ego_avoidable("side", False, True, drove_up) == (False, SIDE_SWIPE)
    creeping_away = [row(-1.8 - 0.01 * k, dy=3.1, v=0.4 * (k % 2), v_sv=0.0, action="Faster", allowed=ALL)
                     for k in range(24)]
    assert ego_avoidable("side", False, True, creeping_away) == (True, SIDE_ROOM)
    # ahead of the ego's centre at one decision, or closing by less than a metre: the follower's doubt again
    assert ego_avoidable("side", False, True, [row(0.5, dy=3.2), *drove_up[1:]]) == (True, SIDE_ROOM)
    assert ego_avoidable("side", False, True, drove_up[-4:]) == (True, SIDE_ROOM)


def test_a_cut_in_with_room_to_brake_is_avoidable():
    rows = [row(22.0, dy=3.5), row(21.0, dy=2.2), row(15.0), row(9.0), row(5.0)]  # 16 m gap, 8 vs 6 m/s
    assert ego_avoidable("front", False, True, rows) == (True, RAN_INTO)


def test_the_ego_accelerating_into_a_stopped_car_is_avoidable():
    rows = [row(25.0 - 1.2 * k, v=8.0 + 0.4 * k, v_sv=0.0, action="Faster") for k in range(8)]
    assert ego_avoidable("front", False, False, rows) == (True, RAN_INTO)
    rows[-1]["allowed"] = ["Slower"]  # and with Faster forbidden at the last decision, that is named first
    assert ego_avoidable("front", False, False, rows) == (True, FORBIDDEN_ACTION)


def test_a_standing_ego_with_no_allowed_move_is_not_responsible():
    """RSS: a car at standstill has performed the proper response (zero speed, longitudinal and lateral).
    The ego stands through the last second (8 decisions) with Slower alone allowed while a car turning in stays within the
    path margin (the traced multi-lane F case: without the standstill case doubt makes it avoidable)."""
    alongside = [row(2.5 + 0.2 * k, dy=2.3 - 0.1 * k, v=0.0, v_sv=1.4, action="Slower", allowed=["Slower"])
                 for k in range(8)]
    assert ego_avoidable("side", False, True, alongside) == (False, STOOD)
    assert ego_avoidable("front", False, True, alongside) == (False, STOOD)
    # a move allowed at any decision, or the ego moving at one: doubt again, avoidable
    assert ego_avoidable("side", False, True, [{**alongside[0], "allowed": ALL}, *alongside[1:]]) == (True, SIDE_ROOM)
    assert ego_avoidable("side", False, True, [{**alongside[0], "v": 0.5}, *alongside[1:]]) == (True, SIDE_ROOM)
    # the last second decides: braking to a stop before it (the falsifier's two-lane D case: Slower alone
    # from 3 m/s, then standing while a car alongside turned in across its front corner) changes nothing
    braked = [row(2.4, dy=-2.9, v=3.0 - 0.75 * k, v_sv=0.0, action="Slower", allowed=["Slower"]) for k in range(4)]
    assert ego_avoidable("side", False, True, braked + alongside) == (False, STOOD)
    assert ego_avoidable("side", False, True, braked + alongside[:7]) == (True, SIDE_ROOM)  # 7 standing decisions
    # behind: the rear case keeps its own reason
    assert ego_avoidable("rear", False, False, [row(-6.0, v=0.0, v_sv=5.0, action="Slower", allowed=["Slower"], r1=False)]) == (False, REAR)


def test_an_ego_changing_lanes_counts_as_changing_into_the_car_only_if_it_moved_sideways_toward_it():
    """RSS's lateral rule blames the car that moved sideways toward the other. The traced merge C case: the
    ego stands centred in lane 1 (y 3.59) with LaneChange's target lane 2, so the census counts it as
    changing lanes; a car from lane 0 behind turns in and meets its side. It has not moved toward that car,
    so the side case judges it (the car came in from out of the path, from behind: no room, unavoidable).
    The same for a change stalled half-way (y 2.09, the traced multi-lane A case), for an ego moving away
    and for one settling toward its own lane's centre (lane 1's is 3.5); 0.2 m (LATERAL_MOVE_M) or more
    toward the car past that centre within the trace is changing into it."""
    standing = [{**row(-6.3 + 0.6 * k, dy=-3.5 + 0.3 * k, v=0.0, v_sv=6.0, action="LaneChange",
                       allowed=["Faster", "Idle", "LaneChange"]), "y": 3.59, "lane": 1} for k in range(8)]
    assert ego_avoidable("side", True, True, standing) == (False, SIDE_SWIPE)
    stalled = [{**s, "y": 2.09} for s in standing]
    assert ego_avoidable("side", True, True, stalled) == (False, SIDE_SWIPE)
    creeping = [{**s, "v": 0.44} for s in standing]  # moving on along its lane is not moving sideways
    assert ego_avoidable("side", True, True, creeping) == (False, SIDE_SWIPE)
    # the car is below it (dy < 0): toward is down, past lane 1's centre 3.5
    assert ego_avoidable("side", True, True, [*standing[:-1], {**standing[-1], "y": 3.5 - 0.2}]) == (True, EGO_CHANGED)
    assert ego_avoidable("side", True, True, [*standing[:-1], {**standing[-1], "y": 3.5 - 0.19}]) == (False, SIDE_SWIPE)
    assert ego_avoidable("side", True, True, [*standing[:-1], {**standing[-1], "y": 4.2}]) == (False, SIDE_SWIPE)
    # from 4.3 (above the centre) down to 3.6: 0.7 m toward the car, none of it past the centre (the uniform
    # ego's multi-lane A case, mirrored: its nose up at 0.4 rad, it crept toward its own lane's centre)
    settling = [{**s, "y": 4.3 - 0.1 * k} for k, s in enumerate(standing)]
    assert ego_avoidable("side", True, True, settling) == (False, SIDE_SWIPE)
    assert ego_avoidable("side", True, True, [{**s, "y": None} for s in standing]) == (True, EGO_CHANGED)
    # a stalled ego met by a car keeping its lane: the side case with neither changing, doubt on the ego
    assert ego_avoidable("side", True, False, stalled) == (True, SIDE_KEEPING)


def test_rss_lateral_safe_distance_golden_values():
    """RSS Definition 4 in the 'toward each other' form, μ = 0.1, ρ = 0.125 s, a_lat,accel = 0.2, a_lat,brake =
    0.8 m/s² (ad-rss's and CARLA's defaults). By hand, both standing: μ + 2 (½·0.2·0.125² + 0.025²/1.6) =
    0.1 + 2 (0.0015625 + 0.000390625) = 0.10390625; the ego at 0.5 m/s toward a car standing sideways:
    0.1 + (0.0625 + 0.0015625 + 0.525²/1.6) + 0.001953125 = 0.338281..; a car moving away faster than
    it can accelerate toward: its travel counts negative (it brakes to a stop moving away)."""
    assert lateral_safe_distance(0.0, 0.0) == pytest.approx(0.10390625, abs=1e-12)
    assert lateral_safe_distance(0.5, 0.0) == pytest.approx(0.1 + 0.0625 + 0.0015625 + 0.525 ** 2 / 1.6 + 0.001953125,
                                                            abs=1e-12)
    away = -1.0 * 0.125 + 0.0015625 - 0.975 ** 2 / 1.6
    assert lateral_safe_distance(0.5, -1.0) == pytest.approx(0.1 + max(0.0, 0.0625 + 0.0015625 + 0.525 ** 2 / 1.6 + away))
    assert lateral_safe_distance(0.0, -3.0) == 0.1  # [.]_+ clamps, μ stays
    # ρ = 1 s, a = 1, b = 1, u = 1 each: μ + 2 (1 + 0.5 + 2²/2) = 7.1
    assert lateral_safe_distance(1.0, 1.0, response_s=1.0, accel=1.0, brake=1.0) == pytest.approx(7.1)


def test_the_blame_time_is_the_start_of_the_last_dangerous_run():
    """A car two lanes over (dy 7 m) is no lateral danger to an ego changing lanes toward it at 0.5 m/s;
    once it turns in toward the ego (h_sv −0.25 at 8 m/s: 2 m/s sideways) with the gap closing, it is."""
    far = {**row(-4.0, dy=7.0, v=2.0, v_sv=8.0), "y": 1.0, "h": 0.245, "h_sv": 0.0}
    near = {**row(-2.0, dy=3.5, v=2.0, v_sv=8.0), "y": 2.0, "h": 0.245, "h_sv": -0.25}
    assert lateral_danger_from([far, far, near, near]) == 2
    assert lateral_danger_from([near, far, near]) == 2  # the last unbroken run
    assert lateral_danger_from([far, far]) == 1  # never dangerous: the last decision only
    assert lateral_danger_from([{**far, "h": None}, far]) == 1
    assert lateral_danger_from([near, {**far, "h_sv": None}]) == 0  # a missing heading is danger (doubt)


def test_a_car_that_kept_its_line_did_not_come_in_the_ego_moved_into_it():
    """The RSS oracle's two-lane F case (paper profile, uniform ego): the ego, changing lanes at 1-2.5 m/s with
    its nose up to 0.48 rad, slows while its centre drifts 0.45 m toward a car standing in the next lane
    (speed 0, heading 0) and its front meets that car's rear in the colliding step. Its lateral speed fell fast
    enough for RSS's lateral response, so case 3 passes it; the car, outside the path margin at first, is
    inside it from the seventh decision with its centre 4.6 m ahead (no bumper gap), and the front case read
    that as a car coming in alongside. That car never moved; the ego brought itself into its path, which is
    the ego's to avoid (RSS: the one that moved sideways into the other)."""
    ys = [0.03, 0.04, 0.07, 0.12, 0.19, 0.28, 0.35, 0.41, 0.46, 0.48]
    vs = [0.87, 1.31, 1.31, 1.74, 2.15, 2.54, 1.77, 1.04, 1.02, 0.34]
    hs = [0.05, 0.09, 0.13, 0.18, 0.25, 0.34, 0.39, 0.43, 0.46, 0.48]
    drift = [{**row(5.91 - 0.19 * k, dy=3.58 - y, v=v, v_sv=0.0, action="Slower"), "y": y, "h": h, "lane": 0,
              "h_sv": 0.0} for k, (y, v, h) in enumerate(zip(ys, vs, hs))]
    assert [in_path(r) for r in drift] == [False] * 6 + [True] * 4
    assert ego_avoidable("front", True, False, drift) == (True, EGO_MOVED_IN)
    assert ego_avoidable("front", False, False, drift) == (True, EGO_MOVED_IN)
    # the same geometry with the car turning in by 0.1 m (RSS's lateral margin μ) or more before the entry,
    # from wherever it was: it came in, at no gap
    came_in = [{**r, "dy": r["dy"] - 0.025 * k} for k, r in enumerate(drift)]
    assert [in_path(r) for r in came_in] == [False] * 5 + [True] * 5
    assert ego_avoidable("front", False, True, came_in) == (False, CUT_IN)
    # a car that kept its line until the ego's drift brought it into the path, then turned in: it came in
    turned = [*drift[:-2], *({**r, "dy": r["dy"] - 0.15} for r in drift[-2:])]
    assert ego_avoidable("front", True, True, turned) == (False, CUT_IN)
    # without the lateral positions the front case stands as before
    assert ego_avoidable("front", False, False, [{**r, "y": None} for r in drift]) == (False, CUT_IN)


def test_braking_sideways_is_the_rss_lateral_response():
    """u = v tan h toward the car may grow by 0.2·δt within ρ (one decision), then must fall by 0.8·δt a
    decision until 0. Braking at 6 m/s² at a fixed heading does it; settling on at the same speed does not."""
    h = math.atan(0.5 / 4.0)  # 0.5 m/s sideways at 4 m/s
    braking = [{"v": 4.0 - 0.75 * k, "h": h} for k in range(5)]
    assert braked_sideways(braking, 1.0)
    assert not braked_sideways([{"v": 4.0, "h": h}] * 3, 1.0)
    assert braked_sideways([{"v": 4.0, "h": h}] * 2, 1.0)  # within the response time
    assert braked_sideways([{"v": 4.0, "h": -h}] * 5, 1.0)  # moving away
    assert not braked_sideways([{"v": 4.0, "h": None}] * 2, 1.0)


def test_a_change_into_room_answered_once_the_car_turned_in_is_not_the_egos():
    """The traced exit A case, in short: the ego entered a free lane at 0.5 m/s sideways; a car from two lanes
    over turned into that lane behind it. Settling on after the blame time is changing into it; braking
    sideways from then on is RSS's proper response, and the side case judges the other car."""
    h = math.atan(0.5 / 1.0)
    before = [{**row(-6.0 + 0.5 * k, dy=4.8 - 0.05 * k, v=1.0, v_sv=8.0), "y": 1.2 + 0.06 * k, "h": h, "h_sv": 0.0,
               "lane": 0} for k in range(6)]
    turning = [{**row(-3.0 + 0.7 * k, dy=4.3 - 0.3 * k, v=1.0, v_sv=8.0), "y": 1.6 + 0.06 * k, "h": h,
                "h_sv": -0.25, "lane": 0} for k in range(4)]
    assert lateral_danger_from(before + turning) == 6
    assert ego_avoidable("side", True, True, before + turning) == (True, EGO_CHANGED)
    braking = [{**r, "v": max(0.0, 1.0 - 0.5 * k)} for k, r in enumerate(turning)]
    assert ego_avoidable("side", True, True, before + braking) == (False, SIDE_SWIPE)


def test_the_holds_speed_cap_slows_the_lateral_speed_by_the_rss_braking():
    """proper_lateral_speed: after one step of unwinding at the yaw limit (v / 4 m, at most 0.8 rad/s, and
    K_HEADING·h), v' sin h' = v sin h − 0.8·δt; an aligned ego keeps its speed."""
    from highway_srl.sim.dynamics import K_HEADING, MIN_TURN_RADIUS_M, YAW_RATE_MAX

    v, h = torch.tensor([1.0, 8.0, 5.0]), torch.tensor([0.55, 0.25, 0.0])
    cap = proper_lateral_speed(v, h)
    for k in range(2):
        yaw = min(K_HEADING * float(h[k]), float(v[k]) / MIN_TURN_RADIUS_M, YAW_RATE_MAX)
        h_next = float(h[k]) - yaw * 0.125
        assert float(cap[k]) * math.sin(h_next) == pytest.approx(float(v[k]) * math.sin(float(h[k])) - 0.1, abs=1e-5)
    assert float(cap[2]) == 5.0


def test_the_other_cases():
    assert ego_avoidable("road", False, False, [row(0.0)]) == (True, ROAD)
    assert ego_avoidable("side", True, False, [row(0.0, dy=2.0)]) == (True, EGO_CHANGED)
    assert ego_avoidable("front", True, False, [row(5.0)]) == (True, EGO_CHANGED)
    assert ego_avoidable("side", False, True, [row(1.0, dy=3.5), row(0.5, dy=2.8)]) == (False, SIDE_SWIPE)
    assert ego_avoidable("side", False, True, [row(25.0, dy=3.5), row(24.0, dy=3.0)]) == (True, SIDE_ROOM)
    assert ego_avoidable("side", False, False, [row(1.0, dy=2.5)]) == (True, SIDE_KEEPING)
    follower = [row(-6.0, v=8.0, v_sv=9.0)]  # 1 m behind, faster: it needs ~8 m to stop for the ego
    assert ego_avoidable("rear", False, False, follower) == (False, REAR)
    follower[0]["action"] = "Slower"
    assert ego_avoidable("rear", False, False, follower) == (True, NEEDLESS_BRAKE)
    follower[0]["r1"] = False  # braking that the car ahead required is no fault
    assert ego_avoidable("rear", False, False, follower) == (False, REAR)
    unseen = [{**row(5.0), "dx": None, "dy": None, "v_sv": None}] * 3
    assert ego_avoidable("front", False, True, unseen) == (True, RAN_INTO)  # doubt falls on avoidable
    with pytest.raises(ValueError, match="unknown collision kind"):
        ego_avoidable("above", False, False, [])


def test_rss_safe_distance_agrees_with_intel_ad_rss_where_it_is_installed():
    """An implementation nobody here wrote: ad-rss (the [rss] extra) through rules.rss_oracle."""
    pytest.importorskip("ad_rss")
    from highway_srl.rules.rss_oracle import ad_rss_safe_distance

    for v_rear, v_front in ((10.0, 0.0), (10.0, 10.0), (5.0, 5.0), (0.0, 0.0), (5.0, 10.0), (7.3, 2.1)):
        assert ad_rss_safe_distance(v_rear, v_front) == pytest.approx(float(rss_safe_distance(v_rear, v_front)),
                                                                       abs=1e-9)
    behind = dict(accel_max=0.0, brake_min=6.0, brake_max=6.0)  # the SV behind keeps its speed during δt
    assert ad_rss_safe_distance(10.0, 0.0, **behind) == pytest.approx(float(rss_safe_distance(10.0, 0.0, **behind)))