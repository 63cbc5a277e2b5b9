"""The reduced action set A* (§3.3, action mapping) and the safe-action table (Table 1, §3.4)."""

from __future__ import annotations

import torch

# A* in the order of every action index and mask in the project.
ACTIONS: tuple[str, ...] = ("Faster", "Idle", "Slower", "LaneChange")
FASTER, IDLE, SLOWER, LANE_CHANGE = range(4)
NUM_ACTIONS = len(ACTIONS)


def safe_action_mask(r1: torch.Tensor, r2: torch.Tensor, r3: torch.Tensor, r4: torch.Tensor) -> torch.Tensor:
    """Table 1: (..., 4) bool in ACTIONS order from R*_SV1..4 (each (...) bool, broadcast).

    Read row by row, the table is: Faster ⇔ R1; Slower ⇔ R3; LaneChange ⇔ R2 ∧ R4;
    Idle ⇔ R1 ∨ (¬R3 ∧ ¬(R2 ∧ R4)), so every row has at least one safe action (Idle is the last resort
    when neither braking nor changing lanes is safe). tests/rules/test_safe_actions.py types the 16 rows in.
    """
    r1, r2, r3, r4 = torch.broadcast_tensors(*(torch.as_tensor(r, dtype=torch.bool) for r in (r1, r2, r3, r4)))
    lane_change = r2 & r4
    idle = r1 | (~r3 & ~lane_change)
    return torch.stack([r1, idle, r3, lane_change], dim=-1)


def safe_action_mask_from(r_star: torch.Tensor) -> torch.Tensor:
    """Table 1 from a stacked (..., 4) bool R*_SV1..4 tensor; returns (..., 4) bool in ACTIONS order."""
    return safe_action_mask(r_star[..., 0], r_star[..., 1], r_star[..., 2], r_star[..., 3])
