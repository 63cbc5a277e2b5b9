"""The paper's safety logic as pure, batched torch functions (§3.1-§3.3, Table 1, §4.2-§4.3).

safe_distance   R_SVi (Eqs. 19-27), sound by default, literal on request
safe_actions    A* = ACTIONS and the safe-action mask of Table 1
reward_machine  a generic batched RM, the highway RM (Eqs. U1-U4), v*, r_RM and the scenario rewards
mappings        ID, rule (Eqs. 31-32), action and control (Eqs. 34-35) mappings, default virtual vehicles
observation     the 37 network inputs
pipeline        SafetyLayer: everything above for one step of B envs
metrics         deployment reward R_r, C_r, average speed, R_s with confidence intervals
worst_case      brute-force worst-case simulation used to check the safe distance
"""

from highway_srl.rules.mappings import (
    IdMapping,
    LaneModel,
    Vehicles,
    default_virtual_vehicles,
    fill_defaults,
    id_mapping,
    crossing_toward,
    near_boundary,
    rule_mapping,
    target_lane_local,
    target_speed,
)
from highway_srl.rules.metrics import (
    Estimate,
    average_speed,
    collision_free_rate,
    deployment_episode_reward,
    deployment_step_reward,
    mean_interval,
    success_rate,
    wilson_interval,
)
from highway_srl.rules.observation import OBS_NAMES, build_observation, observation_ranges
from highway_srl.rules.pipeline import ModelStep, SafetyLayer, SafetyStep, choose_second, may_use_second
from highway_srl.rules.profiles import PROFILES, ControlProfile, control_profile
from highway_srl.rules.reward_machine import (
    COLLISION_REWARD,
    D_ACC_M,
    RM_STATES,
    HighwayPropositions,
    RewardMachine,
    desired_speed,
    highway_reward_machine,
    reward_machine_state,
    rm_reward,
    scenario_reward,
    speed_ratio,
)
from highway_srl.rules.safe_actions import (
    ACTIONS,
    FASTER,
    IDLE,
    LANE_CHANGE,
    NUM_ACTIONS,
    SLOWER,
    safe_action_mask,
    safe_action_mask_from,
)
from highway_srl.rules.safe_distance import rule_indicator, safe_distance
from highway_srl.rules.worst_case import worst_case_collides

__all__ = [
    "ACTIONS", "FASTER", "IDLE", "SLOWER", "LANE_CHANGE", "NUM_ACTIONS",
    "safe_action_mask", "safe_action_mask_from",
    "rule_indicator", "safe_distance", "worst_case_collides",
    "RewardMachine", "HighwayPropositions", "highway_reward_machine", "reward_machine_state", "rm_reward",
    "desired_speed", "speed_ratio", "scenario_reward", "RM_STATES", "D_ACC_M", "COLLISION_REWARD",
    "IdMapping", "LaneModel", "Vehicles", "id_mapping", "default_virtual_vehicles", "fill_defaults",
    "near_boundary", "crossing_toward", "rule_mapping", "target_lane_local", "target_speed",
    "OBS_NAMES", "build_observation", "observation_ranges",
    "SafetyLayer", "SafetyStep", "ModelStep", "choose_second", "ControlProfile", "PROFILES", "control_profile",
    "may_use_second",
    "Estimate", "deployment_step_reward", "deployment_episode_reward", "average_speed",
    "collision_free_rate", "success_rate", "wilson_interval", "mean_interval",
]
