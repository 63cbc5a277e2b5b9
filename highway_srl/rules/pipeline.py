"""The safety layer: one step of the paper's rule machinery for B envs (Algorithm 1, lines 6-9, and §3.3).

    layer = SafetyLayer(world.road)              # once per world
    layer.reset()                                # or layer.reset(mask) for envs that start a new episode
    step = layer.observe(world)                  # SafetyStep: obs (B, 37), mask (B, 4), RM state, r_RM, ...
    use_second = ...                             # multi-lane only: where step.two_models and model B's Q wins
    lane, speed = layer.act(action, use_second)  # -> world.step(lane, speed)

`world` needs `road` and `neighbours(current_lane (B,), adjacent_lane (B,), by_body=False) -> Snapshot`
(by_body: the safe profile's lanes_by_body asks a second time). observe() does:
ID mapping -> snapshot -> default virtual vehicles -> R_SVi (Eq. 26) -> m*_L (Eq. 31) -> R*_SVi (Eq. 32)
-> safe-action mask (Table 1) -> d_VL with the carried T*_ID -> RM state u* (Eqs. U1-U4) -> v* -> r_RM
-> the 37 inputs. act() is the action and control mapping (Eqs. 34-35, Δv_A, Δv_D). Between the two calls
the layer keeps one thing per env: the global target lane T* (and the last SafetyStep).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch

from highway_srl.constants import (
    DEFAULT_PROFILE,
    DT_S,
    EGO_BRAKE_MAX_MPS2,
    LANE_WIDTH_M,
    SV_BRAKE_MAX_MPS2,
    VEHICLE_LENGTH_M,
)
from highway_srl.rules.mappings import (
    EPS_S_M,
    NO_LANE,
    IdMapping,
    LaneModel,
    Vehicles,
    change_fits_window,
    crossing_allowed,
    crossing_toward,
    crosses_line,
    fill_defaults,
    front_room,
    id_mapping,
    lane_exists,
    near_boundary,
    reaching_over,
    rule_mapping,
    stopping_speed,
    straddle_grouping,
    target_lane_local,
    target_speed,
)
from highway_srl.rules.avoidable import proper_lateral_speed
from highway_srl.rules.body_swing import NearCars, near_cars, swing_guard
from highway_srl.rules.lanes_by_body import body_room, body_slots, with_bodies
from highway_srl.rules.lateral import entry_response
from highway_srl.rules.observation import build_observation, ego_progress_feature
from highway_srl.rules.profiles import control_profile
from highway_srl.rules.reward_machine import (D_ACC_M, HighwayPropositions, desired_speed, highway_reward_machine,
                                              speed_ratio)
from highway_srl.rules.safe_actions import IDLE, LANE_CHANGE, SLOWER, safe_action_mask_from
from highway_srl.rules.safe_distance import rule_indicator
from highway_srl.rules.third_lane import third_lane, third_lane_cars, third_lane_room, with_third_lane
from highway_srl.sim.ego import HOLD_LANE
from highway_srl.sim.road import Road
from highway_srl.sim.snapshot import Snapshot

FRONT_SLOTS = (True, True, False, False)  # SV1, SV2 ahead; SV3, SV4 behind
@dataclass
class ModelStep:
    """One two-lane model's view of the step, all (B, ...): obs (B, 37) float32; mask (B, 4) bool in ACTIONS
    order; rm_state (B,) long u*; r_rm (B,) RM reward; r_sv / r_star (B, 4) bool R_SVi (a third-lane car joining
    a slot included, watch_third_lane) and R*_SVi; m_l_ego (B,) bool; t_id (B,) long local T*_ID used for d_VL;
    v_star (B,) m/s; speed_ratio (B,) v/v* (clipped, for the deployment reward); gaps_m (B, 4) bumper gaps;
    vehicles: SV1..SV4 with defaults; lanes: the ID mapping of this model; front_room_m (B,) the distance the
    ego may cover before it must stand (front_room), None where the layer does not stop at the last resort."""

    obs: torch.Tensor
    mask: torch.Tensor
    rm_state: torch.Tensor
    r_rm: torch.Tensor
    r_sv: torch.Tensor
    r_star: torch.Tensor
    m_l_ego: torch.Tensor
    t_id: torch.Tensor
    v_star: torch.Tensor
    speed_ratio: torch.Tensor
    gaps_m: torch.Tensor
    vehicles: Vehicles
    lanes: LaneModel
    front_room_m: torch.Tensor | None
    near: NearCars | None  # every car the model's queries returned, for hold_lateral's body swing

    def scoring_r_rm(self) -> torch.Tensor:
        """(B,) r_RM of the paper's mapped rules, what every method's episodes are scored with (the RM return
        beside the training return); the raw view returns its mapped layer's."""
        return self.r_rm


@dataclass
class SafetyStep:
    """primary: the model to use everywhere; second: model B of a multi-lane ego in the middle lane, valid
    where two_models (B,) is True (elsewhere it repeats primary); snapshot: the primary's snapshot; static:
    made by a layer in its static form (the second model is always computed)."""

    primary: ModelStep
    second: ModelStep
    two_models: torch.Tensor
    snapshot: Snapshot
    static: bool = False

    def select(self, use_second: torch.Tensor | None) -> ModelStep:
        """The per-env chosen model: second where use_second & two_models, else primary."""
        if use_second is None:
            return self.primary
        pick = use_second.bool() & self.two_models
        return where_tree(pick, self.second, self.primary)


def where_tree(pick: torch.Tensor, a, b):
    if a is None:  # a field the layer does not compute (ModelStep.front_room_m), None in both
        return None
    if isinstance(a, torch.Tensor):
        p = pick.reshape(pick.shape + (1,) * (a.dim() - 1))
        return torch.where(p, a, b)
    return type(a)(**{f.name: where_tree(pick, getattr(a, f.name), getattr(b, f.name)) for f in fields(a)})


def may_use_second(step: SafetyStep) -> bool:
    """Whether a method must weigh step's second model: always in the static form (no host read; the
    choice is a select), else only where some env has two models (one host read)."""
    return getattr(step, "static", False) or bool(step.two_models.any())


def choose_second(q_primary: torch.Tensor, q_second: torch.Tensor, two_models: torch.Tensor) -> torch.Tensor:
    """§3.3 multi-lane: use model B where there are two models and its Q value is the larger; (B,) bool."""
    return two_models.bool() & (q_second > q_primary)


class SafetyLayer:
    """Batched rule machinery for one road (see the module docstring for the call order).

    profile: "paper" (Eqs. 31-35 as printed plus the hold below) or "safe" (our safety additions on); see
    ControlProfile. Its default is every entry point's (constants.DEFAULT_PROFILE, the reproduction's): a
    layer made without it masks and maps as train, evaluate and the envs do. Each addition can still be set on its own (None: the profile's value).
    literal_sd: use the printed Eqs. 21-27 instead of the sound safe distance; grouped_rule_mapping: the
    Eq. 32 reading (see mappings.rule_mapping); hold_lane_change: Faster/Idle/Slower keep the previous
    target lane ("the lateral plan remains unchanged") instead of the literal Eq. 34 T* = C_ID, in both
    profiles (without it no lane change completes); abort_unsafe_change: the held change is given up when
    its target turns unsafe; finish_in_window: a lane change is started or held only if it can end before
    the road's change window closes (mappings.change_fits_window).

    static (set by the static training step): the same numbers without host reads: the second model of a
    multi-lane ego is always computed (a select picks it), the neighbours are always queried afresh for the
    primary model, and the action indices are not checked (the methods produce valid ones).
    """

    def __init__(
        self,
        road: Road,
        *,
        profile: str = DEFAULT_PROFILE,
        literal_sd: bool = False,
        d_acc_m: float = D_ACC_M,
        eps_s_m: float = EPS_S_M,
        grouped_rule_mapping: bool = True,
        hold_lane_change: bool = True,
        abort_unsafe_change: bool | None = None,
        brake_while_changing: bool | None = None,
        finish_in_window: bool | None = None,
        standstill_gap_m: float | None = None,
        straddle_grouping: bool | None = None,
        turning_in_is_near: bool | None = None,
        last_resort_stops: bool | None = None,
        reaching_over_is_near: bool | None = None,
        watch_third_lane: bool | None = None,
        ego_body_straddles: bool | None = None,
        lanes_by_body: bool | None = None,
        back_out_of_entry: bool | None = None,
        hold_lateral: bool | None = None,
        reaction_s: float = DT_S,
        ego_brake_mps2: float = EGO_BRAKE_MAX_MPS2,
        sv_brake_mps2: float = SV_BRAKE_MAX_MPS2,
    ):
        prof = control_profile(profile)
        pick = lambda value, default: default if value is None else value  # noqa: E731
        self.road = road
        self.profile = profile
        self.literal_sd = literal_sd
        self.d_acc_m = d_acc_m
        self.eps_s_m = eps_s_m
        self.grouped = grouped_rule_mapping
        self.hold_lane_change = hold_lane_change
        self.abort_unsafe_change = pick(abort_unsafe_change, prof.abort_unsafe_change)
        self.brake_while_changing = pick(brake_while_changing, prof.brake_while_changing)
        self.finish_in_window = pick(finish_in_window, prof.finish_in_window)
        self.standstill_gap_m = pick(standstill_gap_m, prof.standstill_gap_m)
        self.straddle_grouping = pick(straddle_grouping, prof.straddle_grouping)
        self.turning_in_is_near = pick(turning_in_is_near, prof.turning_in_is_near)
        self.last_resort_stops = pick(last_resort_stops, prof.last_resort_stops)
        self.reaching_over_is_near = pick(reaching_over_is_near, prof.reaching_over_is_near)
        self.watch_third_lane = pick(watch_third_lane, prof.watch_third_lane)
        self.ego_body_straddles = pick(ego_body_straddles, prof.ego_body_straddles)
        self.lanes_by_body = pick(lanes_by_body, prof.lanes_by_body)
        self.back_out_of_entry = pick(back_out_of_entry, prof.back_out_of_entry)
        self.hold_lateral = pick(hold_lateral, prof.hold_lateral)
        self.reaction_s, self.ego_brake, self.sv_brake = reaction_s, ego_brake_mps2, sv_brake_mps2
        self.rm = highway_reward_machine()
        self.target_lane: torch.Tensor | None = None  # (B,) long global T*; -1: not yet known
        self._query: tuple[torch.Tensor, torch.Tensor] | None = None
        self.last: SafetyStep | None = None
        self.static = False

    # ------------------------------------------------------------------ episodes
    def reset(self, mask: torch.Tensor | None = None) -> None:
        """Forget the target lane of the envs where mask (B,) is True (all if None); the next observe()
        starts them in lane keeping of their current lane."""
        if mask is None or self.target_lane is None:
            self.target_lane = None
            self.last = None
            return
        self.target_lane = torch.where(mask.bool(), torch.full_like(self.target_lane, NO_LANE), self.target_lane)

    # ------------------------------------------------------------------ observe
    def observe(self, world) -> SafetyStep:
        """Run the rule machinery on the world's current state; returns (and keeps) a SafetyStep."""
        road = self.road
        # the probe's ego fields are all it is read for; the static form does not carry the last query over
        # (a traced step keeps no view of the step before)
        if self.static or self._query is None or self.target_lane is None:
            probe = world.neighbours(*self._probe_lanes(world))
        else:
            probe = world.neighbours(*self._query)
        batch = probe.ego_x.shape[0]
        ego_lane = probe.ego_lane.long()
        target = self.target_lane if self.target_lane is not None else torch.full_like(ego_lane, NO_LANE)
        # a target that is unknown, not a neighbour any more or no longer reachable falls back to the ego lane
        reachable = (target == ego_lane) | crossing_allowed(road, ego_lane, target, probe.ego_x)
        target = torch.where(reachable & lane_exists(road, target, probe.ego_x), target, ego_lane)
        self.target_lane = target
        ids: IdMapping = id_mapping(road, probe.ego_x, ego_lane, target)
        snap = self._snapshot(world, probe, ids.primary, self.static)
        primary = self._model_step(snap, ids.primary, target, self._third_lane(world, ids.primary, probe.ego_x),
                                   self._by_body(world, ids.primary))
        # where two_models is False, second repeats primary; the static form computes it wherever the road has
        # a middle lane (a fact of the road, no host read), which only multi-lane has
        if (self.static and road.mainline_lanes >= 3) or (not self.static and bool(ids.two_models.any())):
            snap_b = world.neighbours(ids.second.current_lane, ids.second.adjacent_lane)
            second = self._model_step(snap_b, ids.second, target, self._third_lane(world, ids.second, probe.ego_x),
                                      self._by_body(world, ids.second))
        else:
            second = primary
        self._query = (ids.primary.current_lane, ids.primary.adjacent_lane)
        assert primary.obs.shape[0] == batch
        self.last = SafetyStep(primary, second, ids.two_models, snap, self.static)
        return self.last

    def _probe_lanes(self, world) -> tuple[torch.Tensor, torch.Tensor]:
        """Lanes for a first query; only the ego fields of its answer are used before the real query."""
        lane = getattr(world, "ego_lane", None)
        if isinstance(lane, torch.Tensor):
            return lane.long(), torch.full_like(lane.long(), NO_LANE)
        if self.target_lane is not None:
            return self.target_lane.clamp(min=0), torch.full_like(self.target_lane, NO_LANE)
        n = getattr(world, "num_envs", None)
        if isinstance(n, int):
            zero = torch.zeros(n, dtype=torch.long, device=getattr(world, "device", None))
            return zero, torch.full_like(zero, NO_LANE)
        raise ValueError("the first observe() needs world.ego_lane (B,) or world.num_envs to size the batch")

    @staticmethod
    def _snapshot(world, probe: Snapshot, lanes: LaneModel, static: bool = False) -> Snapshot:
        """The neighbours of lanes: the probe's answer when it asked for the same lanes (a host read),
        a fresh query otherwise and always in the static form (the same answer either way)."""
        if static:
            return world.neighbours(lanes.current_lane, lanes.adjacent_lane)
        same = torch.equal(probe.current_lane.long(), lanes.current_lane) and torch.equal(
            probe.adjacent_lane.long(), lanes.adjacent_lane
        )
        return probe if same else world.neighbours(lanes.current_lane, lanes.adjacent_lane)

    def _third_lane(self, world, lanes: LaneModel, ego_x: torch.Tensor) -> Snapshot | None:
        """The third lane's nearest cars where the layer watches it on a road of three lanes; None otherwise."""
        if not self.watch_third_lane or self.road.num_lanes < 3:
            return None
        lane = third_lane(self.road, lanes.base_lane, ego_x)
        return world.neighbours(lane, torch.full_like(lane, NO_LANE))

    def _by_body(self, world, lanes: LaneModel) -> Snapshot | None:
        """The pair's lanes asked by body (lanes_by_body); None where the layer does not."""
        return world.neighbours(lanes.current_lane, lanes.adjacent_lane, by_body=True) if self.lanes_by_body else None

    def _rule(self, gaps: torch.Tensor, ego_vx: torch.Tensor, sv_vx: torch.Tensor, front: torch.Tensor) -> torch.Tensor:
        """R_SV (Eq. 26) of bumper gaps (B, K) less the standstill margin: the SD rule treats cars as points;
        the margin covers rotated boxes (0.1 m at 0.1 rad for a 2 m wide car) and the controller's steps."""
        return rule_indicator(gaps - self.standstill_gap_m, ego_vx[:, None], sv_vx, front=front,
                              reaction_s=self.reaction_s, ego_brake=self.ego_brake, other_brake=self.sv_brake,
                              literal=self.literal_sd)

    def _near_line(self, sv_y_local: torch.Tensor, veh: Vehicles, ego_y_local: torch.Tensor, w: float) -> torch.Tensor:
        """m*_L,SV (Eq. 31) of SV1..SV4 (B, 4), with the profile's additions (turning in, reaching over)."""
        m_l_sv = near_boundary(sv_y_local, veh.heading, lane_width_m=w)
        if self.turning_in_is_near:
            m_l_sv |= crossing_toward(sv_y_local, veh.heading, ego_y_local[:, None], lane_width_m=w)
        if self.reaching_over_is_near:
            m_l_sv |= reaching_over(sv_y_local, veh.heading, ego_y_local[:, None], lane_width_m=w)
        return m_l_sv & ~veh.virtual

    def _model_step(self, snap: Snapshot, lanes: LaneModel, target_global: torch.Tensor,
                    third: Snapshot | None = None, bodies: Snapshot | None = None) -> ModelStep:
        w = self.road.lane_width_m if hasattr(self.road, "lane_width_m") else LANE_WIDTH_M
        veh = fill_defaults(snap, lanes.c_id, lanes.default_adjacent)
        ego_x, ego_vx = snap.ego_x, snap.ego_vx
        front = torch.tensor(FRONT_SLOTS, device=ego_x.device)
        dx = veh.x - ego_x[:, None]
        gaps = torch.where(front, dx, -dx) - VEHICLE_LENGTH_M
        slots = None if bodies is None else body_slots(bodies, lanes.default_adjacent, front)
        if slots is None:
            r_sv = self._rule(gaps, ego_vx, veh.vx, front)
        else:  # the cars whose bodies reach into the pair's lanes join their slots (one rule call for both)
            both = self._rule(torch.cat([gaps, slots.gaps_m], 1), ego_vx, torch.cat([veh.vx, slots.vx], 1),
                              torch.cat([front, front]))
            r_sv = with_bodies(both[:, :4], slots, both[:, 4:])
        cars = None if third is None else third_lane_cars(third, lanes, w)
        if cars is not None:  # the third lane's cars reaching into the near lane join its rules
            r_sv = with_third_lane(r_sv, cars, self._rule(cars.gaps_m, ego_vx, cars.vx, front[[0, 2]]))
        base_y = lanes.base_lane.to(ego_x.dtype) * w
        ego_y_local = snap.ego_y - base_y
        sv_y_local = veh.y - base_y[:, None]
        m_l_ego = near_boundary(ego_y_local, snap.ego_heading, lane_width_m=w)
        m_l_sv = self._near_line(sv_y_local, veh, ego_y_local, w)
        _, r_star = rule_mapping(r_sv, m_l_ego, m_l_sv, dx, eps_s_m=self.eps_s_m, grouped=self.grouped)
        straddles = m_l_ego | crosses_line(ego_y_local, snap.ego_heading, w) if self.ego_body_straddles else m_l_ego
        if self.straddle_grouping:
            r_star = straddle_grouping(r_star, straddles)
        room = self._front_room(gaps, veh, m_l_sv, straddles, cars, slots) if self.last_resort_stops else None
        mask = safe_action_mask_from(r_star)
        t_id = (target_global - lanes.base_lane).clamp(0, 1)
        d_vl = (ego_y_local - t_id.to(ego_x.dtype) * w).abs()
        v_star = desired_speed(gaps[:, 0], veh.vx[:, 0], r_star, d_acc_m=self.d_acc_m)
        props = HighwayPropositions(m_l_ego, d_vl, r_star, ego_vx, v_star, w)
        # the highway RM is state-based (δ_u ignores u_t), so the previous state need not be carried
        u, r_rm = self.rm.step(self.rm.initial(ego_x.shape[0], ego_x.device), props)
        obs = build_observation(
            ego_progress=ego_progress_feature(self.road, ego_x),
            ego_y_local_m=ego_y_local,
            ego_vx_mps=ego_vx,
            ego_vy_mps=snap.ego_vy,
            ego_heading=snap.ego_heading,
            sv_dx_m=dx,
            sv_y_local_m=sv_y_local,
            sv_vx_mps=veh.vx,
            sv_vy_mps=veh.vy,
            sv_heading=veh.heading,
            c_id=lanes.c_id,
            m_l=m_l_ego,
            t_id=t_id,
            v_star_mps=v_star,
            r_star=r_star,
            rm_state=u,
            lane_width_m=w,
        )
        near = near_cars(veh, third, bodies) if self.hold_lateral else None
        return ModelStep(obs, mask, u, r_rm, r_sv, r_star, m_l_ego, t_id, v_star, speed_ratio(ego_vx, v_star),
                         gaps, veh, lanes, room, near)

    def _front_room(self, gaps: torch.Tensor, veh: Vehicles, m_l_sv: torch.Tensor, m_l_ego: torch.Tensor,
                    cars, slots) -> torch.Tensor:
        """front_room: SV2 where Eq. 32 or the straddle grouping joins it to R*1; a third-lane car or a car by
        body in a slot."""
        sv2_joins = (m_l_sv[:, 0] | m_l_sv[:, 1]) if self.grouped else m_l_sv[:, 0]
        if self.straddle_grouping:
            sv2_joins = sv2_joins | m_l_ego
        extra = None if cars is None else third_lane_room(cars, self.standstill_gap_m, self.sv_brake)
        if slots is not None:
            room = body_room(slots, self.standstill_gap_m, self.sv_brake)
            extra = room if extra is None else torch.minimum(extra, room)
        return front_room(gaps, veh.vx, sv2_joins, self.standstill_gap_m, self.sv_brake, extra)

    # ------------------------------------------------------------------ act
    def act(self, action: torch.Tensor, use_second: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Action and control mapping (Eqs. 34-35): (target_lane (B,) long global, target_speed (B,) m/s).

        action (B,) long index into ACTIONS, chosen on the model given by use_second (B,) bool (multi-lane).
        A LaneChange whose target cannot be reached here (a barrier, the off-ramp, a missing lane) keeps the
        lane. The target speed is relative to the speed along the heading, hypot(v_x, v_y), which is what the
        ego's speed controller tracks, so an Idle during a lane change does not brake.
        """
        if self.last is None or self.target_lane is None:
            raise RuntimeError("call observe(world) before act(action)")
        m = self.last.select(use_second)
        snap = self.last.snapshot
        previous, backing, hold = None, None, None
        if self.hold_lane_change:
            # "the lateral plan remains unchanged": Faster/Idle/Slower keep the target of a change under way
            previous = (self.target_lane - m.lanes.base_lane).clamp(0, 1)
            if self.abort_unsafe_change:
                # ours: held only while the target lane is still safe (R*2 ∧ R*4); otherwise Faster/Idle/
                # Slower fall back to the literal Eq. 34 (T* = C_ID) and the change is aborted
                still_safe = m.r_star[:, 1] & m.r_star[:, 3]
                previous = torch.where(still_safe, previous, m.lanes.c_id.long())
            if self.back_out_of_entry or self.hold_lateral:
                previous, backing, hold = entry_response(m, snap, previous, self.road.lane_width_m,
                                                         self.back_out_of_entry, self.hold_lateral)
        dx34 = snap.ego_x[:, None] - m.vehicles.x[:, 2:4]  # Eq. 35's SV3 and SV4 offsets
        t_local = target_lane_local(action, m.lanes.c_id, m.m_l_ego, m.r_star[:, 2], m.r_star[:, 3], dx34[:, 0],
                                    dx34[:, 1], previous_target=previous, check=not self.static)
        if backing is not None:
            t_local = torch.where(backing, previous, t_local)
        lane = m.lanes.base_lane + t_local
        ego_lane = snap.ego_lane.long()
        ok = (lane == ego_lane) | crossing_allowed(self.road, ego_lane, lane, snap.ego_x)
        speed_now = torch.hypot(snap.ego_vx, snap.ego_vy)
        if self.finish_in_window:  # a change that cannot end before the window closes is not started / held
            ok &= (lane == ego_lane) | change_fits_window(self.road, ego_lane, lane, snap.ego_x, snap.ego_y, speed_now)
        lane = torch.where(ok, lane, ego_lane)
        self.target_lane = lane
        speed = target_speed(action, speed_now, check=not self.static)
        # Table 1 allows LaneChange while R*_SV1 = 0 (rows 9, 13), but the lateral move takes ~2.5 s during
        # which the ego is still behind SV1: it changes lanes braking as Slower would (docs/paper-notes.md).
        if self.brake_while_changing:
            brake = (action == LANE_CHANGE) & ~m.r_star[:, 0]
            speed = torch.where(brake, target_speed(torch.full_like(action, SLOWER), speed_now, check=False), speed)
        # Table 1 leaves Idle alone where R*1 = R*3 = 0 and no lane change is safe; keeping the speed drove the
        # ego into standing queues. The front comes first (RSS: the follower answers for the rear gap), braking
        # no harder than stopping within the room ahead needs (docs/paper-notes.md).
        if self.last_resort_stops:
            last = (action == IDLE) & ~m.r_star[:, 0]
            speed = torch.where(last, stopping_speed(speed_now, m.front_room_m, self.ego_brake), speed)
        if hold is not None:  # RSS's lateral response: stop moving sideways, braking as far as that needs
            hold, going_back = hold
            in_lane = lane == m.lanes.base_lane + m.lanes.c_id
            hold, brake = hold & in_lane, (hold & in_lane) | (going_back & ~in_lane)
            speed = torch.where(brake, torch.minimum(speed, proper_lateral_speed(speed_now, snap.ego_heading)), speed)
            lane = torch.where(hold, HOLD_LANE, lane)
        if m.near is not None:  # ... and no corner of the body swings toward a car within RSS's margin
            lane = swing_guard(snap, m.near, lane, speed, self.road.lane_width_m)
        return lane, speed
