"""The safe profile's answer to the lane being entered turning unsafe (back_out_of_entry, hold_lateral in
rules.profiles): go back where the ego came from if that lane is safe, hold the lateral position if not,
and brake sideways as RSS's proper lateral response needs (docs/paper-notes.md, "Profiles: paper vs safe")."""

from __future__ import annotations

import torch

from highway_srl.rules.mappings import crosses_line


def entry_response(m, snap, previous: torch.Tensor, lane_width_m: float, back_out: bool, hold_lateral: bool):
    """(previous, backing, hold) for rules.pipeline.SafetyLayer.act.

    m: the acting model's step (lanes, r_star, m_l_ego); snap: the snapshot (ego_y, ego_heading); previous:
    (B,) long local target held so far. Returns the held target (local), where every action keeps it (B,)
    bool, and None or (where to hold the lateral position, where going back still heads into the lane turning
    unsafe), (B,) bool each.
    """
    # the centre has crossed, the body not yet: the lane being entered turning unsafe (a car turning into it)
    # sends the ego back where it came from, if that lane is safe; settling on toward the lane's centre met
    # the car (RSS: stop moving sideways toward it)
    w, c_id, r_star = lane_width_m, m.lanes.c_id, m.r_star
    y_local = snap.ego_y - m.lanes.base_lane * w
    body = m.m_l_ego | crosses_line(y_local, snap.ego_heading, w)
    unsafe = ~(r_star[:, 0] & r_star[:, 2])
    entering = (previous == c_id) & unsafe
    way_back = body & r_star[:, 1] & r_star[:, 3] & back_out
    back = entering & way_back
    previous = torch.where(back, 1 - c_id, previous)
    # going back (decided now or before), every action keeps that target: Eq. 35's LaneChange on the line
    # (both rears safe: C_ID) sent the ego into the unsafe lane again
    backing = (previous == 1 - c_id) & unsafe & way_back
    if not hold_lateral:
        return previous, backing, None
    # no way back (or from a lane the model no longer holds): hold. Going back with the heading still into
    # the lane turning unsafe, the sideways speed toward it is braked as RSS's lateral response needs: a slow
    # ego unwinds its heading at v / 4 m rad/s only and went on into that lane for seconds
    over = body | crosses_line(y_local + w, snap.ego_heading, w) | crosses_line(y_local - w, snap.ego_heading, w)
    toward = snap.ego_heading * (2 * c_id - 1) > 0
    return previous, backing, (entering & over & ~back, (previous == 1 - c_id) & unsafe & over & toward)
