"""Safe distance and the traffic-rule indicator R_SVi of §3.2 (Eqs. 19-27), batched.

Numbering used here for the "Safe Distance" block of §3.2 (the paper numbers it as one run of equations;
docs/paper-notes.md gives the same table):
  Eq. 19  reaction quantities Δx_SV,δt, Δx_EV,δt, v_SV,Res
  Eq. 20  stopping distances d_EV,SD, d_SV,SD
  Eq. 21  front condition (SV ahead, i = 1, 2)
  Eq. 22  rear condition (SV behind, i = 3, 4)
  Eq. 23  stopping times t_EV,Stop, t*_SV,Stop
  Eq. 24  front safe distances d_SD1, d_SD2, d_SD3 with B_F, C_F
  Eq. 25  rear safe distances d_SD1, d_SD2, d_SD3 with B_R, C_R
  Eq. 26  the indicator R_SVi
  Eq. 27  the cases D (certainly unsafe) and E (certainly safe)

Conventions: every function is elementwise and broadcasts over tensor (or float) arguments; speeds are
longitudinal and >= 0 (negative values are clamped to 0), braking decelerations are positive numbers
(the paper's |a_D,max|), `gap_m` is the bumper-to-bumper gap, which is the paper's point-mass Δx
(a collision is gap <= 0).

Two readings (docs/paper-notes.md, "Safe distance"):
- literal=True: Eqs. 19-27 as printed, subscripts resolved as v_SV,Res,x = v_SV,Res, t*_SV,Stop =
  v_SV,Res / |a_SV| (time for the braking SV to stop once the reaction time is over) and t_SV,Stop =
  v_SV / |a_SV|. It breaks its own promise (scripts/sd_sweep.py finds counterexamples).
- literal=False (default): the same structure (cases D, E, then d_SD3) written for a follower and a
  leader, with the corrections that make R = 1 exactly the promise: "if the leader brakes at its
  maximum from now on and the follower, after the reaction time δt, brakes at its maximum, they never
  touch". Front (SV1, SV2): the ego follows; during δt it may accelerate at `reaction_accel` (default
  3.5 m/s^2: the ego may have just chosen Faster, and only the next step can brake). Rear (SV3, SV4):
  the SV follows and keeps its speed during δt (reaction_accel 0); the ego leads and brakes now.
  With these, R = 1 if and only if gap > safe_distance(...), the exact worst-case requirement.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from highway_srl.constants import DT_S, EGO_ACCEL_MAX_MPS2, EGO_BRAKE_MAX_MPS2, SV_BRAKE_MAX_MPS2

Num = torch.Tensor | float


def _t(x: Num, like: torch.Tensor | None = None) -> torch.Tensor:
    if isinstance(x, torch.Tensor):
        return x if x.is_floating_point() else x.float()
    if like is not None:
        return torch.as_tensor(x, dtype=like.dtype, device=like.device)
    return torch.as_tensor(x, dtype=torch.get_default_dtype())


def _promote(*xs: Num) -> list[torch.Tensor]:
    like = next((x for x in xs if isinstance(x, torch.Tensor) and x.is_floating_point()), None)
    return [_t(x, like) for x in xs]


# --------------------------------------------------------------------------- Eqs. 19, 20, 23 (building blocks)
def braking_displacement(v: Num, brake: Num, duration_s: Num, *, clamp_at_stop: bool = True) -> torch.Tensor:
    """Eq. 19, Δx_SV,δt = v δt - ½ |a| δt²: distance covered while braking at `brake` for `duration_s`.

    clamp_at_stop=True counts no backward motion once the vehicle has stopped (then it is v²/(2|a|));
    the literal Eq. 19 (False) goes negative for v < |a| δt / 2.
    """
    v, brake, d = _promote(v, brake, duration_s)
    if clamp_at_stop:
        d = torch.minimum(d, v / brake)
    return v * d - 0.5 * brake * d * d


def reaction_displacement(v: Num, duration_s: Num, accel: Num = 0.0) -> torch.Tensor:
    """Eq. 19, Δx_EV,δt = v δt, generalised to v δt + ½ a δt² for a follower accelerating at a >= 0."""
    v, d, a = _promote(v, duration_s, accel)
    return v * d + 0.5 * a * d * d


def residual_speed(v: Num, brake: Num, duration_s: Num, *, clamp_at_stop: bool = True) -> torch.Tensor:
    """Eq. 19, v_SV,Res = v - |a| δt: speed after braking for δt (clamped at 0 unless clamp_at_stop=False)."""
    v, brake, d = _promote(v, brake, duration_s)
    res = v - brake * d
    return res.clamp(min=0.0) if clamp_at_stop else res


def stopping_distance(v: Num, brake: Num) -> torch.Tensor:
    """Eq. 20, d_SD = v² / (2 |a_D,max|)."""
    v, brake = _promote(v, brake)
    return v * v / (2.0 * brake)


def stopping_time(v: Num, brake: Num) -> torch.Tensor:
    """Eq. 23, t_Stop = v / |a_D,max|."""
    v, brake = _promote(v, brake)
    return v / brake


@dataclass
class SafeDistances:
    """d_SD1, d_SD2, d_SD3 of Eq. 24/25 and the Eq. 21/22 condition that chose the d_SD3 branch."""

    d1: torch.Tensor
    d2: torch.Tensor
    d3: torch.Tensor
    condition: torch.Tensor  # bool: the B branch of d_SD3 was taken


# --------------------------------------------------------------------------- literal Eqs. 21-25
def condition_front_literal(v_ego, v_sv, ego_brake, sv_brake, reaction_s) -> torch.Tensor:
    """Eq. 21 as printed: (Δx_SV,δt <= d_EV,SD) ∧ (|a_SV| < |a_EV|) ∧ (v_SV,Res < v_EV) ∧ (t_EV,Stop < t*_SV,Stop)."""
    v_ego, v_sv, a_e, a_s, dt = _promote(v_ego, v_sv, ego_brake, sv_brake, reaction_s)
    dx_sv = braking_displacement(v_sv, a_s, dt, clamp_at_stop=False)
    v_res = residual_speed(v_sv, a_s, dt, clamp_at_stop=False)
    return (
        (dx_sv <= stopping_distance(v_ego, a_e))
        & (a_s < a_e)
        & (v_res < v_ego)
        & (stopping_time(v_ego, a_e) < stopping_time(v_res, a_s))
    )


def condition_rear_literal(v_ego, v_sv, ego_brake, sv_brake, reaction_s) -> torch.Tensor:
    """Eq. 22 as printed: (d_EV,SD <= Δx_SV,δt) ∧ (|a_EV| < |a_SV|) ∧ (v_EV < v_SV,Res) ∧ (t_EV,Stop < t*_SV,Stop)."""
    v_ego, v_sv, a_e, a_s, dt = _promote(v_ego, v_sv, ego_brake, sv_brake, reaction_s)
    dx_sv = braking_displacement(v_sv, a_s, dt, clamp_at_stop=False)
    v_res = residual_speed(v_sv, a_s, dt, clamp_at_stop=False)
    return (
        (stopping_distance(v_ego, a_e) <= dx_sv)
        & (a_e < a_s)
        & (v_ego < v_res)
        & (stopping_time(v_ego, a_e) < stopping_time(v_res, a_s))
    )


def safe_distances_front_literal(v_ego, v_sv, ego_brake, sv_brake, reaction_s) -> SafeDistances:
    """Eq. 24 as printed (SV ahead): d_SD1 = Δx_EV,δt + d_EV,SD; d_SD2 = d_SD1 - Δx_SV,δt;
    d_SD3 = B_F - Δx_SV,δt if Eq. 21 else C_F - d_SV,SD, with
    B_F = Δx_EV,δt - (v_SV,Res - v_EV)² / (2(|a_EV| - |a_SV|)), C_F = d_EV,SD + Δx_EV,δt."""
    v_ego, v_sv, a_e, a_s, dt = _promote(v_ego, v_sv, ego_brake, sv_brake, reaction_s)
    dx_sv = braking_displacement(v_sv, a_s, dt, clamp_at_stop=False)
    dx_ev = reaction_displacement(v_ego, dt)
    v_res = residual_speed(v_sv, a_s, dt, clamp_at_stop=False)
    d_ev = stopping_distance(v_ego, a_e)
    d1 = dx_ev + d_ev
    d2 = d1 - dx_sv
    cond = condition_front_literal(v_ego, v_sv, a_e, a_s, dt)
    denom = torch.where(cond, a_e - a_s, torch.ones_like(a_e - a_s))
    b_f = dx_ev - (v_res - v_ego) ** 2 / (2.0 * denom)
    c_f = d_ev + dx_ev
    d3 = torch.where(cond, b_f - dx_sv, c_f - stopping_distance(v_sv, a_s))
    return SafeDistances(*torch.broadcast_tensors(d1, d2, d3, cond))


def safe_distances_rear_literal(v_ego, v_sv, ego_brake, sv_brake, reaction_s) -> SafeDistances:
    """Eq. 25 as printed (SV behind): d_SD1 = Δx_SV,δt + d_SV,SD; d_SD2 = d_SD1 - v_EV δt - ½|a_EV| δt²;
    d_SD3 = B_R - v_EV δt if Eq. 22 else C_R + v_SV δt, with
    B_R = (v_EV - |a_EV| δt - v_SV)² / (2(|a_SV| - |a_EV|)), C_R = d_SV,SD - d_EV,SD."""
    v_ego, v_sv, a_e, a_s, dt = _promote(v_ego, v_sv, ego_brake, sv_brake, reaction_s)
    dx_sv = braking_displacement(v_sv, a_s, dt, clamp_at_stop=False)
    d_sv = stopping_distance(v_sv, a_s)
    d1 = dx_sv + d_sv
    d2 = d1 - v_ego * dt - 0.5 * a_e * dt * dt
    cond = condition_rear_literal(v_ego, v_sv, a_e, a_s, dt)
    denom = torch.where(cond, a_s - a_e, torch.ones_like(a_s - a_e))
    b_r = (v_ego - a_e * dt - v_sv) ** 2 / (2.0 * denom)
    c_r = d_sv - stopping_distance(v_ego, a_e)
    d3 = torch.where(cond, b_r - v_ego * dt, c_r + v_sv * dt)
    return SafeDistances(*torch.broadcast_tensors(d1, d2, d3, cond))


def case_d_literal(gap_m, dv, other_brake, reaction_s) -> torch.Tensor:
    """Eq. 27, D as printed: (Δx <= Δv δt + ½|a_SV| δt²) ∨ (Δx <= 0); Δv = v_SV - v_EV ahead, v_EV - v_SV behind."""
    gap_m, dv, a_s, dt = _promote(gap_m, dv, other_brake, reaction_s)
    return (gap_m <= dv * dt + 0.5 * a_s * dt * dt) | (gap_m <= 0)


def case_e_literal(gap_m, sd: SafeDistances, t_sv_stop, reaction_s) -> torch.Tensor:
    """Eq. 27, E as printed: (Δx > d_SD1) ∨ ((δt <= t_SV,Stop) ∧ (Δx > d_SD2))."""
    gap_m, t_stop, dt = _promote(gap_m, t_sv_stop, reaction_s)
    return (gap_m > sd.d1) | ((dt <= t_stop) & (gap_m > sd.d2))


def rule_from_cases(gap_m: torch.Tensor, d: torch.Tensor, e: torch.Tensor, d3: torch.Tensor) -> torch.Tensor:
    """Eq. 26: R = 0 if D, else 1 if E, else (Δx > d_SD3)."""
    return ~d & (e | (gap_m > d3))


# --------------------------------------------------------------------------- the sound reading (default)
def condition_follower_leader(v_follower, v_leader, follower_brake, leader_brake, reaction_s, reaction_accel=0.0):
    """Eqs. 21/22, sound form: the worst-case relative displacement peaks while both still move.

    With v_F1 = v_F + a δt (follower speed when it starts braking) and v_L,Res the leader's residual
    speed (Eq. 19, clamped): (|a_L| < |a_F|) ∧ (v_L,Res < v_F1) ∧ (t_F,Stop < t*_L,Stop), where
    t_F,Stop = v_F1/|a_F| and t*_L,Stop = v_L,Res/|a_L| (Eq. 23). The paper's extra clause
    Δx_SV,δt <= d_EV,SD is implied and dropped.
    """
    v_f, v_l, a_f, a_l, dt, acc = _promote(v_follower, v_leader, follower_brake, leader_brake, reaction_s, reaction_accel)
    v_f1 = v_f + acc * dt
    v_lres = residual_speed(v_l, a_l, dt)
    return (a_l < a_f) & (v_lres < v_f1) & (v_f1 * a_l < v_lres * a_f)


def safe_distances_follower_leader(
    v_follower, v_leader, follower_brake, leader_brake, reaction_s, reaction_accel=0.0
) -> tuple[SafeDistances, torch.Tensor]:
    """Eqs. 24/25, sound form for a follower F behind a leader L; returns (d_SD1..3, D-threshold).

    Δx_F,δt = v_F δt + ½ a δt² (Eq. 19, follower, a = reaction_accel), Δx_L,δt = braking displacement
    clamped at stop (Eq. 19), d_F,SD = v_F1²/(2|a_F|), d_L,SD = v_L²/(2|a_L|) (Eq. 20):
      d_SD1 = Δx_F,δt + d_F,SD                 (the leader could be standing: the follower's whole stop)
      d_SD2 = d_SD1 - Δx_L,δt                  (the leader covers at least Δx_L,δt)
      d_SD3 = Δx_F,δt - Δx_L,δt + (v_F1 - v_L,Res)² / (2(|a_F| - |a_L|))   if the condition holds (B)
            = d_SD1 - d_L,SD                                                otherwise (C: both stopped)
    The paper's B_F subtracts the last term (a sign slip) and its rear d_SD2 adds ½|a_EV|δt² to the
    leader's travel; both are fixed here. The D threshold is Δx_F,δt - Δx_L,δt, the gap closed during
    the reaction time (the printed D has Δv with the opposite sign).
    """
    v_f, v_l, a_f, a_l, dt, acc = _promote(v_follower, v_leader, follower_brake, leader_brake, reaction_s, reaction_accel)
    v_f, v_l = v_f.clamp(min=0.0), v_l.clamp(min=0.0)
    v_f1 = v_f + acc * dt
    v_lres = residual_speed(v_l, a_l, dt)
    dx_f = reaction_displacement(v_f, dt, acc)
    dx_l = braking_displacement(v_l, a_l, dt)
    d1 = dx_f + stopping_distance(v_f1, a_f)
    d2 = d1 - dx_l
    cond = condition_follower_leader(v_f, v_l, a_f, a_l, dt, acc)
    denom = torch.where(cond, a_f - a_l, torch.ones_like(a_f - a_l))
    d3 = torch.where(cond, dx_f - dx_l + (v_f1 - v_lres) ** 2 / (2.0 * denom), d1 - stopping_distance(v_l, a_l))
    d1, d2, d3, cond, d_thr = torch.broadcast_tensors(d1, d2, d3, cond, dx_f - dx_l)
    return SafeDistances(d1, d2, d3, cond), d_thr


def _roles(v_ego, v_other, front, ego_brake, other_brake, reaction_accel):
    """(v_follower, v_leader, follower_brake, leader_brake, reaction_accel) for SV ahead (front) or behind."""
    acc_front = EGO_ACCEL_MAX_MPS2 if reaction_accel is None else reaction_accel
    acc_rear = 0.0 if reaction_accel is None else reaction_accel
    if isinstance(front, bool):
        if front:
            return v_ego, v_other, ego_brake, other_brake, acc_front
        return v_other, v_ego, other_brake, ego_brake, acc_rear
    f = front
    v_ego, v_other, ego_brake, other_brake, acc_front, acc_rear = _promote(
        v_ego, v_other, ego_brake, other_brake, acc_front, acc_rear
    )
    w = torch.where
    return (
        w(f, v_ego, v_other),
        w(f, v_other, v_ego),
        w(f, ego_brake, other_brake),
        w(f, other_brake, ego_brake),
        w(f, acc_front, acc_rear),
    )


def _check_positive(name: str, value: Num) -> None:
    bad = (value <= 0).any().item() if isinstance(value, torch.Tensor) else value <= 0
    if bad:
        raise ValueError(f"{name} must be a positive deceleration in m/s^2, got {value!r}")


def safe_distance(
    v_ego: Num,
    v_other: Num,
    *,
    front: bool | torch.Tensor,
    reaction_s: Num = DT_S,
    ego_brake: Num = EGO_BRAKE_MAX_MPS2,
    other_brake: Num = SV_BRAKE_MAX_MPS2,
    reaction_accel: Num | None = None,
) -> torch.Tensor:
    """The smallest bumper gap (m) the default R_SVi accepts: R = 1 if and only if gap > safe_distance.

    It is max(0, Δx_F,δt - Δx_L,δt, d_SD3) of the sound Eqs. 24/25, i.e. the largest amount by which the
    follower closes in on the leader in the worst case described in the module docstring.
    """
    _check_positive("ego_brake", ego_brake)
    _check_positive("other_brake", other_brake)
    v_f, v_l, a_f, a_l, acc = _roles(v_ego, v_other, front, ego_brake, other_brake, reaction_accel)
    sd, d_thr = safe_distances_follower_leader(v_f, v_l, a_f, a_l, reaction_s, acc)
    return torch.maximum(torch.maximum(d_thr, sd.d3), torch.zeros_like(sd.d3))


def rule_indicator(
    gap_m: Num,
    v_ego: Num,
    v_other: Num,
    *,
    front: bool | torch.Tensor,
    reaction_s: Num = DT_S,
    ego_brake: Num = EGO_BRAKE_MAX_MPS2,
    other_brake: Num = SV_BRAKE_MAX_MPS2,
    literal: bool = False,
    reaction_accel: Num | None = None,
) -> torch.Tensor:
    """R_SVi of Eq. 26 (bool tensor, broadcast over the tensor arguments).

    gap_m: bumper-to-bumper longitudinal gap (m); v_ego, v_other: longitudinal speeds (m/s, >= 0);
    front: True for SV1/SV2 (other ahead), False for SV3/SV4 (other behind), or a bool tensor;
    ego_brake, other_brake: maximum decelerations (m/s^2, > 0); reaction_s: δt.
    literal=False (default): the sound reading, R = 1 iff gap > safe_distance(...). reaction_accel is the
      follower's acceleration during δt; None means EGO_ACCEL_MAX_MPS2 (3.5) ahead and 0 behind.
    literal=True: Eqs. 21-27 as printed (reaction_accel is ignored: the paper assumes constant speed).
    """
    _check_positive("ego_brake", ego_brake)
    _check_positive("other_brake", other_brake)
    gap_m, v_ego, v_other = _promote(gap_m, v_ego, v_other)
    v_ego, v_other = v_ego.clamp(min=0.0), v_other.clamp(min=0.0)
    if literal:
        return _rule_literal(gap_m, v_ego, v_other, front, reaction_s, ego_brake, other_brake)
    v_f, v_l, a_f, a_l, acc = _roles(v_ego, v_other, front, ego_brake, other_brake, reaction_accel)
    sd, d_thr = safe_distances_follower_leader(v_f, v_l, a_f, a_l, reaction_s, acc)
    d = (gap_m <= d_thr) | (gap_m <= 0)  # Eq. 27 D (sound): contact already within the reaction time
    e = (gap_m > sd.d1) | (gap_m > sd.d2)  # Eq. 27 E (sound; with Δx_L,δt clamped the δt-clause is implied)
    return rule_from_cases(gap_m, d, e, sd.d3)


def _rule_literal(gap_m, v_ego, v_other, front, reaction_s, ego_brake, other_brake) -> torch.Tensor:
    def one(is_front: bool) -> torch.Tensor:
        if is_front:
            sd = safe_distances_front_literal(v_ego, v_other, ego_brake, other_brake, reaction_s)
            dv = v_other - v_ego
        else:
            sd = safe_distances_rear_literal(v_ego, v_other, ego_brake, other_brake, reaction_s)
            dv = v_ego - v_other
        d = case_d_literal(gap_m, dv, other_brake, reaction_s)
        e = case_e_literal(gap_m, sd, stopping_time(v_other, _t(other_brake, v_other)), reaction_s)
        return rule_from_cases(gap_m, d, e, sd.d3)

    if isinstance(front, bool):
        return one(front)
    return torch.where(front, one(True), one(False))
