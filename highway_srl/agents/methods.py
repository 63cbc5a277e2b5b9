"""Training methods: what differs between MoE-RM-SRL, its ablations and the baselines.

A method decides the action from the rule layer's view of the step, names the learner member that owns
the transition, computes the training reward and updates its members. The trainer does everything else,
so each method is the few lines that make it different.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from highway_srl.agents.dqn import DQNLearner, UpdateStats
from highway_srl.agents.gating import EXPERT_NAMES, NUM_EXPERTS, expert_action_mask, gate_tables
from highway_srl.agents.moe import MoEPolicy, seed_of_env
from highway_srl.agents.replay import ExpertReplay
from highway_srl.constants import DEFAULT_PROFILE
from highway_srl.rules import ACTIONS, SafetyLayer, choose_second, control_profile, may_use_second, scenario_reward


@dataclass
class Decision:
    action: torch.Tensor  # (B,) long, index into the rule layer's A* = ACTIONS
    member: torch.Tensor  # (B,) long, learner member that owns the transition; -1: none
    use_second: torch.Tensor | None  # (B,) bool, multi-lane: the middle-right model decided


class Method:
    """Base class with the MoE-RM-SRL defaults for reward, storage and updates.

    profile: the control profile of every rule layer the method makes (rules.PROFILES: "paper", "safe")."""

    name = "base"
    trains = True  # False: nothing is learned (the rule-based driver)
    out_dim = 4
    uses_cost = False
    layer_options: dict = {}

    def __init__(self, scenario: str, seeds: int, options: dict, profile: str = DEFAULT_PROFILE):
        control_profile(profile)  # one-line error naming the profiles
        self.scenario, self.seeds, self.options, self.profile = scenario, seeds, dict(options), profile

    num_members: int = 1
    action_names: tuple[str, ...] = ACTIONS  # what Decision.action indexes (5-action baselines: FIVE_ACTIONS)

    def make_layer(self, road):
        """The rule layer this method observes and acts through (trainer, evaluate, render)."""
        return SafetyLayer(road, profile=self.profile, **self.layer_options)

    def safe_mask(self, model) -> torch.Tensor:
        """(B, len(action_names)) bool: the safe actions of a model step, in action_names order."""
        return model.mask

    def action_mask(self) -> torch.Tensor:
        raise NotImplementedError

    # columns of the uniforms (B, draw_width) decide reads for its random actions; 0: it draws none
    draw_width: int = 0

    def decide(self, learner, step, explore: torch.Tensor, u: torch.Tensor | None) -> Decision:
        """The decision on the layer's view step (SafetyStep). explore (B,) bool: the ε-greedy draw; u
        (B, draw_width) uniforms in [0, 1) for the random actions (drawn by the caller, so that a traced step
        takes them as an input), or None where explore is all False (evaluation: no draw)."""
        raise NotImplementedError

    def reward(self, scenario, nxt, events, flags) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The paper's RM reward (§3.2, §4.3): r_RM, or its merge/exit mix; -320 on collision."""
        r = scenario_reward(scenario, nxt.r_rm, events.collision, **flags.reward_inputs())
        return r, None

    def store(self, replay: ExpertReplay, d: Decision, obs, reward, next_obs, done, cost, share: bool = False):
        replay.add(d.member, obs, d.action, reward, next_obs, done, cost)

    def updatable(self, acted_count: torch.Tensor, sizes: torch.Tensor, batch_size: int) -> torch.Tensor:
        """(M,) bool, the members to train after a vector step in which member m acted in acted_count[m]
        (M,) envs: Algorithm 1 trains the member that acted, once its buffer (sizes (M,)) holds a batch."""
        return (acted_count > 0) & (sizes >= batch_size)

    def trained_members(self, device) -> torch.Tensor:
        """(K,) long: every member that can ever be chosen by `updatable` (the static form updates these
        under a mask)."""
        return torch.arange(self.num_members, device=device)

    def update(self, learner: DQNLearner, members: torch.Tensor, batch: dict,
               mask: torch.Tensor | None = None) -> UpdateStats:
        """One gradient step of each of members (K,) on its batch; mask (K,) bool: only those (static form)."""
        if mask is None:
            return learner.update(members, batch)
        return learner.update_masked(members, batch, mask)

    def start(self, batch: int, device: torch.device, static: bool) -> None:
        """Called by the trainer of batch envs on device before its first step and after a resume: the
        static form keeps whatever state the method carries on the device from the start (a traced step
        then sees the same tensors every step)."""

    def after_step(self, trainer, cost, done) -> None:
        """Called after each vector step's updates with its cost signal (B,) (None for methods without one)
        and the envs whose episode ended (B,) bool."""

    def state_dict(self) -> dict[str, torch.Tensor]:
        return {}

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        pass


class MoERMSRL(Method):
    """MoE-RM-SRL (§3.4): 11 experts per seed over the subsets of A*, PoG when exploiting, ExG when exploring."""

    name = "moe-rm-srl"
    draw_width = NUM_EXPERTS  # ExG: a random proposal of every expert

    def __init__(self, scenario, seeds, options, profile=DEFAULT_PROFILE):
        super().__init__(scenario, seeds, options, profile)
        self.policy = MoEPolicy(seeds)
        self.num_members = self.policy.members_per_seed * seeds
        self.member_names = list(EXPERT_NAMES)

    def action_mask(self) -> torch.Tensor:
        return self.policy.action_mask()

    def start(self, batch, device, static) -> None:
        gate_tables(device)

    def gate_mask(self, model) -> torch.Tensor:
        """(B, 4) bool: the actions the sparse gate treats as safe (Table 1 on R*_SV)."""
        return model.mask

    def decide(self, learner, step, explore, u) -> Decision:
        use_second = None
        if may_use_second(step):
            v1 = self.policy.value(learner, step.primary.obs, self.gate_mask(step.primary))
            v2 = self.policy.value(learner, step.second.obs, self.gate_mask(step.second))
            use_second = choose_second(v1, v2, step.two_models)
        model = step.select(use_second)
        action, member = self.policy.act(learner, model.obs, self.gate_mask(model), explore, u)
        return Decision(action, member, use_second)

    def store(self, replay, d, obs, reward, next_obs, done, cost, share=False):
        if not share:
            return super().store(replay, d, obs, reward, next_obs, done, cost, share)
        # off-policy option: every expert (of the env's own seed) whose action set holds the executed action
        per = self.policy.members_per_seed
        holds = expert_action_mask(obs.device)[:, d.action].T  # (B, 11)
        b = obs.shape[0]
        seed = seed_of_env(b, self.seeds, obs.device)
        mask = torch.zeros(b, self.num_members, dtype=torch.bool, device=obs.device)
        cols = seed[:, None] * per + torch.arange(per, device=obs.device)
        mask.scatter_(1, cols, holds)
        replay.add_shared(mask, obs, d.action, reward, next_obs, done, cost)
