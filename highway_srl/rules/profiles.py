"""The control profiles: which of the project's safety additions to the rule and control mappings (Eqs. 31-35)
are on. `paper` is Eqs. 31-35 as printed; `safe` adds each of ours, every one justified by a measured crash
(docs/paper-notes.md, "Profiles: paper vs safe"). rules.pipeline.SafetyLayer reads them."""

from __future__ import annotations

from dataclasses import dataclass

STANDSTILL_GAP_M = 1.0  # margin subtracted from every bumper gap before the SD rule (docs/paper-notes.md)


@dataclass(frozen=True)
class ControlProfile:
    """Which of our safety additions to the rule and control mappings (Eqs. 31-35) are on.

    abort_unsafe_change: a held lane change is given up (T* = C_ID) when R*2 ∧ R*4 fail; brake_while_changing:
    LaneChange behind an unsafe SV1 (R*1 = 0) brakes as Slower; finish_in_window: a change is started or held
    only if it ends before the road's change window closes; straddle_grouping: an ego near the boundary
    occupies both lanes (R*1 ∧ R*2, R*3 ∧ R*4); standstill_gap_m: margin taken off every bumper gap before
    the SD rule; turning_in_is_near: an SV whose body crosses the lane line while it heads toward the ego's
    side is near it in Eq. 31 (mappings.crossing_toward); last_resort_stops: Idle as Table 1's last resort
    (R*1 = 0, so Idle is the only safe action) brakes just hard enough to stop within the room ahead
    (mappings.stopping_speed) instead of keeping the speed; reaching_over_is_near: an SV whose centre is
    beyond the line while its body crosses it is near it (mappings.reaching_over); watch_third_lane: cars of
    the lane the model does not hold join the rules of the lane they reach into (rules.third_lane);
    ego_body_straddles: the straddle grouping also holds while the ego's body crosses the line; lanes_by_body:
    the nearest cars whose bodies reach into the pair's lanes join those lanes' rules (rules.lanes_by_body);
    back_out_of_entry: an ego whose body still crosses the line into the lane it is entering goes back to the
    lane it came from when the one it enters turns unsafe and that one is safe, whatever the action; hold_lateral: where it cannot go
    back (that lane unsafe too, or one the model no longer holds), it stops moving sideways instead (the
    simulator's HOLD_LANE), braking as far as RSS's lateral response needs (rules.avoidable.
    proper_lateral_speed), also while going back heading into that lane (rules.lateral), and it holds where a
    command would swing a corner of its body (turning about its centre) within RSS's lateral margin of a car
    (rules.body_swing). docs/paper-notes.md, "Profiles: paper vs safe", gives each with the crash that
    motivated it.
    """

    abort_unsafe_change: bool
    brake_while_changing: bool
    finish_in_window: bool
    straddle_grouping: bool
    standstill_gap_m: float
    turning_in_is_near: bool
    last_resort_stops: bool
    reaching_over_is_near: bool
    watch_third_lane: bool
    ego_body_straddles: bool
    lanes_by_body: bool
    back_out_of_entry: bool
    hold_lateral: bool


# paper: Eqs. 31-35 as printed plus only the readings they cannot work without (holding a change under way);
# safe: the project's additions on top, each justified by a measured crash.
PROFILES: dict[str, ControlProfile] = {
    "paper": ControlProfile(False, False, False, False, 0.0, False, False, False, False, False, False, False, False),
    "safe": ControlProfile(True, True, True, True, STANDSTILL_GAP_M, True, True, True, True, True, True, True, True),
}


def control_profile(name: str) -> ControlProfile:
    """The profile called name ("paper" or "safe"); ValueError naming the choices otherwise."""
    if name not in PROFILES:
        raise ValueError(f"unknown profile {name!r}; choose one of {', '.join(PROFILES)}")
    return PROFILES[name]
