"""Reward machines (§2.4) and the paper's highway RM (§3.2, Eqs. U1-U4, r_RM, v*) with the scenario rewards (§4.3).

A reward machine is ⟨U, u0, δ_u, δ_r⟩. Here it is batched: states are long tensors (B,) of indices into
`states`, propositions are any object of (B, ...) tensors, δ_u(u, σ) -> u' and δ_r(u, u', σ) -> reward.

The highway RM is state-based: u_{t+1} = δ_u(u_t, σ_{t+1}) depends only on the propositions evaluated
on the state reached after the action (σ_{t+1}), not on u_t:
  lane keeping   K = ¬m_L ∧ (d_VL < w_L/2)        (the prose: aligned with the target lane)
  u1 = K ∧ R1,  u2 = K ∧ ¬R1,  u3 = ¬K ∧ (R1 ∧ R2 ∧ R3 ∧ R4),  u4 = ¬K ∧ (¬R1 ∨ ¬R2 ∨ ¬R3 ∨ ¬R4)
(Eqs. U3/U4 lack brackets; read as (m_L ∨ d_VL >= w_L/2) ∧ (...), so the four states partition the
propositions). With the rule mapping, m_L is m*_L,EV (Eq. 31) and R_i is R*_SVi (Eq. 32).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Generic, TypeVar

import torch

from highway_srl.constants import EPISODE_STEPS, LANE_WIDTH_M, V_MAX_MPS
from highway_srl.scenarios import RewardTerm, scenario_spec

# the keyword argument of the reward functions that carries each stage flag of the specs' reward terms
FLAG_ARGUMENT = {"merged": "r_merge", "exit1": "r_exit1", "exit2": "r_exit2"}


def weighted_sum(main_weight: float, main: torch.Tensor, terms: tuple[RewardTerm, ...],
                 inputs: dict[str, torch.Tensor | None]) -> torch.Tensor:
    """main_weight * main + each term's weight * (sum of its inputs), added left to right in the spec's order
    (the order fixes the float rounding, so it is the order the paper's equations are written in). (B,)"""
    r = main if main_weight == 1.0 else main_weight * main
    for term in terms:
        total = inputs[term.inputs[0]].to(main.dtype)
        for name in term.inputs[1:]:
            total = total + inputs[name].to(main.dtype)
        r = r + term.weight * total
    return r

P = TypeVar("P")

RM_STATES: tuple[str, ...] = ("u1", "u2", "u3", "u4")
U1, U2, U3, U4 = range(4)
NUM_RM_STATES = len(RM_STATES)

# d_ACC (§3.2, not given by the paper): the front gap (bumper to bumper) under which the ego is "following"
# SV1 in ACC fashion: 2 s of headway at v_max = 20 m, about twice the sound safe distance at v_max to a
# standing vehicle (10.4 m), so a following ego sees v* = v_SV1 before the rule fails.
D_ACC_M = 2.0 * V_MAX_MPS
# Collision reward (§4.3 gives -320 for the ramps): -n_max, the same on every scenario, so that a
# collision costs as much as the best episode earns; consistent with R_r's -n_max n_col (Tables 5-6).
COLLISION_REWARD = -float(EPISODE_STEPS)
V_STAR_MIN_MPS = 1e-3  # below this, v* counts as 0: the ratio v/v* is then 1 (the ego cannot be slower)


@dataclass(frozen=True)
class RewardMachine(Generic[P]):
    """⟨U, u0, δ_u, δ_r⟩ of §2.4 over a batch: transition(u (B,), σ) -> u' (B,); reward(u, u', σ) -> (B,)."""

    states: tuple[str, ...]
    initial_state: int
    transition: Callable[[torch.Tensor, P], torch.Tensor]
    reward: Callable[[torch.Tensor, torch.Tensor, P], torch.Tensor]

    def __post_init__(self) -> None:
        if not 0 <= self.initial_state < len(self.states):
            raise ValueError(f"initial_state {self.initial_state} is not one of 0..{len(self.states) - 1}")

    def initial(self, batch_size: int, device: torch.device | str | None = None) -> torch.Tensor:
        """(B,) long filled with u0."""
        return torch.full((batch_size,), self.initial_state, dtype=torch.long, device=device)

    def step(self, u: torch.Tensor, props: P) -> tuple[torch.Tensor, torch.Tensor]:
        """One transition of every env: u_{t+1} = δ_u(u_t, σ), r = δ_r(u_t, u_{t+1}, σ)."""
        u_next = self.transition(u, props)
        return u_next, self.reward(u, u_next, props)


@dataclass
class HighwayPropositions:
    """σ of the highway RM for B envs: m_l (B,) bool = m*_L,EV; d_vl_m (B,) = |y_local - T*_ID w_L|;
    r_sv (B, 4) bool = R*_SV1..4; v_ego_mps (B,) longitudinal speed; v_star_mps (B,) desired speed."""

    m_l: torch.Tensor
    d_vl_m: torch.Tensor
    r_sv: torch.Tensor
    v_ego_mps: torch.Tensor
    v_star_mps: torch.Tensor
    lane_width_m: float = LANE_WIDTH_M


def lane_keeping(m_l: torch.Tensor, d_vl_m: torch.Tensor, lane_width_m: float = LANE_WIDTH_M) -> torch.Tensor:
    """Eqs. U1-U4: the lane-keeping mode ¬m_L ∧ (d_VL < w_L/2) (B,) bool; its complement is lane changing."""
    return ~m_l & (d_vl_m < 0.5 * lane_width_m)


def reward_machine_state(
    m_l: torch.Tensor, d_vl_m: torch.Tensor, r_sv: torch.Tensor, lane_width_m: float = LANE_WIDTH_M
) -> torch.Tensor:
    """Eqs. U1-U4 with the prose's brackets: (B,) long in {U1, U2, U3, U4}; r_sv (B, 4) bool."""
    keep = lane_keeping(m_l, d_vl_m, lane_width_m)
    all_safe = r_sv.all(dim=-1)
    r1 = r_sv[..., 0]
    u_keep = torch.where(r1, U1, U2)
    u_change = torch.where(all_safe, U3, U4)
    return torch.where(keep, u_keep, u_change).long()


def desired_speed(
    gap_sv1_m: torch.Tensor,
    v_sv1_mps: torch.Tensor,
    r_sv: torch.Tensor,
    *,
    d_acc_m: float = D_ACC_M,
    v_max_mps: float = V_MAX_MPS,
) -> torch.Tensor:
    """v*_EV,x (§3.2): v_SV1 if (gap to SV1 <= d_ACC) ∧ (some R_i false), else v_max; (B,).

    gap_sv1_m is the bumper gap (the paper's Δx_SV1 with point masses); r_sv (B, 4) bool.
    """
    follow = (gap_sv1_m <= d_acc_m) & ~r_sv.all(dim=-1)
    return torch.where(follow, v_sv1_mps.clamp(min=0.0), torch.full_like(v_sv1_mps, v_max_mps))


def speed_ratio(v_ego_mps: torch.Tensor, v_star_mps: torch.Tensor) -> torch.Tensor:
    """v / v*, clipped to [0, 1], and 1 where v* ~ 0 (guard); (B,).

    The clip keeps the per-step reward <= 1, which is what the paper's 'at most 320 per episode' needs
    (v* = v_SV1 may be below the ego's speed).
    """
    safe = v_star_mps > V_STAR_MIN_MPS
    ratio = v_ego_mps.clamp(min=0.0) / torch.where(safe, v_star_mps, torch.ones_like(v_star_mps))
    return torch.where(safe, ratio.clamp(max=1.0), torch.ones_like(ratio))


def rm_reward(u: torch.Tensor, v_ego_mps: torch.Tensor, v_star_mps: torch.Tensor) -> torch.Tensor:
    """r_RM (§3.2): v/v* in u1 or u3, else 0; (B,)."""
    paid = (u == U1) | (u == U3)
    return torch.where(paid, speed_ratio(v_ego_mps, v_star_mps), torch.zeros_like(v_ego_mps))


def highway_reward_machine() -> RewardMachine[HighwayPropositions]:
    """The paper's four-state RM; δ_u ignores u_t (state-based), δ_r pays r_RM on the state reached."""

    def transition(u: torch.Tensor, p: HighwayPropositions) -> torch.Tensor:
        return reward_machine_state(p.m_l, p.d_vl_m, p.r_sv, p.lane_width_m)

    def reward(u: torch.Tensor, u_next: torch.Tensor, p: HighwayPropositions) -> torch.Tensor:
        return rm_reward(u_next, p.v_ego_mps, p.v_star_mps)

    return RewardMachine(RM_STATES, U1, transition, reward)


def scenario_reward(
    scenario: str,
    r_rm: torch.Tensor,
    collided: torch.Tensor,
    *,
    r_merge: torch.Tensor | None = None,
    r_exit1: torch.Tensor | None = None,
    r_exit2: torch.Tensor | None = None,
    collision_reward: float = COLLISION_REWARD,
) -> torch.Tensor:
    """Training reward (§4.3), (B,): collision_reward (-320) on collision, else
    two-lane / multi-lane: r_RM;  merge: 0.7 r_RM + 0.3 r_merge;  exit: 0.5 r_RM + 0.25 r_exit,1 + 0.25 r_exit,2.

    r_merge, r_exit1, r_exit2: (B,) 0/1 latched stage flags from the environment (merge: the ego has
    reached the stability zone in a mainline lane; exit1: it has entered lane 1, next to the off-ramp;
    exit2: it has entered the off-ramp lane 2).
    """
    spec = scenario_spec(scenario)
    given = {"merged": r_merge, "exit1": r_exit1, "exit2": r_exit2}
    missing = [FLAG_ARGUMENT[i] for t in spec.training_terms for i in t.inputs if given[i] is None]
    if missing:
        raise ValueError(f"scenario {scenario!r} needs the stage flags {', '.join(missing)}")
    r = weighted_sum(spec.training_main_weight, r_rm, spec.training_terms, given)
    return torch.where(collided.bool(), torch.full_like(r, collision_reward), r)
