"""MoE-RM-SRL's acting rule (§3.4, Algorithms 1-3): 11 experts, sparsely gated by the safe-action mask.

Several independent agents (seeds) can share one learner: the learner holds S * 11 members and env b
belongs to seed b // (B / S). Each seed's experts only ever see their own envs' data.
"""

from __future__ import annotations

import torch

from highway_srl.agents.dqn import DQNLearner
from highway_srl.agents.gating import NUM_EXPERTS, expert_action_mask, polite_gate, random_expert_actions


def seed_of_env(batch: int, seeds: int, device=None) -> torch.Tensor:
    """(B,) long: the seed (agent) each env belongs to; the B envs are split into `seeds` equal blocks."""
    return torch.arange(batch, device=device) // (batch // seeds)


def grouped_q(learner: DQNLearner, obs: torch.Tensor, seeds: int, members_per_seed: int) -> torch.Tensor:
    """Q-values of each env's own seed's members: obs (B, D) -> (B, members_per_seed, out), masked to -inf
    outside each member's action set. B must be a multiple of seeds."""
    b, d = obs.shape
    per = b // seeds
    x = obs.reshape(seeds, 1, per, d).expand(seeds, members_per_seed, per, d).reshape(seeds * members_per_seed, per, d)
    with torch.no_grad():
        q = learner.online(x)  # (S*m, per, out)
    q = q.masked_fill(~learner.action_mask.unsqueeze(1), float("-inf"))
    return q.reshape(seeds, members_per_seed, per, -1).permute(0, 2, 1, 3).reshape(b, members_per_seed, -1)


class MoEPolicy:
    """The gated experts. act() returns the executed action, the acting member (global index, -1 for the
    final fallback) and, for the multi-lane model choice, the value of each env's greedy safe action."""

    members_per_seed = NUM_EXPERTS
    out_dim = 4

    def __init__(self, seeds: int = 1):
        self.seeds = seeds

    def action_mask(self) -> torch.Tensor:
        return expert_action_mask().repeat(self.seeds, 1)

    def value(self, learner: DQNLearner, obs: torch.Tensor, safe: torch.Tensor) -> torch.Tensor:
        """max over safe actions of E_1,1's Q: how good this two-lane model's view is (multi-lane choice)."""
        q = grouped_q(learner, obs, self.seeds, self.members_per_seed)[:, 0]
        return q.masked_fill(~safe, float("-inf")).amax(1)

    def act(
        self,
        learner: DQNLearner,
        obs: torch.Tensor,
        safe: torch.Tensor,
        explore: torch.Tensor,
        u: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """obs (B, 37), safe (B, 4) bool, explore (B,) bool (ε-greedy draw: ExG where True, PoG elsewhere),
        u (B, 11) the uniforms of ExG's random proposals (None: explore is all False, PoG everywhere)."""
        greedy = grouped_q(learner, obs, self.seeds, self.members_per_seed).argmax(-1)  # (B, 11)
        proposals = greedy if u is None else torch.where(explore.unsqueeze(1), random_expert_actions(u), greedy)
        action, expert = polite_gate(proposals, safe)
        seed = seed_of_env(obs.shape[0], self.seeds, obs.device)
        member = torch.where(expert >= 0, seed * self.members_per_seed + expert, expert)
        return action, member
