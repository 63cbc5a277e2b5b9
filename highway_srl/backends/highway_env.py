"""highway-env behind our Backend interface (one env).

highway-env's own environments build the roads: HighwayEnv (2 or 3 lanes), ConnectedLaneMergeGenericEnv
(merge) and ConnectedLaneExitEnv (exit), the variants whose neighbour search follows connected lane
segments, with their section lengths set to our zones where their API takes them (the merge through its
config, the exit through the arguments of its road builder). We then replace their vehicles with ours:
the ego is a ControlledVehicle driven by its own speed and lane-keeping controllers through target_speed
and target_lane_index; the surrounding vehicles are IDMVehicles with the parameters of our traffic model
and Table 3's styles, placed by our spawn. highway-env moves and collides everything (its bicycle model,
IDM, MOBIL, polygon collisions); backends/bookkeeping.py does the paper's bookkeeping, as for SUMO.

Frame: highway-env's x runs along every road here; ours is x_he - X_SHIFT_M (its roads start at 0, ours
need room behind the ego). Its lanes are 4 m wide (a class constant, not configurable), ours 3.5 m: a
vehicle on highway-env lane k at lateral offset `lat` from its centre is at y = (k + lat / 4) * 3.5, so lane
centres and boundaries coincide and lateral distances are scaled by 3.5 / 4 (headings and lateral speeds
accordingly). Ramp lanes (the merge's approach and converging sine lane, the exit's circular off-ramp)
are our lane 2, with x measured along them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from highway_srl.backends.base import SingleEnvBackend
from highway_srl.backends.bookkeeping import Move
from highway_srl.constants import DT_S, EGO_ACCEL_MAX_MPS2, EGO_BRAKE_MAX_MPS2, LANE_WIDTH_M, STYLES, VEHICLE_LENGTH_M
from highway_srl.scenarios import EXIT_X, MERGE_X, scenario_spec
from highway_srl.sim.idm_mobil import (
    IDM_ACCEL_MPS2,
    IDM_COMFORT_BRAKE_MPS2,
    IDM_DELTA,
    IDM_TIME_HEADWAY_S,
    MOBIL_POLITENESS,
    MOBIL_SAFE_BRAKE_MPS2,
    MOBIL_THRESHOLD_MPS2,
    SV_BRAKE_LIMIT_MPS2,
)
from highway_srl.sim.state import EXIT_INTENT, MERGE_INTENT, NO_INTENT

X_SHIFT_M = 400.0  # our x = highway-env x - X_SHIFT_M
ROAD_LENGTH_M = 1600.0  # mainline beyond our x = 0
POLICY_FREQUENCY_HZ = round(1 / DT_S)  # 8: one decision step is our δt = 0.125 s
MERGE_APPROACH_M = 20.0  # the straight part of the on-ramp in [0, x1); the rest of it is the sine-shaped converge
MIN_CHANGE_GAP_M = 2.0  # our MOBIL safety gaps (sim/idm_mobil.py, used in sim/sv_drivers.py)


@dataclass(frozen=True)
class _LaneInfo:
    index: tuple  # highway-env lane index (from, to, id)
    lane: object  # highway-env lane
    ours: int  # our lane
    x0: float  # our x at the lane's longitudinal 0
    x1: float  # our x at its end


class _ConnectedNeighbours:
    """Road.neighbour_vehicles with lane segments connected by geometry instead of by lane id.

    highway-env's connected-lane search continues lane id k of one road with lane id k of the next, which
    holds on straight multi-lane roads but not at the ramps: the merge's on-ramp (id 0 of its one-lane
    road) would continue as mainline lane 0, the exit's diverging lane (id 2) as mainline lane 0 after the
    split. Here a lane continues into the lane that starts where it ends and is the same lane of ours.
    Otherwise the same rule: the nearest vehicle or obstacle ahead and behind on the chain, by longitudinal
    coordinate, among those on a lane of the chain (margin 1 m).
    """

    def __init__(self, road, lanes: dict):
        self.road = road
        self.chains: dict[tuple, list] = {}
        infos = list(lanes.values())
        for a in infos:
            chain = [(a.lane, 0.0)]
            for b in infos:
                if b.ours == a.ours and b is not a and abs(b.x0 - a.x1) < 1e-6:
                    chain.append((b.lane, float(a.lane.length)))
                if b.ours == a.ours and b is not a and abs(b.x1 - a.x0) < 1e-6:
                    chain.append((b.lane, -float(b.lane.length)))
            self.chains[a.index] = chain

    def __call__(self, vehicle, lane_index=None):
        from highway_env.vehicle.objects import Landmark

        lane_index = lane_index or vehicle.lane_index
        if not lane_index:
            return None, None
        chain = self.chains.get(tuple(lane_index))
        if chain is None:
            chain = [(self.road.network.get_lane(lane_index), 0.0)]
        s = chain[0][0].local_coordinates(vehicle.position)[0]
        s_front = s_rear = None
        v_front = v_rear = None
        for v in self.road.vehicles + self.road.objects:
            if v is vehicle or isinstance(v, Landmark):
                continue
            for lane, offset in chain:
                s_v, lat_v = lane.local_coordinates(v.position)
                if not lane.on_lane(v.position, s_v, lat_v, margin=1):
                    continue
                s_v += offset
                if s <= s_v and (s_front is None or s_v <= s_front):
                    s_front, v_front = s_v, v
                if s_v < s and (s_rear is None or s_v > s_rear):
                    s_rear, v_rear = s_v, v
                break
        return v_front, v_rear


def _env_class(scenario: str):
    from highway_env.envs.exit_env import ConnectedLaneExitEnv
    from highway_env.envs.highway_env import HighwayEnv
    from highway_env.envs.merge_env import ConnectedLaneMergeGenericEnv

    kind = scenario_spec(scenario).highway_env_kind
    if kind == "highway":
        return HighwayEnv
    if kind == "merge":
        return ConnectedLaneMergeGenericEnv

    class OurExitEnv(ConnectedLaneExitEnv):
        """highway-env's exit with our zones: diverging lane [x1, x2), off-ramp from x2 (its road builder's
        own arguments; the off-ramp is its quarter circle of radius 150 m)."""

        def _create_road(self, road_length=None, exit_position=None, exit_length=None) -> None:
            super()._create_road(road_length=X_SHIFT_M + ROAD_LENGTH_M, exit_position=X_SHIFT_M + EXIT_X["x1"],
                                 exit_length=EXIT_X["x2"] - EXIT_X["x1"])

    return OurExitEnv


def env_config(scenario: str, max_steps: int, frames_per_step: int) -> dict:
    """highway-env configuration with the paper's constants where its API takes them."""
    cfg = {
        "lanes_count": scenario_spec(scenario).mainline_lanes,
        "vehicles_count": 0,  # we place our own traffic
        "controlled_vehicles": 1,
        "policy_frequency": POLICY_FREQUENCY_HZ,
        "simulation_frequency": POLICY_FREQUENCY_HZ * frames_per_step,
        "duration": max_steps * DT_S,  # seconds: 320 steps = 40 s
        "neighbour_vehicles_connected_lanes": True,
        "other_vehicles_type": "highway_env.vehicle.behavior.IDMVehicle",
        "offroad_terminal": False,
    }
    if scenario_spec(scenario).highway_env_kind == "merge":
        cfg.update({
            "before_merge_length": X_SHIFT_M + MERGE_APPROACH_M,
            "converge_merge_length": MERGE_X["x1"] - MERGE_APPROACH_M,
            "parallel_merge_length": MERGE_X["x2"] - MERGE_X["x1"],
            "after_merge_length": ROAD_LENGTH_M - MERGE_X["x2"],
        })
    return cfg


class HighwayEnvBackend(SingleEnvBackend):
    """One highway-env episode of a scenario behind the Backend protocol (num_envs = 1, CPU).

    frames_per_step: highway-env physics frames per 0.125 s decision step (simulation_frequency = 8 x this;
    highway-env's own default is 15 Hz, its "fast" variants 5 Hz).
    ego_speed_time_constant_s: time constant of the ego's speed controller (ControlledVehicle.KP_A = 1 / it).
    The default δt makes it reach the commanded speed within one step, as our ego does (the command is
    clamped to the ego's acceleration limits); highway-env's own is 0.6 s, which brakes at a fifth of what
    a controller that assumes our ego dynamics asks for.
    """

    def __init__(self, *args, frames_per_step: int = 1, ego_speed_time_constant_s: float = DT_S, **kwargs):
        """args, kwargs: SingleEnvBackend's (scenario, traffic, adversarial, seed, style, num_vehicles, max_steps)."""
        if not isinstance(frames_per_step, int) or frames_per_step < 1:
            raise ValueError(f"frames_per_step must be a positive integer, got {frames_per_step!r}")
        if not ego_speed_time_constant_s > 0:
            raise ValueError(f"ego_speed_time_constant_s must be positive, got {ego_speed_time_constant_s!r}")
        self.frames_per_step = frames_per_step
        self.ego_speed_gain = 1.0 / ego_speed_time_constant_s
        super().__init__(*args, **kwargs)

    def _open(self) -> None:
        import highway_env  # noqa: F401 - registers the environments; ImportError names the missing extra

        from highway_env.vehicle.behavior import IDMVehicle
        from highway_env.vehicle.controller import ControlledVehicle

        self._IDMVehicle, self._ControlledVehicle = IDMVehicle, ControlledVehicle
        self.env = _env_class(self.scenario)(config=env_config(self.scenario, self.max_steps, self.frames_per_step))
        self._vehicles: list = []

    # ------------------------------------------------------------------ road
    def _build_lane_table(self) -> None:
        net = self.env.unwrapped.road.network
        mainline = self.road.mainline_lanes
        self._lanes: dict[tuple, _LaneInfo] = {}
        for _from, to_dict in net.graph.items():
            for _to, lanes in to_dict.items():
                for i, lane in enumerate(lanes):
                    ours = i if len(lanes) > 1 else mainline  # one-lane roads are ramps: our lane 2
                    x0 = float(lane.position(0.0, 0.0)[0]) - X_SHIFT_M
                    self._lanes[(_from, _to, i)] = _LaneInfo((_from, _to, i), lane, ours, x0, x0 + float(lane.length))

    def _lane_at(self, x: float, lane: int) -> _LaneInfo | None:
        best = None
        for info in self._lanes.values():
            if info.ours == lane and info.x0 <= x < info.x1:
                # prefer the lane that starts last (the merge's parallel lane over its approach, etc.)
                if best is None or info.x0 > best.x0:
                    best = info
        return best

    def _place(self, veh, x: float, lane: int, v: float) -> bool:
        info = self._lane_at(x, lane)
        if info is None:
            return False
        s = x - info.x0
        veh.position = np.array(info.lane.position(s, 0.0), dtype=float)
        veh.heading = float(info.lane.heading_at(s))
        veh.speed = float(v)
        veh.lane_index, veh.lane = info.index, info.lane
        veh.target_lane_index = info.index
        veh.crashed, veh.impact = False, None
        return True

    # ------------------------------------------------------------------ episodes
    def _spawn_episode(self) -> None:
        core = self._core
        env = self.env.unwrapped
        env.reset(seed=core.seed * 1_000_003 + core.episode)
        road = env.road
        road.vehicles.clear()
        self._build_lane_table()
        road.neighbour_vehicles = _ConnectedNeighbours(road, self._lanes)
        if self.road.spec.highway_env_kind == "merge":
            # highway-env's wall at the end of the on-ramp is a 2 m box centred on the lane end; ours is a wall
            # whose face is the lane end: move the box forward by half its length
            end = self._lane_at(MERGE_X["x2"] - 1.0, 2)
            for obj in road.objects:
                obj.position = np.array(end.lane.position(end.lane.length + 0.5 * obj.LENGTH, 0.0), dtype=float)
        init = core.initial
        self._vehicles = []
        ego = self._ControlledVehicle(road, np.zeros(2), 0.0, 0.0)
        self._place(ego, float(init["x"][0]), int(init["lane"][0]), float(init["v"][0]))
        ego.target_speed = float(init["v"][0])
        ego.KP_A = self.ego_speed_gain
        self._vehicles.append(ego)
        for j in range(1, core.num_vehicles):
            sv = self._IDMVehicle(road, np.zeros(2), 0.0, 0.0)
            self._configure_sv(sv, j)
            if not self._place(sv, float(init["x"][j]), int(init["lane"][j]), float(init["v"][j])):
                self._park(sv)
            self._vehicles.append(sv)
        road.vehicles.extend(self._vehicles)
        env.vehicle = ego
        env.time = env.steps = 0
        self._read_frame()

    def _park(self, veh) -> None:
        """Outside the road's x range: put it far behind, the recycling brings it back."""
        self._place(veh, self._lanes_min_x() + 1.0, 0, 0.0)

    def _lanes_min_x(self) -> float:
        return min(i.x0 for i in self._lanes.values() if i.ours == 0)

    def _configure_sv(self, sv, j: int) -> None:
        """Our traffic model on a highway-env IDMVehicle: IDM parameters, Table 3 style, MOBIL parameters."""
        core = self._core
        style = STYLES[int(core.style_of[j])]
        sv.COMFORT_ACC_MAX = IDM_ACCEL_MPS2
        sv.COMFORT_ACC_MIN = -IDM_COMFORT_BRAKE_MPS2
        sv.ACC_MAX = SV_BRAKE_LIMIT_MPS2
        sv.DISTANCE_WANTED = float(core.s0[j]) + VEHICLE_LENGTH_M  # its gaps are centre to centre
        sv.TIME_WANTED = IDM_TIME_HEADWAY_S
        sv.DELTA = IDM_DELTA
        sv.POLITENESS = MOBIL_POLITENESS
        sv.LANE_CHANGE_MIN_ACC_GAIN = MOBIL_THRESHOLD_MPS2
        sv.LANE_CHANGE_MAX_BRAKING_IMPOSED = MOBIL_SAFE_BRAKE_MPS2
        sv.target_speed = float(core.v0[j])
        sv.route = None
        sv.enable_lane_change = bool(style.lane_change) and core.intent(j) == NO_INTENT

    # ------------------------------------------------------------------ stepping (SingleEnvBackend's hooks)
    def _simulate(self) -> tuple[bool, int]:
        core, env = self._core, self.env.unwrapped
        ego = self._vehicles[0]
        self._mandatory_changes()
        crashed_before = [v.crashed for v in self._vehicles]
        dt = 1.0 / env.config["simulation_frequency"]
        for _ in range(self.frames_per_step):
            env.road.act()
            env.road.step(dt)
            env.steps += 1
            for sv in self._vehicles[1:]:  # its IDM lets a stopped vehicle roll backwards; ours never reverse
                if sv.speed < 0.0:
                    sv.speed = 0.0
        env.time += DT_S
        self._read_frame()
        f = self._frame
        new_crash = [v.crashed and not before for v, before in zip(self._vehicles, crashed_before)]
        collision = bool(ego.crashed) or core.ego_collision(f, with_vehicles=False)
        sv_collisions = max(sum(new_crash[1:]) - (1 if new_crash[0] else 0), 0)
        return collision, sv_collisions

    def _release(self, j: int) -> None:
        core = self._core
        self._vehicles[j].enable_lane_change = bool(core.lane_change[j]) and core.intent(j) == NO_INTENT

    def _move(self, mv: Move) -> None:
        sv = self._vehicles[mv.index]
        if not self._place(sv, mv.x, mv.lane, mv.v):
            self._park(sv)
        sv.enable_lane_change = bool(self._core.lane_change[mv.index]) and mv.intent == NO_INTENT

    def _after_moves(self) -> None:
        self._read_frame()

    def _command_ego(self, target: int, speed: float) -> None:
        ego = self._vehicles[0]
        v = float(self._frame.v[0])
        ego.target_speed = min(max(speed, v - EGO_BRAKE_MAX_MPS2 * DT_S), v + EGO_ACCEL_MAX_MPS2 * DT_S)
        road_id = ego.lane_index[:2]
        want = self._index_on_road(road_id, target)
        if want is not None and want != ego.target_lane_index:
            ego.target_lane_index = want

    def _index_on_road(self, road_id: tuple, lane: int) -> tuple | None:
        for info in self._lanes.values():
            if info.index[:2] == road_id and info.ours == lane:
                return info.index
        return None

    def _cut_in(self, j: int, lane: int) -> None:
        sv = self._vehicles[j]
        want = self._index_on_road(sv.lane_index[:2], lane)
        if want is not None:
            sv.target_lane_index = want
            sv.enable_lane_change = False  # no MOBIL second thoughts during the cut-in

    def _mandatory_changes(self) -> None:
        """Merging and exiting SVs move towards the ramp lane when the gap is safe (our MOBIL's mandatory
        part; highway-env's MOBIL has none)."""
        core = self._core
        f = self._frame
        for j in range(1, core.num_vehicles):
            intent = core.intent(j)
            if intent == NO_INTENT or core.forced(j):
                continue
            sv = self._vehicles[j]
            if sv.lane_index != sv.target_lane_index or sv.crashed:
                continue
            lane = int(f.lane[j])
            to = lane - 1 if intent == MERGE_INTENT and lane >= self.road.mainline_lanes else (
                lane + 1 if intent == EXIT_INTENT and lane < 2 else None)
            if to is None or not core.can_change(f.x[j], lane, to):
                continue
            want = self._index_on_road(sv.lane_index[:2], to)
            if want is not None and self._safe_change(sv, want):
                sv.target_lane_index = want

    @staticmethod
    def _safe_change(sv, lane_index) -> bool:
        front, rear = sv.road.neighbour_vehicles(sv, lane_index)
        lane = sv.road.network.get_lane(lane_index)
        s = lane.local_coordinates(sv.position)[0]
        if front is not None and lane.local_coordinates(front.position)[0] - s - VEHICLE_LENGTH_M <= MIN_CHANGE_GAP_M:
            return False
        if rear is not None:
            if s - lane.local_coordinates(rear.position)[0] - VEHICLE_LENGTH_M <= MIN_CHANGE_GAP_M:
                return False
            if sv.acceleration(ego_vehicle=rear, front_vehicle=sv) < -MOBIL_SAFE_BRAKE_MPS2:
                return False
        return True

    def _read_frame(self) -> None:
        f = self._frame
        w = LANE_WIDTH_M
        for j, veh in enumerate(self._vehicles):
            info = self._lanes.get(tuple(veh.lane_index))
            if info is None:  # not on one of the lanes we know: far away, the recycling brings it back
                f.x[j], f.present[j] = 1e9, j > 0
                continue
            s, lat = info.lane.local_coordinates(veh.position)
            scale = w / info.lane.width_at(s)
            h = math.remainder(veh.heading - info.lane.heading_at(s), math.tau)
            cx, cy = math.cos(h), math.sin(h) * scale  # body direction in our (laterally scaled) frame
            f.x[j] = info.x0 + s
            f.y[j] = (info.ours + lat / info.lane.width_at(s)) * w
            f.v[j], f.heading[j] = veh.speed * math.hypot(cx, cy), math.atan2(cy, cx)
            tgt = self._lanes.get(tuple(veh.target_lane_index)) if hasattr(veh, "target_lane_index") else None
            f.target_lane[j] = tgt.ours if tgt is not None else -1
            f.present[j] = True
        f.lane[:] = self._core.lane_of(f.y)
        f.target_lane[:] = np.where(f.target_lane < 0, f.lane, f.target_lane)

    def close(self) -> None:
        self.env.close()
