"""The ego's low-level controller: it takes the commanded lane if that change is allowed here and tracks the
commanded speed within its acceleration and braking limits (the lateral motion is the shared controller
in sim/dynamics.py).

Besides a lane, the ego may be commanded HOLD_LANE: stop moving sideways where it is (heading back to 0, no
lateral tracking), RSS's proper lateral response, which a lane centre cannot express: a change half done,
with its target lane turning unsafe and going back swinging the body toward a car, has no safe lane to
track. While held the ego's target lane is the lane its centre is in, so the traffic sees no change."""

from __future__ import annotations

import torch

from highway_srl.constants import DT_S, EGO_ACCEL_MAX_MPS2, EGO_BRAKE_MAX_MPS2, V_MAX_MPS
from highway_srl.sim.lane_tables import LaneTables
from highway_srl.sim.state import WorldState

HOLD_LANE = -1  # the ego's lateral hold, in place of a target lane (see the module's docstring)


def ego_control(s: WorldState, tables: LaneTables, target_lane: torch.Tensor, target_speed: torch.Tensor,
                accel: torch.Tensor) -> None:
    """Accept the commanded target lane (B,) long where it is the ego's lane or an allowed change, and set
    the ego's acceleration accel[:, 0] (m/s^2) that reaches target_speed (B,) m/s within one step, clamped.
    A HOLD_LANE command sets the target lane to the ego's lane (dynamics.lateral then holds its y)."""
    ego_lane = s.lane[:, 0]
    hold = target_lane == HOLD_LANE
    target_lane = torch.where(hold, ego_lane, target_lane)
    ok = (target_lane == ego_lane) | tables.can_change(s.x[:, 0], ego_lane, target_lane)
    s.target_lane[:, 0] = torch.where(ok, target_lane, s.target_lane[:, 0])
    v_bar = target_speed.clamp(0.0, V_MAX_MPS)
    accel[:, 0] = ((v_bar - s.v[:, 0]) / DT_S).clamp(-EGO_BRAKE_MAX_MPS2, EGO_ACCEL_MAX_MPS2)
