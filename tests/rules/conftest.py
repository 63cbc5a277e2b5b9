"""Fixtures of the rules tests.

hand_world: a hand-built stand-in for the simulator's world: B scenes of an ego and a few SVs, no dynamics.

neighbours() picks, per env, the nearest SV ahead and behind (centre x) in the queried lanes, lane
membership by the nearest lane centre (or by_body: every lane its rotated box reaches into), within d_max;
it records every query by centre it answers.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))  # table_1 (the golden Table 1) importable by name

from highway_srl.constants import D_MAX_M, VEHICLE_LENGTH_M, VEHICLE_WIDTH_M
from highway_srl.sim.road import Road
from highway_srl.sim.snapshot import NO_VEHICLE, Snapshot


class HandWorld:
    def __init__(self, road: Road, scenes: list[dict]):
        """scenes[b] = {"ego": (x, y, v, heading), "svs": [(x, y, v, heading), ...]}."""
        self.road = road
        self.scenes = scenes
        self.num_envs = len(scenes)
        self.queries: list[tuple[list[int], list[int]]] = []

    @property
    def ego_lane(self) -> torch.Tensor:
        return torch.tensor([self._lane(s["ego"][1]) for s in self.scenes])

    def _lane(self, y: float) -> int:
        return max(0, min(self.road.num_lanes - 1, round(y / self.road.lane_width_m)))

    def _in(self, sv, lane: int, by_body: bool) -> bool:
        """The SV is in the lane by its centre, or by_body where its rotated box reaches into the lane's strip."""
        if not by_body:
            return self._lane(sv[1]) == lane
        half = 0.5 * VEHICLE_WIDTH_M * abs(math.cos(sv[3])) + 0.5 * VEHICLE_LENGTH_M * abs(math.sin(sv[3]))
        w = self.road.lane_width_m
        return sv[1] + half > (lane - 0.5) * w and sv[1] - half < (lane + 0.5) * w

    def neighbours(self, current_lane: torch.Tensor, adjacent_lane: torch.Tensor, by_body: bool = False) -> Snapshot:
        if not by_body:  # `queries` keeps the ID mapping's asks (by centre)
            self.queries.append((current_lane.tolist(), adjacent_lane.tolist()))
        rows = []
        for b, scene in enumerate(self.scenes):
            ex, ey, ev, eh = scene["ego"]
            slots = []
            for lane in (int(current_lane[b]), int(adjacent_lane[b])):
                cand = [(i, sv) for i, sv in enumerate(scene["svs"])
                        if lane >= 0 and self._in(sv, lane, by_body) and abs(sv[0] - ex) <= D_MAX_M]
                ahead = min((c for c in cand if c[1][0] > ex), key=lambda c: c[1][0], default=None)
                behind = max((c for c in cand if c[1][0] <= ex), key=lambda c: c[1][0], default=None)
                slots.append((ahead, behind))
            order = (slots[0][0], slots[1][0], slots[0][1], slots[1][1])
            rows.append((scene["ego"], order))
        f = lambda v: torch.tensor(v, dtype=torch.float32)  # noqa: E731
        def sv_field(k):
            return f([[(sv[1][k] if sv else 0.0) for sv in order] for _, order in rows])

        sv_v, sv_h = sv_field(2), sv_field(3)
        return Snapshot(
            ego_x=f([e[0] for e, _ in rows]),
            ego_y=f([e[1] for e, _ in rows]),
            ego_vx=f([e[2] * math.cos(e[3]) for e, _ in rows]),
            ego_vy=f([e[2] * math.sin(e[3]) for e, _ in rows]),
            ego_heading=f([e[3] for e, _ in rows]),
            ego_lane=self.ego_lane,
            sv_x=sv_field(0),
            sv_y=sv_field(1),
            sv_vx=sv_v * torch.cos(sv_h),
            sv_vy=sv_v * torch.sin(sv_h),
            sv_heading=sv_h,
            sv_valid=torch.tensor([[sv is not None for sv in order] for _, order in rows]),
            sv_index=torch.tensor([[sv[0] + 1 if sv else NO_VEHICLE for sv in order] for _, order in rows]),
            current_lane=current_lane.clone(),
            adjacent_lane=adjacent_lane.clone(),
        )


@pytest.fixture
def hand_world():
    """The HandWorld class: hand_world(road, scenes)."""
    return HandWorld
