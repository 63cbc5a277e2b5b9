"""Which methods exist: the name -> class table and `make_method`, the one way to build a method by name.

The table is written out here (no registration by import side effect); the ablations of MoE-RM-SRL are
options of "moe-rm-srl" (agents/ablations.py), not methods of their own.
"""

from __future__ import annotations

from highway_srl.agents.ablations import ABLATIONS, MoEAblation, NoMoE
from highway_srl.agents.baselines import ETRL, LMRL, MPRL, RL, RMRL, SRRL, Manual, RuleBased
from highway_srl.agents.methods import Method, MoERMSRL
from highway_srl.constants import DEFAULT_PROFILE

METHODS: dict[str, type[Method]] = {
    cls.name: cls for cls in (MoERMSRL, RL, SRRL, RMRL, MPRL, LMRL, ETRL, RuleBased, Manual)
}


def make_method(name: str, scenario: str, seeds: int, options: dict | None = None,
                profile: str = DEFAULT_PROFILE) -> Method:
    """The method `name` for `seeds` agents on `scenario`; options are its switches (moe-rm-srl: ablations);
    profile: the control profile of its rule layer ("paper" or "safe", rules.PROFILES)."""
    if name not in METHODS:
        raise ValueError(f"unknown method {name!r}; choose one of {', '.join(METHODS)}")
    if name == MoERMSRL.name and options:  # the ablations of Table 6 (and a check of the option names)
        return make_ablation(scenario, seeds, dict(options), profile)
    return METHODS[name](scenario, seeds, options or {}, profile)


def make_ablation(scenario: str, seeds: int, options: dict, profile: str = DEFAULT_PROFILE) -> Method:
    """MoE-RM-SRL with options: no_mapping, no_moe, no_rm (any combination; none set gives the full method)."""
    unknown = sorted(k for k, v in options.items() if v and k not in ABLATIONS)
    if unknown:
        raise ValueError(f"method 'moe-rm-srl' does not take option(s) {', '.join(unknown)}; "
                         f"its ablations are {', '.join(ABLATIONS)}")
    if options.get("no_moe"):
        return NoMoE(scenario, seeds, options, profile)
    if any(options.get(k) for k in ABLATIONS):
        return MoEAblation(scenario, seeds, options, profile)
    return MoERMSRL(scenario, seeds, options, profile)
