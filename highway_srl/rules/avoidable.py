"""Ego-avoidable collisions: whether the ego could have prevented a collision, grounded in RSS.

Definition (docs/paper-notes.md, "Ego-avoidable collisions"): a collision is ego-avoidable if some action
sequence within the ego's limits (accelerate <= 3.5, brake <= 6 m/s^2, keep or change lanes) from a state
it was in would have prevented it, while every other car keeps to its own limits: a leader brakes at most
at SV_BRAKE_MAX_MPS2 (the simulator's physical limit), a car behind brakes for the ego. That is the
responsibility rule of Responsibility-Sensitive Safety (Shalev-Shwartz, Shammah, Shashua 2017,
arXiv:1708.06374): the follower keeps the safe longitudinal distance (Definition 1, Lemma 2) and is to
blame for running into its leader; a car that cuts in at a distance below it is to blame itself.

The verdict reads what the decision trace keeps for a collision (experiments.collisions.DecisionTrace):
its kind (front, rear, side, road), who was changing lanes, and per decision the executed and allowed
actions and the longitudinal and lateral offsets and speeds of the vehicle that was hit. Cases, in order:
  1. an action the rule layer forbade was executed: avoidable (any allowed action was a choice);
  2. road (a lane end, a barrier, the road's edge): avoidable (the ego's own path);
  3. the ego was changing lanes and moved sideways toward the car it hit, past the centre of the lane it
     started the trace in, by LATERAL_MOVE_M or more: avoidable (it changed into an occupied or closing
     gap). An ego whose change stood still, went away from that car or settled toward its own lane's
     centre (a change stalled half-way, a target lane it had not begun to move to, an abort) has kept its
     lane: it is judged by the cases below, as RSS's lateral rule judges the car that moved sideways into
     the other;
  4. front: unavoidable only if the car it hit came into its path within the trace (seen out of it first,
     or out of it at the last decision; moving toward the ego by RSS's margin μ or more within the trace,
     not a car that kept its line while the ego moved into it: kept_its_line) at a bumper gap the ego could
     not stop in, braking at its limit at once while that car braked at its own (room_to_stop); avoidable otherwise, also when the car was
     in its path all along, unless it was behind the ego all along and drove up on it (came_from_behind);
  5. side: with the other car changing lanes, as case 4 (a car that turned in ahead with room to brake
     is avoidable, one that turned in alongside or below the stopping distance is not); else avoidable;
  6. rear: avoidable if the ego braked (Slower) while the car ahead did not require it (R*1 = 1) and the
     hit car behind was inside the RSS distance it needed to stop for the ego; else unavoidable.
Before 4 and 5: the ego stood through the last STANDING_ROWS decisions (1 s) and none of them allowed it to
move (Faster, the only action that moves a standing ego, never allowed): unavoidable. RSS's proper response, longitudinal and
lateral, ends at zero speed; a car at standstill with no allowed move has performed it, and the car that
moved into it is responsible.
Doubtful cases fall on the avoidable side: a claim of zero avoidable collisions must not rest on them.
"""

from __future__ import annotations

import math

import torch

from highway_srl.constants import (
    DT_S,
    EGO_ACCEL_MAX_MPS2,
    EGO_BRAKE_MAX_MPS2,
    EPS_P_M,
    LANE_WIDTH_M,
    SV_BRAKE_MAX_MPS2,
    VEHICLE_LENGTH_M,
    VEHICLE_WIDTH_M,
)
from highway_srl.sim.dynamics import K_HEADING, MIN_TURN_RADIUS_M, YAW_RATE_MAX

Num = torch.Tensor | float

# A car is in the ego's path when the two bodies are closer sideways than this: a car in the next lane whose
# corner has come within ε_p of the lane line (Eq. 31's near-boundary test, 1.25 m with w_L = 3.5, B = 2),
# the moment the rule layer groups it with the ego's lane and the ego can first answer it.
PATH_MARGIN_M = LANE_WIDTH_M / 2 + EPS_P_M - VEHICLE_WIDTH_M / 2

FORBIDDEN_ACTION = "executed an action the rule layer forbade"
ROAD = "left the road or ran into a lane end"
STOOD = "stood with no allowed move while a car moved into it"
EGO_CHANGED = "changed lanes into an occupied or closing gap"
RAN_INTO = "ran into the car ahead with room to stop"
CUT_IN = "cut in ahead below the ego's stopping distance"
SIDE_SWIPE = "an SV changing lanes met the ego's side"
SIDE_ROOM = "an SV turning in ahead left room to brake"
SIDE_KEEPING = "side contact with neither car changing lanes"
EGO_MOVED_IN = "moved sideways into a car that kept its line"
NEEDLESS_BRAKE = "braked without need in front of a close follower"
REAR = "hit from behind by a car that did not brake for the ego"
AVOIDABLE_REASONS = (FORBIDDEN_ACTION, ROAD, EGO_CHANGED, RAN_INTO, SIDE_ROOM, SIDE_KEEPING, NEEDLESS_BRAKE)
UNAVOIDABLE_REASONS = (STOOD, CUT_IN, SIDE_SWIPE, REAR)
# RSS's lateral rule blames the car that moved sideways toward the other beyond a small fluctuation (its μ):
# the ego counts as changing into the car it hit only if it moved this much toward it, past its lane's
# centre, within the trace (3 s); a standing car creeping at 0.44 m/s at 0.15 rad drifts 0.05 m in that time.
LATERAL_MOVE_M = 0.2
# the standing verdict reads the last second: a car that has stood that long with no allowed move has done
# RSS's proper response, whatever it did before (the trace is 3 s; it braked to a stop within it)
STANDING_ROWS = 8
# a car behind that came this much nearer over the trace (3 s) drove up on the ego; one that stood or fell back
# (the ego creeping away from a car standing beside it) did not, and the ego's doubt stays
CLOSING_M = 1.0
# RSS's lateral parameters as ad-rss and CARLA's RSS sensor set them by default: lateral acceleration within
# the response time, the lateral braking of the proper response, the fluctuation margin μ
LAT_ACCEL_MPS2, LAT_BRAKE_MPS2, LAT_MARGIN_M = 0.2, 0.8, 0.1
OFF_CENTRE_M = 0.5  # the census (experiments.collisions) takes a centre this far off its lane's centre as changing


def rss_safe_distance(v_rear: Num, v_front: Num, *, response_s: Num = DT_S, accel_max: Num = EGO_ACCEL_MAX_MPS2,
                      brake_min: Num = EGO_BRAKE_MAX_MPS2, brake_max: Num = SV_BRAKE_MAX_MPS2) -> torch.Tensor:
    """RSS minimum safe longitudinal distance, same direction (Shalev-Shwartz et al. 2017, Definition 1 and
    the closed form of Lemma 2), in m:

        d_min = [v_r ρ + ½ a_max,accel ρ² + (v_r + ρ a_max,accel)² / (2 a_min,brake) - v_f² / (2 a_max,brake)]_+

    v_rear, v_front: speeds of the rear and the front car (m/s, >= 0); response_s: ρ; accel_max: the rear
    car's largest acceleration during ρ; brake_min: the braking the rear car applies after ρ; brake_max: the
    front car's largest braking. Defaults: the paper's ego behind an SV (ρ = δt = 0.125 s, 3.5, 6, 6 m/s²).
    """
    v_r, v_f, rho, acc, b_min, b_max = (torch.as_tensor(z, dtype=torch.float64)
                                        for z in (v_rear, v_front, response_s, accel_max, brake_min, brake_max))
    if bool((b_min <= 0).any()) or bool((b_max <= 0).any()):
        raise ValueError("brake_min and brake_max must be positive decelerations in m/s^2")
    v_r1 = v_r + rho * acc
    d = v_r * rho + 0.5 * acc * rho * rho + v_r1 * v_r1 / (2.0 * b_min) - v_f * v_f / (2.0 * b_max)
    return d.clamp(min=0.0)


def stopping_distance_steps(v: float, brake: float = EGO_BRAKE_MAX_MPS2) -> float:
    """Distance (m) the ego covers from speed v braking at `brake` every step until it stands, as the
    simulator integrates it: constant deceleration exactly over each step, the last one ending where the
    car stands (sim/dynamics.integrate_speed), so v^2 / (2 brake) whatever the step's length."""
    return v * v / (2.0 * brake) if v > 0 else 0.0


def room_to_stop(gap_m: float, v_ego: float, v_sv: float, ego_brake: float = EGO_BRAKE_MAX_MPS2,
                 sv_brake: float = SV_BRAKE_MAX_MPS2) -> bool:
    """Whether the ego, braking at its limit from this decision on, stops behind a car `gap_m` ahead that
    brakes at its own limit from now (the end-state comparison of RSS with ρ = 0: the decision is the
    response)."""
    return gap_m > stopping_distance_steps(v_ego, ego_brake) - v_sv * v_sv / (2.0 * sv_brake)


def in_path(row: dict) -> bool | None:
    """Whether the hit car was in the ego's path at this decision (None: its offsets were not recorded)."""
    if row.get("dy") is None:
        return None
    return abs(row["dy"]) < VEHICLE_WIDTH_M + PATH_MARGIN_M


def ego_avoidable(kind: str, ego_changing: bool, sv_changing: bool, rows: list[dict]) -> tuple[bool, str]:
    """(avoidable, reason) of one collision, by the cases of the module docstring.

    kind: front, rear, side or road (experiments.collisions.classify); ego_changing / sv_changing: who was
    changing lanes at contact; rows: the decisions before it, oldest first, each with action and allowed
    (action names), r1 (R*1), v (the ego's speed), y (its lateral position, m) and, for the car that was hit, dx (its centre ahead of
    the ego's, m; negative behind), dy (sideways, m) and v_sv (m/s), or None where it was not recorded."""
    if kind not in ("front", "rear", "side", "road"):
        raise ValueError(f"unknown collision kind {kind!r}; choose front, rear, side or road")
    if any(r["action"] not in r["allowed"] for r in rows):
        return True, FORBIDDEN_ACTION
    if kind == "road":
        return True, ROAD
    if ego_changing and moved_toward(rows):
        return True, EGO_CHANGED
    if kind == "rear":
        return (True, NEEDLESS_BRAKE) if any(_needless_brake(r) for r in rows) else (False, REAR)
    standing = rows[-STANDING_ROWS:]
    if stood(standing) and not any("Faster" in r["allowed"] for r in standing):
        return False, STOOD
    if kind == "side":
        return entry_verdict(rows, SIDE_ROOM, SIDE_SWIPE) if sv_changing else (True, SIDE_KEEPING)
    return entry_verdict(rows, RAN_INTO, CUT_IN)


def entry_verdict(rows: list[dict], avoidable_reason: str, unavoidable_reason: str) -> tuple[bool, str]:
    """Cases 4 and 5: find where the hit car last came into the ego's path; room to stop behind it there
    decides (a car alongside or behind at that moment leaves none). Not seen out of the path first (in it
    since before the trace, or not recorded): the follower's responsibility, avoidable."""
    paths = [in_path(r) for r in rows]
    if paths and paths[-1] is False:  # it came into the path in the colliding step itself
        return (True, EGO_MOVED_IN) if kept_its_line(rows) else (False, unavoidable_reason)
    i = len(rows) - 1
    while i > 0 and paths[i] and paths[i - 1]:
        i -= 1
    if i <= 0 or not paths[i] or paths[i - 1] is not False:
        return (False, unavoidable_reason) if came_from_behind(rows) else (True, avoidable_reason)
    if kept_its_line(rows):
        return True, EGO_MOVED_IN
    r = rows[i]
    gap = r["dx"] - VEHICLE_LENGTH_M
    if gap <= 0.0:  # alongside or behind the ego's front when it came in: no braking of the ego answers it
        return False, unavoidable_reason
    return (True, avoidable_reason) if room_to_stop(gap, r["v"], r["v_sv"]) else (False, unavoidable_reason)


def kept_its_line(rows: list[dict]) -> bool:
    """The hit car did not come toward the ego: at no decision of the trace was its own lateral position (the
    ego's y + dy) farther from the ego, on its side, than at the last decision by RSS's lateral margin μ or
    more, so the ego's sideways motion brought it into the path (a standing car the ego's nose swung into,
    say). False where the trace does not keep both lateral positions."""
    if any(r.get(k) is None for r in rows for k in ("y", "dy")):
        return False
    side = 1.0 if rows[-1]["dy"] > 0 else -1.0
    at_last = rows[-1]["y"] + rows[-1]["dy"]
    return all((r["y"] + r["dy"] - at_last) * side < LAT_MARGIN_M for r in rows)


def came_from_behind(rows: list[dict]) -> bool:
    """The hit car drove up from behind: its centre behind the ego's at every decision of the trace and
    CLOSING_M or more nearer at the last than at the first. RSS puts the contact on it twice over: it is the
    rear car, to keep the distance (Lemma 2), and, turning in, the one that moved sideways into the other. A
    car in the path all along is otherwise the follower's doubt; this one was never ahead of the ego."""
    dxs = [r.get("dx") for r in rows]
    if not dxs or any(dx is None or dx >= 0.0 for dx in dxs):
        return False
    return dxs[-1] - dxs[0] >= CLOSING_M


def stood(rows: list[dict]) -> bool:
    """The ego stood through these decisions: at standstill in the state of every one and never executing
    Faster, the only action that moves a standing ego (the others' target speeds are at most v)."""
    return bool(rows) and all(r["v"] == 0.0 and r["action"] != "Faster" for r in rows)


def moved_toward(rows: list[dict]) -> bool:
    """Case 3: within the trace the ego moved LATERAL_MOVE_M or more sideways toward the car it hit (the side
    that car is on at the last decision), counting only the part past the centre of the lane it started the
    trace in (settling toward its own lane's centre is keeping its lane, not changing into the car's), and
    from RSS's blame time on (lateral_danger_from) it did not brake sideways (braked_sideways): a change
    into room that was there, answered once the other car turned toward it, is RSS's proper lateral response.
    True where the trace does not keep the ego's or that car's lateral position (doubt falls on the
    avoidable side)."""
    first, last = rows[0], rows[-1]
    if first.get("y") is None or last.get("y") is None or last.get("dy") is None:
        return True
    side = 1.0 if last["dy"] > 0 else -1.0
    centre = first["y"] if first.get("lane") is None else first["lane"] * LANE_WIDTH_M
    past = lambda y: max(0.0, (y - centre) * side)  # noqa: E731
    moved = past(last["y"]) - past(first["y"]) >= LATERAL_MOVE_M
    return moved and not braked_sideways(rows[lateral_danger_from(rows):], side)


def braked_sideways(rows: list[dict], side: float) -> bool:
    """RSS's proper lateral response from the first of rows on: the ego's lateral speed toward `side`
    (v tan h) grew by at most LAT_ACCEL_MPS2 within the response time (one decision), then fell by at least
    LAT_BRAKE_MPS2 a second until it was 0. False where a heading is missing."""
    if any(r.get("h") is None for r in rows):
        return False
    u = [r["v"] * math.tan(r["h"]) * side for r in rows]
    return all(u[k] <= max(0.0, u[0] + (LAT_ACCEL_MPS2 - LAT_BRAKE_MPS2 * (k - 1)) * DT_S) + 1e-6
               for k in range(1, len(u)))


def proper_lateral_speed(v: torch.Tensor, heading: torch.Tensor) -> torch.Tensor:
    """(B,) m/s: the speed at which an ego holding its lateral position (sim's HOLD_LANE: its heading turns
    back toward 0 at the lateral controller's rate) slows its lateral speed v sin h by LAT_BRAKE_MPS2 within
    the next step, RSS's lateral braking; a slow car unwinds its heading too slowly to do it by steering
    alone (yaw rate <= v / MIN_TURN_RADIUS_M). v, heading: (B,) the ego's speed and heading now."""
    yaw = torch.minimum(torch.minimum(K_HEADING * heading.abs(), v / MIN_TURN_RADIUS_M), torch.full_like(v, YAW_RATE_MAX))
    sin_next = torch.sin((heading.abs() - yaw * DT_S).clamp(min=0.0))
    lateral_next = (v * torch.sin(heading.abs()) - LAT_BRAKE_MPS2 * DT_S).clamp(min=0.0)
    return torch.where(sin_next > 1e-3, lateral_next / sin_next.clamp(min=1e-3), v)


def lateral_danger_from(rows: list[dict]) -> int:
    """The first decision from which the ego and the car it hit stayed closer sideways than RSS's lateral
    safe distance (lateral_safe_distance; bodies' lateral extents from their headings): RSS's blame time,
    after which a car moving sideways toward the other owes the lateral response. Before it the ego's
    sideways move was a change into room that was there (a car two lanes over turning in later is the
    one that moved into the other). 0 where a row lacks the headings (older traces: the whole trace)."""
    i = len(rows)
    while i > 0 and lateral_danger(rows[i - 1]):
        i -= 1
    return min(i, len(rows) - 1)


def lateral_danger(row: dict) -> bool:
    """The bodies' lateral gap at this decision is below lateral_safe_distance for the two lateral speeds
    toward each other (the ego's v tan h, the car's v_sv sin h_sv). True where a value is missing."""
    if any(row.get(k) is None for k in ("dy", "h", "h_sv", "v_sv")):
        return True
    side = 1.0 if row["dy"] > 0 else -1.0
    extent = lambda h: 0.5 * VEHICLE_LENGTH_M * abs(math.sin(h)) + 0.5 * VEHICLE_WIDTH_M * math.cos(h)  # noqa: E731
    gap = abs(row["dy"]) - extent(row["h"]) - extent(row["h_sv"])
    toward_ego = row["v"] * math.tan(row["h"]) * side
    toward_sv = -row["v_sv"] * math.sin(row["h_sv"]) * side
    return gap < lateral_safe_distance(toward_ego, toward_sv)


def lateral_safe_distance(u_a: float, u_b: float, *, response_s: float = DT_S, accel: float = LAT_ACCEL_MPS2,
                          brake: float = LAT_BRAKE_MPS2, margin: float = LAT_MARGIN_M) -> float:
    """RSS minimum safe lateral distance (Shalev-Shwartz et al. 2017, Definition 4), m, for two cars whose
    lateral speeds toward each other are u_a, u_b (m/s; negative: away): μ plus each car's worst-case travel
    toward the other, accelerating sideways at `accel` for ρ, then braking sideways at `brake` to a stop."""
    def travel(u: float) -> float:
        u1 = u + response_s * accel
        return u * response_s + 0.5 * accel * response_s ** 2 + u1 * abs(u1) / (2.0 * brake)
    return margin + max(0.0, travel(u_a) + travel(u_b))


def _needless_brake(row: dict) -> bool:
    """Case 6: Slower with the front safe, the hit car behind in the path and closer than its RSS distance
    (it keeps its speed for δt, as the rule layer assumes behind, then brakes at its limit)."""
    if row["action"] != "Slower" or not row["r1"] or not in_path(row) or row["dx"] >= 0:
        return False
    gap = -row["dx"] - VEHICLE_LENGTH_M
    need = rss_safe_distance(row["v_sv"], row["v"], accel_max=0.0, brake_min=SV_BRAKE_MAX_MPS2,
                             brake_max=EGO_BRAKE_MAX_MPS2)
    return gap < float(need)
