"""The RSS oracle (rules/rss_oracle.py): RSS's longitudinal responsibility rule on decision traces."""

from __future__ import annotations

import sys

import pytest

from highway_srl.rules.avoidable import rss_safe_distance
from highway_srl.rules.rss_oracle import compare, load_ad_rss, rss_verdict


def ours(v_rear, v_front):  # Lemma 2 by our own code: the verdict logic is tested without ad-rss
    return float(rss_safe_distance(v_rear, v_front))


def row(dx, dy=0.0, v=8.0, v_sv=6.0):
    return {"action": "Idle", "allowed": ["Idle"], "r1": True, "v": v, "dx": dx, "dy": dy, "v_sv": v_sv}


ASIDE = 3.5  # a car one lane over: out of the ego's path


def test_a_cut_in_below_the_safe_distance_is_the_cutters_responsibility():
    # dx 6 m = a 1 m bumper gap at 8 m/s behind 6 m/s: d_min = 8·0.125 + ½·3.5·0.125² + 8.4375²/12 - 6²/12 = 3.96 m
    assert ours(8.0, 6.0) == pytest.approx(3.9599609375, abs=1e-12)
    assert rss_verdict("front", False, True, [row(6.0, ASIDE), row(6.0)], ours) is False
    assert rss_verdict("front", False, True, [row(6.0, ASIDE)], ours) is False  # entered in the colliding step


def test_the_ego_that_runs_into_its_leader_is_responsible():
    assert rss_verdict("front", False, False, [row(30.0), row(20.0), row(6.0)], ours) is True  # in path all along
    # entered 15 m ahead (10 m bumper gap, above d_min): the ego had room and kept none
    assert rss_verdict("front", False, True, [row(15.0, ASIDE), row(15.0), row(6.0)], ours) is True


def test_rear_road_side_and_lane_changes():
    assert rss_verdict("rear", False, False, [row(-6.0)], ours) is False  # the car behind keeps d_min
    assert rss_verdict("road", False, False, [], ours) is None
    assert rss_verdict("side", False, True, [row(0.0, 2.0)], ours) is None
    assert rss_verdict("front", True, False, [row(6.0)], ours) is True  # the ego moved into the other's path


def test_an_ego_changing_lanes_is_responsible_only_if_it_moved_sideways_toward_the_car():
    """The oracle's multi-lane C cases (paper profile, adversarial): the ego stands at its lane's centre
    (y 3.49) with a lane change commanded while a car from behind turns into its side; RSS's lateral rule
    looks at lateral motion, so the side contact is left unjudged. An ego whose centre moved 0.45 m toward
    the car (the two-lane F drift into a standing car) is responsible."""
    standing = [{**row(-7.4 + 0.6 * k, 3.5 - 0.07 * k, v=0.0), "y": 3.49 - 0.001 * k} for k in range(10)]
    assert rss_verdict("side", True, True, standing, ours) is None
    drifting = [{**row(5.9 - 0.2 * k, 3.55 - 0.05 * k, v=1.0, v_sv=0.0), "y": 0.03 + 0.05 * k} for k in range(10)]
    assert rss_verdict("side", True, False, drifting, ours) is True
    assert rss_verdict("front", True, False, drifting, ours) is True
    # a change finished before the last second (from lane 0 up to 3.49) is not moving toward the car now
    assert rss_verdict("side", True, True, [{**standing[0], "y": 0.0}, *standing], ours) is None
    # 0.11 m toward is moving toward (μ = 0.1); without the lateral positions the change is the ego's
    assert rss_verdict("side", True, True, [{**standing[0], "y": 3.49}, {**standing[-1], "y": 3.6}], ours) is True
    assert rss_verdict("side", True, True, [{**r, "y": None} for r in standing], ours) is True


def test_compare_counts_both_directions():
    cut_in = {"kind": "front", "ego_changing": False, "sv_changing": True, "decisions": [row(6.0, ASIDE), row(6.0)]}
    records = [{**cut_in, "ego_avoidable": False}, {**cut_in, "ego_avoidable": True},
               {"kind": "rear", "ego_changing": False, "sv_changing": False, "decisions": [], "ego_avoidable": True},
               {"kind": "road", "ego_changing": False, "sv_changing": False, "decisions": [], "ego_avoidable": True}]
    assert compare(records, ours) == {"collisions": 4, "agree": 1, "ours_avoidable_rss_not": 2,
                                      "rss_ego_ours_not": 0, "not_judged": 1}


def test_without_ad_rss_the_oracle_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "ad_rss.ad_rss_python311", None)
    with pytest.raises(ValueError, match=r"pip install -e \".\[rss\]\""):
        load_ad_rss()


def test_ad_rss_verdicts_on_the_same_cases_where_it_is_installed():
    pytest.importorskip("ad_rss")
    assert rss_verdict("front", False, True, [row(6.0, ASIDE), row(6.0)]) is False
    assert rss_verdict("front", False, True, [row(15.0, ASIDE), row(15.0), row(6.0)]) is True
