"""Road geometry of the four scenarios in a Frenet frame.

Frame (see docs/paper-notes.md, "Lateral frame"): x is arc length along the mainline in metres; y is the
lateral offset in metres, growing to the right. Lane k's centre line is at y = k * w_L, so lane 0 is the
leftmost lane (the paper's L_ID = 0) and the boundary between lanes k and k+1 is at y = (k + 1/2) * w_L.
With this frame the paper's d_VL = |y - T_ID * w_L| is the distance to the target lane's centre.

A ramp is one more lane to the right of the mainline that exists only over part of x:
- merge: lane 2 is the on-ramp. On-ramp lane [x0, x1) (no lane change: a barrier separates it), merging
  zone [x1, x2) (it runs beside lane 1 and may be left for lane 1), then it ends (a lane drop at x2);
  the stability zone is the mainline from x2 to x3.
- exit: lane 2 is the off-ramp. Exit-preparation zone [x0, x1) (no off-ramp yet), diverging zone
  [x1, x2) (the deceleration lane beside lane 1), then the off-ramp [x2, x3_suc) leaves the mainline
  (no lane change back) and the mainline continues [x2, x3_fail).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from highway_srl.constants import LANE_WIDTH_M
from highway_srl.scenarios import EXIT_X, MERGE_X, ScenarioSpec, scenario_spec  # noqa: F401  (MERGE_X, EXIT_X: re-exported)

INF = math.inf


@dataclass(frozen=True)
class Road:
    scenario: str
    num_lanes: int  # lanes in the frame, ramp included
    mainline_lanes: int  # lanes that exist everywhere
    lane_start_m: tuple[float, ...]  # where each lane begins (-inf: always there)
    lane_end_m: tuple[float, ...]  # where each lane ends (+inf: never)
    lane_drop: tuple[bool, ...]  # True: the lane physically ends (a wall at lane_end_m); False: it leaves the map
    change_window_m: tuple[tuple[float, float], ...]  # per boundary k|k+1: x-interval where crossing is allowed
    zones: dict[str, tuple[float, float]] = field(default_factory=dict)
    ego_start_lanes: tuple[int, ...] = (0, 1)  # the ego starts in one of these, uniformly
    ego_start_x_m: float = 0.0
    lane_width_m: float = LANE_WIDTH_M

    @property
    def spec(self) -> ScenarioSpec:
        return scenario_spec(self.scenario)

    @property
    def has_ramp(self) -> bool:
        return self.num_lanes > self.mainline_lanes

    def lane_centre_m(self, lane: int) -> float:
        return lane * self.lane_width_m

    @property
    def y_min_m(self) -> float:
        return -0.5 * self.lane_width_m

    @property
    def y_max_m(self) -> float:
        return (self.num_lanes - 0.5) * self.lane_width_m


def make_road(scenario: str) -> Road:
    """The road of one scenario, built from its spec; raises ValueError naming the allowed scenarios.

    The mainline lanes exist everywhere and may be crossed anywhere; a ramp lane (if the spec has one) is
    one more lane on the right over spec.ramp_span_m, crossable to / from the mainline in spec.change_zone.
    """
    spec = scenario_spec(scenario)
    n = spec.mainline_lanes
    starts, ends, drops = [-INF] * n, [INF] * n, [False] * n
    windows = [(-INF, INF)] * (n - 1)
    if spec.ramp_span_m is not None:
        starts.append(spec.ramp_span_m[0])
        ends.append(spec.ramp_span_m[1])
        drops.append(spec.ramp_drops)
        windows.append(spec.zones[spec.change_zone])
    return Road(scenario, len(starts), n, tuple(starts), tuple(ends), tuple(drops), tuple(windows),
                zones=dict(spec.zones), ego_start_lanes=spec.ego_start_lanes, ego_start_x_m=spec.ego_start_x_m)
