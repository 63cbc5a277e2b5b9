"""One step of motion: the traffic model's accelerations and lane decisions, the adversary, the ego's
controller, and the integration with the lateral controller shared by all vehicles.

Events (contacts, collisions, stages) are in sim/collisions_and_stages.py, recycling in sim/recycle.py; World.step
runs them in that order.
"""

from __future__ import annotations

import torch

from highway_srl.constants import DT_S, V_MAX_MPS
from highway_srl.sim import adversary, sv_drivers
from highway_srl.sim.collisions_and_stages import sv_contacts
from highway_srl.sim.ego import HOLD_LANE, ego_control
from highway_srl.sim.lane_tables import LaneTables
from highway_srl.sim.road import Road
from highway_srl.sim.selection import entries, flat_index, none_left, put_flat, take_flat
from highway_srl.sim.spawn import Layout
from highway_srl.sim.state import WorldState
from highway_srl.sim.sv_drivers import CENTRED_M, Neighbours

# Lateral tracking controller on a kinematic model (shared by the ego and the SVs): a desired lateral
# speed proportional to the lateral error, turned into a desired heading that a rate-limited heading
# loop follows. At 8 m/s a lane change settles (|e_y| < 0.2 m, |heading| < 0.02) in about 2.6 s without
# overshoot. Below LOW_SPEED_VY_MPS / HEADING_MAX_RAD = 4 m/s the heading limit opens up to
# HEADING_MAX_LOW_RAD, so that a car that has slowed down (at a lane end, in a jam) can still move
# sideways at about LOW_SPEED_VY_MPS. The yaw rate is at most v / MIN_TURN_RADIUS_M (a standing car
# neither turns nor moves sideways), and the heading is never more than can be unwound within the
# remaining lateral error (UNWIND_MARGIN x the turning radius), so that slow cars do not overshoot.
K_Y = 2.0  # 1/s
VY_MAX_MPS = 2.0
HEADING_MAX_RAD = 0.25
HEADING_MAX_LOW_RAD = 0.6
LOW_SPEED_VY_MPS = 1.0
K_HEADING = 8.0  # 1/s
YAW_RATE_MAX = 0.8  # rad/s
MIN_TURN_RADIUS_M = 4.0  # yaw rate <= v / R: the heading of a standing car does not change
UNWIND_MARGIN = 1.5
SETTLED_M, SETTLED_RAD = 1e-3, 1e-3  # a car this close to its lane's centre line, and aligned, is put on it


def move_vehicles(s: WorldState, road: Road, tables: LaneTables, layout: Layout, target_lane, target_speed,
                  adversarial, static: bool = False) -> tuple[torch.Tensor, Neighbours]:
    """Move every vehicle by one step in place.

    Returns the number of SV-SV contacts per env (B,) long and the neighbours found at the start of the
    step (which ego_collision uses). static: static shapes and no host reads (see sim/selection.py)."""
    nb = sv_drivers.find_neighbours(s, road, static)
    accel, near = sv_drivers.car_following(s, road, tables, nb, static)
    accel = sv_drivers.yield_to_mergers(s, road, nb, accel, static)
    sv_drivers.abort_unsafe_changes(s, road, nb, accel, static)
    sv_drivers.mobil_lane_changes(s, road, tables, nb, accel, static)
    if adversarial:
        adversary.cut_ins_ahead_with_room(s, tables, nb, static)
    ego_control(s, tables, target_lane, target_speed, accel)

    v_new, v_mid = integrate_speed(s.v, accel, DT_S, V_MAX_MPS)
    x_old = s.x.clone()
    s.x.add_(v_mid * DT_S)  # along the lane; corrected below for the few cars that are turned
    hold = torch.zeros_like(s.forced)
    hold[:, 0] = target_lane == HOLD_LANE
    lateral(s, road, v_mid, x_old, static, hold)
    s.v.copy_(v_new)
    return sv_contacts(s, near, nb.leader, static), nb


def integrate_speed(v: torch.Tensor, accel: torch.Tensor, dt: float, ego_v_max: float
                    ) -> tuple[torch.Tensor, torch.Tensor]:
    """Exact kinematics of a constant acceleration over one step, with the speed held at its bounds.

    v, accel (B, N): speeds (m/s) and accelerations (m/s^2), column 0 the ego. Returns the speeds at the end
    of the step (>= 0; the ego's <= ego_v_max) and the mean speed over the step (distance / dt). A car that
    reaches 0 within the step stands still for the rest of it: it covers v^2 / (2 |a|), not the trapezoid
    to 0 (which overshoots: 2.7 cm instead of 1.6 cm from 0.44 m/s at -6 m/s^2, enough to creep into a
    standing leader). Likewise the ego that reaches its limit within the step drives on at the limit."""
    v_free = v + accel * dt
    v_new = v_free.clamp(min=0.0)
    v_new[:, 0] = v_new[:, 0].clamp(max=ego_v_max)
    v_mean = 0.5 * (v + v_new)
    # stopping: accel < -v/dt <= 0 there, so the divisor is positive; the clamp only keeps the unused
    # entries of torch.where finite
    stop_mean = v * v / (-2.0 * accel * dt).clamp(min=1e-9)
    v_mean = torch.where(v_free < 0.0, stop_mean, v_mean)
    v0, a0 = v[:, 0], accel[:, 0]
    t_cap = ((ego_v_max - v0) / a0.clamp(min=1e-9)).clamp(0.0, dt)  # time to reach the limit
    capped_mean = (v0 * t_cap + 0.5 * a0 * t_cap * t_cap + ego_v_max * (dt - t_cap)) / dt
    v_mean[:, 0] = torch.where(v_free[:, 0] > ego_v_max, capped_mean, v_mean[:, 0])
    return v_new, v_mean


def steer(y: torch.Tensor, h: torch.Tensor, v: torch.Tensor, y_t: torch.Tensor) -> torch.Tensor:
    """The heading after one step of the lateral controller: y, h, v the car's lateral position (m), heading
    (rad) and speed (m/s) at the start of the step, y_t the line it tracks (m). Shared by lateral() and the
    rule layer's prediction of the ego's next pose (rules.body_swing)."""
    e_y = y_t - y
    vy_d = (K_Y * e_y).clamp(-VY_MAX_MPS, VY_MAX_MPS)
    v_safe = v.clamp(min=0.5)
    sin_max = torch.sin((LOW_SPEED_VY_MPS / v_safe).clamp(HEADING_MAX_RAD, HEADING_MAX_LOW_RAD))
    # never steer further than can be unwound within the remaining lateral error: turning back from
    # heading h on a circle of radius R moves the car R (1 - cos h) sideways
    radius = UNWIND_MARGIN * torch.clamp(v / YAW_RATE_MAX, min=MIN_TURN_RADIUS_M)
    cos_u = (1.0 - e_y.abs() / radius).clamp(min=0.0)
    sin_max = torch.minimum(sin_max, torch.sqrt(1.0 - cos_u * cos_u))
    heading_d = torch.asin(torch.maximum(torch.minimum(vy_d / v_safe, sin_max), -sin_max))
    yaw_max = (v / MIN_TURN_RADIUS_M).clamp(max=YAW_RATE_MAX)
    return h + torch.maximum(torch.minimum(K_HEADING * (heading_d - h), yaw_max), -yaw_max) * DT_S


def lateral(s: WorldState, road: Road, v_mid: torch.Tensor, x_old: torch.Tensor, static: bool = False,
            hold: torch.Tensor | None = None) -> None:
    """Lateral tracking and the lateral part of the integration, for the cars that are not settled in
    their lane (a changing car, one off its lane's centre, or one not aligned with the road); a car that
    comes within SETTLED_M / SETTLED_RAD of its lane's centre line is snapped onto it. hold (B, N) bool: cars
    that stop moving sideways instead (their own y is the line they track: the heading turns back to 0)."""
    w = road.lane_width_m
    active = (s.target_lane != s.lane) | (s.heading != 0) | (s.y != s.lane.float() * w)
    bb, ii, sel = entries(active, static)
    if none_left(bb, sel):
        return
    flat = flat_index(bb, ii, s.x.shape[1])
    y, h, v, tgt = (take_flat(t, flat) for t in (s.y, s.heading, s.v, s.target_lane))
    y_t = tgt.float() * w
    if hold is not None:
        y_t = torch.where(take_flat(hold, flat), y, y_t)
    h = steer(y, h, v, y_t)
    vm = take_flat(v_mid, flat)
    x = take_flat(x_old, flat) + vm * torch.cos(h) * DT_S
    y = y + vm * torch.sin(h) * DT_S
    settled = ((y - y_t).abs() < SETTLED_M) & (h.abs() < SETTLED_RAD)
    y = torch.where(settled, y_t, y)
    h = torch.where(settled, 0.0, h)
    lane = torch.round(y / w).long().clamp(0, road.num_lanes - 1)
    centred = (lane == tgt) & ((y - y_t).abs() < CENTRED_M)
    forced = take_flat(s.forced, flat) & ~centred
    for t, value in ((s.x, x), (s.y, y), (s.heading, h), (s.lane, lane), (s.forced, forced)):
        put_flat(t, flat, value, sel)

