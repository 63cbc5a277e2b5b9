"""The lane a two-lane model does not hold (the safe profile's `watch_third_lane`).

A two-lane model (§3.3) sees two lanes. On a road of three (multi-lane, and the ramps where the ramp lane
exists) the third lane borders the pair's middle lane, the "near lane": lane 2 for the pair (0, 1), lane 0
for the pair (1, 2). A car of the third lane whose body reaches over the line into the near lane, or that
Eq. 31 flags near that line, is a car of the near lane too, but neither model's SV1..SV4 holds it: the
multi-lane falsifier found an ego in the middle lane meeting a lane-2 car turning in beside it while it
acted on the pair (0, 1), and an ego changing from lane 2 into lane 1 meeting the tail of a lane-0 car
standing mid-change. Here the third lane's nearest cars ahead and behind join the near lane's rules: R_SV
of the near lane's slot holds only if it holds for the joining car too (Eq. 26 against the same ego), and
its room ahead counts for Idle as the last resort. The same holds the other way round: where the ego's own
body reaches over the line into the third lane (an ego settling back into the middle lane at walking pace,
its body still 0.9 m into lane 2 while it acts on the pair (0, 1)), the third lane's cars are cars of the
ego's lane; the nominal greedy sweep found such an ego creeping into the tail of a car standing in lane 2
(`tests/rules/cases/safe-greedy-reaching-over-into-the-lane-the-model-does-not-hold-*`).
The observation (the 37 inputs) is unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from highway_srl.constants import VEHICLE_LENGTH_M
from highway_srl.rules.mappings import NO_LANE, LaneModel, crosses_line, lane_exists, near_boundary, room_ahead
from highway_srl.sim.road import Road
from highway_srl.sim.snapshot import Snapshot


def third_lane(road: Road, base_lane: torch.Tensor, ego_x: torch.Tensor) -> torch.Tensor:
    """(B,) long global index of the lane next to the pair (base_lane, base_lane + 1) on the side it has
    one (roads have at most three lanes), NO_LANE where it does not exist at ego_x."""
    right = base_lane + 2
    lane = torch.where(right < road.num_lanes, right, base_lane - 1)
    return torch.where(lane_exists(road, lane, ego_x), lane, torch.full_like(lane, NO_LANE))


@dataclass
class ThirdLaneCars:
    """The third lane's nearest car ahead and behind, all (B, 2) in (ahead, behind) order: joins (the car
    reaches into the near lane), gaps_m (bumper gaps to the ego, the same way as ModelStep.gaps_m) and vx
    (m/s); near_slot (B,) long: the near lane's front slot among SV1..SV4 (0: it is the ego's lane, 1: the
    adjacent one; its rear slot is near_slot + 2)."""

    joins: torch.Tensor
    gaps_m: torch.Tensor
    vx: torch.Tensor
    near_slot: torch.Tensor


def third_lane_cars(snap: Snapshot, lanes: LaneModel, lane_width_m: float) -> ThirdLaneCars:
    """The cars of snap (a query of the third lane as the current lane: SV1 ahead, SV3 behind) against the
    pair `lanes`. A car joins where its body crosses the line between the third lane and the near lane or
    Eq. 31 flags it near that line (the same test as the pair's own SVs, in the frame of those two lanes)."""
    third = snap.current_lane.long()
    base = lanes.base_lane
    near = torch.where(third > base, base + 1, base)
    frame = torch.minimum(near, third).to(snap.ego_x.dtype) * lane_width_m  # local 0 of the (near, third) pair
    cols = [0, 2]
    y = snap.sv_y[:, cols] - frame[:, None]
    heading = snap.sv_heading[:, cols]
    reaches = near_boundary(y, heading, lane_width_m=lane_width_m) | crosses_line(y, heading, lane_width_m)
    # the ego's own body reaching over into the third lane makes that lane's cars cars of the ego's lane
    ego_in_near = near - base == lanes.c_id
    ego_reaches = ego_in_near & crosses_line(snap.ego_y - frame, snap.ego_heading, lane_width_m)
    joins = (reaches | ego_reaches[:, None]) & snap.sv_valid[:, cols].bool() & (third >= 0)[:, None]
    dx = snap.sv_x[:, cols] - snap.ego_x[:, None]
    gaps = torch.stack([dx[:, 0], -dx[:, 1]], 1) - VEHICLE_LENGTH_M
    return ThirdLaneCars(joins, gaps, snap.sv_vx[:, cols], (near - base != lanes.c_id).long())


def with_third_lane(r_sv: torch.Tensor, cars: ThirdLaneCars, r_cars: torch.Tensor) -> torch.Tensor:
    """(B, 4) R_SV1..4 with the near lane's front and rear slots ANDed with the rule R (B, 2) of the car
    that joins them (r_cars: Eq. 26 for the third lane's cars ahead and behind)."""
    ok = r_cars.bool() | ~cars.joins
    slots = torch.stack([cars.near_slot, cars.near_slot + 2], 1)
    return r_sv & torch.ones_like(r_sv).scatter(1, slots, ok)


def third_lane_room(cars: ThirdLaneCars, margin_m: float, sv_brake_mps2: float) -> torch.Tensor:
    """(B, 2) extra room for front_room's SV1 and SV2 slots: room_ahead of the joining car ahead in the near
    lane's slot, +inf elsewhere."""
    room = room_ahead(cars.gaps_m[:, 0], cars.vx[:, 0], margin_m, sv_brake_mps2)
    room = torch.where(cars.joins[:, 0], room, torch.full_like(room, float("inf")))
    slot = torch.stack([cars.near_slot == 0, cars.near_slot == 1], 1)
    return torch.where(slot, room[:, None], torch.full_like(slot, float("inf"), dtype=room.dtype))
