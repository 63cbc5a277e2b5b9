"""Episode bookkeeping that the one-env backends (SUMO, highway-env) share with our World.

A backend moves vehicles with its own simulator and reports, after every step, where they are in our
Frenet frame (sim/road.py) as a `Frame`. Everything the paper defines on top of the motion is done by our
World's own functions, run on a one-env WorldState that mirrors the backend's frame, so that a seed and
an event mean the same on every backend and follow any change to World's semantics:

- the initial placement: sim/spawn.spawn (same vehicles, styles, headways, speeds per seed and episode);
- which commanded ego lane changes are accepted: LaneTables.can_change;
- the adversarial cut-in trigger and its random draw: adversary.cut_ins_ahead_with_room;
- keeping the flow centred on the ego: recycle.recycle (who moves, to which lane, where, how fast);
- the ego's collisions (boxes, lane ends, change windows, road edges): collisions_and_stages.ego_collision;
- stage flags and success / failure events: collisions_and_stages.stage_events; termination and truncation as World;
- the neighbour snapshot: snapshot.ego_neighbours, the function behind World.neighbours.

The backend turns the results into commands for its simulator (a forced lane change, a vehicle moved).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from highway_srl.constants import (
    D_MAX_M,
    EPISODE_STEPS,
    STYLE_NAMES,
    TRAFFIC_LEVELS,
)
from highway_srl.scenarios import scenario_spec
from highway_srl.sim.adversary import cut_ins_ahead_with_room
from highway_srl.sim.collisions_and_stages import ego_collision, stage_events
from highway_srl.sim.ego import HOLD_LANE
from highway_srl.sim.events import StageFlags, StepEvents
from highway_srl.sim.lane_tables import LaneTables
from highway_srl.sim.recycle import recycle
from highway_srl.sim.road import Road, make_road
from highway_srl.sim.snapshot import Snapshot, ego_neighbours
from highway_srl.sim.spawn import Layout, make_layout, spawn
from highway_srl.sim.state import WorldState
from highway_srl.sim.sv_drivers import CENTRED_M, find_neighbours

FAR_M = 1.0e9  # x of a vehicle that is not on the road right now (never within d_max of anything)


@dataclass
class Frame:
    """Vehicles in our Frenet frame: centres (m), speed along the heading (m/s), heading (rad, + = right).

    All (N,), vehicle 0 = ego. lane: the lane whose centre is nearest; target_lane: the lane a vehicle is
    changing into (= lane when it is not changing). present: False for an SV the simulator does not show
    right now (moved for re-entry and not yet re-inserted); x then holds where it will enter, and the
    snapshot does not see it.
    """

    x: np.ndarray
    y: np.ndarray
    v: np.ndarray
    heading: np.ndarray
    lane: np.ndarray
    target_lane: np.ndarray
    present: np.ndarray

    @staticmethod
    def empty(n: int) -> "Frame":
        z = lambda dt: np.zeros(n, dt)  # noqa: E731
        return Frame(np.full(n, FAR_M), z(float), z(float), z(float), z(np.int64), z(np.int64), z(bool))


@dataclass
class Move:
    """An SV that leaves the window around the ego and re-enters at its other end."""

    index: int  # vehicle index (1..N-1)
    x: float  # new centre
    lane: int
    v: float
    intent: int


def validate(scenario: str, traffic: str, style: str | None, num_vehicles: int | None, max_steps: int,
             max_vehicles: int = 63) -> int:
    """Check the arguments every backend shares (same messages as World); returns the number of SVs."""
    scenario_spec(scenario)  # raises the one-line error naming the scenarios
    if traffic not in TRAFFIC_LEVELS:
        raise ValueError(f"unknown traffic level {traffic!r}; choose one of {', '.join(TRAFFIC_LEVELS)}")
    if style is not None and style not in STYLE_NAMES:
        raise ValueError(f"unknown driving style {style!r}; choose one of {', '.join(STYLE_NAMES)} or none")
    m = TRAFFIC_LEVELS[traffic].num_vehicles if num_vehicles is None else num_vehicles
    if not isinstance(m, int) or m < 1 or m > max_vehicles:
        raise ValueError(f"num_vehicles must be between 1 and {max_vehicles}, got {m!r}")
    if not isinstance(max_steps, int) or max_steps < 1:
        raise ValueError(f"max_steps must be a positive integer, got {max_steps!r}")
    return m


class EpisodeCore:
    """The paper's episode logic for one env, driven by a backend that supplies Frames."""

    def __init__(self, scenario: str, traffic: str, adversarial: bool, seed: int, style: str | None = None,
                 num_vehicles: int | None = None, max_steps: int = EPISODE_STEPS):
        m = validate(scenario, traffic, style, num_vehicles, max_steps)
        if not isinstance(seed, int) or isinstance(seed, bool):
            raise ValueError(f"seed must be an int, got {seed!r}")
        self.scenario, self.traffic, self.adversarial = scenario, traffic, bool(adversarial)
        self.road: Road = make_road(scenario)
        self.level = TRAFFIC_LEVELS[traffic]
        self.layout: Layout = make_layout(self.road, self.level, m)
        self.num_vehicles = m + 1
        self.max_steps = max_steps
        self.style = None if style is None else STYLE_NAMES.index(style)
        self.tables = LaneTables.of(self.road, "cpu")
        self.seed, self.episode = seed, 0
        self.new_episode(0)

    # ------------------------------------------------------------------ episodes
    def new_episode(self, episode: int, seed: int | None = None) -> None:
        """Draw episode `episode` of the seed exactly as World's spawn does."""
        if seed is not None:
            if not isinstance(seed, int) or isinstance(seed, bool):
                raise ValueError(f"seed must be an int, got {seed!r}")
            self.seed = seed
        self.episode = int(episode)
        self.ws: WorldState = spawn(self.road, self.level, self.layout, torch.tensor([self.seed]),
                                    torch.tensor([self.episode]), self.style)
        a = lambda t: t[0].numpy().copy()  # noqa: E731
        self.initial = {"x": a(self.ws.x).astype(np.float64), "lane": a(self.ws.lane),
                        "v": a(self.ws.v).astype(np.float64)}
        self.style_of = a(self.ws.style)
        self.v0 = a(self.ws.v0).astype(np.float64)
        self.s0 = a(self.ws.s0).astype(np.float64)
        self.lane_change = a(self.ws.lane_change)
        self.forced_lane = np.zeros(self.num_vehicles, np.int64)
        self.ego_target_lane = int(self.ws.lane[0, 0])

    @property
    def t(self) -> int:
        return int(self.ws.t[0])

    def intent(self, j: int) -> int:
        return int(self.ws.intent[0, j])

    def forced(self, j: int) -> bool:
        return bool(self.ws.forced[0, j])

    # ------------------------------------------------------------------ the mirror
    def sync(self, frame: Frame) -> WorldState:
        """Write the backend's frame into the one-env WorldState that World's functions read."""
        ws = self.ws
        f32 = lambda a: torch.from_numpy(np.asarray(a, np.float32))[None]  # noqa: E731
        ws.x, ws.y, ws.v, ws.heading = f32(frame.x), f32(frame.y), f32(frame.v), f32(frame.heading)
        ws.lane = torch.from_numpy(frame.lane.astype(np.int64))[None]
        target = frame.target_lane.astype(np.int64).copy()
        target[0] = self.ego_target_lane
        forced = ws.forced[0].numpy()
        target = np.where(forced, self.forced_lane, target)
        ws.target_lane = torch.from_numpy(target)[None]
        return ws

    def lane_of(self, y) -> np.ndarray:
        """Lane whose centre is nearest (World's rule), clamped to the road's lanes."""
        return np.clip(np.round(np.asarray(y) / self.road.lane_width_m), 0, self.road.num_lanes - 1).astype(np.int64)

    def lane_exists(self, lane: int, x: float) -> bool:
        return 0 <= lane < self.road.num_lanes and self.road.lane_start_m[lane] <= x < self.road.lane_end_m[lane]

    def can_change(self, x: float, lane: int, to: int) -> bool:
        """LaneTables.can_change for one vehicle: moving from lane to `to` is allowed at x."""
        return bool(self.tables.can_change(torch.tensor([float(x)]), torch.tensor([int(lane)]), torch.tensor([int(to)]))[0])

    def accept_ego_target(self, frame: Frame, target_lane: int) -> int:
        """World's rule: the ego takes a new target lane only if it is its lane or an allowed change. The
        lateral hold (HOLD_LANE) is the lane its centre is in here: the foreign simulators' lane-based
        controllers cannot stop a car between two lanes (docs/backends.md)."""
        lane = int(frame.lane[0])
        if target_lane == HOLD_LANE:
            target_lane = lane
        if target_lane == lane or self.can_change(frame.x[0], lane, target_lane):
            self.ego_target_lane = int(target_lane)
        return self.ego_target_lane

    # ------------------------------------------------------------------ adversarial cut-ins
    def adversarial_cut_ins(self, frame: Frame) -> list[int]:
        """SVs that start a forced cut-in into the ego's lane this step (adversary.cut_ins_ahead_with_room)."""
        if not self.adversarial:
            return []
        near = frame.present & (np.abs(frame.lane - frame.lane[0]) == 1) & (frame.x - frame.x[0] < D_MAX_M)
        near[0] = False
        if not (near & ~self.ws.trigger_used[0].numpy()).any():
            return []  # nothing can trigger; skips the tensor work on most steps
        ws = self.sync(frame)
        before = ws.forced.clone()
        cut_ins_ahead_with_room(ws, self.tables, find_neighbours(ws, self.road))
        fired = (ws.forced & ~before)[0].numpy() & frame.present
        self.forced_lane = np.where(fired, int(frame.lane[0]), self.forced_lane)
        return [int(i) for i in np.nonzero(fired)[0]]

    def release_forced(self, frame: Frame) -> list[int]:
        """Forced SVs that have arrived centred in their target lane (World clears `forced` then)."""
        forced = self.ws.forced[0].numpy()
        done = forced & (frame.lane == self.forced_lane) & (
            np.abs(frame.y - self.forced_lane * self.road.lane_width_m) < CENTRED_M)
        if done.any():
            self.ws.forced[0, torch.from_numpy(done)] = False
        return [int(i) for i in np.nonzero(done)[0]]

    # ------------------------------------------------------------------ keeping the flow centred on the ego
    def recycle(self, frame: Frame) -> list[Move]:
        """SVs that fell out of the window around the ego and where they re-enter (recycle.recycle)."""
        dx = np.abs(frame.x - frame.x[0])
        out = dx > self.layout.window_m + self.layout.margin_m  # World's reach: only beyond it does anyone move
        if self.road.spec.svs_may_exit:  # an SV at the off-ramp's end leaves the map
            out |= (frame.lane == 2) & (frame.x >= self.road.zones["off_ramp"][1])
        out[0] = False
        if not out.any():
            return []  # nobody is beyond the reach; skips the tensor work on most steps
        ws = self.sync(frame)
        x0, lane0, v0, intent0 = ws.x.clone(), ws.lane.clone(), ws.v.clone(), ws.intent.clone()
        recycle(ws, self.road, self.layout, self.level)
        moved = ((ws.x != x0) | (ws.lane != lane0) | (ws.v != v0) | (ws.intent != intent0))[0].numpy()
        moved[0] = False
        x, lane, v, intent = (t[0].numpy() for t in (ws.x, ws.lane, ws.v, ws.intent))
        return [Move(int(j), float(x[j]), int(lane[j]), float(v[j]), int(intent[j])) for j in np.nonzero(moved)[0]]

    # ------------------------------------------------------------------ ego events
    def ego_collision(self, frame: Frame, with_vehicles: bool = True) -> bool:
        """collisions_and_stages.ego_collision on this frame; with_vehicles=False checks only the corridor (lane ends,
        boundaries outside change windows, road edges), for a backend whose simulator checks contacts."""
        ws = self.sync(frame)
        if not with_vehicles:
            ws.x = ws.x.clone()
            ws.x[0, 1:] = FAR_M
        return bool(ego_collision(ws, self.road, self.tables, find_neighbours(ws, self.road))[0])

    def finish_step(self, frame: Frame, collision: bool, sv_collisions: int, ego_gone: bool = False) -> StepEvents:
        """Stage events, termination and truncation of the step just simulated (after recycling); advances t."""
        ws = self.sync(frame)
        success, failure = stage_events(ws, self.road)
        success, failure = bool(success[0]), bool(failure[0])
        ws.t += 1
        terminated = collision or failure or (success and self.road.spec.success_terminates)
        truncated = (self.t >= self.max_steps or ego_gone) and not terminated
        b = lambda v: torch.tensor([bool(v)])  # noqa: E731
        return StepEvents(b(collision), b(success), b(failure), b(terminated), b(truncated),
                          torch.tensor([int(sv_collisions)]))

    def stage_flags(self) -> StageFlags:
        ws = self.ws
        return StageFlags(ws.merged.clone(), ws.exit1.clone(), ws.exit2.clone())

    # ------------------------------------------------------------------ the snapshot
    def snapshot(self, frame: Frame, current_lane, adjacent_lane, d_max: float = D_MAX_M, by_body: bool = False) -> Snapshot:
        """World.neighbours' function run on this frame: the same slots, lane membership, lane-end obstacles;
        SVs the simulator does not show right now are out of sight."""
        x = np.where(frame.present, frame.x, FAR_M)
        x[0] = frame.x[0]
        ws = replace(self.sync(frame), x=torch.from_numpy(np.asarray(x, np.float32))[None])
        cur = torch.as_tensor(current_lane).long().reshape(1)
        adj = torch.as_tensor(adjacent_lane).long().reshape(1)
        return ego_neighbours(ws, self.road, self.tables, cur, adj, d_max, by_body)


class FrameQueries:
    """The Backend protocol's queries, answered from a backend's `_frame` and `_core` (SUMO and highway-env)."""

    _frame: Frame
    _core: EpisodeCore

    @property
    def frame(self) -> Frame:
        """The vehicles after the last step in our Frenet frame (read-only use; vehicle 0 = ego)."""
        return self._frame

    @property
    def episode(self) -> int:
        return self._core.episode

    @property
    def seed(self) -> int:
        return self._core.seed

    @property
    def ego_lane(self) -> torch.Tensor:
        return torch.tensor([int(self._frame.lane[0])])

    @property
    def ego_speed(self) -> torch.Tensor:
        return torch.tensor([float(self._frame.v[0])], dtype=torch.float32)

    @property
    def state(self) -> WorldState:
        """The current scene as a one-env WorldState (for renderings; read-only use)."""
        return self._core.sync(self._frame)

    def stage_flags(self) -> StageFlags:
        return self._core.stage_flags()

    def neighbours(self, current_lane: torch.Tensor, adjacent_lane: torch.Tensor, d_max: float = D_MAX_M,
                   by_body: bool = False) -> Snapshot:
        """SV1..SV4 of the ego with World.neighbours' semantics (vehicle centres; lanes by centre or by_body)."""
        return self._core.snapshot(self._frame, current_lane, adjacent_lane, d_max, by_body)
