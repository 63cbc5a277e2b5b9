"""The paper's adversary (§4.3, group 3; sim/adversary.py) next to the mild one, and the per-episode
counters of triggers and cut-ins (docs/paper-notes.md, "The paper's adversary")."""

import pytest
import torch

from highway_srl.agents.registry import make_method
from highway_srl.constants import VEHICLE_LENGTH_M
from highway_srl.sim import World
from highway_srl.sim.lane_tables import LaneTables
from highway_srl.sim.adversary import cut_ins_whatever_the_gaps
from highway_srl.sim.state import WorldState

W = 3.5


def staged(scenario="two-lane", ego_x=50.0, ego_lane=1, sv=(1, 0, 0.0), offset=5.0, abp=1.0):
    """A one-env world whose SV 1 is at bumper gap sv[2] (m, ahead if sv[1] >= 0, else behind) in lane
    sv[0] with threshold `offset` and probability `abp`; every other SV is parked 200 m ahead in lane 0,
    out of reach."""
    torch.set_num_threads(1)
    world = World(scenario, "C", True, 1, "cpu", 3, adversary="paper")
    s = world.state
    s.x[:, 1:], s.lane[:, 1:], s.y[:, 1:] = ego_x + 200.0 + torch.arange(s.x.shape[1] - 1) * 10.0, 0, 0.0
    s.x[0, 0], s.lane[0, 0], s.y[0, 0] = ego_x, ego_lane, ego_lane * W
    s.target_lane.copy_(s.lane)
    lane, ahead, gap = sv
    s.x[0, 1] = ego_x + (1 if ahead >= 0 else -1) * (gap + VEHICLE_LENGTH_M)
    s.lane[0, 1], s.target_lane[0, 1], s.y[0, 1] = lane, lane, lane * W
    s.adversarial_prob[0, 1], s.trigger_offset[0, 1] = abp, offset
    s.adversarial_prob[0, 2:] = 0.0
    return world, LaneTables.of(world.road, "cpu")


def fired(world) -> bool:
    s = world.state
    return bool(s.forced[0, 1]) and int(s.target_lane[0, 1]) == int(s.lane[0, 0])


@pytest.mark.parametrize("offset,gap,fires", [(5.0, 4.9, True), (5.0, 5.1, False), (10.0, 9.9, True),
                                              (0.0, 0.1, False), (0.0, -2.0, True)])
def test_trigger_is_the_bumper_gap_below_the_sampled_threshold(offset, gap, fires):
    """|d_trig - d_SVi| in {0, 5, 10} m against the bumper gap |Δx| - L: 0 m fires only alongside."""
    world, tables = staged(sv=(0, 1, gap), offset=offset)
    cut_ins_whatever_the_gaps(world.state, tables)
    assert fired(world) is fires
    counts = world.adversary_counts()
    assert counts["triggers"].tolist() == [int(fires)] and counts["cut_ins"].tolist() == [int(fires)]


def test_an_sv_behind_or_alongside_also_cuts_in_whatever_the_gap():
    for ahead, gap in ((-1, 3.0), (1, -5.0)):  # 3 m behind; exactly alongside
        world, tables = staged(sv=(0, ahead, gap), offset=5.0)
        cut_ins_whatever_the_gaps(world.state, tables)
        assert fired(world)


def test_the_trigger_is_drawn_once_per_episode_with_the_styles_probability():
    world, tables = staged(sv=(0, 1, 1.0), offset=5.0, abp=0.0)
    cut_ins_whatever_the_gaps(world.state, tables)
    assert not fired(world) and not bool(world.state.trigger_used[0, 1])  # ABP 0: not a candidate
    world, tables = staged(sv=(0, 1, 1.0), offset=5.0, abp=1e-9)  # drawn, does not fire
    cut_ins_whatever_the_gaps(world.state, tables)
    assert not fired(world) and bool(world.state.trigger_used[0, 1])
    world.state.adversarial_prob[0, 1] = 1.0
    cut_ins_whatever_the_gaps(world.state, tables)
    assert not fired(world)  # already drawn this episode
    assert world.adversary_counts()["triggers"].tolist() == [1] and world.adversary_counts()["cut_ins"].tolist() == [0]


def test_only_adjacent_lanes_and_never_into_a_lane_that_ends():
    world, tables = staged(scenario="multi-lane", ego_lane=0, sv=(2, 1, 1.0))  # two lanes away
    cut_ins_whatever_the_gaps(world.state, tables)
    assert not fired(world)
    world, tables = staged(scenario="multi-lane", ego_lane=1, sv=(2, 1, 1.0))  # from the right
    cut_ins_whatever_the_gaps(world.state, tables)
    assert fired(world)
    merging = World("merge").road.zones["merging"]
    world, tables = staged(scenario="merge", ego_x=sum(merging) / 2, ego_lane=2, sv=(1, 1, 1.0))
    cut_ins_whatever_the_gaps(world.state, tables)
    assert not fired(world)  # the ego is on the on-ramp, which ends: no SV is sent there


def test_counters_reset_per_episode_and_stay_zero_in_nominal_traffic():
    world = World("two-lane", "C", True, 4, "cpu", 11, adversary="paper")
    counts = torch.zeros(4, dtype=torch.long)
    for _ in range(200):
        world.step(world.ego_lane, torch.full((4,), 8.0))
        counts = torch.maximum(counts, world.adversary_counts()["triggers"])
    assert int(counts.sum()) > 0
    world.reset(torch.tensor([True, False, True, False]))
    after = world.adversary_counts()["triggers"]
    assert after[0] == 0 and after[2] == 0
    state = WorldState(**{k: v for k, v in vars(world.state).items()})  # a resumed world keeps them
    assert torch.equal(state.adv_triggers, world.state.adv_triggers)
    nominal = World("two-lane", "C", False, 4, "cpu", 11, adversary="paper")
    for _ in range(100):
        nominal.step(nominal.ego_lane, torch.full((4,), 8.0))
    assert int(nominal.adversary_counts()["triggers"].sum()) == 0


def test_a_state_saved_before_the_counters_existed_loads_with_zero_counters():
    world = World("two-lane", "C", True, 2, "cpu", 0)
    old = {k: v for k, v in vars(world.state).items() if not k.startswith("adv_")}
    assert WorldState(**old).adv_cut_ins.tolist() == [0, 0]


def test_unknown_adversary_is_a_value_error_naming_the_choices():
    with pytest.raises(ValueError, match="mild, paper"):
        World("two-lane", adversary="harsh")


def rule_based_collisions(adversary: str, profile: str = "paper") -> tuple[int, int]:
    torch.set_num_threads(1)
    world = World("two-lane", "C", True, 100, "cpu", 10**9, adversary=adversary)
    method = make_method("rule-based", "two-lane", 1, profile=profile)
    layer = method.make_layer(world.road)
    alive, collided = torch.ones(100, dtype=torch.bool), torch.zeros(100, dtype=torch.bool)
    cut_ins = torch.zeros(100, dtype=torch.long)
    step = layer.observe(world)
    for _ in range(world.max_steps):
        decision = method.decide(None, step, torch.zeros(100, dtype=torch.bool), None)
        events = world.step(*layer.act(decision.action, decision.use_second))
        step = layer.observe(world)
        cut_ins = torch.where(alive, world.adversary_counts()["cut_ins"], cut_ins)
        collided |= alive & events.collision
        alive &= ~(events.terminated | events.truncated)
    return int(collided.sum()), int(cut_ins.sum())


def test_paper_adversary_makes_the_rule_based_driver_collide_more_than_the_mild_one():
    """The issue's check: 100 adversarial two-lane level-C episodes (evaluation seeds 10^9...) of the
    rule-based driver under its default (paper) profile. Paper adversary: C_r < 100 % (4 collisions when
    written, 3 since the driver takes the built-in drivers' gap rule); mild: C_r 100 % when written, 99 %
    with the gap rule (env 27: a forced SV stops half-way across the line beside the 2.6 m/s ego, which
    accelerates into its corner; the paper profile's Eq. 31 does not flag it). Under the safe profile mild
    stays at 100 % since its turning_in_is_near (before it, one collision: a forced SV crawling at 1.5 m/s
    from 15 m ahead turned in at up to 0.58 rad and its nose reached the ego while Eq. 31 flagged none of
    its corners; docs/paper-notes.md)."""
    paper, paper_cut = rule_based_collisions("paper")
    mild, mild_cut = rule_based_collisions("mild")
    assert paper > 0 and paper > mild and mild <= 1
    assert paper_cut > 0 and mild_cut > 0
    assert rule_based_collisions("mild", "safe")[0] == 0  # the crash that turning_in_is_near was added for
