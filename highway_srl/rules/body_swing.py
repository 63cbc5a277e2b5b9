"""The body's swing (part of the safe profile's `hold_lateral`): no part of the ego moves sideways into a car
that is already within RSS's lateral margin of it.

The simulator turns a car about its centre. An ego beginning or unwinding a lateral move next to a car whose
body is within centimetres of its flank swings its rear (or front) corner toward that car, however slowly it
drives: the falsifier's adversarial sweeps found an ego creeping off toward the far lane while a car that had
cut in stood with its nose 6 cm from the ego's flank, behind-beside it
(`tests/rules/cases/safe-*swung-its-flank-into-*`). The lane rules cannot see this (the car is not ahead and
the move is away from it); RSS's lateral rule can: a car within the lateral margin μ may not move toward the
other. Here the ego's pose after the step is predicted with the simulator's own controller (sim.dynamics.
steer, integrate_speed) for the commanded target and for holding its lateral position (the simulator's
HOLD_LANE); where the command would bring the ego's body within μ of a car and holding would keep it
farther, the ego holds.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from highway_srl.constants import DT_S, EGO_ACCEL_MAX_MPS2, EGO_BRAKE_MAX_MPS2, V_MAX_MPS
from highway_srl.rules.avoidable import LAT_MARGIN_M
from highway_srl.sim.box_geometry import boxes_separation
from highway_srl.sim.dynamics import integrate_speed, steer
from highway_srl.sim.ego import HOLD_LANE
from highway_srl.sim.snapshot import Snapshot


@dataclass
class NearCars:
    """Every car the model's queries returned (its SV1..SV4, the third lane's and the by-body ones), (B, K)
    each: centre x, y (m), heading (rad) and valid (a real car, not a default virtual vehicle)."""

    x: torch.Tensor
    y: torch.Tensor
    heading: torch.Tensor
    valid: torch.Tensor


def near_cars(veh, third: Snapshot | None, bodies: Snapshot | None) -> NearCars:
    """The cars of veh (rules.mappings.Vehicles, SV1..SV4 with defaults) and of the optional third-lane and
    by-body snapshots (all four of their slots)."""
    parts = [(veh.x, veh.y, veh.heading, ~veh.virtual)]
    for snap in (third, bodies):
        if snap is not None:
            parts.append((snap.sv_x, snap.sv_y, snap.sv_heading, snap.sv_valid.bool()))
    return NearCars(*(torch.cat([p[k] for p in parts], 1) for k in range(4)))


def next_pose(snap: Snapshot, lane: torch.Tensor, speed: torch.Tensor, lane_width_m: float):
    """(x, y, heading) of the ego after one step commanded to lane (B,) long (global, or HOLD_LANE: hold its
    lateral position) at target speed (B,) m/s, by the simulator's controller and integration."""
    v = torch.hypot(snap.ego_vx, snap.ego_vy)
    accel = ((speed.clamp(0.0, V_MAX_MPS) - v) / DT_S).clamp(-EGO_BRAKE_MAX_MPS2, EGO_ACCEL_MAX_MPS2)
    v_mid = integrate_speed(v[:, None], accel[:, None], DT_S, V_MAX_MPS)[1][:, 0]
    y_t = torch.where(lane == HOLD_LANE, snap.ego_y, lane.to(snap.ego_y.dtype) * lane_width_m)
    h = steer(snap.ego_y, snap.ego_heading, v, y_t)
    return snap.ego_x + v_mid * torch.cos(h) * DT_S, snap.ego_y + v_mid * torch.sin(h) * DT_S, h


def _nearest(poses, cars: NearCars) -> torch.Tensor:
    """(B, P) separation (sim.box_geometry.boxes_separation: a lower bound of the distance, exact side to
    corner) of the ego at each of P poses ((B, P) x, y, heading) from the nearest valid car."""
    x, y, h = (t[:, :, None] for t in poses)  # (B, P, 1) against the cars' (B, 1, K)
    d = boxes_separation(x, y, h, cars.x[:, None], cars.y[:, None], cars.heading[:, None])
    return torch.where(cars.valid[:, None], d, torch.full_like(d, float("inf"))).amin(-1)


def swing_guard(snap: Snapshot, cars: NearCars, lane: torch.Tensor, speed: torch.Tensor,
                lane_width_m: float) -> torch.Tensor:
    """(B,) long: lane, or HOLD_LANE where the commanded move would bring the ego's body within LAT_MARGIN_M
    of a car (by the boxes' separation) and holding its lateral position keeps it farther from every car."""
    moved = next_pose(snap, lane, speed, lane_width_m)
    held = next_pose(snap, torch.full_like(lane, HOLD_LANE), speed, lane_width_m)
    d = _nearest([torch.stack(pair, 1) for pair in zip(moved, held)], cars)
    return torch.where((d[:, 0] < LAT_MARGIN_M) & (d[:, 1] > d[:, 0]), torch.full_like(lane, HOLD_LANE), lane)
