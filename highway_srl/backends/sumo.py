"""Eclipse SUMO behind our Backend interface (one env; libsumo runs one simulation per process).

SUMO moves every vehicle: the surrounding traffic with its IDM car-following model and LC2013 lane
changes (continuous, --lanechange.duration), the ego through TraCI commands (setSpeed, changeLane) with
SUMO's safety checks switched off so that it can crash. What the paper defines on top of the motion
(initial placement, adversarial trigger, recycling, stage events, the snapshot) is backends/bookkeeping.py,
shared with highway-env and equal to our World's.

Frame: the networks (backends/sumo_networks.py) put SUMO's X on our x and our lane k's centre at
SUMO Y = -(k + 1/2) w_L, so y = -Y - w_L/2. SUMO reports the front bumper; we report centres
(x = X - L/2: SUMO keeps a vehicle's body along its lane, also during a continuous lane change).
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import torch

from highway_srl.constants import (
    D_MAX_M,
    DT_S,
    EGO_ACCEL_MAX_MPS2,
    EGO_BRAKE_MAX_MPS2,
    STYLES,
    V_MAX_MPS,
    VEHICLE_LENGTH_M,
    VEHICLE_WIDTH_M,
)
from highway_srl.backends.base import SingleEnvBackend
from highway_srl.backends.bookkeeping import FAR_M, Move
from highway_srl.backends.sumo_networks import EdgeSpec, edges_of, links_of, network_path, sumo_binary
from highway_srl.sim.dynamics import HEADING_MAX_RAD
from highway_srl.sim.snapshot import Snapshot
from highway_srl.sim.state import EXIT_INTENT
from highway_srl.sim.idm_mobil import IDM_ACCEL_MPS2, IDM_COMFORT_BRAKE_MPS2, IDM_DELTA, IDM_TIME_HEADWAY_S, SV_BRAKE_LIMIT_MPS2

LANE_CHANGE_DURATION_S = 2.5  # our lateral controller takes about 2.5 s for a lane change at 8 m/s
EGO_SPEED_MODE = 6  # respect max acceleration and deceleration only: no safe speed, no right of way
EGO_LANE_CHANGE_MODE = 0  # no lane change of its own, and TraCI's requests are carried out regardless of others
SV_LANE_CHANGE_MODE = 1621  # SUMO's default
FORCED_LANE_CHANGE_MODE = 0  # an adversarial cut-in ignores the safety of others
EGO_ID = "ego"
# Lane-change eagerness per style (LC2013); the normal style makes strategic changes only (to stay on its
# route), as our normal style changes only to merge or exit.
LC_PARAMS = {
    "aggressive": {"lcSpeedGain": "2.0", "lcAssertive": "1.5", "lcCooperative": "0.5"},
    "normal": {"lcSpeedGain": "0", "lcCooperative": "0"},
    "cautious": {"lcSpeedGain": "0.5", "lcAssertive": "1.0", "lcCooperative": "1.0"},
}

_LIBSUMO_OWNER: "SumoBackend | None" = None


def sumo_options(net: Path, additional: Path, seed: int) -> list[str]:
    """The command line of one simulation (without the binary)."""
    return [
        "-n", str(net), "-a", str(additional),
        "--step-length", str(DT_S),
        "--step-method.ballistic", "true",  # x += (v + v') / 2 dt, as our World integrates
        "--lanechange.duration", str(LANE_CHANGE_DURATION_S),
        "--collision.action", "warn",
        "--collision.mingap-factor", "0",
        "--collision.check-junctions", "true",
        "--insertion-checks", "none",  # vehicles enter exactly where and as fast as our spawn says
        "--time-to-teleport", "-1",
        "--seed", str(seed),
        "--no-step-log", "true",
        "--no-warnings", "true",
        "--duration-log.disable", "true",
    ]


def _additional_xml(scenario: str) -> str:
    """vTypes (ego and the three styles of Table 3) and a route from every edge to every exit."""
    t = []
    t.append(
        f'  <vType id="ego" length="{VEHICLE_LENGTH_M}" width="{VEHICLE_WIDTH_M}" minGap="0" '
        f'accel="{EGO_ACCEL_MAX_MPS2}" decel="{EGO_BRAKE_MAX_MPS2}" emergencyDecel="{EGO_BRAKE_MAX_MPS2}" '
        f'maxSpeed="{V_MAX_MPS}" speedFactor="1" speedDev="0" carFollowModel="IDM" tau="{IDM_TIME_HEADWAY_S}"/>'
    )
    for s in STYLES:
        lc = " ".join(f'{k}="{v}"' for k, v in LC_PARAMS[s.name].items())
        t.append(
            f'  <vType id="{s.name}" length="{VEHICLE_LENGTH_M}" width="{VEHICLE_WIDTH_M}" '
            f'minGap="{s.desired_headway_m}" accel="{IDM_ACCEL_MPS2}" decel="{IDM_COMFORT_BRAKE_MPS2}" '
            f'emergencyDecel="{SV_BRAKE_LIMIT_MPS2}" maxSpeed="{2 * V_MAX_MPS}" '
            f'speedFactor="{1 + s.speed_violation:.3f}" speedDev="0" carFollowModel="IDM" '
            f'tau="{IDM_TIME_HEADWAY_S}" delta="{IDM_DELTA}" lcKeepRight="0" {lc}/>'
        )
    for rid, edges in routes_of(scenario).items():
        t.append(f'  <route id="{rid}" edges="{" ".join(edges)}"/>')
    return "<additional>\n" + "\n".join(t) + "\n</additional>\n"


def routes_of(scenario: str) -> dict[str, list[str]]:
    """Route id 'start>end' -> edges, for every edge and every edge reachable from it without successor."""
    nxt: dict[str, list[str]] = {e.id: [] for e in edges_of(scenario)}
    for fe, _, te, _ in links_of(scenario):
        if te not in nxt[fe]:
            nxt[fe].append(te)
    routes = {}

    def walk(path: list[str]) -> None:
        if not nxt[path[-1]]:
            routes[f"{path[0]}>{path[-1]}"] = list(path)
        for e in nxt[path[-1]]:
            walk(path + [e])

    for e in nxt:
        walk([e])
    return routes


class SumoBackend(SingleEnvBackend):
    """One SUMO simulation of a scenario behind the Backend protocol (num_envs = 1, CPU).

    api: "libsumo" (in-process, fast; one simulation per process: starting a second SumoBackend closes the
    first) or "traci" (a sumo process per backend over a socket; several per process, about 30x slower).
    """

    def __init__(self, *args, api: str = "libsumo", **kwargs):
        """args, kwargs: SingleEnvBackend's (scenario, traffic, adversarial, seed, style, num_vehicles, max_steps)."""
        if api not in ("libsumo", "traci"):
            raise ValueError(f"unknown SUMO api {api!r}; choose libsumo or traci")
        self._api_name = api
        super().__init__(*args, **kwargs)

    # ------------------------------------------------------------------ process
    def _open(self) -> None:
        scenario = self.scenario
        self._edges: dict[str, EdgeSpec] = {e.id: e for e in edges_of(scenario)}
        self._mainline_end = next(e.id for e in edges_of(scenario) if e.first_lane == 0 and e.x_to == max(
            f.x_to for f in edges_of(scenario) if f.first_lane == 0))
        self._tmp = tempfile.TemporaryDirectory(prefix="highway-srl-sumo-")
        additional = Path(self._tmp.name) / "types.add.xml"
        additional.write_text(_additional_xml(scenario))
        self._options = sumo_options(network_path(scenario), additional, self._core.seed)
        self._api = self._start(self._api_name)
        self._closed = False
        n = self._core.num_vehicles
        self._ids: list[str | None] = [None] * n
        self._generation = 0
        self._ego_gone = False
        self._ego_dest = ""

    def _start(self, api: str):
        global _LIBSUMO_OWNER
        if api == "libsumo":
            try:
                import libsumo
            except ImportError as e:  # pragma: no cover - the factory reports the extra
                raise ImportError("SumoBackend needs libsumo: pip install 'highway-srl[sumo]'") from e
            if _LIBSUMO_OWNER is not None and not _LIBSUMO_OWNER._closed:
                _LIBSUMO_OWNER.close()
            libsumo.start(["sumo", *self._options])
            _LIBSUMO_OWNER = self
            return libsumo
        import traci

        label = f"highway-srl-{id(self)}"
        traci.start([sumo_binary(), *self._options], label=label)
        return traci.getConnection(label)

    def close(self) -> None:
        """End the simulation (the backend cannot be used afterwards)."""
        global _LIBSUMO_OWNER
        if self._closed:
            return
        self._closed = True
        try:
            self._api.close()
        except Exception:  # noqa: BLE001 - already closed by SUMO itself
            pass
        if _LIBSUMO_OWNER is self:
            _LIBSUMO_OWNER = None
        self._tmp.cleanup()

    def __del__(self):  # pragma: no cover - best effort at interpreter exit
        try:
            self.close()
        except Exception:  # noqa: BLE001
            pass

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError("this SumoBackend is closed (libsumo runs one simulation per process: a newer "
                               "SumoBackend replaced it, or close() was called); create a new one or use api='traci'")

    # ------------------------------------------------------------------ geometry
    def _edge_at(self, x_front: float, lane: int) -> EdgeSpec | None:
        for e in self._edges.values():
            if e.first_lane <= lane < e.first_lane + e.lanes and e.x_from <= x_front < e.x_to:
                return e
        return None

    @staticmethod
    def _sumo_lane(e: EdgeSpec, lane: int) -> int:
        return e.lanes - 1 - (lane - e.first_lane)

    def _destination(self, lane: int, intent: int) -> str:
        off = self.road.spec.sumo_off_ramp_edge
        if off is not None and (intent == EXIT_INTENT or lane == self.road.mainline_lanes):
            return off
        return self._mainline_end

    def _add(self, j: int, x: float, lane: int, v: float, intent: int) -> None:
        """Put vehicle j (0 = ego) on the road with its centre at x in our lane `lane` (inserted next step)."""
        front = x + 0.5 * VEHICLE_LENGTH_M
        e = self._edge_at(front, lane)
        if e is None:  # off the network: park it far away; the recycling brings it back
            self._ids[j] = None
            return
        dest = self._destination(lane, intent)
        rid = f"{e.id}>{dest}"
        if rid not in routes_of(self.scenario):
            rid = f"{e.id}>{self._mainline_end}"
        if j == 0:
            vid, vtype = EGO_ID, "ego"
            self._ego_dest = rid.split(">")[1]
        else:
            self._generation += 1
            vid, vtype = f"sv{j}.{self._generation}", STYLES[int(self._core.style_of[j])].name
            # SUMO refuses to insert a vehicle faster than its own desired speed (speed factor x limit)
            v = min(v, float(self._core.v0[j]))
        self._api.vehicle.add(vid, rid, vtype, depart="now", departLane=str(self._sumo_lane(e, lane)),
                              departPos=f"{front - e.x_from:.4f}", departSpeed=f"{max(v, 0.0):.4f}")
        self._ids[j] = vid

    def _remove(self, j: int) -> None:
        vid = self._ids[j]
        if vid is not None:
            try:
                self._api.vehicle.remove(vid)
            except Exception:  # noqa: BLE001 - it already left the network
                pass
        self._ids[j] = None

    # ------------------------------------------------------------------ episodes
    def _spawn_episode(self) -> None:
        api = self._api
        for j in range(len(self._ids)):
            self._remove(j)
        for vid in api.vehicle.getIDList():
            api.vehicle.remove(vid)
        core = self._core
        init = core.initial
        for j in range(core.num_vehicles):
            self._add(j, float(init["x"][j]), int(init["lane"][j]), float(init["v"][j]), core.intent(j))
        api.simulationStep()  # inserts everybody where they belong; nobody moves in its insertion step
        api.vehicle.setSpeedMode(EGO_ID, EGO_SPEED_MODE)
        api.vehicle.setLaneChangeMode(EGO_ID, EGO_LANE_CHANGE_MODE)
        api.vehicle.setSpeed(EGO_ID, float(init["v"][0]))
        self._ego_gone = False
        self._read_frame()

    # ------------------------------------------------------------------ stepping (SingleEnvBackend's hooks)
    def _simulate(self) -> tuple[bool, int]:
        self._api.simulationStep()
        self._read_frame()
        collision, sv_collisions = self._collisions()
        if not self._ego_gone:
            collision |= self._core.ego_collision(self._frame)
        return collision, sv_collisions

    def _release(self, j: int) -> None:
        if self._ids[j] is not None:
            self._api.vehicle.setLaneChangeMode(self._ids[j], SV_LANE_CHANGE_MODE)

    def _move(self, mv: Move) -> None:
        f, j = self._frame, mv.index
        self._remove(j)
        self._add(j, mv.x, mv.lane, mv.v, mv.intent)
        f.x[j], f.y[j] = mv.x, mv.lane * self.road.lane_width_m
        f.v[j], f.heading[j], f.lane[j] = mv.v, 0.0, mv.lane
        f.target_lane[j] = mv.lane
        f.present[j] = False

    def _command_ego(self, target: int, speed: float) -> None:
        api, f = self._api, self._frame
        api.vehicle.setSpeed(EGO_ID, speed)
        lane = int(f.lane[0])
        edge = self._edges.get(api.vehicle.getRoadID(EGO_ID))
        if edge is None:
            return
        centred = abs(f.y[0] - lane * self.road.lane_width_m) < 0.05
        if target != lane and centred and edge.first_lane <= target < edge.first_lane + edge.lanes:
            api.vehicle.changeLane(EGO_ID, self._sumo_lane(edge, target), DT_S)
        if edge.id in self.road.spec.sumo_route_edges:
            dest = self._destination(lane, 0)
            if dest != self._ego_dest:
                api.vehicle.changeTarget(EGO_ID, dest)
                self._ego_dest = dest

    def _cut_in(self, j: int, to: int) -> None:
        api, vid = self._api, self._ids[j]
        if vid is None:
            return
        edge = self._edges.get(api.vehicle.getRoadID(vid))
        if edge is None or not edge.first_lane <= to < edge.first_lane + edge.lanes:
            return
        api.vehicle.setLaneChangeMode(vid, FORCED_LANE_CHANGE_MODE)
        api.vehicle.changeLane(vid, self._sumo_lane(edge, to), 2 * LANE_CHANGE_DURATION_S)

    def _read_frame(self) -> None:
        api, f = self._api, self._frame
        live = set(api.vehicle.getIDList())
        half_l, half_w = 0.5 * VEHICLE_LENGTH_M, 0.5 * self.road.lane_width_m
        for j, vid in enumerate(self._ids):
            if vid is None or vid not in live:
                if j == 0:
                    self._ego_gone = self._ego_gone or vid is None or vid not in live
                    continue
                if vid is not None:  # it left the network (end of its route): bring it back by recycling
                    f.x[j], f.present[j] = FAR_M, True
                    self._ids[j] = None
                continue
            px, py = api.vehicle.getPosition(vid)
            vx = api.vehicle.getSpeed(vid)
            vy = -api.vehicle.getLateralSpeed(vid)
            f.x[j], f.y[j] = px - half_l, -py - half_w
            # heading of the motion, but SUMO slides a vehicle sideways even at a standstill while its body
            # stays along the lane: cap it at our lateral controller's largest heading; v keeps v_x exact
            h = max(-HEADING_MAX_RAD, min(HEADING_MAX_RAD, math.atan2(vy, max(vx, 1e-6))))
            f.v[j], f.heading[j] = vx / math.cos(h), h
            f.present[j] = True
        f.lane[:] = self._core.lane_of(f.y)
        # a vehicle in a lane change (off its lane centre, moving sideways) targets the lane it moves towards
        w = self.road.lane_width_m
        off = np.abs(f.y - f.lane * w) > 0.05
        toward = np.where(f.heading > 0, np.ceil(f.y / w), np.floor(f.y / w)).astype(np.int64)
        f.target_lane[:] = np.where(off & (np.abs(f.heading) > 1e-6), np.clip(toward, 0, self.road.num_lanes - 1), f.lane)

    def _collisions(self) -> tuple[bool, int]:
        ego, others = False, 0
        for c in self._api.simulation.getCollisions():
            if EGO_ID in (c.collider, c.victim):
                ego = True
            else:
                others += 1
        return ego, others

    # ------------------------------------------------------------------ queries
    def neighbours(self, current_lane: torch.Tensor, adjacent_lane: torch.Tensor, d_max: float = D_MAX_M,
                   by_body: bool = False) -> Snapshot:
        """SV1..SV4 of the ego with World.neighbours' semantics (vehicle centres; lanes by centre or by_body)."""
        self._check_open()
        return self._core.snapshot(self._frame, current_lane, adjacent_lane, d_max, by_body)

    @property
    def sumo(self):
        """The libsumo module or TraCI connection, for inspection."""
        return self._api
