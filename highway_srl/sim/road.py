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

from highway_srl.constants import LANE_WIDTH_M, SCENARIOS

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


# Zone lengths are not given by the paper; these are chosen so that an ego at 5-10 m/s reaches each zone
# well inside the 320-step (40 s) episode and has several seconds in the merging / diverging zone.
MERGE_X = {"x0": 0.0, "x1": 60.0, "x2": 160.0, "x3": INF}
# Short enough that level-C traffic (about 6.5 m/s) reaches the end within the 40 s episode (210 m from the
# ego's start at x = 10 needs 5.3 m/s on average); see docs/paper-notes.md, "Roads".
EXIT_X = {"x0": 0.0, "x1": 60.0, "x2": 140.0, "x3_suc": 220.0, "x3_fail": 220.0}


def make_road(scenario: str) -> Road:
    """The road of one scenario; raises ValueError naming the allowed scenarios."""
    if scenario == "two-lane":
        return Road(scenario, 2, 2, (-INF, -INF), (INF, INF), (False, False), ((-INF, INF),))
    if scenario == "multi-lane":
        return Road(
            scenario, 3, 3, (-INF,) * 3, (INF,) * 3, (False,) * 3, ((-INF, INF), (-INF, INF)), ego_start_lanes=(0, 1, 2)
        )
    if scenario == "merge":
        m = MERGE_X
        return Road(
            scenario,
            3,
            2,
            (-INF, -INF, -INF),
            (INF, INF, m["x2"]),
            (False, False, True),
            ((-INF, INF), (m["x1"], m["x2"])),
            zones={"on_ramp": (m["x0"], m["x1"]), "merging": (m["x1"], m["x2"]), "stability": (m["x2"], m["x3"])},
            ego_start_lanes=(2,),
            ego_start_x_m=10.0,
        )
    if scenario == "exit":
        e = EXIT_X
        return Road(
            scenario,
            3,
            2,
            (-INF, -INF, e["x1"]),
            (INF, INF, e["x3_suc"]),
            (False, False, False),
            ((-INF, INF), (e["x1"], e["x2"])),
            zones={
                "exit_preparation": (e["x0"], e["x1"]),
                "diverging": (e["x1"], e["x2"]),
                "mainline_continuation": (e["x2"], e["x3_fail"]),
                "off_ramp": (e["x2"], e["x3_suc"]),
            },
            ego_start_lanes=(0,),
            ego_start_x_m=10.0,
        )
    raise ValueError(f"unknown scenario {scenario!r}; choose one of {', '.join(SCENARIOS)}")
