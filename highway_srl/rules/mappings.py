"""The four mappings of §3.3 (ID, rule, action, control) and the default virtual vehicles of §3.1, batched.

Frames (sim/road.py): lane k's centre is at y = k w_L, y grows to the right, lane 0 is the leftmost.
A two-lane model sees a pair of neighbouring lanes (base_lane, base_lane + 1) as its local lanes 0 and 1;
its local lateral coordinate is y_local = y - base_lane w_L, so the local lane centres are at 0 and w_L
and the boundary between them at w_L / 2 (docs/paper-notes.md, "Lateral frame").
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from highway_srl.constants import (
    D_MAX_M,
    DT_S,
    EGO_ACCEL_MAX_MPS2,
    EGO_BRAKE_MAX_MPS2,
    EPS_D_M,
    EPS_P_M,
    LANE_WIDTH_M,
    V_MAX_MPS,
    VEHICLE_LENGTH_M,
    VEHICLE_WIDTH_M,
)
from highway_srl.rules.safe_actions import FASTER, LANE_CHANGE, NUM_ACTIONS, SLOWER
from highway_srl.sim.road import Road
from highway_srl.sim.snapshot import Snapshot

# ε_s of R'_SVi (Eq. 32), not given by the paper: two car lengths of centre distance, i.e. an adjacent
# vehicle that overlaps the ego longitudinally or is within 5 m (bumper to bumper) of doing so.
EPS_S_M = 2.0 * VEHICLE_LENGTH_M
DV_ACCEL_MPS = EGO_ACCEL_MAX_MPS2 * DT_S  # Δv_A: one step of full acceleration (0.4375 m/s)
DV_DECEL_MPS = EGO_BRAKE_MAX_MPS2 * DT_S  # Δv_D: one step of full braking (0.75 m/s)
NO_LANE = -1

# §3.1: η_i and λ_i of SV_i,Def for SV1..SV4
ETA = (1.0, 1.0, -1.0, -1.0)
LAMBDA = (0.0, 1.0, 0.0, 1.0)


# --------------------------------------------------------------------------- ID mapping
@dataclass
class LaneModel:
    """One two-lane model's view (all (B,)): base_lane = global index of local lane 0; c_id = local
    current lane (0/1); current_lane, adjacent_lane = global lanes to query (adjacent -1: none);
    default_adjacent: SV2 and SV4 are the default virtual vehicles."""

    base_lane: torch.Tensor
    c_id: torch.Tensor
    current_lane: torch.Tensor
    adjacent_lane: torch.Tensor
    default_adjacent: torch.Tensor


@dataclass
class IdMapping:
    """ID mapping (§3.3): the primary model, and a second one where two_models (B,) is True (multi-lane,
    ego in the middle lane, lane keeping: primary = pair (0, 1) with c_id 1, second = pair (1, 2) with
    c_id 0). Where two_models is False the second model repeats the primary."""

    primary: LaneModel
    second: LaneModel
    two_models: torch.Tensor


def _zone(road: Road, name: str) -> tuple[float, float]:
    if name not in road.zones:
        raise ValueError(f"road {road.scenario!r} has no zone {name!r}; it has {', '.join(road.zones) or 'none'}")
    return road.zones[name]


def lane_exists(road: Road, lane: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """(B,) bool: global lane index `lane` exists at x (lane_start <= x < lane_end); -1 never exists."""
    start = torch.tensor(road.lane_start_m, dtype=x.dtype, device=x.device)
    end = torch.tensor(road.lane_end_m, dtype=x.dtype, device=x.device)
    ok = (lane >= 0) & (lane < road.num_lanes)
    k = lane.clamp(0, road.num_lanes - 1)
    return ok & (start[k] <= x) & (x < end[k])


def crossing_allowed(road: Road, lane_a: torch.Tensor, lane_b: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """(B,) bool: lanes a and b are neighbours, both exist at x and x is inside their change window."""
    lo_list = [w[0] for w in road.change_window_m] or [0.0]
    hi_list = [w[1] for w in road.change_window_m] or [0.0]
    lo = torch.tensor(lo_list, dtype=x.dtype, device=x.device)
    hi = torch.tensor(hi_list, dtype=x.dtype, device=x.device)
    k = torch.minimum(lane_a, lane_b).clamp(0, max(road.num_lanes - 2, 0))
    neighbours = (lane_a - lane_b).abs() == 1
    return neighbours & lane_exists(road, lane_a, x) & lane_exists(road, lane_b, x) & (lo[k] <= x) & (x < hi[k])


EGO_CHANGE_TIME_S = 3.0  # the ego's controller centres it in the next lane within 3 s (tests/sim)
WINDOW_MARGIN_M = 1.0


def change_fits_window(road: Road, ego_lane: torch.Tensor, target_lane: torch.Tensor, ego_x: torch.Tensor,
                       ego_y: torch.Tensor, speed: torch.Tensor, change_time_s: float = EGO_CHANGE_TIME_S,
                       margin_m: float = WINDOW_MARGIN_M) -> torch.Tensor:
    """(B,) bool: a change from ego_lane to target_lane (global) ends before its change window closes.

    The control mapping (Eq. 34) only knows the current lane pair; the road's window (the merging zone's end,
    the exit's gore) is a hard boundary an ego straddling the lanes would cross. The change has the share
    `remaining` of a lane width left, change_time_s * remaining seconds at the controller's pace; a held change
    lets the ego take Faster at every step, so its centre may cover as much as accelerating at its limit
    (to the speed limit) for that long: change_run_m. It must be inside the window, both lanes present, that
    far (+ margin) ahead. Why not speed * time: from a standstill that is 0 m, and an ego that started a change
    10 m before the gore at 0 m/s drove into it (docs/paper-notes.md, "control mapping").
    """
    w = road.lane_width_m
    remaining = ((target_lane.to(ego_y.dtype) * w - ego_y).abs() / w).clamp(max=1.0)
    ahead = ego_x + change_run_m(speed, change_time_s * remaining) + margin_m
    return crossing_allowed(road, ego_lane, target_lane, ahead)


def change_run_m(speed: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """(B,) metres an ego at `speed` covers in `t` seconds accelerating at its limit until the speed limit."""
    t_acc = ((V_MAX_MPS - speed) / EGO_ACCEL_MAX_MPS2).clamp(min=0.0)
    t_acc = torch.minimum(t_acc, t)
    return speed * t_acc + 0.5 * EGO_ACCEL_MAX_MPS2 * t_acc * t_acc + torch.maximum(speed, torch.full_like(
        speed, V_MAX_MPS)) * (t - t_acc)


def _base_lane(road: Road, ego_x: torch.Tensor, ego_lane: torch.Tensor) -> torch.Tensor:
    """The pair each scenario's prose assigns when the ego keeps its lane (§3.3, ID mapping)."""
    spec = road.spec
    if spec.change_zone is None:
        # expressway: lane 0 -> (0,1); lane 1 -> (0,1) primary; lane 2 -> (1,2) (clamped to the road later,
        # so on two lanes every lane gets (0,1))
        return (ego_lane - 1).clamp(min=0)
    # ramp road (right mainline lane r-1, ramp r): merge: on the on-ramp and in the merging zone the ramp is
    # local 1 and mainline lane 1 local 0; in the merging zone the ego in lane 1 keeps that pair (its frame
    # does not jump mid-merge); stability zone: lanes 0/1. exit: in the diverging zone the current lane 1 is
    # local 0, the off-ramp's deceleration lane local 1; on the off-ramp local 1 with lane 1 local 0;
    # preparation and continuation: lanes 0/1.
    ramp = road.mainline_lanes
    x1, x2 = _zone(road, spec.change_zone)
    in_zone = (ego_x >= x1) & (ego_x < x2)
    ramp_pair = (ego_lane == ramp) | ((ego_lane == ramp - 1) & in_zone)
    return torch.where(ramp_pair, torch.full_like(ego_lane, ramp - 1), torch.zeros_like(ego_lane))


def _lane_model(road: Road, ego_x: torch.Tensor, ego_lane: torch.Tensor, base: torch.Tensor) -> LaneModel:
    c_id = (ego_lane - base).clamp(0, 1)
    adjacent = base + (1 - c_id)
    real = crossing_allowed(road, ego_lane, adjacent, ego_x)
    adjacent = torch.where(real, adjacent, torch.full_like(adjacent, NO_LANE))
    return LaneModel(base, c_id, ego_lane.clone(), adjacent, ~real)


def id_mapping(
    road: Road, ego_x: torch.Tensor, ego_lane: torch.Tensor, target_lane: torch.Tensor | None = None
) -> IdMapping:
    """ID mapping of §3.3 for B egos: ego_x (B,) m, ego_lane (B,) long global (nearest lane centre).

    target_lane (B,) long global, optional: where a lane change is under way (target != ego lane), the
    model is the pair holding both lanes (so T*_ID stays 0/1 in the local frame) and there is one model.
    The adjacent lane is real only if the boundary to it may be crossed at ego_x (its change window);
    otherwise (on-ramp before the merging zone, the off-ramp, a lane that does not exist) SV2 and SV4 are
    the default virtual vehicles.
    """
    ego_lane = ego_lane.long()
    base = _base_lane(road, ego_x, ego_lane)
    changing = torch.zeros_like(ego_lane, dtype=torch.bool)
    if target_lane is not None:
        target_lane = target_lane.long()
        changing = (target_lane - ego_lane).abs() == 1
        base = torch.where(changing, torch.minimum(target_lane, ego_lane), base)
    base = base.clamp(0, max(road.num_lanes - 2, 0))
    primary = _lane_model(road, ego_x, ego_lane, base)
    if road.spec.id_two_models:
        two = (ego_lane == 1) & ~changing
        second = _lane_model(road, ego_x, ego_lane, torch.where(two, torch.ones_like(base), base))
    else:
        two = torch.zeros_like(changing)
        second = replace(primary)
    return IdMapping(primary, second, two)


# --------------------------------------------------------------------------- default virtual vehicles (§3.1)
@dataclass
class Vehicles:
    """SV1..SV4 states (B, 4) each, in the global Frenet frame; virtual (B, 4) bool marks SV_i,Def."""

    x: torch.Tensor
    y: torch.Tensor
    vx: torch.Tensor
    vy: torch.Tensor
    heading: torch.Tensor
    virtual: torch.Tensor


def default_virtual_vehicles(
    ego_x: torch.Tensor,
    ego_y: torch.Tensor,
    c_id: torch.Tensor,
    *,
    d_max_m: float = D_MAX_M,
    v_max_mps: float = V_MAX_MPS,
    lane_width_m: float = LANE_WIDTH_M,
) -> tuple[torch.Tensor, ...]:
    """SV_i,Def of §3.1 for i = 1..4: (x, y, v_x, v_y, heading), each (B, 4):
    (x_EV + η_i d_max, y_EV + λ_i (1 - 2 C_ID) w_L, (1 + η_i)/2 v_max, 0, 0), η = (1, 1, -1, -1), λ = (0, 1, 0, 1).
    Phantom front vehicles drive at v_max at the edge of perception; phantom rear vehicles stand there."""
    eta = torch.tensor(ETA, dtype=ego_x.dtype, device=ego_x.device)
    lam = torch.tensor(LAMBDA, dtype=ego_x.dtype, device=ego_x.device)
    x = ego_x[:, None] + eta * d_max_m
    y = ego_y[:, None] + lam * (1.0 - 2.0 * c_id.to(ego_x.dtype))[:, None] * lane_width_m
    vx = ((1.0 + eta) / 2.0 * v_max_mps).expand_as(x)
    zero = torch.zeros_like(x)
    return x, y, vx.clone(), zero, zero.clone()


def fill_defaults(snap: Snapshot, c_id: torch.Tensor, default_adjacent: torch.Tensor, **kwargs) -> Vehicles:
    """SV1..SV4 of the snapshot with SV_i,Def in every invalid slot, and in SV2/SV4 where default_adjacent."""
    dx, dy, dvx, dvy, dh = default_virtual_vehicles(snap.ego_x, snap.ego_y, c_id, **kwargs)
    adjacent_slot = torch.tensor([False, True, False, True], device=snap.ego_x.device)
    virtual = ~snap.sv_valid.bool() | (default_adjacent[:, None] & adjacent_slot)
    w = lambda d, s: torch.where(virtual, d, s.to(d.dtype))  # noqa: E731
    return Vehicles(w(dx, snap.sv_x), w(dy, snap.sv_y), w(dvx, snap.sv_vx), w(dvy, snap.sv_vy),
                    w(dh, snap.sv_heading), virtual)


# --------------------------------------------------------------------------- rule mapping (Eqs. 28-33)
def corner_points(
    x: torch.Tensor,
    y: torch.Tensor,
    heading: torch.Tensor,
    length_m: float = VEHICLE_LENGTH_M,
    width_m: float = VEHICLE_WIDTH_M,
) -> tuple[torch.Tensor, torch.Tensor]:
    """P_j = c_j 1ᵀ + R(φ_j) Q (the corner equations before Eq. 31): corner (x, y), each (..., 4),
    corners in Q's order (front-left, front-right, rear-left, rear-right in the vehicle frame)."""
    qx = torch.tensor([0.5, 0.5, -0.5, -0.5], dtype=x.dtype, device=x.device) * length_m
    qy = torch.tensor([0.5, -0.5, 0.5, -0.5], dtype=x.dtype, device=x.device) * width_m
    c, s = torch.cos(heading)[..., None], torch.sin(heading)[..., None]
    return x[..., None] + c * qx - s * qy, y[..., None] + s * qx + c * qy


def near_boundary(
    y_local: torch.Tensor,
    heading: torch.Tensor,
    *,
    lane_width_m: float = LANE_WIDTH_M,
    eps_p_m: float = EPS_P_M,
    eps_d_m: float = EPS_D_M,
    length_m: float = VEHICLE_LENGTH_M,
    width_m: float = VEHICLE_WIDTH_M,
) -> torch.Tensor:
    """m*_L of Eq. 31, (...) bool: (δ_min < ε_p) ∨ (|y - y_lane| < ε_d).

    y_lane is the line between the pair's two lanes (y_local = w_L / 2) and δ_k = |y_k - y_lane| is corner
    k's lateral distance to it. With a 2 m wide car, ε_p = 0.5 and ε_d = 0.6 the two clauses together
    flag a car whose centre is within B/2 + ε_p = 1.5 m of the line (the centre clause covers a car
    straddling it, whose corners are all B/2 away).
    """
    x0 = torch.zeros_like(y_local)
    _, cy = corner_points(x0, y_local, heading, length_m, width_m)
    y_lane = 0.5 * lane_width_m
    delta_min = (cy - y_lane).abs().min(dim=-1).values
    return (delta_min < eps_p_m) | ((y_local - y_lane).abs() < eps_d_m)


def crosses_line(y_local: torch.Tensor, heading: torch.Tensor, lane_width_m: float = LANE_WIDTH_M) -> torch.Tensor:
    """(...) bool: a car's body crosses the pair's lane line (its corners lie on both sides of y_local = w_L/2)."""
    x0 = torch.zeros_like(y_local)
    _, cy = corner_points(x0, y_local, heading, VEHICLE_LENGTH_M, VEHICLE_WIDTH_M)
    y_lane = 0.5 * lane_width_m
    return (cy.min(dim=-1).values < y_lane) & (cy.max(dim=-1).values > y_lane)


def crossing_toward(y_local: torch.Tensor, heading: torch.Tensor, ego_y_local: torch.Tensor,
                    lane_width_m: float = LANE_WIDTH_M) -> torch.Tensor:
    """(...) bool: a car whose body crosses the pair's lane line (crosses_line) while it heads toward the
    ego's side of the line. The safe profile ORs it into m*_L,SV (Eq. 31): at a large heading Eq. 31 misses
    such a car (a 5 m car turning in at 0.54 rad with its centre 1.1 m short of the line has its nose 1 m
    over it and no corner within ε_p of it). Cars turning away are left out here: a leader leaving the ego's
    lane must not block the ego's own change (reaching_over takes the one whose centre has left). y_local,
    heading: (B, K) or (...); ego_y_local broadcasts against them."""
    return crosses_line(y_local, heading, lane_width_m) & ((ego_y_local - y_local) * torch.sin(heading) > 0)


def reaching_over(y_local: torch.Tensor, heading: torch.Tensor, ego_y_local: torch.Tensor,
                  lane_width_m: float = LANE_WIDTH_M) -> torch.Tensor:
    """(...) bool: a car whose centre is on the far side of the pair's lane line from the ego's while its
    body crosses the line, whichever way it heads: its tail (or nose) is in the ego's lane. The safe profile
    ORs it into m*_L,SV (Eq. 31): a car standing mid-change at 0.453 rad with its centre 1.15 m beyond the
    line has its tail 0.84 m into the ego's lane and no corner within ε_p of the line, and it heads away
    from the ego, so neither Eq. 31 nor crossing_toward flags it. y_local, heading: (B, K) or (...);
    ego_y_local broadcasts against them."""
    y_lane = 0.5 * lane_width_m
    far_side = (y_local - y_lane) * (ego_y_local - y_lane) < 0
    return crosses_line(y_local, heading, lane_width_m) & far_side


def rule_mapping(
    r_sv: torch.Tensor,
    m_l_ego: torch.Tensor,
    m_l_sv: torch.Tensor,
    dx_sv_m: torch.Tensor,
    *,
    eps_s_m: float = EPS_S_M,
    grouped: bool = True,
) -> tuple[torch.Tensor, torch.Tensor]:
    """R'_SVi and R*_SVi of Eq. 32; returns (r_prime, r_star), each (B, 4) bool.

    r_sv (B, 4) bool R_SV1..4; m_l_ego (B,) bool m*_L,EV; m_l_sv (B, 4) bool m*_L,SVi; dx_sv_m (B, 4)
    longitudinal centre distance |Δx_SVi| is taken of.
    R'_i = 0 for i in {2, 4} if m*_L,EV ∧ |Δx_SVi| < ε_s ∧ ¬(R_2 ∧ R_4), else R_i.
    R*: a front vehicle (SV1 or SV2) near the boundary belongs to both lanes, so R*_1 = R*_2 = R'_1 ∧ R'_2;
    the same for the rear pair. grouped=False is the per-index reading (only R*_i of the SV near the
    boundary becomes the conjunction); grouped is the default because the per-index reading lets an SV2
    cutting in over the boundary leave R*_1 (and so Faster) untouched.
    """
    r = r_sv.bool()
    adjacent_unsafe = ~(r[:, 1] & r[:, 3])
    close = dx_sv_m.abs() < eps_s_m
    kill = m_l_ego.bool()[:, None] & close & adjacent_unsafe[:, None]
    kill = kill & torch.tensor([False, True, False, True], device=r.device)
    r_prime = r & ~kill
    front = r_prime[:, 0] & r_prime[:, 1]
    rear = r_prime[:, 2] & r_prime[:, 3]
    m = m_l_sv.bool()
    if grouped:
        m_front, m_rear = m[:, 0] | m[:, 1], m[:, 2] | m[:, 3]
        m = torch.stack([m_front, m_front, m_rear, m_rear], dim=1)
    pair = torch.stack([front, front, rear, rear], dim=1)
    r_star = torch.where(m, pair, r_prime)
    return r_prime, r_star


def straddle_grouping(r_star: torch.Tensor, m_l_ego: torch.Tensor) -> torch.Tensor:
    """Eq. 32 extended to the ego: while the ego is near the boundary (m*_L,EV = 1) it occupies both lanes,
    so the front rule is R*1 ∧ R*2 and the rear rule R*3 ∧ R*4 (the paper groups only for SVs near the
    boundary). Without it an ego that crossed the boundary and returned, or one finishing a change with
    Idle, drove into a vehicle it no longer tracked as SV1. r_star (B, 4), m_l_ego (B,) -> (B, 4)."""
    front = torch.where(m_l_ego, r_star[:, 0] & r_star[:, 1], r_star[:, 0])
    rear = torch.where(m_l_ego, r_star[:, 2] & r_star[:, 3], r_star[:, 2])
    return torch.stack([front, r_star[:, 1], rear, r_star[:, 3]], 1)


# --------------------------------------------------------------------------- action and control mapping
def _check_actions(action: torch.Tensor) -> None:
    if action.numel() and (int(action.min()) < 0 or int(action.max()) >= NUM_ACTIONS):
        raise ValueError(f"actions must be indices 0..{NUM_ACTIONS - 1} of ACTIONS, got {action.unique().tolist()}")


def target_lane_local(
    action: torch.Tensor,
    c_id: torch.Tensor,
    m_l_ego: torch.Tensor,
    r3s: torch.Tensor,
    r4s: torch.Tensor,
    dx3: torch.Tensor,
    dx4: torch.Tensor,
    previous_target: torch.Tensor | None = None,
    check: bool = True,
) -> torch.Tensor:
    """T*_ID of Eqs. 34-35 in the local pair, (B,) long.

    action (B,) long index into ACTIONS; c_id (B,) long; m_l_ego (B,) bool m*_L,EV; r3s, r4s (B,) bool
    R*_SV3, R*_SV4; dx3, dx4 (B,) distances of SV3, SV4 behind the ego (m, x_EV - x_SV).
    Eq. 34: Faster/Idle/Slower -> C_ID; LaneChange with m*_L,EV = 0 -> 1 - C_ID.
    Eq. 35 (LaneChange, m*_L,EV = 1): 1 - C_ID if ¬R3 ∧ R4; C_ID if R3 ∧ ¬R4; both false: stay if
    Δx3 > Δx4, change if Δx3 < Δx4; otherwise (both true, or a tie) C_ID.
    previous_target (B,) long local, optional: the reading "the lateral plan remains unchanged" for
    Faster/Idle/Slower (they keep the previous target instead of resetting it to C_ID), which lets a lane
    change in progress finish; the default (None) is the literal Eq. 34.
    check: raise ValueError on an index outside ACTIONS (a host read; the static training step skips it).
    """
    action = action.long()
    if check:
        _check_actions(action)
    c_id = c_id.long()
    other = 1 - c_id
    r3s, r4s, m = r3s.bool(), r4s.bool(), m_l_ego.bool()
    both_unsafe = ~r3s & ~r4s
    refined = torch.where(~r3s & r4s, other, c_id)
    refined = torch.where(both_unsafe & (dx3 < dx4), other, refined)
    lane_change = torch.where(m, refined, other)
    keep = c_id if previous_target is None else previous_target.long()
    return torch.where(action == LANE_CHANGE, lane_change, keep)


def target_speed(
    action: torch.Tensor,
    v_mps: torch.Tensor,
    *,
    dv_accel_mps: float = DV_ACCEL_MPS,
    dv_decel_mps: float = DV_DECEL_MPS,
    v_max_mps: float = V_MAX_MPS,
    check: bool = True,
) -> torch.Tensor:
    """v̄_EV,x (§3.1): Faster v + Δv_A, Slower v - Δv_D, Idle and LaneChange v; clipped to [0, v_max]; (B,).
    check: as in target_lane_local."""
    action = action.long()
    if check:
        _check_actions(action)
    dv = torch.zeros_like(v_mps)
    dv = torch.where(action == FASTER, torch.full_like(dv, dv_accel_mps), dv)
    dv = torch.where(action == SLOWER, torch.full_like(dv, -dv_decel_mps), dv)
    return (v_mps + dv).clamp(0.0, v_max_mps)


def room_ahead(gap_m: torch.Tensor, sv_vx: torch.Tensor, margin_m: float, sv_brake_mps2: float) -> torch.Tensor:
    """The distance the ego may cover behind a car gap_m ahead (bumper gap) before it must stand: up to
    where that car would stand braking at its limit now (Eq. 20: v_SV² / 2|a_SV| beyond the gap), less the
    standstill margin. Any shape."""
    return gap_m - margin_m + sv_vx.clamp(min=0.0) ** 2 / (2.0 * sv_brake_mps2)


def front_room(gaps_m: torch.Tensor, sv_vx: torch.Tensor, sv2_joins: torch.Tensor, margin_m: float,
               sv_brake_mps2: float, extra_m: torch.Tensor | None = None) -> torch.Tensor:
    """(B,) the distance the ego may cover before it must stand: room_ahead of SV1, or of the nearer of SV1
    and SV2 where sv2_joins (B,) (Eq. 32 or the straddle grouping makes R*1 answer for SV2 too). gaps_m,
    sv_vx (B, 4) as in ModelStep; extra_m (B, 2), optional: more room limits of the SV1 and SV2 slots (a
    third-lane car joining them)."""
    room = room_ahead(gaps_m[:, :2], sv_vx[:, :2], margin_m, sv_brake_mps2)
    if extra_m is not None:
        room = torch.minimum(room, extra_m)
    return torch.where(sv2_joins, room.min(1).values, room[:, 0])


def stopping_speed(v_mps: torch.Tensor, room_m: torch.Tensor, brake_mps2: float = EGO_BRAKE_MAX_MPS2,
                   dt_s: float = DT_S) -> torch.Tensor:
    """(B,) the target speed that brakes to a stop within room_m (B,): the constant deceleration
    a = v² / (2 room) (Eq. 20's stopping distance solved for a) for one step, v - a dt, capped at the
    ego's braking limit (Slower's Δv_D) and at 0; where room_m <= 0 the limit. The simulator integrates a
    constant acceleration exactly over a step, so holding a stops the ego at the end of the room."""
    need = v_mps * v_mps / (2.0 * room_m.clamp(min=1e-6))
    a = torch.where(room_m > 0.0, need, torch.full_like(need, brake_mps2)).clamp(max=brake_mps2)
    return (v_mps - a * dt_s).clamp(min=0.0)
