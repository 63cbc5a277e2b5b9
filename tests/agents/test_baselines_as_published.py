"""Each baseline's defining behaviour as §4.2 and its cited work describe it (docs/paper-notes.md, Baselines)."""

from types import SimpleNamespace

import torch

from highway_srl.agents.baselines import RL, TAKEOVER_TTC_S, takeover_trigger, time_to_collision
from highway_srl.agents.gating import EXPERT_NAMES
from highway_srl.agents.rule_based import rule_based_action
from highway_srl.agents.trainer import Trainer
from highway_srl.rules import FASTER, IDLE, LANE_CHANGE, SLOWER
from highway_srl.rules.raw import LANE_LEFT


def _watch(trainer, check, vector_steps: int = 60):
    """Run the trainer, calling check(step, decision) on every decision; ε = 1 (random proposals) here."""
    decide = trainer.method.decide

    def watched(learner, step, explore, generator):
        d = decide(learner, step, explore, generator)
        check(step, d)
        return d

    trainer.method.decide = watched
    for _ in range(vector_steps):
        trainer.step()


def test_rl_executes_its_highest_q_action_even_when_table_1_forbids_it():
    q = torch.tensor([[5.0, 1.0, 0.0, 0.0, 0.0]]).repeat(2, 1)  # Faster is worth most
    mask5 = torch.tensor([[False, True, True, False, False]] * 2)  # ... and forbidden (R1 = 0)
    model = SimpleNamespace(obs=torch.zeros(2, 37), mask5=mask5)
    step = SimpleNamespace(two_models=torch.zeros(2, dtype=torch.bool), primary=model, select=lambda _: model)
    learner = SimpleNamespace(online=lambda x: q.unsqueeze(0).expand(x.shape[0], -1, -1),
                              action_mask=torch.ones(1, 5, dtype=torch.bool))
    d = RL("two-lane", 1, {}).decide(learner, step, torch.zeros(2, dtype=torch.bool), None)
    assert d.action.tolist() == [FASTER, FASTER]


def test_sr_rl_never_executes_a_forbidden_action_while_one_is_allowed(short_config):
    config = short_config("sr-rl")
    config.traffic = "C"
    seen = {"forbidden": 0, "steps": 0}

    def check(step, d):
        model = step.select(d.use_second)
        assert model.mask5.any(1).all()  # an allowed action always exists ...
        assert model.mask5.gather(1, d.action[:, None]).all()  # ... and it is what runs
        seen["forbidden"] += int((~model.mask5).sum())
        seen["steps"] += 1

    _watch(Trainer(config), check)
    assert seen["forbidden"] > 0  # level C has states where Table 1 forbids something


def test_without_mapping_the_first_expert_acts_even_where_table_1_forbids_its_action(short_config):
    config = short_config("moe-rm-srl", options={"no_mapping": True})
    config.traffic = "C"
    trainer = Trainer(config)
    seen = {"forbidden_run": 0}

    def check(step, d):
        model = step.select(d.use_second)
        assert (d.member % len(EXPERT_NAMES) == 0).all()  # E1,1 every time: the gate rejects nothing
        seen["forbidden_run"] += int((~model.mask.gather(1, d.action[:, None])).sum())

    _watch(trainer, check)
    assert seen["forbidden_run"] > 0


def test_time_to_collision_and_the_takeover_trigger_golden_values():
    ttc = time_to_collision(torch.tensor([10.0, 10.0, 10.0, -1.0]), torch.tensor([6.0, 4.0, -1.0, 1.0]))
    assert torch.allclose(ttc[:2], torch.tensor([10 / 6, 2.5])) and ttc[2] == float("inf") and ttc[3] == 0.0
    # ego at 10 m/s; SV1 10 m ahead at 4 m/s (TTC 1.67 s), or at 6 m/s (2.5 s); SV4 5 m behind at 13 m/s
    gaps = torch.tensor([[10.0, 50.0, 50.0, 5.0], [10.0, 50.0, 50.0, 5.0], [10.0, 50.0, 50.0, 5.0]])
    vx = torch.tensor([[4.0, 10.0, 0.0, 13.0], [6.0, 10.0, 0.0, 13.0], [6.0, 10.0, 0.0, 13.0]])
    model = SimpleNamespace(gaps_m=gaps, vehicles=SimpleNamespace(vx=vx), t_id=torch.zeros(3, dtype=torch.long),
                            lanes=SimpleNamespace(c_id=torch.zeros(3, dtype=torch.long)))
    proposal = torch.tensor([IDLE, IDLE, LANE_CHANGE])
    fired = takeover_trigger(model, torch.full((3,), 10.0), proposal)
    assert TAKEOVER_TTC_S == 2.0 and fired.tolist() == [True, False, True]  # the last: SV4 closes in 1.67 s


def test_et_rl_expert_acts_only_on_its_trigger_and_forbidden_proposals_run_otherwise(short_config):
    config = short_config("et-rl")
    config.traffic = "C"
    trainer = Trainer(config)
    method = trainer.method
    seen = {"takeovers": 0, "forbidden_run": 0, "quiet": 0}

    def check(step, d):
        model = step.select(d.use_second)
        ego_v = torch.hypot(step.snapshot.ego_vx, step.snapshot.ego_vy)
        expert = rule_based_action(model, ego_v, "two-lane", hold_lane_change=True)
        assert torch.equal(d.action, torch.where(method.takeover, expert, method.proposal))
        allowed = model.mask.gather(1, d.action[:, None]).squeeze(1)
        seen["takeovers"] += int(method.takeover.sum())
        seen["quiet"] += int((~method.takeover).sum())
        seen["forbidden_run"] += int((~method.takeover & ~allowed).sum())

    _watch(trainer, check)
    assert seen["takeovers"] > 0 and seen["quiet"] > seen["takeovers"]
    assert seen["forbidden_run"] > 0  # not a shield: Table 1 does not decide when the expert acts


def test_an_et_rl_lane_change_under_way_completes_when_the_expert_drives(short_config):
    # the expert drives every step (threshold +inf); its lane changes must end in the other lane, not be
    # cancelled by its own LaneChange request near the boundary (Eq. 35)
    config = short_config("et-rl", options={"takeover_ttc_s": float("inf")})
    config.envs = 32
    trainer = Trainer(config)
    start = trainer.world.ego_lane.clone()
    crossed = torch.zeros_like(start, dtype=torch.bool)
    for _ in range(200):
        trainer.step()
        crossed |= trainer.world.ego_lane != start
    assert int(crossed.sum()) >= 6  # 9 of 32 here; 2 when the expert was told the layer does not hold
