"""The ablations of MoE-RM-SRL (Table 6): the full method with one or more of its parts removed.

  no_mapping  the raw view over A* (no ID/rule/action/control mapping) and so no R*_SV for the gate to read:
              every action passes it, so E1,1 always acts (it can pick an action Table 1 forbids)
  no_rm       the speed reward instead of r_RM
  no_moe      one DQN over A*, no gate and so no shield (with the RM reward: rm-rl)
"""

from __future__ import annotations

import torch

from highway_srl.agents.baselines import SingleDQN, speed_reward
from highway_srl.agents.methods import MoERMSRL
from highway_srl.constants import DEFAULT_PROFILE
from highway_srl.rules.raw import RawSafetyLayer

ABLATIONS = ("no_mapping", "no_moe", "no_rm")


def ablation_name(options: dict) -> str:
    return "moe-rm-srl/" + "+".join(k for k in ABLATIONS if options.get(k))


class MoEAblation(MoERMSRL):
    """MoE-RM-SRL with the mappings (no_mapping: the raw view over A*, nothing for the gate to reject) and/or
    the RM reward (no_rm: the speed reward) removed; the 11 experts and the gate stay."""

    def __init__(self, scenario, seeds, options, profile=DEFAULT_PROFILE):
        super().__init__(scenario, seeds, options, profile)
        self.no_mapping, self.no_rm = bool(self.options.get("no_mapping")), bool(self.options.get("no_rm"))
        self.name = ablation_name(self.options)

    def make_layer(self, road):
        return RawSafetyLayer(road, five_actions=False, profile=self.profile) if self.no_mapping else super().make_layer(road)

    def gate_mask(self, model):
        # w/o MAP: the rule mapping is what turns the raw R_SVi into the R*_SV the gate checks; without it
        # nothing is rejected, so the first expert's action executes (the paper's T_c = 0 for this variant)
        return torch.ones_like(model.mask) if self.no_mapping else model.mask

    def reward(self, scenario, nxt, events, flags):
        if self.no_rm:
            return speed_reward(scenario, nxt.obs, events, flags), None
        return super().reward(scenario, nxt, events, flags)


class NoMoE(SingleDQN):
    """w/o MoE: one DQN over A*, no gate and so no shield; what is left of the safety logic is the RM reward
    (this is rm-rl; with no_mapping on the raw view, with no_rm on the speed reward)."""

    allowed_options = frozenset(ABLATIONS)

    def __init__(self, scenario, seeds, options, profile=DEFAULT_PROFILE):
        super().__init__(scenario, seeds, options, profile)
        self.view = "raw" if self.options.get("no_mapping") else "mapped"
        self.reward_kind = "speed" if self.options.get("no_rm") else "rm"
        self.name = ablation_name(self.options)
