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

from highway_srl.constants import (DT_S, EGO_ACCEL_MAX_MPS2, EGO_BRAKE_MAX_MPS2, V_MAX_MPS, VEHICLE_LENGTH_M,
                                   VEHICLE_WIDTH_M)
from highway_srl.rules.avoidable import LAT_MARGIN_M
from highway_srl.sim.box_geometry import boxes_overlap
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


def _corners(x, y, h):
    """(..., 4) corner x and y of L x B boxes."""
    qx = torch.tensor([0.5, 0.5, -0.5, -0.5], dtype=x.dtype, device=x.device) * VEHICLE_LENGTH_M
    qy = torch.tensor([0.5, -0.5, 0.5, -0.5], dtype=x.dtype, device=x.device) * VEHICLE_WIDTH_M
    c, s = torch.cos(h)[..., None], torch.sin(h)[..., None]
    return x[..., None] + c * qx - s * qy, y[..., None] + s * qx + c * qy


def _points_to_box(px, py, x, y, h):
    """(..., 4) distance of points (..., 4) to the L x B box (x, y, h) (...,), 0 inside it."""
    dx, dy = px - x[..., None], py - y[..., None]
    c, s = torch.cos(h)[..., None], torch.sin(h)[..., None]
    along = ((dx * c + dy * s).abs() - 0.5 * VEHICLE_LENGTH_M).clamp(min=0.0)
    across = ((dy * c - dx * s).abs() - 0.5 * VEHICLE_WIDTH_M).clamp(min=0.0)
    return torch.hypot(along, across)


def box_distance(xa, ya, ha, xb, yb, hb) -> torch.Tensor:
    """The distance between two L x B boxes (broadcast), 0 where they overlap: for disjoint convex polygons
    it is reached between a corner of one and the other."""
    ax, ay = _corners(xa, ya, ha)
    bx, by = _corners(xb, yb, hb)
    d = torch.minimum(_points_to_box(ax, ay, xb, yb, hb).amin(-1), _points_to_box(bx, by, xa, ya, ha).amin(-1))
    return torch.where(boxes_overlap(xa, ya, ha, xb, yb, hb), torch.zeros_like(d), d)


def _nearest(pose, cars: NearCars) -> torch.Tensor:
    x, y, h = pose
    d = box_distance(x[:, None], y[:, None], h[:, None], cars.x, cars.y, cars.heading)
    return torch.where(cars.valid, d, torch.full_like(d, float("inf"))).amin(1)


def swing_guard(snap: Snapshot, cars: NearCars, lane: torch.Tensor, speed: torch.Tensor,
                lane_width_m: float) -> torch.Tensor:
    """(B,) long: lane, or HOLD_LANE where the commanded move would bring the ego's body within LAT_MARGIN_M
    of a car and holding its lateral position keeps it farther from every car."""
    moved = _nearest(next_pose(snap, lane, speed, lane_width_m), cars)
    held = _nearest(next_pose(snap, torch.full_like(lane, HOLD_LANE), speed, lane_width_m), cars)
    return torch.where((moved < LAT_MARGIN_M) & (held > moved), torch.full_like(lane, HOLD_LANE), lane)
