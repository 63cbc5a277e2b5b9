"""Brute-force check of the safe-distance promise (used by scripts/sd_sweep.py and the property tests).

The worst case behind R_SVi (§3.2): the leader brakes at its maximum from t = 0 until it stands; the
follower moves with `reaction_accel` for the reaction time δt, then brakes at its maximum until it
stands. Positions are sampled on a fine time grid (default 1 ms) with exact constant-acceleration
kinematics and speeds clamped at 0, up to the time both stand (and at t = inf). A collision is a sampled
gap <= 0. This module knows nothing of the closed forms in safe_distance.py, so it checks them.
"""

from __future__ import annotations

import math

import torch

from highway_srl.constants import DT_S, EGO_ACCEL_MAX_MPS2, EGO_BRAKE_MAX_MPS2, SV_BRAKE_MAX_MPS2


def _position_braking(v: torch.Tensor, brake: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Distance covered by t (>= 0) when braking at `brake` from speed v, standing still once stopped."""
    tau = torch.minimum(t, v / brake)
    return v * tau - 0.5 * brake * tau * tau


def _sampled_min(g, vf, vl, bf, bl, a, vf1, xr, reaction_s, step_s, steps, time_block):
    """Smallest gap sampled at t = 0, step_s, ..., steps * step_s and at t = inf; inputs (n, 1), output (n,)."""
    x_f_end = xr + vf1 * vf1 / (2 * bf)
    best = torch.minimum(g, g + vl * vl / (2 * bl) - x_f_end)[:, 0]
    for t0 in range(0, steps + 1, time_block):
        t = torch.arange(t0, min(t0 + time_block, steps + 1), dtype=torch.float64)[None, :] * step_s
        t_react = t.clamp(max=reaction_s)
        x_f = vf * t_react + 0.5 * a * t_react * t_react + _position_braking(vf1, bf, (t - reaction_s).clamp(min=0.0))
        best = torch.minimum(best, (g + _position_braking(vl, bl, t) - x_f).min(1).values)
    return best


def worst_case_min_gap(
    gap_m: torch.Tensor,
    v_follower: torch.Tensor,
    v_leader: torch.Tensor,
    follower_brake: torch.Tensor,
    leader_brake: torch.Tensor,
    reaction_s: float = DT_S,
    reaction_accel: torch.Tensor | float = 0.0,
    *,
    dt_s: float = 1e-3,
    coarse: int = 50,
    chunk: int = 16384,
    time_block: int = 256,
) -> torch.Tensor:
    """Smallest sampled bumper gap (m) over the worst case, (N,) float64, for N cases given as (N,) tensors.

    The answer "min gap <= 0" is that of sampling every dt_s. To save time the grid is first sampled
    every coarse * dt_s; the gap G(t) has |G''| <= A = |a_F| + |a_L| + |reaction_accel|, so on an
    interval of length h it never dips more than A h^2 / 8 below its end points. Cases this bound cannot
    decide are sampled again every dt_s. The returned value is the coarse minimum for decided cases
    (within A h^2/8 of the fine one) and the fine minimum for the others.
    """
    args = torch.broadcast_tensors(
        *(torch.as_tensor(a, dtype=torch.float64) for a in (gap_m, v_follower, v_leader, follower_brake,
                                                              leader_brake, reaction_accel))
    )
    gap, v_f, v_l, b_f, b_l, acc = (a.reshape(-1) for a in args)
    v_f, v_l = v_f.clamp(min=0.0), v_l.clamp(min=0.0)
    if (acc < 0).any():
        raise ValueError("reaction_accel must be >= 0 (a follower that brakes during δt is not the worst case)")
    v_f1 = v_f + acc * reaction_s
    x_f_react = v_f * reaction_s + 0.5 * acc * reaction_s**2
    horizon = torch.maximum(v_l / b_l, reaction_s + v_f1 / b_f)
    h = dt_s * coarse
    bound = (b_f + b_l + acc) * h * h / 8.0
    order = torch.argsort(horizon)
    out = torch.empty_like(gap)
    for start in range(0, gap.numel(), chunk):
        idx = order[start:start + chunk]
        cols = [z[idx, None] for z in (gap, v_f, v_l, b_f, b_l, acc, v_f1, x_f_react)]
        steps = int(math.ceil(float(horizon[idx].max()) / h)) + 1
        best = _sampled_min(*cols, reaction_s, h, steps, time_block)
        # every coarse sample is an end point of an interval, so the certified lower bound is best - bound
        unsure = (best > 0) & (best - bound[idx] <= 0)
        if unsure.any():
            sub = [c[unsure] for c in cols]
            steps_f = int(math.ceil(float(horizon[idx][unsure].max()) / dt_s)) + 1
            best[unsure] = _sampled_min(*sub, reaction_s, dt_s, steps_f, 4 * time_block)
        out[idx] = best
    return out


def worst_case_collides(
    gap_m: torch.Tensor,
    v_ego: torch.Tensor,
    v_other: torch.Tensor,
    *,
    front: bool | torch.Tensor,
    reaction_s: float = DT_S,
    ego_brake: torch.Tensor | float = EGO_BRAKE_MAX_MPS2,
    other_brake: torch.Tensor | float = SV_BRAKE_MAX_MPS2,
    reaction_accel: torch.Tensor | float | None = None,
    dt_s: float = 1e-3,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(collides (N,) bool, min_gap (N,) m) of the worst case in the roles of rule_indicator.

    front: the ego follows the other vehicle; else the other vehicle follows the ego. reaction_accel is
    the follower's acceleration during δt; None means EGO_ACCEL_MAX_MPS2 ahead and 0 behind.
    """
    f64 = lambda z: torch.as_tensor(z, dtype=torch.float64)  # noqa: E731
    gap_m, v_ego, v_other, ego_brake, other_brake = torch.broadcast_tensors(
        f64(gap_m), f64(v_ego), f64(v_other), f64(ego_brake), f64(other_brake)
    )
    front_t = torch.broadcast_to(torch.as_tensor(front), gap_m.shape)
    if reaction_accel is None:
        acc = torch.where(front_t, EGO_ACCEL_MAX_MPS2, 0.0).to(torch.float64)
    else:
        acc = torch.broadcast_to(f64(reaction_accel), gap_m.shape)
    w = torch.where
    min_gap = worst_case_min_gap(
        gap_m,
        w(front_t, v_ego, v_other),
        w(front_t, v_other, v_ego),
        w(front_t, ego_brake, other_brake),
        w(front_t, other_brake, ego_brake),
        reaction_s,
        acc,
        dt_s=dt_s,
    ).reshape(gap_m.shape)
    return min_gap <= 0, min_gap
