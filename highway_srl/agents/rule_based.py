"""A rule-based ego driver: IDM car following and MOBIL-style lane changes through the paper's safety check.

It chooses among A* on a SafetyLayer's model of the step, so it drives every scenario the mappings cover:
  1. longitudinal wish from the IDM (Treiber et al.) behind SV1: Faster above +A_FASTER, Slower below
     -A_SLOWER, else Idle;
  2. lane-change wish: mandatory changes (merge: off the on-ramp; exit: towards the off-ramp);
     discretionary changes when the IDM acceleration behind SV2 beats the one behind SV1 by MOBIL_GAIN (not
     while near the boundary, never back onto a ramp, only rightwards on exit); either only when the target
     lane has room by the built-in driver's gap rule (sim/ego_driver.room_to_change on SV2 ahead, SV4 behind);
  3. a change under way: with the layer's hold_lane_change (Faster/Idle/Slower keep the target lane) the
     driver continues it with the longitudinal wish, now also behind the target lane's leader SV2; with the
     literal Eq. 34 (they reset the target to C_ID) it keeps asking for LaneChange;
  4. the first action of a fixed preference order that Table 1 marks safe (every row has one).
It is the expert of ET-RL and, as the method `rule-based`, a driver with no learning.
"""

from __future__ import annotations

import torch

from highway_srl.constants import V_MAX_MPS
from highway_srl.scenarios import EXIT, MERGE, scenario_spec
from highway_srl.rules import FASTER, IDLE, LANE_CHANGE, SLOWER, ModelStep, SafetyStep, choose_second, may_use_second
from highway_srl.sim.ego_driver import EGO_JAM_M, room_to_change
from highway_srl.sim.idm_mobil import idm_accel

JAM_DISTANCE_M = EGO_JAM_M  # IDM s0 of the ego, shared with the built-in driver (sim/ego_driver.py)
A_FASTER_MPS2 = 0.5  # IDM acceleration above which the driver asks for Faster
A_SLOWER_MPS2 = 1.0  # IDM deceleration above which it asks for Slower
MOBIL_GAIN_MPS2 = 0.5  # acceleration advantage a discretionary lane change must bring (hysteresis)
NO_WISH = float("-inf")

# Preference order (first safe one wins), per wish: Faster, Idle, Slower, LaneChange. Braking comes
# before Idle when Faster is not allowed, because Idle is safe without R1 only when braking is not.
_ORDER = {
    FASTER: (FASTER, SLOWER, IDLE, LANE_CHANGE),
    IDLE: (IDLE, SLOWER, FASTER, LANE_CHANGE),
    SLOWER: (SLOWER, IDLE, LANE_CHANGE, FASTER),
}


def _rank_table(device) -> torch.Tensor:
    """(3, 4): score of each action (higher = preferred) for each longitudinal wish."""
    table = torch.zeros(3, 4, device=device)
    for wish, order in _ORDER.items():
        for rank, a in enumerate(order):
            table[wish, a] = float(len(order) - rank)
    return table


def lane_change_in_progress(model: ModelStep) -> torch.Tensor:
    """(B,) bool: the target lane differs from the current one (a change that has not crossed the boundary)."""
    return model.t_id != model.lanes.c_id


def lane_change_wish(model: ModelStep, ego_v: torch.Tensor, scenario: str, hold_lane_change: bool = False) -> torch.Tensor:
    """(B,) float: how much the driver wants a LaneChange on this model (NO_WISH = not at all; +inf = must)."""
    lanes, veh, gaps = model.lanes, model.vehicles, model.gaps_m
    v0 = torch.full_like(ego_v, V_MAX_MPS)
    s0 = torch.full_like(ego_v, JAM_DISTANCE_M)
    a_own = idm_accel(ego_v, v0, s0, gaps[:, 0], veh.vx[:, 0], ~veh.virtual[:, 0])
    a_adj = idm_accel(ego_v, v0, s0, gaps[:, 1], veh.vx[:, 1], ~veh.virtual[:, 1])
    adjacent = lanes.adjacent_lane  # global lane LaneChange goes to (off the boundary), -1: none
    real = adjacent >= 0
    gain = a_adj - a_own
    spec = scenario_spec(scenario)
    ramp = spec.mainline_lanes
    if spec.task == MERGE:
        mandatory = real & (lanes.current_lane == ramp) & (adjacent == ramp - 1)
        allowed = real & (adjacent < ramp)
    elif spec.task == EXIT:
        mandatory = real & (adjacent == lanes.current_lane + 1)
        allowed = mandatory
    else:
        mandatory = torch.zeros_like(real)
        allowed = real
    # the built-in driver's gap rule on the target lane's SV2 (ahead) and SV4 (behind); SV_i,Def are no cars
    inf = torch.full_like(gain, float("inf"))
    gap_ahead = torch.where(veh.virtual[:, 1], inf, gaps[:, 1])
    gap_behind = torch.where(veh.virtual[:, 3], inf, gaps[:, 3])
    room = room_to_change(gap_ahead, veh.vx[:, 1], gap_behind, veh.vx[:, 3], ego_v)
    start = allowed & ~model.m_l_ego & room & ((gain > MOBIL_GAIN_MPS2) | mandatory)
    wish = torch.where(mandatory, torch.full_like(gain, float("inf")), gain)
    wish = torch.where(start, wish, torch.full_like(gain, NO_WISH))
    in_progress = lane_change_in_progress(model)
    if hold_lane_change:  # Faster/Idle/Slower continue the change; LaneChange near the boundary would undo it
        return torch.where(in_progress, torch.full_like(gain, NO_WISH), wish)
    return torch.where(in_progress, torch.full_like(gain, float("inf")), wish)


def longitudinal_wish(model: ModelStep, ego_v: torch.Tensor) -> torch.Tensor:
    """(B,) long in {FASTER, IDLE, SLOWER}: the IDM's acceleration behind SV1 (and, during a lane change,
    behind the target lane's SV2 too), discretised."""
    veh = model.vehicles
    v0, s0 = torch.full_like(ego_v, V_MAX_MPS), torch.full_like(ego_v, JAM_DISTANCE_M)
    a = idm_accel(ego_v, v0, s0, model.gaps_m[:, 0], veh.vx[:, 0], ~veh.virtual[:, 0])
    a_target = idm_accel(ego_v, v0, s0, model.gaps_m[:, 1], veh.vx[:, 1], ~veh.virtual[:, 1])
    a = torch.where(lane_change_in_progress(model), torch.minimum(a, a_target), a)
    return torch.where(a > A_FASTER_MPS2, FASTER, torch.where(a < -A_SLOWER_MPS2, SLOWER, IDLE)).long()


def rule_based_action(model: ModelStep, ego_v: torch.Tensor, scenario: str, hold_lane_change: bool = False) -> torch.Tensor:
    """(B,) long index into ACTIONS: the driver's action on this model, always inside model.mask.
    hold_lane_change: the SafetyLayer's option of that name (how Faster/Idle/Slower treat a change under way)."""
    wish = longitudinal_wish(model, ego_v)
    score = _rank_table(ego_v.device)[wish]  # (B, 4)
    wants_change = lane_change_wish(model, ego_v, scenario, hold_lane_change) > NO_WISH
    score[:, LANE_CHANGE] = torch.where(wants_change, 10.0, score[:, LANE_CHANGE])
    return score.masked_fill(~model.mask, float("-inf")).argmax(1)


def rule_based_decision(step: SafetyStep, scenario: str, hold_lane_change: bool = False
                        ) -> tuple[torch.Tensor, torch.Tensor | None]:
    """(action (B,), use_second (B,) bool or None) on a SafetyStep; on a multi-lane middle lane the model
    whose lane change the driver wants more (left on a tie) decides."""
    ego_v = torch.hypot(step.snapshot.ego_vx, step.snapshot.ego_vy)
    use_second = None
    if may_use_second(step):  # the static form: always (no host read); choose_second picks per env
        w1 = lane_change_wish(step.primary, ego_v, scenario, hold_lane_change)
        w2 = lane_change_wish(step.second, ego_v, scenario, hold_lane_change)
        use_second = choose_second(w1, w2, step.two_models)
    return rule_based_action(step.select(use_second), ego_v, scenario, hold_lane_change), use_second
