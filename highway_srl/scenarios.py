"""What each of the four scenarios is, as data: one frozen ScenarioSpec per scenario.

Everything the code decides per scenario is read from here (road and zones, change windows, the ego's
task, reward terms, success and failure events, the ID mapping's lane pairs, the SUMO and highway-env
network parameters), so a new scenario is one more spec plus, if its geometry is new, its road in
sim/road.py. Leaf data: imports only constants.

Frame and lane numbering: see sim/road.py (x along the mainline, lane 0 leftmost, a ramp is the lane
right of the mainline, index mainline_lanes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from highway_srl.constants import SCENARIOS

INF = math.inf

# The ego's task, which decides its mandatory lane changes, the stage flags and the events:
CRUISE = "cruise"  # expressway: no mandatory change, no stage flags, no success / failure event
MERGE = "merge"  # leave the on-ramp for the mainline; success: in a mainline lane in the stability zone
EXIT = "exit"  # move right onto the off-ramp; success: its end, failure: the mainline continuation's end


@dataclass(frozen=True)
class SumoEdge:
    """One SUMO edge: its id, where it starts and ends along x (the network's start / end where None),
    its number of lanes and our index of its leftmost lane."""

    id: str
    x_from_m: float | None
    x_to_m: float | None
    lanes: int
    first_lane: int


@dataclass(frozen=True)
class RewardTerm:
    """weight * (sum of the named 0/1 inputs), added after the main term in the order listed.

    Inputs: "merged", "exit1", "exit2" (latched stage flags), "r_star_sv1", "r_star_sv2" (R*_SV1, R*_SV2).
    Several inputs in one term are summed before weighting (Eq. 40's exit term is 0.3 (r_exit1 + r_exit2))."""

    weight: float
    inputs: tuple[str, ...]


@dataclass(frozen=True)
class ScenarioSpec:
    name: str
    task: str  # CRUISE, MERGE or EXIT
    mainline_lanes: int
    # zones along x (name -> [start, end)); zone lengths are not given by the paper, see sim/road.py
    zones: dict[str, tuple[float, float]] = field(default_factory=dict)
    # the ramp lane (index mainline_lanes), if any: where it exists, whether it physically ends (a wall)
    # or leaves the map there, and the zone over which it may be crossed to / from the mainline
    ramp_span_m: tuple[float, float] | None = None
    ramp_drops: bool = False
    change_zone: str | None = None
    ego_start_lanes: tuple[int, ...] = (0, 1)
    ego_start_x_m: float = 0.0
    # surrounding traffic: merge: 1 in 8 SVs (at least one) start on the ramp with merge intent;
    # exit: each SV is bound for the off-ramp with EXIT_INTENT_PROB (also when it re-enters)
    svs_start_on_ramp: bool = False
    svs_may_exit: bool = False
    # events: success ends the episode (exit) or only latches (merge); at episode end the trainer counts
    # an episode as a success when `success_flag` (a stage flag name) is set, if any
    success_terminates: bool = False
    success_flag: str | None = None
    # the zone whose end is x_key of the observation's progress feature (None: the feature is 0)
    progress_zone: str | None = None
    # ID mapping (§3.3): on a ramp road the ego in the ramp lane, or in the mainline's right lane inside
    # the change zone, uses the pair (right mainline lane, ramp); otherwise (lane - 1, lane) clamped to the
    # road. two_models: in a middle lane of a three-lane expressway both pairs are models.
    id_two_models: bool = False
    # rewards: training (§4.3) main weight on r_RM; deployment R_r (Eq. 40) main weight on v / v*
    training_main_weight: float = 1.0
    training_terms: tuple[RewardTerm, ...] = ()
    deployment_main_weight: float = 0.5
    deployment_terms: tuple[RewardTerm, ...] = ()
    # foreign simulators
    sumo_edges: tuple[SumoEdge, ...] = ()
    sumo_links: tuple[tuple[str, int, str, int], ...] = ()  # (from edge, our lane) -> (to edge, our lane)
    sumo_route_edges: tuple[str, ...] = ()  # edges on which the route (off-ramp or mainline) is chosen
    sumo_off_ramp_edge: str | None = None
    highway_env_kind: str = "highway"  # "highway", "merge" or "exit": which highway-env env it builds on
    gym_name: str = ""  # the Gymnasium id's scenario part (env/: highway-srl/<gym_name>-v0 style ids)

    @property
    def reports_success(self) -> bool:
        """Whether the evaluation reports a success rate R_s (the ramp tasks; an expressway has no goal)."""
        return self.task != CRUISE

    @property
    def stage_flags(self) -> tuple[str, ...]:
        """The latched stage flags the rewards need (what the env must pass)."""
        names = [i for t in self.training_terms + self.deployment_terms for i in t.inputs if not i.startswith("r_star")]
        return tuple(dict.fromkeys(names))


# Short enough that an ego at 5-10 m/s reaches each zone well inside the 320-step (40 s) episode and has
# several seconds in the merging / diverging zone.
MERGE_X = {"x0": 0.0, "x1": 60.0, "x2": 160.0, "x3": INF}
# Short enough that level-C traffic (about 6.5 m/s) reaches the end within the 40 s episode (210 m from the
# ego's start at x = 10 needs 5.3 m/s on average); see docs/paper-notes.md, "Roads".
EXIT_X = {"x0": 0.0, "x1": 60.0, "x2": 140.0, "x3_suc": 220.0, "x3_fail": 220.0}
OFF_RAMP_END_M = 450.0  # SUMO: the off-ramp edge runs past x3_suc (220 m) so success is reached before its end

_EXPRESSWAY_DEPLOYMENT = (RewardTerm(0.25, ("r_star_sv1",)), RewardTerm(0.25, ("r_star_sv2",)))

SPECS: dict[str, ScenarioSpec] = {
    "two-lane": ScenarioSpec(
        "two-lane", CRUISE, 2,
        gym_name="TwoLane",
        deployment_terms=_EXPRESSWAY_DEPLOYMENT,
        sumo_edges=(SumoEdge("main", None, None, 2, 0),),
    ),
    "multi-lane": ScenarioSpec(
        "multi-lane", CRUISE, 3,
        gym_name="MultiLane",
        ego_start_lanes=(0, 1, 2),
        id_two_models=True,
        deployment_terms=_EXPRESSWAY_DEPLOYMENT,
        sumo_edges=(SumoEdge("main", None, None, 3, 0),),
    ),
    "merge": ScenarioSpec(
        "merge", MERGE, 2,
        gym_name="Merge",
        zones={"on_ramp": (MERGE_X["x0"], MERGE_X["x1"]), "merging": (MERGE_X["x1"], MERGE_X["x2"]),
               "stability": (MERGE_X["x2"], MERGE_X["x3"])},
        ramp_span_m=(-INF, MERGE_X["x2"]),
        ramp_drops=True,
        change_zone="merging",
        ego_start_lanes=(2,),
        ego_start_x_m=10.0,
        svs_start_on_ramp=True,
        success_flag="merged",
        progress_zone="merging",
        training_main_weight=0.7,
        training_terms=(RewardTerm(0.3, ("merged",)),),
        deployment_main_weight=0.7,
        deployment_terms=(RewardTerm(0.3, ("merged",)),),
        sumo_edges=(
            SumoEdge("up", None, MERGE_X["x1"], 2, 0),
            SumoEdge("ramp", None, MERGE_X["x1"], 1, 2),
            SumoEdge("mrg", MERGE_X["x1"], MERGE_X["x2"], 3, 0),
            SumoEdge("down", MERGE_X["x2"], None, 2, 0),
        ),
        sumo_links=(("up", 0, "mrg", 0), ("up", 1, "mrg", 1), ("ramp", 2, "mrg", 2), ("mrg", 0, "down", 0),
                    ("mrg", 1, "down", 1)),
        highway_env_kind="merge",
    ),
    "exit": ScenarioSpec(
        "exit", EXIT, 2,
        gym_name="Exit",
        zones={"exit_preparation": (EXIT_X["x0"], EXIT_X["x1"]), "diverging": (EXIT_X["x1"], EXIT_X["x2"]),
               "mainline_continuation": (EXIT_X["x2"], EXIT_X["x3_fail"]),
               "off_ramp": (EXIT_X["x2"], EXIT_X["x3_suc"])},
        ramp_span_m=(EXIT_X["x1"], EXIT_X["x3_suc"]),
        ramp_drops=False,
        change_zone="diverging",
        ego_start_lanes=(0,),
        ego_start_x_m=10.0,
        svs_may_exit=True,
        success_terminates=True,
        progress_zone="diverging",
        training_main_weight=0.5,
        training_terms=(RewardTerm(0.25, ("exit1",)), RewardTerm(0.25, ("exit2",))),
        deployment_main_weight=0.5,
        deployment_terms=(RewardTerm(0.3, ("exit1", "exit2")),),
        sumo_edges=(
            SumoEdge("up", None, EXIT_X["x1"], 2, 0),
            SumoEdge("div", EXIT_X["x1"], EXIT_X["x2"], 3, 0),
            SumoEdge("down", EXIT_X["x2"], None, 2, 0),
            SumoEdge("off", EXIT_X["x2"], OFF_RAMP_END_M, 1, 2),
        ),
        sumo_links=(("up", 0, "div", 0), ("up", 1, "div", 1), ("div", 0, "down", 0), ("div", 1, "down", 1),
                    ("div", 2, "off", 2)),
        sumo_route_edges=("up", "div"),
        sumo_off_ramp_edge="off",
        highway_env_kind="exit",
    ),
}
assert tuple(SPECS) == SCENARIOS, "constants.SCENARIOS and the specs must list the same scenarios"
ENV_IDS = {name: spec.gym_name for name, spec in SPECS.items()}  # scenario -> <name> of highway-srl/<name>-v0


def scenario_spec(name: str) -> ScenarioSpec:
    """The spec of scenario `name`; raises ValueError (one line) naming the allowed scenarios."""
    try:
        return SPECS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown scenario {name!r}; choose one of {', '.join(SCENARIOS)}") from None


def check_scenario(name: str) -> str:
    """name, if it is a scenario; else the ValueError of scenario_spec."""
    return scenario_spec(name).name
