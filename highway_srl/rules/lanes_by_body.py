"""Lanes by the cars' bodies (the safe profile's `lanes_by_body`).

The paper's SV1..SV4 are the nearest cars ahead and behind in the ego's lane and the adjacent one, a car
counting for the lane of its centre (§3.1). A car standing across a lane line, its centre in one lane and
its tail or nose in the other, is in both; when a car of its centre's lane is nearer the ego, no slot holds
it, so neither Eq. 31 nor the profile's reaching-over test ever sees it. The falsifier's greedy ego found
this in multi-lane D, merge B and exit E
(`tests/rules/cases/safe-greedy-across-the-line-behind-the-nearest-*`): the ego drove
at 10 m/s toward the tail of a car stopped mid-change at 0.5-0.6 rad, second in its lane, and could not
stop when the car ahead of it moved on and the stopped one became SV2.

Here the pair's lanes are asked a second time by body (`World.neighbours(..., by_body=True)`): the nearest
car ahead and behind whose body reaches into each lane joins that lane's slot. R_SV of the slot holds only
if Eq. 26 holds for it too, and the car ahead counts in Idle's last-resort room (SV1's slot always, SV2's
where SV2 counts). The observation (the 37 inputs) is unchanged: the policy sees the paper's SV1..SV4.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from highway_srl.constants import VEHICLE_LENGTH_M
from highway_srl.rules.mappings import room_ahead
from highway_srl.sim.snapshot import Snapshot


@dataclass
class BodySlots:
    """The by-body neighbours of a pair's lanes, all (B, 4) in SV1..SV4 order: joins (a car is there and
    the slot is real: not the default SV2/SV4 of a barrier), gaps_m (bumper gaps, as ModelStep.gaps_m)
    and vx (m/s)."""

    joins: torch.Tensor
    gaps_m: torch.Tensor
    vx: torch.Tensor


def body_slots(snap: Snapshot, default_adjacent: torch.Tensor, front: torch.Tensor) -> BodySlots:
    """The slots of snap (a by-body query of the pair's lanes); default_adjacent (B,) bool: SV2/SV4 are the
    default virtual vehicles there (the rule layer ignores what is across a barrier); front (4,) bool."""
    adjacent = torch.tensor([False, True, False, True], device=snap.ego_x.device)
    joins = snap.sv_valid.bool() & ~(default_adjacent[:, None] & adjacent)
    dx = snap.sv_x - snap.ego_x[:, None]
    return BodySlots(joins, torch.where(front, dx, -dx) - VEHICLE_LENGTH_M, snap.sv_vx)


def with_bodies(r_sv: torch.Tensor, slots: BodySlots, r_bodies: torch.Tensor) -> torch.Tensor:
    """(B, 4) R_SV1..4 ANDed, slot by slot, with Eq. 26 for the car that joins it (r_bodies (B, 4))."""
    return r_sv & (r_bodies.bool() | ~slots.joins)


def body_room(slots: BodySlots, margin_m: float, sv_brake_mps2: float) -> torch.Tensor:
    """(B, 2) room limits of the SV1 and SV2 slots (front_room's extra_m): room_ahead of the joining car,
    +inf where none joins."""
    room = room_ahead(slots.gaps_m[:, :2], slots.vx[:, :2], margin_m, sv_brake_mps2)
    return torch.where(slots.joins[:, :2], room, torch.full_like(room, float("inf")))
