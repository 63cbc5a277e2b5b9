"""Scenario specs (highway_srl/scenarios.py): the lookup and the consistency of every spec's fields."""

import pytest

from highway_srl.constants import SCENARIOS
from highway_srl.rules.reward_machine import FLAG_ARGUMENT
from highway_srl.scenarios import CRUISE, EXIT, MERGE, SPECS, scenario_spec
from highway_srl.sim.road import make_road


def test_every_scenario_has_a_spec_of_its_name():
    assert tuple(SPECS) == SCENARIOS
    for name in SCENARIOS:
        assert scenario_spec(name).name == name


@pytest.mark.parametrize("bad", ["three-lane", "", "Merge", None])
def test_unknown_scenario_is_a_one_line_error_naming_the_allowed_ones(bad):
    with pytest.raises(ValueError) as err:
        scenario_spec(bad)
    message = str(err.value)
    assert "\n" not in message
    assert all(name in message for name in SCENARIOS)


@pytest.mark.parametrize("name", SCENARIOS)
def test_spec_fields_are_consistent(name):
    spec = scenario_spec(name)
    assert spec.task in (CRUISE, MERGE, EXIT)
    ramp = spec.ramp_span_m is not None
    assert ramp == (spec.task != CRUISE) == (spec.change_zone is not None)
    if ramp:
        assert spec.change_zone in spec.zones and spec.progress_zone in spec.zones
    assert spec.success_flag is None or spec.success_flag in spec.stage_flags
    assert set(spec.stage_flags) <= set(FLAG_ARGUMENT)
    lanes = spec.mainline_lanes + ramp
    assert all(0 <= k < lanes for k in spec.ego_start_lanes)
    # the SUMO edges cover every lane and the links join existing edges
    ids = {e.id for e in spec.sumo_edges}
    assert {k for e in spec.sumo_edges for k in range(e.first_lane, e.first_lane + e.lanes)} == set(range(lanes))
    assert all(fe in ids and te in ids for fe, _, te, _ in spec.sumo_links)
    assert set(spec.sumo_route_edges) <= ids and (spec.sumo_off_ramp_edge in ids or spec.sumo_off_ramp_edge is None)


@pytest.mark.parametrize("name", SCENARIOS)
def test_road_follows_its_spec(name):
    spec, road = scenario_spec(name), make_road(name)
    assert road.spec is spec
    assert road.mainline_lanes == spec.mainline_lanes and road.zones == spec.zones
    assert road.has_ramp == (spec.ramp_span_m is not None)
    if road.has_ramp:
        assert (road.lane_start_m[-1], road.lane_end_m[-1]) == spec.ramp_span_m
        assert road.change_window_m[-1] == spec.zones[spec.change_zone]
        assert road.lane_drop[-1] == spec.ramp_drops


def test_only_exit_success_ends_the_episode_and_only_merge_success_is_a_flag():
    assert [n for n, s in SPECS.items() if s.success_terminates] == ["exit"]
    assert {n: s.success_flag for n, s in SPECS.items() if s.success_flag} == {"merge": "merged"}


def test_success_rate_is_reported_for_the_ramp_tasks_only_and_gym_names_are_distinct():
    assert [n for n, s in SPECS.items() if s.reports_success] == ["merge", "exit"]
    assert len({s.gym_name for s in SPECS.values()}) == len(SPECS) and all(s.gym_name for s in SPECS.values())
