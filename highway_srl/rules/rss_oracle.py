"""Intel's ad-rss as an independent oracle for the ego-avoidable verdict (optional extra: pip install -e ".[rss]").

ad-rss is the C++ implementation of Responsibility-Sensitive Safety by Intel/Mobileye with a Python binding
(the packages `ad-rss` and `ad-physics`). The oracle judges a collision by RSS's longitudinal rule alone:
the rear car must keep the safe distance d_min (Definition 1, computed by ad-rss's
calculateSafeLongitudinalDistanceSameDirection, not by our code) and is responsible for running into its
leader, unless the leader came into its path at a distance below d_min, which makes the leader responsible.
So:
  front: the ego is responsible unless the car it hit entered its path at a gap below d_min(v_ego, v_sv);
  rear: the car behind is responsible (RSS lets the leader brake as hard as it can);
  the ego changing lanes and moving sideways toward the car it hit by RSS's lateral margin μ or more
  in the last second before the contact: the ego is responsible (it moved into the other car's path); an ego whose change was
  commanded but whose centre held or moved away is judged by the other lines (RSS's lateral rule looks at
  lateral motion, not at intentions);
  side contact with the other car changing lanes, and road: not judged (RSS's lateral rule needs lateral
  speeds and accelerations the decision trace does not keep; a road edge is no RSS object).
rules.avoidable decides with ρ = 0 at the entry (the decision is the response) and puts doubtful cases on
the avoidable side, so where the two disagree the oracle is expected to be the lenient one; `compare`
counts both directions, and a case where the oracle blames the ego while ours does not is a finding.
"""

from __future__ import annotations

import warnings

from highway_srl.constants import DT_S, EGO_ACCEL_MAX_MPS2, EGO_BRAKE_MAX_MPS2, SV_BRAKE_MAX_MPS2, VEHICLE_LENGTH_M
from highway_srl.rules.avoidable import LAT_MARGIN_M, in_path

NOT_JUDGED = "not judged by RSS's longitudinal rule"


def load_ad_rss():
    """(rss, physics) modules of ad-rss; ValueError naming the extra when it is not installed."""
    try:
        with warnings.catch_warnings():  # the binding re-registers a boost converter and warns on import
            warnings.simplefilter("ignore")
            from ad_physics.ad_physics_python311 import physics
            from ad_rss.ad_rss_python311 import rss
    except ImportError as missing:
        raise ValueError("the RSS oracle needs Intel's ad-rss (Python 3.11): pip install -e \".[rss]\"") from missing
    return rss, physics


def _object_state(rss, ph, v: float, accel_max: float, brake_min: float, brake_max: float, rho: float):
    """A RelativeObjectState driving straight at v with the given longitudinal limits (brakes negative in
    ad-rss); every field its input check reads is set, the lateral and unstructured ones to neutral values."""
    s = rss.core.RelativeObjectState()
    s.object_type = rss.world.ObjectType.OtherVehicle
    d = s.dynamics
    d.alpha_lon.accel_max, d.alpha_lon.brake_max = ph.Acceleration(accel_max), ph.Acceleration(-brake_max)
    d.alpha_lon.brake_min = d.alpha_lon.brake_min_correct = ph.Acceleration(-brake_min)
    d.alpha_lat.accel_max, d.alpha_lat.brake_min = ph.Acceleration(0.1), ph.Acceleration(-0.1)
    d.response_time, d.max_speed_on_acceleration = ph.Duration(rho), ph.Speed(100.0)
    d.lateral_fluctuation_margin = d.min_longitudinal_safety_distance = ph.Distance(0.0)
    u = d.unstructured_settings
    u.pedestrian_turning_radius, u.drive_away_max_angle = ph.Distance(2.0), ph.Angle(2.4)
    u.vehicle_yaw_rate_change, u.vehicle_min_radius = ph.AngularAcceleration(0.3), ph.Distance(3.5)
    u.vehicle_trajectory_calculation_step = ph.Duration(0.2)
    o = s.unstructured_object_state
    o.yaw = o.steering_angle = ph.Angle(0.0)
    o.yaw_rate = ph.AngularVelocity(0.0)
    o.dimension.length, o.dimension.width = ph.Distance(5.0), ph.Distance(2.0)
    o.center_point.x = o.center_point.y = ph.Distance(0.0)
    o.speed_range.minimum, o.speed_range.maximum = ph.Speed(0.0), ph.Speed(max(v, 0.0))
    so = s.structured_object_state
    so.velocity.speed_lon_min = so.velocity.speed_lon_max = ph.Speed(v)
    so.velocity.speed_lat_min = so.velocity.speed_lat_max = ph.Speed(0.0)
    so.is_in_correct_lane, so.has_priority = True, False
    so.distance_to_enter_intersection = so.distance_to_leave_intersection = ph.Distance(0.0)
    return s


def ad_rss_safe_distance(v_rear: float, v_front: float, *, response_s: float = DT_S,
                         accel_max: float = EGO_ACCEL_MAX_MPS2, brake_min: float = EGO_BRAKE_MAX_MPS2,
                         brake_max: float = SV_BRAKE_MAX_MPS2) -> float:
    """ad-rss's minimum safe longitudinal distance (m), same direction, rear car at v_rear behind a car at
    v_front; the defaults are the paper's ego behind an SV (ρ = δt, 3.5 m/s² during ρ, both brakes 6)."""
    rss, ph = load_ad_rss()
    rear = _object_state(rss, ph, v_rear, accel_max, brake_min, brake_max, response_s)
    front = _object_state(rss, ph, v_front, accel_max, brake_min, brake_max, response_s)
    out = ph.Distance(0.0)
    if not rss.structured.calculateSafeLongitudinalDistanceSameDirection(front, rear, out):
        raise ValueError(f"ad-rss refused the state v_rear={v_rear!r}, v_front={v_front!r}")
    return float(out.mDistance)


def rss_verdict(kind: str, ego_changing: bool, sv_changing: bool, rows: list[dict],
                distance=ad_rss_safe_distance) -> bool | None:
    """Whether RSS holds the ego responsible for this collision (None: not judged); the inputs of
    rules.avoidable.ego_avoidable. `distance(v_rear, v_front)` is ad-rss's d_min unless a test passes another."""
    if kind == "road":
        return None
    if ego_changing and moved_sideways_toward(rows):
        return True
    if kind == "side":
        return None
    if kind == "rear":
        return False
    paths = [in_path(r) for r in rows]
    entries = [i for i in range(1, len(rows)) if paths[i] and paths[i - 1] is False]
    if paths and paths[-1] is False:  # it came into the path in the colliding step itself
        entries.append(len(rows) - 1)
    if not entries:
        return True  # in its path all along: the ego had to keep d_min
    r = rows[entries[-1]]
    return r["dx"] - VEHICLE_LENGTH_M >= distance(r["v"], r["v_sv"])


LATERAL_WINDOW = 8  # decisions (1 s) before the contact in which the ego's lateral motion counts


def moved_sideways_toward(rows: list[dict]) -> bool:
    """In the last LATERAL_WINDOW decisions (1 s) before the contact the ego's centre came LAT_MARGIN_M (μ) or
    more nearer the hit car's side: it was moving sideways toward that car when they met, which RSS's lateral
    rule puts on it (a change finished earlier, or commanded while the ego held its line, is not). True where
    the trace does not keep the lateral positions (the ego changing lanes is then responsible)."""
    recent = rows[-LATERAL_WINDOW:]
    if not recent or any(r.get("y") is None for r in (recent[0], recent[-1])) or recent[-1].get("dy") is None:
        return True
    side = 1.0 if recent[-1]["dy"] > 0 else -1.0
    return (recent[-1]["y"] - recent[0]["y"]) * side >= LAT_MARGIN_M


def compare(records: list[dict], distance=ad_rss_safe_distance) -> dict:
    """Counts over judged collision records of experiments.collisions.DecisionTrace (kind, ego_changing,
    sv_changing, decisions, and our ego_avoidable):
    agreements, both directions of disagreement, and those the oracle does not judge."""
    counts = {"collisions": 0, "agree": 0, "ours_avoidable_rss_not": 0, "rss_ego_ours_not": 0, "not_judged": 0}
    for rec in records:
        counts["collisions"] += 1
        verdict = rss_verdict(rec["kind"], rec["ego_changing"], rec["sv_changing"], rec["decisions"], distance)
        if verdict is None:
            counts["not_judged"] += 1
        elif verdict == rec["ego_avoidable"]:
            counts["agree"] += 1
        else:
            counts["rss_ego_ours_not" if verdict else "ours_avoidable_rss_not"] += 1
    return counts
