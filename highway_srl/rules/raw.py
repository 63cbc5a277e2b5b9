"""The rule layer without the four mappings of §3.3: what SR-RL, RL and the "w/o MAP" ablation see.

    layer = RawSafetyLayer(world.road, five_actions=True)   # same calls as SafetyLayer
    step = layer.observe(world)                              # SafetyStep whose models are RawModelSteps
    lane, speed = layer.act(action)                          # action: index into FIVE_ACTIONS or ACTIONS

What is removed, against `SafetyLayer` (docs/paper-notes.md, "Raw view"):
- ID mapping: lanes keep their global indices (C_ID, T_ID in 0..K-1; y is the global lateral position).
  There is one model per step, never two. Its adjacent lane (SV2, SV4) is the lane being changed into
  during a lane change, else the two-lane "other lane" on raw indices: lane 0's right neighbour, any other
  lane's left neighbour (on a two-lane road the other lane; a three-lane road's right lane is never the
  adjacent lane of the middle lane). A lane that does not exist at x_EV gives the default virtual vehicles.
- Rule mapping: R_SVi of Eq. 26 as they are (vehicles belong to the lane of their nearest centre; no R'
  and no grouping of R*), and m_L by the centre-point test of §3.1 instead of Eq. 31's corner test.
- Action mapping (five_actions=True): the paper's A = {Faster, Idle, Slower, LaneLeft, LaneRight} with
  Eq. 16 on raw indices (LaneLeft: C_ID - 1, LaneRight: C_ID + 1, where the road allows the crossing) and a
  safe-action check per direction (`mask5`). With five_actions=False the layer keeps A* (the MoE's experts
  are defined over it) and LaneChange goes to the adjacent lane above.
- Control mapping: no Eq. 35 refinement and no braking while changing lanes; Faster/Idle/Slower target
  the current lane (the literal Eq. 16/34), unless hold_lane_change (a person's keyboard: a tap commits).

The deployment reward R_r must be the same function of the world for every method, so each RawModelStep
also carries the mapped R*_SV and v/v* of a standard SafetyLayer run alongside (`r_star`, `speed_ratio`);
the agent sees only the raw fields.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from highway_srl.constants import D_ML_M, DEFAULT_PROFILE, DT_S, EGO_BRAKE_MAX_MPS2, SV_BRAKE_MAX_MPS2, VEHICLE_LENGTH_M
from highway_srl.rules.mappings import NO_LANE, LaneModel, crossing_allowed, fill_defaults, lane_exists, target_speed
from highway_srl.rules.observation import OBS_NAMES, build_observation, ego_progress_feature
from highway_srl.rules.pipeline import FRONT_SLOTS, ModelStep, SafetyLayer, SafetyStep, where_tree
from highway_srl.rules.profiles import control_profile
from highway_srl.rules.reward_machine import D_ACC_M, desired_speed, reward_machine_state, rm_reward
from highway_srl.rules.safe_actions import IDLE, LANE_CHANGE, safe_action_mask_from
from highway_srl.rules.safe_distance import rule_indicator
from highway_srl.sim.road import Road

# The paper's action set A (§3.1), before the action mapping; indices 0-2 coincide with A*.
FIVE_ACTIONS: tuple[str, ...] = ("Faster", "Idle", "Slower", "LaneLeft", "LaneRight")
LANE_LEFT, LANE_RIGHT = 3, 4
# m_L (§3.1): y_EV within d_ML of "w_L" would cover a whole 3.5 m lane with d_ML = 1.75 m in any frame, so
# d_ML is read as the width of the region centred on the lane boundary: |y - y_boundary| < d_ML / 2.
RAW_M_L_HALF_WIDTH_M = 0.5 * D_ML_M
T_ID_COLUMN = OBS_NAMES.index("t_id")


@dataclass
class RawModelStep(ModelStep):
    """A ModelStep of the raw view. obs, mask (Table 1 over A* on raw R_SVi), rm_state, r_rm, r_sv (raw R_SVi),
    m_l_ego (centre test), t_id (global), v_star, gaps_m, vehicles, lanes: what the agent sees. r_star and
    speed_ratio: the mapped R*_SV and v/v* of the standard layer, for the deployment reward only (and
    mapped_r_rm its r_RM, for the RM return every method is scored with); front_room_m: the mapped layer's
    (None where its profile does not stop at the last resort), unused (the raw view's Idle keeps the speed).
    mask5 (B, 5) bool: the safe-action check over FIVE_ACTIONS (Faster ⇔ R1, Slower ⇔ R3, LaneLeft/Right ⇔
    the lane exists, may be crossed here and R2 ∧ R4 of that lane, Idle ⇔ R1 ∨ (¬R3 ∧ no lane change safe)).
    lane_left, lane_right (B,) long: the global lanes LaneLeft/LaneRight go to (the ego lane if none)."""

    mask5: torch.Tensor
    lane_left: torch.Tensor
    lane_right: torch.Tensor
    mapped_r_rm: torch.Tensor  # (B,) r_RM of the mapped layer run alongside, for scoring only

    def scoring_r_rm(self) -> torch.Tensor:
        return self.mapped_r_rm


class RawSafetyLayer:
    """SafetyLayer's interface (observe, act, reset, target_lane) with the mappings removed (module docstring)."""

    def __init__(
        self,
        road: Road,
        *,
        five_actions: bool = True,
        hold_lane_change: bool = False,
        profile: str = DEFAULT_PROFILE,  # SafetyLayer's default
        literal_sd: bool = False,
        d_acc_m: float = D_ACC_M,
        standstill_gap_m: float | None = None,
        reaction_s: float = DT_S,
        ego_brake_mps2: float = EGO_BRAKE_MAX_MPS2,
        sv_brake_mps2: float = SV_BRAKE_MAX_MPS2,
    ):
        # of the profile's additions only the standstill margin exists in the raw view (no mappings to extend)
        if standstill_gap_m is None:
            standstill_gap_m = control_profile(profile).standstill_gap_m
        self.road = road
        self.five_actions = five_actions
        self.hold_lane_change = hold_lane_change
        self.literal_sd, self.d_acc_m, self.standstill_gap_m = literal_sd, d_acc_m, standstill_gap_m
        self.reaction_s, self.ego_brake, self.sv_brake = reaction_s, ego_brake_mps2, sv_brake_mps2
        self.mapped = SafetyLayer(road, profile=profile, literal_sd=literal_sd, d_acc_m=d_acc_m, standstill_gap_m=standstill_gap_m,
                                  reaction_s=reaction_s, ego_brake_mps2=ego_brake_mps2, sv_brake_mps2=sv_brake_mps2)
        self._target: torch.Tensor | None = None
        self.last: SafetyStep | None = None

    # ------------------------------------------------------------------ state
    @property
    def static(self) -> bool:
        """The static form (SafetyLayer.static: no host reads), shared with the mapped layer it scores with."""
        return self.mapped.static

    @static.setter
    def static(self, value: bool) -> None:
        self.mapped.static = value

    @property
    def target_lane(self) -> torch.Tensor | None:
        """(B,) long global target lane of the ego (what the last act() commanded)."""
        return self._target

    @target_lane.setter
    def target_lane(self, lane: torch.Tensor | None) -> None:
        self._target = lane
        self.mapped.target_lane = None if lane is None else lane.clone()

    def reset(self, mask: torch.Tensor | None = None) -> None:
        """Forget the target lane of the envs where mask (B,) is True (all if None)."""
        self.mapped.reset(mask)
        if mask is None or self._target is None:
            self._target, self.last = None, None
            return
        self._target = torch.where(mask.bool(), torch.full_like(self._target, NO_LANE), self._target)

    # ------------------------------------------------------------------ observe
    def observe(self, world) -> SafetyStep:
        metric = self.mapped.observe(world).primary  # the paper's view, kept for R_r
        probe = self.mapped.last.snapshot
        road, w = self.road, self.road.lane_width_m
        ego_lane, x = probe.ego_lane.long(), probe.ego_x
        target = self._target if self._target is not None else ego_lane
        ok = (target == ego_lane) | crossing_allowed(road, ego_lane, target, x)
        target = torch.where(ok, target, ego_lane)
        self._target = target

        left, right = ego_lane - 1, ego_lane + 1
        changing = target != ego_lane
        adjacent = torch.where(changing, target, torch.where(ego_lane == 0, right, left))
        adjacent_is_left = adjacent < ego_lane
        sides = []
        for lane in (left, right):
            real = lane_exists(road, lane, x)
            snap = world.neighbours(ego_lane, torch.where(real, lane, torch.full_like(lane, NO_LANE)))
            # fill_defaults' C_ID only places the phantoms: 1 puts them one lane to the left
            veh = fill_defaults(snap, (lane < ego_lane).long(), ~real)
            r, gaps, dx = self._rules(snap, veh)
            change_ok = crossing_allowed(road, ego_lane, lane, x) & r[:, 1] & r[:, 3]
            sides.append((snap, veh, r, gaps, dx, change_ok, real))
        pick = lambda i: where_tree(adjacent_is_left, sides[0][i], sides[1][i])  # noqa: E731
        snap, veh = pick(0), pick(1)
        r_sv, gaps, dx = pick(2), pick(3), pick(4)
        adjacent_real = torch.where(adjacent_is_left, sides[0][6], sides[1][6])
        change_left, change_right = sides[0][5], sides[1][5]

        boundary_y = (torch.minimum(ego_lane, adjacent).to(x.dtype) + 0.5) * w
        m_l = (snap.ego_y - boundary_y).abs() < RAW_M_L_HALF_WIDTH_M
        d_vl = (snap.ego_y - target.to(x.dtype) * w).abs()
        u = reward_machine_state(m_l, d_vl, r_sv, w)
        v_star = desired_speed(gaps[:, 0], veh.vx[:, 0], r_sv, d_acc_m=self.d_acc_m)
        r_rm = rm_reward(u, snap.ego_vx, v_star)
        mask = safe_action_mask_from(r_sv)
        r1, r3 = r_sv[:, 0], r_sv[:, 2]
        idle = r1 | (~r3 & ~change_left & ~change_right)
        mask5 = torch.stack([r1, idle, r3, change_left, change_right], dim=1)
        obs = build_observation(
            ego_progress=ego_progress_feature(road, x), ego_y_local_m=snap.ego_y, ego_vx_mps=snap.ego_vx,
            ego_vy_mps=snap.ego_vy, ego_heading=snap.ego_heading, sv_dx_m=dx, sv_y_local_m=veh.y, sv_vx_mps=veh.vx,
            sv_vy_mps=veh.vy, sv_heading=veh.heading, c_id=ego_lane, m_l=m_l, t_id=target, v_star_mps=v_star,
            r_star=r_sv, rm_state=u, lane_width_m=w,
        )
        obs[:, T_ID_COLUMN] = target.to(obs.dtype)  # raw global T_ID (build_observation clips it to [0, 1])
        lanes = LaneModel(torch.zeros_like(ego_lane), ego_lane, ego_lane.clone(),
                          torch.where(adjacent_real, adjacent, torch.full_like(adjacent, NO_LANE)), ~adjacent_real)
        step = RawModelStep(
            obs=obs, mask=mask, rm_state=u, r_rm=r_rm, r_sv=r_sv, r_star=metric.r_star, m_l_ego=m_l, t_id=target,
            v_star=v_star, speed_ratio=metric.speed_ratio, gaps_m=gaps, vehicles=veh, lanes=lanes,
            front_room_m=metric.front_room_m, near=None, mask5=mask5,
            lane_left=torch.where(crossing_allowed(road, ego_lane, left, x), left, ego_lane),
            lane_right=torch.where(crossing_allowed(road, ego_lane, right, x), right, ego_lane),
            mapped_r_rm=metric.r_rm,
        )
        self.last = SafetyStep(step, step, torch.zeros_like(changing), snap, self.static)
        return self.last

    def _rules(self, snap, veh) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Raw R_SVi (Eq. 26, the same safe distance as SafetyLayer), bumper gaps and centre offsets, (B, 4)."""
        front = torch.tensor(FRONT_SLOTS, device=snap.ego_x.device)
        dx = veh.x - snap.ego_x[:, None]
        gaps = torch.where(front, dx, -dx) - VEHICLE_LENGTH_M
        r = rule_indicator(gaps - self.standstill_gap_m, snap.ego_vx[:, None], veh.vx, front=front,
                           reaction_s=self.reaction_s, ego_brake=self.ego_brake, other_brake=self.sv_brake,
                           literal=self.literal_sd)
        return r, gaps, dx

    # ------------------------------------------------------------------ act
    def act(self, action: torch.Tensor, use_second: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(target_lane (B,) long global, target_speed (B,) m/s) for action (B,) long: an index into
        FIVE_ACTIONS (five_actions) or ACTIONS. use_second is ignored: the raw view has one model."""
        if self.last is None or self._target is None:
            raise RuntimeError("call observe(world) before act(action)")
        m: RawModelStep = self.last.primary
        snap = self.last.snapshot
        action = action.long()
        ego_lane = snap.ego_lane.long()
        keep = self._target if self.hold_lane_change else ego_lane
        if self.five_actions:
            if not self.static and action.numel() and (int(action.min()) < 0 or int(action.max()) >= len(FIVE_ACTIONS)):
                raise ValueError(f"actions must be indices 0..4 of {FIVE_ACTIONS}, got {action.unique().tolist()}")
            lane = torch.where(action == LANE_LEFT, m.lane_left, torch.where(action == LANE_RIGHT, m.lane_right, keep))
            longitudinal = torch.where(action >= LANE_LEFT, torch.full_like(action, IDLE), action)
        else:
            change_to = torch.where(m.lanes.adjacent_lane >= 0, m.lanes.adjacent_lane, ego_lane)
            lane = torch.where(action == LANE_CHANGE, change_to, keep)
            longitudinal = action
        ok = (lane == ego_lane) | crossing_allowed(self.road, ego_lane, lane, snap.ego_x)
        lane = torch.where(ok, lane, ego_lane)
        self.target_lane = lane
        return lane, target_speed(longitudinal, torch.hypot(snap.ego_vx, snap.ego_vy), check=not self.static)


__all__ = ["FIVE_ACTIONS", "LANE_LEFT", "LANE_RIGHT", "RawModelStep", "RawSafetyLayer"]
