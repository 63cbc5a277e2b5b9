"""Adversarial traffic (group 3 of the paper): SVs that cut into the ego's lane.

Two variants, by the names World(adversary=...), the CLI and the configs take (ADVERSARIES): "mild",
`cut_ins_ahead_with_room` (ours: a cut-in ahead of the ego, with room, triggered by the gap falling below the
ego's kinematic safe distance plus a per-SV offset), and "paper", `cut_ins_whatever_the_gaps` (§4.3 as printed: the bumper gap below the sampled |d_trig - d_SVi| in {0, 5, 10} m,
ahead, alongside or behind, whatever the gaps). Both count their draws and cut-ins per episode in the world
state (adv_triggers, adv_cut_ins). docs/paper-notes.md, "The paper's adversary", gives the readings.
"""

from __future__ import annotations

import torch

from highway_srl.constants import DT_S, EGO_BRAKE_MAX_MPS2, SV_BRAKE_MAX_MPS2, VEHICLE_LENGTH_M
from highway_srl.sim import rng
from highway_srl.sim.idm_mobil import FAR_M, MOBIL_MIN_GAP_M
from highway_srl.sim.lane_tables import LaneTables
from highway_srl.sim.selection import entries, narrow, none_left, ones, put
from highway_srl.sim.state import WorldState
from highway_srl.sim.sv_drivers import Neighbours

# Group 3 reading: cut-ins only by SVs wholly ahead of the ego (False) or also alongside it (True)
ADVERSARIAL_ALONGSIDE = False
S_ADV = 20  # random stream of the trigger draw (spawn uses 0-7, recycling 21 and 23)
S_PAPER_ADV = 24  # random stream of the paper adversary's draws


def kinematic_safe_distance(v_follower: torch.Tensor, v_leader: torch.Tensor) -> torch.Tensor:
    """The follower's safe distance (bumper to bumper, m, >= 0) to a leader, both (M,) m/s: one step of
    reaction at v_follower, then the follower braking at |a_EV,D,max| while the leader brakes at
    |a_SV,D,max|, compared by stopping distances.

    It is the simple kinematic form, not the paper's rules/safe_distance (the simulator may not import the
    rules layer, which sits above it, and the trigger's numbers are pinned to this form)."""
    v, u = v_follower, v_leader
    return (v * DT_S + v * v / (2 * EGO_BRAKE_MAX_MPS2) - u * u / (2 * SV_BRAKE_MAX_MPS2)).clamp(min=0)


def cut_ins_ahead_with_room(s: WorldState, tables: LaneTables, nb: Neighbours, static: bool = False) -> None:
    """Group 3: an adjacent-lane SV ahead of the ego (its rear bumper ahead of the ego's front bumper)
    cuts into the ego's lane once its gap falls below d_trig = (the ego's kinematic safe distance to it)
    + offset, offset in {0, 5, 10} m, with probability ABP; each SV evaluates its trigger once per episode.

    The attack is on the ego: only an SV with the ego as its immediate follower in the ego's lane and room
    to its leader there (MOBIL_MIN_GAP_M plus the difference of their braking distances) is a candidate,
    so a cut-in never lands on another SV. With
    ADVERSARIAL_ALONGSIDE an SV alongside the ego (its centre at most L behind the ego's) may also cut
    in, which is a side swipe no driving policy can avoid (see docs/paper-notes.md).
    static: visit every vehicle under a mask (see sim/selection.py) instead of listing the candidates.
    """
    ego_lane, ego_x, ego_v = s.lane[:, :1], s.x[:, :1], s.v[:, :1]
    lowest = ego_x - VEHICLE_LENGTH_M if ADVERSARIAL_ALONGSIDE else ego_x + VEHICLE_LENGTH_M
    cand = ((s.lane - ego_lane).abs() == 1) & (s.x >= lowest) & ~s.trigger_used
    cand &= (s.adversarial_prob > 0) & (s.target_lane == s.lane)
    cand[:, 0] = False
    bb, ii, sel = entries(cand, static)
    if none_left(bb, sel):
        return
    el = ego_lane[bb, 0]
    x, v = s.x[bb, ii], s.v[bb, ii]
    keep = tables.can_change(x, s.lane[bb, ii], el)
    nl, nf = nb.leader[el, bb, ii], nb.follower(el, bb, ii)
    # room to stop behind the car it cuts in front of, whatever that car does (it attacks the ego only)
    v_l = nb.v_pad[bb, nl]
    stop = ((v * v - v_l * v_l) / (2 * SV_BRAKE_MAX_MPS2)).clamp(min=0.0)
    room_ahead = nb.x_pad[bb, nl] - x - VEHICLE_LENGTH_M > MOBIL_MIN_GAP_M + stop
    room_behind = x - torch.where(nf < s.x.shape[1], nb.x_pad[bb, nf], -FAR_M) - VEHICLE_LENGTH_M > MOBIL_MIN_GAP_M
    keep &= ((nf == 0) & room_ahead) | ((nl == 0) & room_behind)
    gap = x - ego_x[bb, 0] - VEHICLE_LENGTH_M
    ev = ego_v[bb, 0]
    d_safe = kinematic_safe_distance(ev, v)
    trig = keep & (gap < d_safe + s.trigger_offset[bb, ii])
    sel, bb, ii, el = narrow(sel, trig, bb, ii, el)
    if none_left(bb, sel):
        return
    _draw_and_force(s, bb, ii, el, S_ADV, sel)


def _draw_and_force(s: WorldState, bb: torch.Tensor, ii: torch.Tensor, lane: torch.Tensor, stream: int,
                    sel: torch.Tensor | None = None) -> None:
    """The trigger of SVs (env bb, vehicle ii), all (M,): one draw each, marked used; with probability ABP
    the SV's target becomes `lane` at once, forced (MOBIL's checks and the abort skipped until it is
    centred). Adds to the episode's counters adv_triggers and adv_cut_ins. sel: see sim/selection.py."""
    u = rng.uniform_at(rng.key(s.seed[bb], s.episode[bb], s.t[bb], stream), ii)
    fire = u < s.adversarial_prob[bb, ii]
    put(s.trigger_used, bb, ii, True, sel)
    s.adv_triggers.index_add_(0, bb, ones(bb, sel))
    sel, bb, ii, lane = narrow(sel, fire, bb, ii, lane)
    put(s.forced, bb, ii, True, sel)
    put(s.target_lane, bb, ii, lane, sel)
    s.adv_cut_ins.index_add_(0, bb, ones(bb, sel))


def cut_ins_whatever_the_gaps(s: WorldState, tables: LaneTables, static: bool = False) -> None:
    """Group 3 as printed (§4.3): "When the distance between the EV and SV_i falls below |d_trig - d_SVi|,
    the SV initiates a forced lane change with probability ABP ... at most once per episode."

    Every SV of a style with ABP > 0 in a lane next to the ego's, keeping its lane, whose bumper gap to the
    ego |x_SV - x_EV| - L (negative side by side) is below its threshold trigger_offset in {0, 5, 10} m
    (the sampled |d_trig - d_SVi|), draws once per episode and, with probability ABP, changes into the ego's
    lane whatever the gaps: ahead, alongside or behind (a swerve into a car beside it cannot be avoided by
    any policy). It must be allowed to cross there (LaneTables.can_change) and never cuts into a lane that
    ends (the merge's on-ramp). Runs on the positions at the start of the step, before the traffic moves.
    static: see sim/selection.py.
    """
    ego_lane, ego_x = s.lane[:, :1], s.x[:, :1]
    cand = ((s.lane - ego_lane).abs() == 1) & ~s.trigger_used & (s.adversarial_prob > 0)
    cand &= (s.target_lane == s.lane) & ~s.forced
    cand &= (s.x - ego_x).abs() - VEHICLE_LENGTH_M < s.trigger_offset
    cand[:, 0] = False
    bb, ii, sel = entries(cand, static)
    if none_left(bb, sel):
        return
    el = ego_lane[bb, 0]
    keep = tables.can_change(s.x[bb, ii], s.lane[bb, ii], el) & ~torch.isfinite(tables.drop_end_m[el])
    if sel is not None or bool(keep.any()):
        sel, bb, ii, el = narrow(sel, keep, bb, ii, el)
        _draw_and_force(s, bb, ii, el, S_PAPER_ADV, sel)


# The adversaries by their user-facing names. step_state runs "paper" on the positions at the start of a step,
# before the traffic moves; the dynamics run "mild" after the SVs' lane decisions (it reads their neighbours).
ADVERSARIES = {"mild": cut_ins_ahead_with_room, "paper": cut_ins_whatever_the_gaps}
